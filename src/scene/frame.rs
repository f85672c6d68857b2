//! The training frame: every scene is trained recentred and scaled to a unit extent, whatever
//! frame its files are in.
//!
//! A COLMAP model can be in any frame: near the origin in arbitrary units, in millimetres, in
//! kilometres, or georeferenced (UTM coordinates from a drone's GPS, 10⁵–10⁷ away from the
//! origin). The GPU works in f32, whose spacing at 4·10⁶ is half a unit: a georeferenced door
//! a few metres wide loses every detail before the first iteration, and fixed lengths (the near
//! plane, scale floors) mean something else in every unit. So [`Scene::load`](super::Scene::load)
//! maps the scene, in f64, through the similarity `x ↦ scale · (x − origin)` with `origin` the
//! mean of every view's camera centre and `scale` the inverse of their extent (1.1 × the largest
//! distance of a camera centre from `origin`; the SfM points' spread for a scene whose cameras
//! stand in one place, 1 when neither has a spread). There is no rotation: "up" and the axes
//! stay the user's, so axis-aligned settings (Neural 3D Video's z cull) still mean what they
//! say. Every view is used (not only the training split) so that one scene folder always gets
//! one frame, whatever `--eval` or the split says.
//!
//! Outputs go back to the user's frame ([`SceneFrame::output_shift`]): models, meshes and
//! `.splat` files hold user coordinates, so they line up with the SfM points and other tools'
//! results — except when the scene lies so far from the origin that f32 coordinates cannot hold
//! it (more than [`SHIFT_ABOVE_EXTENTS`] extents away). Then the files hold positions relative
//! to a round shift near the scene, recorded in the header as `comment lpmsplat shift X Y Z`
//! (the convention of point-cloud tools for georeferenced data: CloudCompare's global shift),
//! and every reader of ours adds it back in f64.

use super::{Pose, SfmPoints};

/// A scene whose centre lies more than this many extents from the origin is written relative to
/// a shift: f32 spacing there is `2⁻²³ · 64 ≈ 8·10⁻⁶` extents, the finest detail a view holds.
pub const SHIFT_ABOVE_EXTENTS: f64 = 64.0;

/// The PLY header comment that records an output's shift (the comment text after `comment `).
pub const SHIFT_COMMENT: &str = "lpmsplat shift";

/// The similarity from the user's frame to the training frame: `train = scale · (user − origin)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneFrame {
    pub origin: [f64; 3],
    pub scale: f64,
}

impl SceneFrame {
    pub const IDENTITY: SceneFrame = SceneFrame {
        origin: [0.0; 3],
        scale: 1.0,
    };

    /// The frame of a scene whose cameras stand at `camera_centres` and whose SfM points (if
    /// any) are `points`: recentred on the cameras' mean, scaled so that 1.1 × the largest
    /// camera distance from it is 1. Cameras without a spread (one camera, or all at one
    /// place) take the points' spread (1.1 × their largest distance from the cameras' mean);
    /// without either, the scale stays 1. Non-finite inputs give the identity (the loaders
    /// refuse them before this is asked).
    pub fn fit(camera_centres: &[[f64; 3]], points: Option<&SfmPoints>) -> SceneFrame {
        if camera_centres.is_empty() || camera_centres.iter().flatten().any(|v| !v.is_finite()) {
            return Self::IDENTITY;
        }
        let n = camera_centres.len() as f64;
        let mut origin = [0.0; 3];
        for c in camera_centres {
            for k in 0..3 {
                origin[k] += c[k] / n;
            }
        }
        let spread = |ps: &mut dyn Iterator<Item = &[f64; 3]>| {
            1.1 * ps
                .map(|c| distance(*c, origin))
                .filter(|d| d.is_finite())
                .fold(0.0f64, f64::max)
        };
        let mut extent = spread(&mut camera_centres.iter());
        // A spread within rounding of the origin's magnitude is no spread.
        let floor = 1e-9 * origin.iter().fold(1.0f64, |m, v| m.max(v.abs()));
        if extent <= floor {
            extent = points.map_or(0.0, |p| spread(&mut p.positions.iter()));
        }
        let scale = if extent > floor && extent.is_finite() {
            1.0 / extent
        } else {
            1.0
        };
        SceneFrame { origin, scale }
    }

