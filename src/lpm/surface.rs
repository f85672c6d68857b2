//! Surface samples inside local zones: the SfM points a view observes in an error block's zone,
//! each a Gaussian to place on the surface the view renders badly (coloured from the ground
//! truth at the point's keypoint). MCMC moves some of its dead Gaussians onto them
//! (`--lpm-surface-share`) instead of stacking them on live ones: the guide then says not only
//! which existing Gaussians to copy but where the missing surface is.
//!
//! Size: the block's pixels are shared among its samples, each covering a disc of radius
//! `½ √(area / k)` pixels (`k` samples in a block of `area` pixels), taken to the world at the
//! point's distance from the camera through the focal length. It is relative to what the view
//! sees, never a world length.

use super::pairing::PixelBox;
use super::record::center_color;
use super::zones::Zone;
use crate::scene::{Image, View};
use crate::train::density::append::NewGaussian;

/// The samples of one zone: the points `world[i]` for `i` in `matched` (their keypoints
/// `xy[i]` in `view`) that lie inside `zone`, each an isotropic Gaussian of opacity `opacity`,
/// coloured by the ground-truth pixel under its keypoint (composited on `background` where the
/// image has alpha), sized by its share of `block` (see the module docs).
#[allow(clippy::too_many_arguments)] // the step's inputs, each used once
pub fn zone_samples(
    view: &View,
    zone: &Zone,
    block: &PixelBox,
    matched: &[u32],
    xy: &[[f32; 2]],
    world: &[[f64; 3]],
    gt: &Image,
    background: [f32; 3],
    opacity: f64,
) -> Vec<NewGaussian> {
    let inside: Vec<usize> = matched
        .iter()
        .map(|&i| i as usize)
        .filter(|&i| i < xy.len() && i < world.len())
        .filter(|&i| world[i].iter().all(|v| v.is_finite()) && zone.contains(world[i], 0.0))
        .collect();
    if inside.is_empty() {
        return Vec::new();
    }
    let area = ((block.x1 - block.x0) * (block.y1 - block.y0)).max(1.0);
    let radius_px = 0.5 * (area / inside.len() as f64).sqrt();
    let focal = 0.5 * (view.camera.fx + view.camera.fy);
    let apex = view.pose.center();
    inside
        .into_iter()
        .filter_map(|i| {
            let p = world[i];
            let d = ((0..3).map(|k| (p[k] - apex[k]).powi(2)).sum::<f64>()).sqrt();
            let scale = (d * radius_px / focal) as f32;
            if !(scale > 0.0 && scale.is_finite()) {
                return None;
            }
            let [x, y] = xy[i].map(|v| v as f64);
            let pixel = PixelBox {
                x0: x - 0.5,
                y0: y - 0.5,
                x1: x + 0.5,
                y1: y + 0.5,
            };
            Some(NewGaussian {
                position: p.map(|v| v as f32),
                scale,
                color: center_color(gt, &pixel, background),
                opacity,
                camera_center: apex.map(|v| v as f32),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::camera::{CameraModel, PinholeCamera, Pose};

    fn view() -> View {
        let camera = PinholeCamera {
            fx: 100.0,
            fy: 100.0,
            cx: 50.0,
            cy: 40.0,
            width: 100,
            height: 80,
        };
        View {
            name: "v".into(),
            stem: "v".into(),
            image_path: "v.png".into(),
            source_model: CameraModel::Pinhole {
                fx: 100.0,
                fy: 100.0,
                cx: 50.0,
                cy: 40.0,
            },
            source_width: 100,
            source_height: 80,
            camera,
            pose: Pose {
                rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                translation: [0.0; 3],
            },
            colmap_image_id: None,
            keypoints: None,
        }
    }

    fn image() -> Image {
        let (w, h) = (100u32, 80u32);
        let rgb = (0..w * h)
            .flat_map(|i| [(i % w) as f32 / w as f32, (i / w) as f32 / h as f32, 0.5])
            .collect();
        Image {
            width: w,
            height: h,
            rgb,
            alpha: None,
        }
    }

    #[test]
    fn only_points_inside_the_zone_become_samples_each_sized_by_its_share_of_the_block() {
        let v = view();
        // A box zone around z = 10 in front of the camera (which looks down +z).
        let zone = Zone::Box {
            min: [-5.0, -5.0, 9.0],
            max: [5.0, 5.0, 11.0],
        };
        let world = [
            [0.0, 0.0, 10.0],  // inside
            [0.0, 0.0, 20.0],  // behind the zone
            [1.0, -1.0, 10.5], // inside
            [f64::NAN, 0.0, 10.0],
        ];
        let xy = [[50.0, 40.0], [50.0, 40.0], [60.0, 30.0], [50.0, 40.0]];
        let block = PixelBox {
            x0: 40.0,
            y0: 30.0,
            x1: 72.0,
            y1: 62.0,
        };
        let gt = image();
        let s = zone_samples(
            &v,
            &zone,
            &block,
            &[0, 1, 2, 3, 9],
            &xy,
            &world,
            &gt,
            [0.0; 3],
            0.1,
        );
        assert_eq!(s.len(), 2);
        assert_eq!(s[0].position, [0.0, 0.0, 10.0]);
        assert_eq!(s[1].position, [1.0, -1.0, 10.5]);
        // 32 × 32 pixels shared by 2: a disc of ½ √512 px at distance d through f = 100.
        let r = 0.5 * (1024.0f64 / 2.0).sqrt();
        assert!((s[0].scale as f64 - 10.0 * r / 100.0).abs() < 1e-5);
        let d1 = (1.0f64 + 1.0 + 10.5 * 10.5).sqrt();
        assert!((s[1].scale as f64 - d1 * r / 100.0).abs() < 1e-5);
        // Colour: the pixel under the keypoint (60, 30) → column 60, row 30.
        assert_eq!(s[1].color, [0.6, 30.0 / 80.0, 0.5]);
        assert!(s
            .iter()
            .all(|g| g.opacity == 0.1 && g.camera_center == [0.0; 3]));
    }

    #[test]
    fn a_zone_without_points_gives_nothing() {
        let v = view();
        let zone = Zone::Box {
            min: [-1.0; 3],
            max: [1.0; 3],
        };
        let block = PixelBox {
            x0: 0.0,
            y0: 0.0,
            x1: 8.0,
            y1: 8.0,
        };
        let s = zone_samples(&v, &zone, &block, &[], &[], &[], &image(), [0.0; 3], 0.1);
        assert!(s.is_empty());
    }
}
