//! Each block's loss masks ([`crate::scene::loss_masks`]): which cells of each of its training
//! views show what the block owns.
//!
//! A block's views also see other blocks' content; trained on all of it, the block explains
//! that content with Gaussians in its own region, and the merge keeps them as floaters. So
//! each view is cut into a [`CELLS`]×[`CELLS`] grid and a cell is learned when
//! - the nearest of the scene's SfM points projecting into it lies in the block's region (core
//!   and margin): the first surface a ray through the cell meets is the block's, as far as the
//!   points tell; and the cells around such a cell (one cell on every side), so that the
//!   block's Gaussians at its silhouette are held to the image there and cannot spill out;
//! - or no point projects into it (sky, a blank wall) and the ray through its centre, followed
//!   to the depth of the view's farthest point, ends over the block's region: the far content
//!   in that direction belongs to the block that owns the ground out there.
//!
//! Every other cell shows content that another block owns in front of anything of this one,
//! and is left to that block. A view into which no point projects learns every cell.

use super::grid::Rect;
use super::ground::GroundFrame;
use crate::scene::{Scene, View};

/// Cells along each side of a view.
pub const CELLS: u32 = 32;

/// At most this many of the scene's points are projected into each view (an even subsample).
const MAX_PROJECTED: usize = 200_000;

/// The cells of `view` that a block whose region is `region` learns (row-major,
/// [`CELLS`]×[`CELLS`]), from the scene's points `positions` and their ground coordinates
/// `ground_xy` (in the same frame as the view's pose).
pub fn view_mask(
    view: &View,
    positions: &[[f64; 3]],
    ground_xy: &[[f64; 2]],
    ground: &GroundFrame,
    region: &Rect,
) -> Vec<bool> {
    let n = CELLS as usize;
    let cam = &view.camera;
    let (w, h) = (cam.width as f64, cam.height as f64);
    // Per cell: the nearest point's depth and whether it lies in the region.
    let mut nearest: Vec<Option<(f64, bool)>> = vec![None; n * n];
    let mut farthest = 0.0f64;
    let step = positions.len().div_ceil(MAX_PROJECTED).max(1);
    for i in (0..positions.len()).step_by(step) {
        let c = view.pose.transform(positions[i]);
        if !(c[2] > 0.0 && c[2].is_finite()) {
            continue;
        }
        let [x, y] = cam.project(c);
        if !(x >= 0.0 && x < w && y >= 0.0 && y < h) {
            continue;
        }
        farthest = farthest.max(c[2]);
        let cell =
            ((y / h * n as f64) as usize).min(n - 1) * n + ((x / w * n as f64) as usize).min(n - 1);
        if nearest[cell].is_none_or(|(d, _)| c[2] < d) {
            nearest[cell] = Some((c[2], region.contains(ground_xy[i])));
        }
    }
    if farthest <= 0.0 {
        // No point in sight: nothing says whose the pixels are, so the block learns them all.
        return vec![true; n * n];
    }
    let owned: Vec<bool> = nearest
        .iter()
        .map(|c| matches!(c, Some((_, true))))
        .collect();
    let centre = view.pose.center();
    let r = view.pose.rotation;
    (0..n * n)
        .map(|cell| {
            let (cx, cy) = (cell % n, cell / n);
            let near_owned = (cy.saturating_sub(1)..=(cy + 1).min(n - 1))
                .any(|y| (cx.saturating_sub(1)..=(cx + 1).min(n - 1)).any(|x| owned[y * n + x]));
            if near_owned {
                return true;
            }
            if nearest[cell].is_some() {
                return false;
            }
            // The ray through the cell's centre, in the world: Rᵀ · ((x − cx)/fx, (y − cy)/fy, 1).
            let px = (cx as f64 + 0.5) / n as f64 * w;
            let py = (cy as f64 + 0.5) / n as f64 * h;
            let d = [(px - cam.cx) / cam.fx, (py - cam.cy) / cam.fy, 1.0];
            let world = [0, 1, 2].map(|k| (0..3).map(|j| r[j][k] * d[j]).sum::<f64>());
            let end = [0, 1, 2].map(|k| centre[k] + farthest * world[k]);
            region.contains(ground.coordinates(end).0)
        })
        .collect()
}

/// Every training view's mask of a block: `(view name, cells)` for the views of `names`, from
/// the scene's points and their ground coordinates `ground_xy`.
pub fn block_masks(
    scene: &Scene,
    ground: &GroundFrame,
    ground_xy: &[[f64; 2]],
    region: &Rect,
    names: &[String],
) -> Vec<(String, Vec<bool>)> {
    let positions: &[[f64; 3]] = scene.points.as_ref().map_or(&[], |p| &p.positions);
    let by_name: std::collections::HashMap<&str, &View> =
        scene.views.iter().map(|v| (v.name.as_str(), v)).collect();
    names
        .iter()
        .filter_map(|name| {
            let view = by_name.get(name.as_str())?;
            Some((
                name.clone(),
                view_mask(view, positions, ground_xy, ground, region),
            ))
        })
        .collect()
}

