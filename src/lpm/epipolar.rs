//! Epipolar geometry from two known poses and pinhole intrinsics.
//!
//! Convention: `F` maps a pixel of view A to its epipolar line in view B, `x_bᵀ F x_a = 0`, with
//! homogeneous pixels `(u, v, 1)` in the same convention as [`PinholeCamera`] (pixel centres at
//! +0.5).

use crate::scene::{PinholeCamera, Pose};
use glam::{DMat3, DVec3};

/// Row-major 3×3 matrix from a pose's rotation.
pub(crate) fn rotation(p: &Pose) -> DMat3 {
    let r = p.rotation;
    DMat3::from_cols_array_2d(&r).transpose()
}

fn intrinsics(c: &PinholeCamera) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(c.fx, 0.0, 0.0),
        DVec3::new(0.0, c.fy, 0.0),
        DVec3::new(c.cx, c.cy, 1.0),
    )
}

/// The fundamental matrix of the pair, row-major: `x_bᵀ F x_a = 0`. It is zero when the two camera
/// centres coincide (no baseline: the epipolar constraint says nothing).
pub fn fundamental(
    cam_a: &PinholeCamera,
    pose_a: &Pose,
    cam_b: &PinholeCamera,
    pose_b: &Pose,
) -> [[f64; 3]; 3] {
    let (ca, cb) = (DVec3::from(pose_a.center()), DVec3::from(pose_b.center()));
    if ca.distance(cb) <= 1e-12 * ca.length().max(cb.length()).max(1.0) {
        return [[0.0; 3]; 3];
    }
    let ra = rotation(pose_a);
    let rb = rotation(pose_b);
    // Relative pose A → B: x_b = R x_a + t.
    let r = rb * ra.transpose();
    let t = DVec3::from(pose_b.translation) - r * DVec3::from(pose_a.translation);
    let tx = DMat3::from_cols(
        DVec3::new(0.0, t.z, -t.y),
        DVec3::new(-t.z, 0.0, t.x),
        DVec3::new(t.y, -t.x, 0.0),
    );
    let e = tx * r;
    let f = intrinsics(cam_b).inverse().transpose() * e * intrinsics(cam_a).inverse();
    f.transpose().to_cols_array_2d()
}

fn apply(f: &[[f64; 3]; 3], x: [f64; 3]) -> [f64; 3] {
    [
        f[0][0] * x[0] + f[0][1] * x[1] + f[0][2] * x[2],
        f[1][0] * x[0] + f[1][1] * x[1] + f[1][2] * x[2],
        f[2][0] * x[0] + f[2][1] * x[1] + f[2][2] * x[2],
    ]
}

fn apply_t(f: &[[f64; 3]; 3], x: [f64; 3]) -> [f64; 3] {
    [
        f[0][0] * x[0] + f[1][0] * x[1] + f[2][0] * x[2],
        f[0][1] * x[0] + f[1][1] * x[1] + f[2][1] * x[2],
        f[0][2] * x[0] + f[1][2] * x[1] + f[2][2] * x[2],
    ]
}

fn point_line_distance(p: [f64; 2], l: [f64; 3]) -> f64 {
    let n = (l[0] * l[0] + l[1] * l[1]).sqrt();
    if n.is_nan() || n <= 0.0 {
        return f64::INFINITY;
    }
    (l[0] * p[0] + l[1] * p[1] + l[2]).abs() / n
}

/// Symmetric epipolar distance in pixels: the larger of (distance of `xb` to the epipolar line of
/// `xa` in B) and (distance of `xa` to the epipolar line of `xb` in A). The larger, not the mean,
/// so a threshold of k pixels means "each point within k pixels of its line". Infinite when a line
/// is undefined (zero baseline, or a point at an epipole).
pub fn symmetric_epipolar_distance(f: &[[f64; 3]; 3], xa: [f64; 2], xb: [f64; 2]) -> f64 {
    let la = apply(f, [xa[0], xa[1], 1.0]);
    let lb = apply_t(f, [xb[0], xb[1], 1.0]);
    point_line_distance(xb, la).max(point_line_distance(xa, lb))
}
