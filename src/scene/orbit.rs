//! A closed camera path fitted to a scene's cameras, for turntable / fly-around videos.
//!
//! The path is an ellipse through the spread of the camera centres, always looking at a target
//! point with the cameras' mean up direction:
//! - **360° captures** (the cameras look inwards from all sides): the target is the point nearest
//!   to every optical axis (least squares), and the ellipse is the ring the cameras stand on, in
//!   the plane perpendicular to up.
//! - **Forward-facing captures** (the optical axes are nearly parallel, so that point is
//!   ill-defined): the target lies on the mean optical axis at a focus depth the caller gives
//!   (e.g. the median depth of the model), and the ellipse is the small spread of the cameras in
//!   the plane perpendicular to the viewing direction, as in the "spiral" paths of
//!   forward-facing NeRF datasets.
//!
//! The ellipse's semi-axes are √2·σ along the two principal directions of the centres (σ their
//! standard deviations): cameras spaced evenly on a circle of radius R give exactly R.

use super::camera::Pose;
use glam::{DMat3, DVec3};

/// Smallest eigenvalue of `Σ (I − d dᵀ)/n` (the squared sine of the optical axes' spread) below
/// which a capture is treated as forward-facing. 0.05 ≈ axes within ±13° of each other.
pub const FORWARD_FACING_SPREAD: f64 = 0.05;

/// How the target was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OrbitKind {
    Inward,
    ForwardFacing,
}

/// The fitted path.
#[derive(Debug, Clone)]
pub struct Orbit {
    pub kind: OrbitKind,
    pub target: [f64; 3],
    pub centre: [f64; 3],
    /// World up (unit).
    pub up: [f64; 3],
    /// Semi-axes as world vectors (direction × length).
    pub axes: [[f64; 3]; 2],
}

fn v(a: [f64; 3]) -> DVec3 {
    DVec3::from_array(a)
}

