//! The ground plane a scene is cut on: two horizontal axes and an up axis, fitted to the
//! cameras and the SfM points.
//!
//! Blocks are columns standing on the ground, so the cut needs a plane that is the ground for
//! the capture, whatever frame its files use: a drone survey's cameras fly over the ground in a
//! plane parallel to it, an orbit around an object circles it in such a plane, but a street
//! captured from a car puts every camera on one line, and a line has no normal. So:
//! - **up**: the normal of the camera centres' plane when they span one (their smallest
//!   principal axis, when it is well below the middle one); otherwise the mean of the cameras'
//!   own up directions (people and cars hold cameras upright); otherwise the SfM points'
//!   smallest principal axis. It is signed to agree with the cameras' up directions.
//! - **u, v**: the principal axes of the points (the cameras when there are too few points)
//!   projected onto the plane orthogonal to up, so that the grid's columns run along the
//!   scene's longest direction (a street's length, a district's long side).

use serde::{Deserialize, Serialize};

/// An orthonormal frame: `u`, `v` span the ground, `up` is its normal; `origin` is where the
/// ground coordinates are measured from (the cameras' mean), all in the files' frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GroundFrame {
    pub origin: [f64; 3],
    pub u: [f64; 3],
    pub v: [f64; 3],
    pub up: [f64; 3],
}

/// A camera centres' plane is a plane when its normal's variance is below this share of the
/// middle axis' (a survey at one altitude: ~0; an orbit at one height: ~0; a line: both ~0).
const PLANAR_RATIO: f64 = 0.25;

/// Fewer points than this and the horizontal axes come from the cameras.
pub const MIN_POINTS: usize = 16;

impl GroundFrame {
    /// Fits the frame to camera centres, the cameras' up directions (world vectors of the
    /// camera's −y axis) and the SfM points (may be empty). At least one camera.
    pub fn fit(centres: &[[f64; 3]], camera_ups: &[[f64; 3]], points: &[[f64; 3]]) -> GroundFrame {
        assert!(!centres.is_empty(), "a ground frame needs a camera");
        let origin = mean(centres);
        let (cam_vals, cam_vecs) = principal_axes(centres, origin);
        let mean_up = normalised(mean(camera_ups));
        let scale = cam_vals[2].max(f64::MIN_POSITIVE);
        let planar = cam_vals[1] > 1e-12 * scale && cam_vals[0] < PLANAR_RATIO * cam_vals[1];
        let mut up = if planar {
            cam_vecs[0]
        } else if let Some(u) = mean_up {
            u
        } else if points.len() >= MIN_POINTS {
            principal_axes(points, mean(points)).1[0]
        } else {
            [0.0, 0.0, 1.0]
        };
        if let Some(m) = mean_up {
            if dot(up, m) < 0.0 {
                up = up.map(|x| -x);
            }
        }
        // Horizontal axes: the spread of what is on the ground, projected onto it.
        let source = if points.len() >= MIN_POINTS {
            points
        } else {
            centres
        };
        let flat: Vec<[f64; 3]> = source
            .iter()
            .map(|p| {
                let d = sub(*p, origin);
                sub(d, up.map(|x| x * dot(d, up)))
            })
            .collect();
        let (_, vecs) = principal_axes(&flat, mean(&flat));
        // The largest in-plane axis; made exactly orthogonal to up.
        let mut u = sub(vecs[2], up.map(|x| x * dot(vecs[2], up)));
        u = normalised(u).unwrap_or_else(|| any_orthogonal(up));
        let v = cross(up, u);
        GroundFrame { origin, u, v, up }
    }

    /// A point's ground coordinates (along u, along v) and its height (along up).
    pub fn coordinates(&self, p: [f64; 3]) -> ([f64; 2], f64) {
        let d = sub(p, self.origin);
        ([dot(d, self.u), dot(d, self.v)], dot(d, self.up))
    }
}

