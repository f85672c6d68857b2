//! Seeded random scenes and views for tests that compare against the reference (CPU here, GPU
//! kernels elsewhere). The distributions are chosen so that a typical view shows every effect
//! the math has: anisotropic rotated splats a few pixels wide, overlaps, Gaussians off-screen
//! (clamped EWA Jacobian), colour channels clamped at 0 and off-centre principal points.

use rand::Rng;

use super::linalg::{self, Vec3};
use super::RefGaussians;
use crate::scene::{PinholeCamera, Pose};

/// `n` Gaussians in a ball of radius 1.2 around the origin:
/// - log-scales uniform in `[ln 0.03, ln 0.3]` per axis (anisotropic);
/// - quaternions with normal-ish components and a norm between 0.5 and 2 (not normalised);
/// - opacity logits uniform in `[−2, 2]`;
/// - SH DC uniform in `[−2.5, 2]` (about one channel in six clamps at 0), higher bands in
///   `[−0.3, 0.3]`; all 16 coefficients are filled whatever degree the test renders.
pub fn random_gaussians(rng: &mut impl Rng, n: usize) -> RefGaussians {
    let mut g = RefGaussians::default();
    for _ in 0..n {
        let p = loop {
            let p: Vec3 = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
            if linalg::dot(p, p) <= 1.0 {
                break linalg::scale(p, 1.2);
            }
        };
        g.positions.push(p);
        g.log_scales
            .push([0; 3].map(|_| rng.gen_range(0.03f64.ln()..0.3f64.ln())));
        let q: [f64; 4] = [0; 4].map(|_| rng.gen_range(-1.0..1.0));
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-3);
        let norm = rng.gen_range(0.5..2.0);
        g.rotations.push(q.map(|v| v / n * norm));
        g.opacity_logits.push(rng.gen_range(-2.0..2.0));
        let mut sh = [[0.0; 3]; 16];
        sh[0] = [0; 3].map(|_| rng.gen_range(-2.5..2.0));
        for coeff in sh.iter_mut().skip(1) {
            *coeff = [0; 3].map(|_| rng.gen_range(-0.3..0.3));
        }
        g.sh.push(sh);
    }
    g
}

/// A `width` × `height` camera about 4 units from the origin looking at it (with a little
/// jitter and a random roll), focal length about the image size and the principal point up to
/// 10% off-centre.
pub fn random_view(rng: &mut impl Rng, width: u32, height: u32) -> (PinholeCamera, Pose) {
    let size = width.max(height) as f64;
    let fx = size * rng.gen_range(0.9..1.3);
    let camera = PinholeCamera {
        fx,
        fy: fx * rng.gen_range(0.95..1.05),
        cx: width as f64 * rng.gen_range(0.4..0.6),
        cy: height as f64 * rng.gen_range(0.4..0.6),
        width,
        height,
    };
    let dir = loop {
        let d: Vec3 = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
        let l = linalg::dot(d, d).sqrt();
        if (0.1..=1.0).contains(&l) {
            break linalg::scale(d, 1.0 / l);
        }
    };
    let center = linalg::scale(dir, rng.gen_range(3.5..4.5));
    let target: Vec3 = [0; 3].map(|_| rng.gen_range(-0.2..0.2));
    let up: Vec3 = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
    (camera, look_at(center, target, up))
}

/// World-to-camera pose of a camera at `center` looking at `target` (OpenCV axes: +z forward,
/// y down), with `up` only fixing the roll. Falls back to another up vector when `up` is
/// parallel to the viewing direction.
pub fn look_at(center: Vec3, target: Vec3, up: Vec3) -> Pose {
    let normalize = |v: Vec3| linalg::scale(v, 1.0 / linalg::dot(v, v).sqrt());
    let cross = |a: Vec3, b: Vec3| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let z = normalize(linalg::sub(target, center));
    let mut x = cross(z, up);
    if linalg::dot(x, x) < 1e-12 {
        x = cross(z, [z[1], z[2], z[0] + 1.0]);
    }
    let x = normalize(x);
    let y = cross(z, x);
    let rotation = [x, y, z];
    let t = linalg::mat_vec(&rotation, center);
    Pose {
        rotation,
        translation: [-t[0], -t[1], -t[2]],
    }
}
