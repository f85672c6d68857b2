//! The SfM points each view observes, as the local zones read them: the pixel of the keypoint
//! and the point's position. A point of a COLMAP model is triangulated over all the views of its
//! track and refined by bundle adjustment, so its depth is a better depth for a zone than the
//! midpoint of two rays from one view pair; and every keypoint of the view with a track speaks,
//! not only those shared with one neighbour.

use crate::scene::Scene;

/// Per view: the pixels (centres at +0.5) of its keypoints that belong to a track, and the
/// positions of those tracks' points, in the scene's frame.
#[derive(Debug, Clone, Default)]
pub struct ViewPoints {
    per_view: Vec<Observed>,
}

/// One view's observed points: keypoint pixels and point positions, index for index.
type Observed = (Vec<[f32; 2]>, Vec<[f64; 3]>);

impl ViewPoints {
    /// From the scene's tracks; a view without keypoints, or a track naming a view or keypoint
    /// that does not exist, contributes nothing (the track index the correspondences are built
    /// from refuses such a model, naming the file).
    pub fn new(scene: &Scene) -> ViewPoints {
        let mut per_view = vec![(Vec::new(), Vec::new()); scene.views.len()];
        let Some(points) = &scene.points else {
            return ViewPoints { per_view };
        };
        for (track, &position) in points.tracks.iter().zip(&points.positions) {
            let mut seen: Vec<u32> = Vec::with_capacity(track.len());
            for &(v, k) in track {
                // A track seeing the same image twice: its first keypoint.
                if seen.contains(&v) || !position.iter().all(|c| c.is_finite()) {
                    continue;
                }
                let Some(xy) = scene
                    .views
                    .get(v as usize)
                    .and_then(|view| view.keypoints.as_ref())
                    .and_then(|kp| kp.xy.get(k as usize))
                else {
                    continue;
                };
                seen.push(v);
                let (pixels, world) = &mut per_view[v as usize];
                pixels.push([xy[0] as f32, xy[1] as f32]);
                world.push(position);
            }
        }
        ViewPoints { per_view }
    }

    /// The pixels and positions of the points `view` observes (empty for an unknown view).
    pub fn of(&self, view: usize) -> (&[[f32; 2]], &[[f64; 3]]) {
        self.per_view
            .get(view)
            .map_or((&[][..], &[][..]), |(p, w)| (p.as_slice(), w.as_slice()))
    }
}