/// Eigenvalues of a symmetric 3×3 matrix, ascending (the trigonometric closed form).
fn symmetric_eigenvalues(m: DMat3) -> [f64; 3] {
    let a = m.to_cols_array_2d();
    let p1 = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
    let q = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
    if p1 == 0.0 {
        let mut e = [a[0][0], a[1][1], a[2][2]];
        e.sort_by(f64::total_cmp);
        return e;
    }
    let p2 = (a[0][0] - q).powi(2) + (a[1][1] - q).powi(2) + (a[2][2] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    let b = (m - DMat3::from_diagonal(DVec3::splat(q))) * (1.0 / p);
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let e_max = q + 2.0 * p * phi.cos();
    let e_min = q + 2.0 * p * (phi + 2.0 * std::f64::consts::PI / 3.0).cos();
    [e_min, 3.0 * q - e_min - e_max, e_max]
}

impl Orbit {
    /// Fits the path to `poses` (at least one). `focus_depth` is used for forward-facing
    /// captures only: the distance along the mean optical axis to look at.
    pub fn fit(poses: &[Pose], focus_depth: impl FnOnce(DVec3, DVec3) -> f64) -> Orbit {
        assert!(!poses.is_empty(), "an orbit needs at least one camera");
        let n = poses.len() as f64;
        let centres: Vec<DVec3> = poses.iter().map(|p| v(p.center())).collect();
        let axes: Vec<DVec3> = poses
            .iter()
            .map(|p| v(p.optical_axis()).normalize())
            .collect();
        let mean_c = centres.iter().sum::<DVec3>() / n;
        // The camera's y axis points down in the image (OpenCV convention).
        let up = {
            let s: DVec3 = poses.iter().map(|p| -v(p.rotation[1])).sum();
            if s.length() > 1e-9 {
                s.normalize()
            } else {
                DVec3::Y
            }
        };

        let mut a = DMat3::ZERO;
        let mut b = DVec3::ZERO;
        for (c, d) in centres.iter().zip(&axes) {
            let proj = DMat3::IDENTITY - DMat3::from_cols(*d * d.x, *d * d.y, *d * d.z);
            a += proj;
            b += proj * *c;
        }
        let spread = symmetric_eigenvalues(a * (1.0 / n))[0];
        // The path's plane: perpendicular to `up` around an inward capture (a turntable),
        // perpendicular to the viewing direction in front of a forward-facing one (the spiral
        // of forward-facing NeRF datasets, staying within the cameras' spread).
        let (kind, target, normal) = if spread >= FORWARD_FACING_SPREAD {
            (OrbitKind::Inward, a.inverse() * b, up)
        } else {
            let mean_axis = {
                let s: DVec3 = axes.iter().sum();
                if s.length() > 1e-9 {
                    s.normalize()
                } else {
                    axes[0]
                }
            };
            let depth = focus_depth(mean_c, mean_axis);
            (
                OrbitKind::ForwardFacing,
                mean_c + mean_axis * depth,
                mean_axis,
            )
        };

        // Principal directions of the centres in that plane.
        let e1 = if normal.x.abs() < 0.9 {
            DVec3::X
        } else {
            DVec3::Y
        };
        let e1 = (e1 - normal * e1.dot(normal)).normalize();
        let e2 = normal.cross(e1);
        let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
        for c in &centres {
            let d = *c - mean_c;
            let (x, y) = (d.dot(e1), d.dot(e2));
            sxx += x * x / n;
            sxy += x * y / n;
            syy += y * y / n;
        }
        let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
        let (s, c) = theta.sin_cos();
        let major = e1 * c + e2 * s;
        let minor = normal.cross(major);
        let tr = sxx + syy;
        let disc = ((sxx - syy).powi(2) / 4.0 + sxy * sxy).sqrt();
        let (l1, l2) = ((tr / 2.0 + disc).max(0.0), (tr / 2.0 - disc).max(0.0));
        let r1 = (2.0 * l1).sqrt();
        // A degenerate (line-like) spread still orbits: the minor axis is at least a fifth
        // of the major one, so the camera moves around the target rather than back and forth.
        let r2 = (2.0 * l2).sqrt().max(0.2 * r1);
        Orbit {
            kind,
            target: target.to_array(),
            centre: mean_c.to_array(),
            up: up.to_array(),
            axes: [(major * r1).to_array(), (minor * r2).to_array()],
        }
    }

    /// `frames` poses evenly spaced around the path, each looking at the target with the
    /// path's up direction.
    pub fn poses(&self, frames: usize) -> Vec<Pose> {
        (0..frames)
            .map(|k| {
                let t = 2.0 * std::f64::consts::PI * k as f64 / frames as f64;
                let c = v(self.centre) + v(self.axes[0]) * t.cos() + v(self.axes[1]) * t.sin();
                look_at(c, v(self.target), v(self.up))
            })
            .collect()
    }
}

/// The world-to-camera pose of a camera at `eye` looking at `target` (OpenCV axes: x right,
/// y down, z forward), with `up` pointing up in the image. A view straight along `up` picks
/// another reference direction rather than failing.
pub fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> Pose {
    let z = (target - eye).normalize();
    let mut down = -up;
    if z.cross(down).length() < 1e-6 {
        down = if z.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    }
    let x = down.cross(z).normalize();
    let y = z.cross(x);
    let rotation = [x.to_array(), y.to_array(), z.to_array()];
    let r = DMat3::from_cols(x, y, z).transpose();
    let translation = (-(r * eye)).to_array();
    Pose {
        rotation,
        translation,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigenvalues_of_a_known_matrix() {
        let m = DMat3::from_cols(
            DVec3::new(2.0, 1.0, 0.0),
            DVec3::new(1.0, 2.0, 0.0),
            DVec3::new(0.0, 0.0, 5.0),
        );
        let e = symmetric_eigenvalues(m);
        for (got, want) in e.iter().zip([1.0, 3.0, 5.0]) {
            assert!((got - want).abs() < 1e-12, "{e:?}");
        }
    }

    #[test]
    fn look_at_centres_the_target() {
        let eye = DVec3::new(1.0, 2.0, 3.0);
        let target = DVec3::new(-1.0, 0.5, 0.0);
        let p = look_at(eye, target, DVec3::Z);
        let t = p.transform(target.to_array());
        assert!(
            t[0].abs() < 1e-12 && t[1].abs() < 1e-12 && t[2] > 0.0,
            "{t:?}"
        );
        let c = p.center();
        assert!((v(c) - eye).length() < 1e-12);
        // A point above the target appears above it in the image (smaller y).
        let above = p.transform((target + DVec3::Z).to_array());
        assert!(above[1] < 0.0, "{above:?}");
    }

    fn ring(n: usize, radius: f64, height: f64, target: DVec3) -> Vec<Pose> {
        (0..n)
            .map(|k| {
                let a = 2.0 * std::f64::consts::PI * k as f64 / n as f64;
                let eye = target + DVec3::new(radius * a.cos(), height, radius * a.sin());
                look_at(eye, target, DVec3::Y)
            })
            .collect()
    }

    #[test]
    fn a_ring_of_inward_cameras_gives_their_circle_around_their_target() {
        let target = DVec3::new(0.5, -1.0, 2.0);
        let orbit = Orbit::fit(&ring(24, 4.0, 1.5, target), |_, _| unreachable!());
        assert_eq!(orbit.kind, OrbitKind::Inward);
        assert!((v(orbit.target) - target).length() < 1e-9, "{orbit:?}");
        assert!((v(orbit.up) - DVec3::Y).length() < 1e-9, "{orbit:?}");
        for pose in orbit.poses(10) {
            let c = v(pose.center());
            let d = c - target;
            assert!((d.y - 1.5).abs() < 1e-9, "height {c}");
            assert!(
                ((d.x * d.x + d.z * d.z).sqrt() - 4.0).abs() < 1e-9,
                "radius {c}"
            );
            let t = pose.transform(target.to_array());
            assert!(t[0].abs() < 1e-9 && t[1].abs() < 1e-9 && t[2] > 0.0);
        }
    }

    #[test]
    fn forward_facing_cameras_look_at_the_focus_depth() {
        // A 3 × 2 grid of cameras 0.1 apart, all looking down +z.
        let poses: Vec<Pose> = (0..6)
            .map(|k| {
                let eye = DVec3::new(0.1 * (k % 3) as f64, 0.1 * (k / 3) as f64, 0.0);
                look_at(eye, eye + DVec3::Z, -DVec3::Y)
            })
            .collect();
        let orbit = Orbit::fit(&poses, |centre, axis| {
            assert!((axis - DVec3::Z).length() < 1e-9);
            assert!((centre - DVec3::new(0.1, 0.05, 0.0)).length() < 1e-9);
            7.0
        });
        assert_eq!(orbit.kind, OrbitKind::ForwardFacing);
        assert!((v(orbit.target) - DVec3::new(0.1, 0.05, 7.0)).length() < 1e-9);
        // The path stays within the cameras' spread.
        for pose in orbit.poses(12) {
            let d = v(pose.center()) - DVec3::new(0.1, 0.05, 0.0);
            assert!(d.length() < 0.2 && d.z.abs() < 1e-9, "{d}");
        }
    }
}
