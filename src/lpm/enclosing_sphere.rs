//! Exact minimum enclosing sphere of a 3D point set (Welzl's algorithm, move-to-front form).
//!
//! The points are first shuffled with a fixed-seed RNG (expected linear time, same answer on every
//! run). The move-to-front loop recurses only when a point joins the support set, so the depth is
//! at most 4. Degenerate inputs (duplicates, collinear, coplanar sets) are handled in two ways:
//! the "is inside" test carries a small tolerance relative to the set's size, so points that lie
//! on the current sphere up to rounding never enter the support set; and a support set that is
//! affinely dependent (which exact arithmetic never produces) is refused instead of giving a
//! wild sphere. A final pass checks that every point is inside and, if rounding ever left one
//! out, grows the radius to cover it, so the result always encloses the input.

use glam::DVec3;
use rand::seq::SliceRandom;
use rand::SeedableRng;

/// A sphere in world units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub center: [f64; 3],
    pub radius: f64,
}

impl Sphere {
    /// True when `p` is inside or on the sphere, up to `tol` (absolute).
    pub fn contains(&self, p: [f64; 3], tol: f64) -> bool {
        DVec3::from(p).distance(DVec3::from(self.center)) <= self.radius + tol
    }
}

#[derive(Clone, Copy)]
struct Ball {
    center: DVec3,
    radius2: f64,
}

/// The smallest sphere enclosing all finite points of `points`; `None` when there are none.
/// Non-finite points are ignored (the zone code filters them before; this keeps the function
/// total).
pub fn minimum_enclosing_sphere(points: &[[f64; 3]]) -> Option<Sphere> {
    let mut pts: Vec<DVec3> = points
        .iter()
        .map(|&p| DVec3::from(p))
        .filter(|p| p.is_finite())
        .collect();
    if pts.is_empty() {
        return None;
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x5eed_5a11);
    pts.shuffle(&mut rng);

    // Tolerance: relative to the size of the set, so the answer does not depend on units.
    let origin = pts[0];
    let scale = pts
        .iter()
        .map(|p| (*p - origin).abs().max_element())
        .fold(0.0, f64::max);
    let eps = 1e-12 * scale.max(f64::MIN_POSITIVE) + 1e-300;

    let mut support: Vec<DVec3> = Vec::with_capacity(4);
    let n = pts.len();
    let ball = move_to_front(&mut pts, n, &mut support, eps);

    let mut radius = ball.radius2.max(0.0).sqrt();
    // Final guarantee: enclose every point (a no-op unless rounding bit).
    for p in &pts {
        radius = radius.max(p.distance(ball.center));
    }
    Some(Sphere {
        center: ball.center.to_array(),
        radius,
    })
}

fn inside(ball: &Ball, p: DVec3, eps: f64) -> bool {
    let r = ball.radius2.max(0.0).sqrt();
    p.distance(ball.center) <= r + eps
}

/// Smallest ball of `pts[..end]` with `support` on its boundary; moves the points that defined
/// it to the front (so later passes meet them first and rarely recurse).
fn move_to_front(pts: &mut [DVec3], end: usize, support: &mut Vec<DVec3>, eps: f64) -> Ball {
    let mut ball = ball_on_boundary(support).unwrap_or(Ball {
        center: DVec3::ZERO,
        radius2: -1.0,
    });
    if support.len() == 4 {
        return ball;
    }
    for i in 0..end {
        let p = pts[i];
        if ball.radius2 >= 0.0 && inside(&ball, p, eps) {
            continue;
        }
        support.push(p);
        if ball_on_boundary(support).is_none() {
            // Affinely dependent support: impossible in exact arithmetic (see module doc);
            // the point is within rounding of the sphere, so leave the ball as it is.
            support.pop();
            continue;
        }
        ball = move_to_front(pts, i, support, eps);
        support.pop();
        pts[..=i].rotate_right(1);
    }
    ball
}

/// The smallest ball with all of `s` (0 to 4 points) on its boundary: its centre lies in the affine
/// hull of `s`. `None` when `s` is affinely dependent (or numerically so).
fn ball_on_boundary(s: &[DVec3]) -> Option<Ball> {
    match s.len() {
        0 => None,
        1 => Some(Ball {
            center: s[0],
            radius2: 0.0,
        }),
        _ => {
            let q0 = s[0];
            let k = s.len() - 1;
            let d: Vec<DVec3> = s[1..].iter().map(|q| *q - q0).collect();
            // Centre c = q0 + Σ λ_j d_j with |c − q_i| = |c − q0|:  2 Σ_j (d_i·d_j) λ_j = |d_i|².
            let mut a = [[0.0f64; 4]; 3];
            for i in 0..k {
                for j in 0..k {
                    a[i][j] = 2.0 * d[i].dot(d[j]);
                }
                a[i][3] = d[i].length_squared();
            }
            let scale = d.iter().map(|v| v.length_squared()).fold(0.0, f64::max);
            let lambda = solve(&mut a, k, scale)?;
            let mut offset = DVec3::ZERO;
            for j in 0..k {
                offset += lambda[j] * d[j];
            }
            let center = q0 + offset;
            if !center.is_finite() {
                return None;
            }
            Some(Ball {
                center,
                radius2: offset.length_squared(),
            })
        }
    }
}

/// Gaussian elimination with partial pivoting on a k×k system (k ≤ 3) stored with its right-hand
/// side in column 3. Refuses pivots that are tiny against `scale` (the Gram matrix is then
/// singular: the support points are affinely dependent).
fn solve(a: &mut [[f64; 4]; 3], k: usize, scale: f64) -> Option<[f64; 3]> {
    let tiny = 1e-10 * scale.max(f64::MIN_POSITIVE);
    for col in 0..k {
        let piv = (col..k).max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))?;
        if a[piv][col].abs().partial_cmp(&tiny) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        a.swap(col, piv);
        let pivot_row = a[col];
        for row in a.iter_mut().take(k).skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (x, p) in row.iter_mut().zip(pivot_row.iter()).skip(col) {
                *x -= f * p;
            }
        }
    }
    let mut x = [0.0; 3];
    for row in (0..k).rev() {
        let mut v = a[row][3];
        for c in row + 1..k {
            v -= a[row][c] * x[c];
        }
        x[row] = v / a[row][row];
    }
    Some(x)
}
