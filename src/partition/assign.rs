//! Which views train which block: every view standing over the block's region, and every view
//! that sees enough of the block's core.
//!
//! Position alone misses what a block needs most: a view taken from outside the block that
//! looks into it (a facade seen from across the street, a drone's oblique view of the next
//! block). So a view also joins a block when at least `visibility` of what it sees lies in
//! the block's core. "What it sees" is, for a view with SfM observations, the points COLMAP
//! matched in that very image (occlusion included: a point behind a wall was never matched
//! there); for a view with too few of them (a transforms scene, an image with few features),
//! the share of its image, on a 16×16 grid of cells, that the core's points project into,
//! in front of the camera. The core's points stand for its volume, airspace included where
//! the reconstruction has points there; a block whose core has no points is seen by nobody
//! this way and keeps only the views over it.

use super::grid::Rect;
use crate::scene::{Scene, View};

/// Views with fewer SfM observations than this are judged by projection instead.
pub const MIN_OBSERVATIONS: usize = 20;

/// The projection test's grid: cells along each image side.
const CELLS: usize = 16;

/// At most this many of a core's points are projected into each view (an even subsample).
const MAX_PROJECTED: usize = 2048;

/// Per-scene geometry the assignment works on, in the files' frame.
pub struct Geometry<'a> {
    pub scene: &'a Scene,
    /// Ground coordinates of every SfM point.
    pub point_ground: Vec<[f64; 2]>,
    /// Ground coordinates of every view's camera centre.
    pub view_ground: Vec<[f64; 2]>,
    /// Per view: the SfM points it observes (indices into the scene's points).
    pub observed: Vec<Vec<u32>>,
}

impl<'a> Geometry<'a> {
    pub fn new(scene: &'a Scene, ground: &super::ground::GroundFrame) -> Geometry<'a> {
        let positions: &[[f64; 3]] = scene.points.as_ref().map_or(&[], |p| &p.positions);
        let point_ground = positions.iter().map(|p| ground.coordinates(*p).0).collect();
        let view_ground = scene
            .views
            .iter()
            .map(|v| ground.coordinates(v.pose.center()).0)
            .collect();
        let mut observed = vec![Vec::new(); scene.views.len()];
        if let Some(points) = &scene.points {
            for (i, track) in points.tracks.iter().enumerate() {
                for &(view, _) in track {
                    if let Some(o) = observed.get_mut(view as usize) {
                        if o.last() != Some(&(i as u32)) {
                            o.push(i as u32);
                        }
                    }
                }
            }
        }
        Geometry {
            scene,
            point_ground,
            view_ground,
            observed,
        }
    }

    /// The share of view `view`'s sight that lies in `core`: the larger of the share of its
    /// observed points there (when it has [`MIN_OBSERVATIONS`]) and the share of its image
    /// cells that `core_points` (indices of the core's points) project into. Both, because
    /// SfM points crowd on textured foreground: a view whose background (sky line, a
    /// building across the street) lies in the core matches few points there, yet the core
    /// fills half of its image, and the block that owns that background needs the view.
    pub fn seen_share(&self, view: usize, core: &Rect, core_points: &[u32]) -> f64 {
        let obs = &self.observed[view];
        let tracked = if obs.len() >= MIN_OBSERVATIONS {
            let inside = obs
                .iter()
                .filter(|&&p| core.contains(self.point_ground[p as usize]))
                .count();
            inside as f64 / obs.len() as f64
        } else {
            0.0
        };
        let Some(points) = &self.scene.points else {
            return tracked;
        };
        tracked.max(projected_coverage(
            &self.scene.views[view],
            &points.positions,
            core_points,
        ))
    }

    /// Indices of the SfM points whose ground position lies in `rect`.
    pub fn points_in(&self, rect: &Rect) -> Vec<u32> {
        (0..self.point_ground.len() as u32)
            .filter(|&i| rect.contains(self.point_ground[i as usize]))
            .collect()
    }
}

/// The share of `view`'s image cells that the points `which` of `positions` project into.
pub fn projected_coverage(view: &View, positions: &[[f64; 3]], which: &[u32]) -> f64 {
    let cam = &view.camera;
    let (w, h) = (cam.width as f64, cam.height as f64);
    if which.is_empty() || w <= 0.0 || h <= 0.0 {
        return 0.0;
    }
    let step = which.len().div_ceil(MAX_PROJECTED);
    let mut hit = [false; CELLS * CELLS];
    for &i in which.iter().step_by(step) {
        let c = view.pose.transform(positions[i as usize]);
        if c[2] <= 0.0 || !c[2].is_finite() {
            continue;
        }
        let [x, y] = cam.project(c);
        if !(x >= 0.0 && x < w && y >= 0.0 && y < h) {
            continue;
        }
        let (cx, cy) = (
            ((x / w) * CELLS as f64) as usize,
            ((y / h) * CELLS as f64) as usize,
        );
        hit[cy.min(CELLS - 1) * CELLS + cx.min(CELLS - 1)] = true;
    }
    hit.iter().filter(|&&b| b).count() as f64 / (CELLS * CELLS) as f64
}

/// The views (indices into `candidates`' scene) that train a block: those whose camera stands
/// over `region`, and those that see at least `visibility` of their sight in `core`.
pub fn views_for_block(
    geom: &Geometry,
    candidates: &[usize],
    core: &Rect,
    region: &Rect,
    core_points: &[u32],
    visibility: f64,
) -> Vec<usize> {
    candidates
        .iter()
        .copied()
        .filter(|&v| {
            region.contains(geom.view_ground[v])
                || geom.seen_share(v, core, core_points) >= visibility
        })
        .collect()
}