/// Writes `loss_masks.json` into every block folder of `plan` (under `out`), from the scene the
/// plan was made of; returns each block's mean learned share over its training views.
pub fn write_block_masks(
    out: &std::path::Path,
    plan: &super::plan::Plan,
    scene: &Scene,
) -> anyhow::Result<Vec<f64>> {
    anyhow::ensure!(
        scene
            .points
            .as_ref()
            .is_some_and(|p| !p.positions.is_empty()),
        "{}: --loss-masks tells each view's cells apart by the scene's SfM points, and it has \
         none. Fix: drop --loss-masks",
        scene.root.display()
    );
    // The points' ground coordinates, once for every block.
    let positions: &[[f64; 3]] = scene.points.as_ref().map_or(&[], |p| &p.positions);
    let ground_xy: Vec<[f64; 2]> = positions
        .iter()
        .map(|&p| plan.ground.coordinates(p).0)
        .collect();
    let mut shares = Vec::with_capacity(plan.blocks.len());
    for block in &plan.blocks {
        let masks = block_masks(
            scene,
            &plan.ground,
            &ground_xy,
            &block.region,
            &block.train_views,
        );
        let share = masks
            .iter()
            .map(|(_, c)| c.iter().filter(|&&b| b).count() as f64 / c.len() as f64)
            .sum::<f64>()
            / masks.len().max(1) as f64;
        shares.push(share);
        let json = crate::scene::loss_masks::to_json(CELLS, CELLS, &masks);
        let path = out
            .join(&block.folder)
            .join(crate::scene::loss_masks::LOSS_MASKS_FILE);
        crate::error::write_atomic(&path, |f| {
            use std::io::Write;
            f.write_all(json.to_string().as_bytes())?;
            Ok(())
        })?;
    }
    Ok(shares)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::partition::grid::Interval;
    use crate::scene::camera::{CameraModel, PinholeCamera, Pose};

    fn view() -> View {
        View {
            name: "v".into(),
            stem: "v".into(),
            image_path: "v.png".into(),
            source_model: CameraModel::Pinhole {
                fx: 64.0,
                fy: 64.0,
                cx: 64.0,
                cy: 64.0,
            },
            source_width: 128,
            source_height: 128,
            camera: PinholeCamera {
                fx: 64.0,
                fy: 64.0,
                cx: 64.0,
                cy: 64.0,
                width: 128,
                height: 128,
            },
            pose: Pose {
                rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                translation: [0.0; 3],
            },
            colmap_image_id: None,
            keypoints: None,
        }
    }

    /// A camera at the origin looking down +z (image y is world +y): a near wall at z = 2 in
    /// the lower left quarter of the image, a far wall at z = 10 across the lower half, nothing
    /// in the upper half. The ground is x (u) and z (v); block A owns x < 0, block B x ≥ 0.
    #[test]
    fn a_cell_goes_to_the_block_of_its_nearest_point_or_of_its_rays_far_end() {
        let mut positions = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                positions.push([-2.0 + 0.025 + 0.05 * i as f64, 0.025 + 0.05 * j as f64, 2.0]);
            }
        }
        for i in 0..67 {
            for j in 0..34 {
                positions.push([-10.0 + 0.15 + 0.3 * i as f64, 0.15 + 0.3 * j as f64, 10.0]);
            }
        }
        let ground = GroundFrame {
            origin: [0.0; 3],
            u: [1.0, 0.0, 0.0],
            v: [0.0, 0.0, 1.0],
            up: [0.0, -1.0, 0.0],
        };
        let xy: Vec<[f64; 2]> = positions.iter().map(|&p| ground.coordinates(p).0).collect();
        let a = Rect {
            u: Interval {
                lo: None,
                hi: Some(0.0),
            },
            v: Interval::ALL,
        };
        let b = Rect {
            u: Interval {
                lo: Some(0.0),
                hi: None,
            },
            v: Interval::ALL,
        };
        let n = CELLS as usize;
        let half = n / 2;
        let ma = view_mask(&view(), &positions, &xy, &ground, &a);
        let mb = view_mask(&view(), &positions, &xy, &ground, &b);
        for cy in 0..n {
            for cx in 0..n {
                let c = cy * n + cx;
                // A: its near wall and the sky to the left, and one cell past the wall's edge.
                let want_a = cx < half || (cx == half && cy + 1 >= half);
                // B: the far wall to the right and its sky, one cell past the wall's edge.
                let want_b = cx >= half || (cx + 1 == half && cy + 1 >= half);
                assert_eq!(ma[c], want_a, "A, cell ({cx}, {cy})");
                assert_eq!(mb[c], want_b, "B, cell ({cx}, {cy})");
            }
        }
        // No point in sight: nothing says whose the pixels are, so every cell is learned.
        let none = view_mask(&view(), &[[0.0, 0.0, -5.0]], &[[0.0, -5.0]], &ground, &b);
        assert!(none.iter().all(|&b| b));
    }
}