fn mean(ps: &[[f64; 3]]) -> [f64; 3] {
    let n = ps.len().max(1) as f64;
    let mut m = [0.0; 3];
    for p in ps {
        for k in 0..3 {
            m[k] += p[k] / n;
        }
    }
    m
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalised(a: [f64; 3]) -> Option<[f64; 3]> {
    let n = dot(a, a).sqrt();
    (n.is_finite() && n > 1e-12).then(|| a.map(|x| x / n))
}

fn any_orthogonal(a: [f64; 3]) -> [f64; 3] {
    let pick = if a[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    normalised(cross(a, pick)).unwrap_or([1.0, 0.0, 0.0])
}

/// Eigenvalues (ascending) and unit eigenvectors of the covariance of `ps` about `centre`.
fn principal_axes(ps: &[[f64; 3]], centre: [f64; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut c = [[0.0f64; 3]; 3];
    let n = ps.len().max(1) as f64;
    for p in ps {
        let d = sub(*p, centre);
        for r in 0..3 {
            for k in 0..3 {
                c[r][k] += d[r] * d[k] / n;
            }
        }
    }
    symmetric_eigen(c)
}

/// Cyclic Jacobi rotations on a symmetric 3×3 matrix: eigenvalues ascending with their unit
/// eigenvectors. Exact to rounding for the small, well-scaled covariances used here.
pub fn symmetric_eigen(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut vecs = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]; // columns
    for _ in 0..64 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        let diag = a[0][0].powi(2) + a[1][1].powi(2) + a[2][2].powi(2);
        if off <= 1e-30 * diag.max(f64::MIN_POSITIVE) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A ← Jᵀ A J with J the rotation in the (p, q) plane.
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            a[p] = [0, 1, 2].map(|k| c * rp[k] - s * rq[k]);
            a[q] = [0, 1, 2].map(|k| s * rp[k] + c * rq[k]);
            for row in &mut vecs {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let vals = order.map(|i| a[i][i]);
    let vectors = order.map(|i| [vecs[0][i], vecs[1][i], vecs[2][i]]);
    (vals, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
    }

    #[test]
    fn eigen_of_a_rotated_diagonal_matrix() {
        // R diag(1, 4, 9) Rᵀ for a rotation about z by 30° then x by 50°.
        let (a, b) = (30f64.to_radians(), 50f64.to_radians());
        let rz = [
            [a.cos(), -a.sin(), 0.0],
            [a.sin(), a.cos(), 0.0],
            [0.0, 0.0, 1.0],
        ];
        let rx = [
            [1.0, 0.0, 0.0],
            [0.0, b.cos(), -b.sin()],
            [0.0, b.sin(), b.cos()],
        ];
        let mut r = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                r[i][j] = (0..3).map(|k| rx[i][k] * rz[k][j]).sum();
            }
        }
        let d = [1.0, 4.0, 9.0];
        let mut m = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] = (0..3).map(|k| r[i][k] * d[k] * r[j][k]).sum();
            }
        }
        let (vals, vecs) = symmetric_eigen(m);
        assert!(close(vals, d, 1e-12), "{vals:?}");
        for k in 0..3 {
            let col = [r[0][k], r[1][k], r[2][k]];
            let c = dot(col, vecs[k]).abs();
            assert!((c - 1.0).abs() < 1e-12, "axis {k}: {c}");
        }
    }

    #[test]
    fn a_survey_plane_tilted_in_the_files_frame_gives_its_normal() {
        // Cameras on a 5×7 grid in a plane tilted about x by 20°, looking down; up = the normal.
        let t = 20f64.to_radians();
        let (ex, ey) = ([1.0, 0.0, 0.0], [0.0, t.cos(), t.sin()]);
        let normal = cross(ex, ey);
        let mut centres = Vec::new();
        for i in 0..5 {
            for j in 0..7 {
                let (x, y) = (i as f64 * 10.0, j as f64 * 13.0);
                centres.push([0, 1, 2].map(|k| 1e6 + x * ex[k] + y * ey[k] + 50.0 * normal[k]));
            }
        }
        // A nadir camera's up direction is horizontal: give them no consistent one.
        let ups = vec![[0.0; 3]; centres.len()];
        let g = GroundFrame::fit(&centres, &ups, &[]);
        assert!(dot(g.up, normal).abs() > 1.0 - 1e-9, "{:?}", g.up);
        // The long side (y, 78 units against 40) is u.
        assert!(dot(g.u, ey).abs() > 1.0 - 1e-9, "{:?}", g.u);
        assert!(dot(g.u, g.v).abs() < 1e-12 && dot(g.v, g.up).abs() < 1e-12);
    }

    #[test]
    fn a_street_on_one_line_takes_up_from_the_cameras() {
        let centres: Vec<[f64; 3]> = (0..20).map(|i| [i as f64, 0.0, 1.5]).collect();
        let ups = vec![[0.0, 0.02, 1.0]; 20];
        let points: Vec<[f64; 3]> = (0..200)
            .map(|i| {
                let s = i as f64;
                [
                    s * 0.1,
                    if i % 2 == 0 { 5.0 } else { -5.0 },
                    (s * 0.37) % 8.0,
                ]
            })
            .collect();
        let g = GroundFrame::fit(&centres, &ups, &points);
        assert!(g.up[2] > 0.99, "{:?}", g.up);
        // The street's length (x: 20 units of points) is u.
        assert!(g.u[0].abs() > 0.9, "{:?}", g.u);
        let (c, h) = g.coordinates([3.0, 0.0, 1.5]);
        assert!(h.abs() < 0.1 && c[0].abs() > 2.5, "{c:?} {h}");
    }
}