    /// The scene's extent in user units (the inverse of the scale).
    pub fn extent(&self) -> f64 {
        1.0 / self.scale
    }

    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }

    /// A user-frame point in the training frame.
    pub fn to_train(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| self.scale * (p[k] - self.origin[k]))
    }

    /// A training-frame point in the user's frame.
    pub fn to_user(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| p[k] / self.scale + self.origin[k])
    }

    /// A user-frame length in the training frame.
    pub fn length_to_train(&self, l: f64) -> f64 {
        l * self.scale
    }

    /// A user-frame world-to-camera pose in the training frame: the rotation is unchanged and
    /// camera space is scaled with the world (`t' = scale · (R·origin + t)`), so every pixel
    /// projects where it did.
    pub fn pose_to_train(&self, pose: &Pose) -> Pose {
        let r = &pose.rotation;
        let o = self.origin;
        let translation = [0, 1, 2].map(|i| {
            self.scale * (r[i][0] * o[0] + r[i][1] * o[1] + r[i][2] * o[2] + pose.translation[i])
        });
        Pose {
            rotation: pose.rotation,
            translation,
        }
    }

    /// A training-frame pose in the user's frame (the inverse of [`SceneFrame::pose_to_train`]).
    pub fn pose_to_user(&self, pose: &Pose) -> Pose {
        let r = &pose.rotation;
        let o = self.origin;
        let translation = [0, 1, 2].map(|i| {
            pose.translation[i] / self.scale - (r[i][0] * o[0] + r[i][1] * o[1] + r[i][2] * o[2])
        });
        Pose {
            rotation: pose.rotation,
            translation,
        }
    }

    /// The shift an output in the user's frame is written relative to: zero for a scene near
    /// the origin; for one more than [`SHIFT_ABOVE_EXTENTS`] extents away, its origin rounded
    /// to a multiple of the power of ten at or above its extent (a shift a person can read and
    /// retype; what remains is at most one such step plus the scene).
    pub fn output_shift(&self) -> [f64; 3] {
        let extent = self.extent();
        let far = self
            .origin
            .iter()
            .any(|v| v.abs() > SHIFT_ABOVE_EXTENTS * extent);
        if !far {
            return [0.0; 3];
        }
        let step = 10f64.powf(extent.log10().ceil());
        self.origin.map(|v| (v / step).round() * step)
    }

    /// This frame as seen from a file that stores user coordinates less `shift`: the frame
    /// that takes the file's coordinates to the training frame.
    pub fn of_stored(&self, shift: [f64; 3]) -> SceneFrame {
        SceneFrame {
            origin: [0, 1, 2].map(|k| self.origin[k] - shift[k]),
            scale: self.scale,
        }
    }

    /// The affine map `x ↦ k·x + b` (uniform `k`) that takes training coordinates to an
    /// output's stored coordinates (user coordinates less `shift`).
    pub fn train_to_stored(&self, shift: [f64; 3]) -> (f64, [f64; 3]) {
        (
            1.0 / self.scale,
            [0, 1, 2].map(|k| self.origin[k] - shift[k]),
        )
    }

    /// The affine map `x ↦ k·x + b` that takes a file's stored coordinates (user coordinates
    /// less `shift`) to the training frame.
    pub fn stored_to_train(&self, shift: [f64; 3]) -> (f64, [f64; 3]) {
        (
            self.scale,
            [0, 1, 2].map(|k| self.scale * (shift[k] - self.origin[k])),
        )
    }

    /// Moves SfM points into the training frame.
    pub fn points_to_train(&self, points: &mut SfmPoints) {
        for p in &mut points.positions {
            *p = self.to_train(*p);
        }
    }
}

/// The header comment recording `shift` (none for a zero shift). `{:?}` prints the shortest
/// text that reads back as the same f64.
pub fn shift_comment(shift: [f64; 3]) -> Option<String> {
    (shift != [0.0; 3]).then(|| {
        format!(
            "{SHIFT_COMMENT} {:?} {:?} {:?}",
            shift[0], shift[1], shift[2]
        )
    })
}

/// The shift recorded in a file's header comments (zero when none is); a malformed one is an
/// error naming the file.
pub fn shift_from_comments(
    path: &std::path::Path,
    comments: &[String],
) -> anyhow::Result<[f64; 3]> {
    let Some(c) = comments
        .iter()
        .find(|c| c.starts_with(SHIFT_COMMENT) && c[SHIFT_COMMENT.len()..].starts_with(' '))
    else {
        return Ok([0.0; 3]);
    };
    let values: Vec<f64> = c[SHIFT_COMMENT.len()..]
        .split_whitespace()
        .map(|v| v.parse::<f64>())
        .collect::<Result<_, _>>()
        .unwrap_or_default();
    if values.len() != 3 || values.iter().any(|v| !v.is_finite()) {
        return crate::error::bad_input(
            path,
            format!("header comment '{c}'"),
            "is not three finite numbers (the shift the file's positions are stored relative \
             to)",
            format!("write it as `comment {SHIFT_COMMENT} X Y Z`, or remove it if the positions are the world's own"),
        );
    }
    Ok([values[0], values[1], values[2]])
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}
