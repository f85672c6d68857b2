//! 2D–2D correspondences between view pairs, and the ones given by COLMAP tracks.

use crate::scene::Scene;

/// Matched points of one pair, seen from one side: (points in this view, points in the other).
pub type OrientedMatches<'a> = (&'a [[f32; 2]], &'a [[f32; 2]]);

/// The matches of one unordered view pair `a < b`: `xy_a[i]` in view `a` matches `xy_b[i]` in
/// view `b`, both in the pixels of the views' pinhole cameras (centres at +0.5).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PairMatches {
    pub a: u32,
    pub b: u32,
    pub xy_a: Vec<[f32; 2]>,
    pub xy_b: Vec<[f32; 2]>,
}

impl PairMatches {
    pub fn len(&self) -> usize {
        self.xy_a.len()
    }
    pub fn is_empty(&self) -> bool {
        self.xy_a.is_empty()
    }
    /// The matches seen from `view`: (points in `view`, points in the other view). `None` when
    /// `view` is not one of the pair.
    pub fn oriented(&self, view: usize) -> Option<OrientedMatches<'_>> {
        if view == self.a as usize {
            Some((&self.xy_a, &self.xy_b))
        } else if view == self.b as usize {
            Some((&self.xy_b, &self.xy_a))
        } else {
            None
        }
    }
}

/// Per view, the (SfM point index, keypoint index) pairs of its track observations, sorted by
/// point: two views then share points by a linear merge.
#[derive(Debug, Clone, Default)]
pub struct TrackIndex {
    per_view: Vec<Vec<(u32, u32)>>,
}

impl TrackIndex {
    /// Builds the index; fails (naming the scene's model) when a track names a view or keypoint
    /// that does not exist.
    pub fn new(scene: &Scene) -> anyhow::Result<TrackIndex> {
        let mut per_view = vec![Vec::new(); scene.views.len()];
        let Some(points) = &scene.points else {
            return Ok(TrackIndex { per_view });
        };
        let file = match &scene.format {
            crate::scene::SceneFormat::Colmap { sparse_dir, .. } => sparse_dir.join("points3D"),
            _ => scene.root.clone(),
        };
        for (p, track) in points.tracks.iter().enumerate() {
            for &(v, k) in track {
                let Some(view) = scene.views.get(v as usize) else {
                    return crate::error::bad_input(
                        &file,
                        format!("track of point index {p}"),
                        format!(
                            "names view index {v}, but the scene has {} views",
                            scene.views.len()
                        ),
                        "re-export the COLMAP model so points3D and images agree",
                    );
                };
                let nkp = view.keypoints.as_ref().map_or(0, |k| k.xy.len());
                if k as usize >= nkp {
                    return crate::error::bad_input(
                        &file,
                        format!("track of point index {p}"),
                        format!(
                            "names keypoint {k} of {}, which has {nkp} keypoints",
                            view.name
                        ),
                        "re-export the COLMAP model so points3D and images agree",
                    );
                }
                per_view[v as usize].push((p as u32, k));
            }
        }
        for list in &mut per_view {
            list.sort_unstable();
            // A track seeing the same image twice: keep its first keypoint.
            list.dedup_by_key(|e| e.0);
        }
        Ok(TrackIndex { per_view })
    }

    /// Number of track observations in `view`.
    pub fn observations(&self, view: usize) -> usize {
        self.per_view.get(view).map_or(0, |l| l.len())
    }

    /// The matches of the pair (a, b) given by shared SfM points (order of `a`, `b` is normalised
    /// so `a < b`).
    pub fn matches(&self, scene: &Scene, a: usize, b: usize) -> PairMatches {
        let (a, b) = (a.min(b), a.max(b));
        let mut out = PairMatches {
            a: a as u32,
            b: b as u32,
            ..Default::default()
        };
        let (Some(la), Some(lb)) = (self.per_view.get(a), self.per_view.get(b)) else {
            return out;
        };
        if a == b {
            return out;
        }
        let (Some(ka), Some(kb)) = (
            scene.views[a].keypoints.as_ref(),
            scene.views[b].keypoints.as_ref(),
        ) else {
            return out;
        };
        let (mut i, mut j) = (0, 0);
        while i < la.len() && j < lb.len() {
            match la[i].0.cmp(&lb[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    let pa = ka.xy[la[i].1 as usize];
                    let pb = kb.xy[lb[j].1 as usize];
                    out.xy_a.push([pa[0] as f32, pa[1] as f32]);
                    out.xy_b.push([pb[0] as f32, pb[1] as f32]);
                    i += 1;
                    j += 1;
                }
            }
        }
        out
    }
}
