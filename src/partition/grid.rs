//! The cut: a grid of core rectangles that tiles the whole ground plane, balanced by the
//! points it holds, and each core's margin.
//!
//! Columns are cut at quantiles of the points' first ground coordinate, so every column holds
//! the same share of the reconstruction; each column's rows at quantiles of the second
//! coordinate of its own points (the layout VastGaussian balances its cameras with). The
//! outermost cores are unbounded, so every position on the ground lies in exactly one core:
//! a Gaussian trained outside the points' bounds still has one block that owns it. A margin is
//! a share of the core's points on each bounded side (the region reaches that much further in
//! the quantiles), the part of a block that is trained only to supervise its core's edges.
//! Measured in points rather than world units, it stays a fair share in a capture whose points
//! are dense at its centre and sparse for kilometres around (an orbit's background): a margin
//! of 20 % of the unbounded outer core's extent would take in most of the scene.

use serde::{Deserialize, Serialize};

/// A half-open interval `[lo, hi)`; `None` is unbounded on that side.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    pub lo: Option<f64>,
    pub hi: Option<f64>,
}

impl Interval {
    pub const ALL: Interval = Interval { lo: None, hi: None };

    pub fn contains(&self, x: f64) -> bool {
        self.lo.is_none_or(|l| x >= l) && self.hi.is_none_or(|h| x < h)
    }
}

/// A rectangle on the ground: an interval along u and one along v.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rect {
    pub u: Interval,
    pub v: Interval,
}

impl Rect {
    pub fn contains(&self, g: [f64; 2]) -> bool {
        self.u.contains(g[0]) && self.v.contains(g[1])
    }

    /// The rectangle clipped to `bounds` where it is unbounded (for drawing and for the
    /// visibility test's box).
    pub fn clipped(&self, bounds: Rect) -> [[f64; 2]; 2] {
        let clip = |i: Interval, b: Interval| {
            let lo = i.lo.or(b.lo).unwrap_or(0.0);
            let hi = i.hi.or(b.hi).unwrap_or(0.0);
            [lo, hi.max(lo)]
        };
        [clip(self.u, bounds.u), clip(self.v, bounds.v)]
    }
}

/// The `q`-quantile of sorted values (nearest rank below).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let k = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[k.min(sorted.len() - 1)]
}

/// The robust extent of ground positions: their 1st to 99th percentile along each axis.
pub fn robust_bounds(ground: &[[f64; 2]]) -> Rect {
    let axis = |a: usize| {
        let mut xs: Vec<f64> = ground.iter().map(|g| g[a]).collect();
        xs.sort_by(f64::total_cmp);
        if xs.is_empty() {
            return Interval::ALL;
        }
        Interval {
            lo: Some(quantile(&xs, 0.01)),
            hi: Some(quantile(&xs, 0.99)),
        }
    };
    Rect {
        u: axis(0),
        v: axis(1),
    }
}

/// The values at the quantiles `k/n` (k = 1..n−1) of sorted `xs`: the cuts between `n`
/// intervals.
fn edges(xs: &[f64], n: usize) -> Vec<Option<f64>> {
    let mut e: Vec<Option<f64>> = vec![None];
    for k in 1..n {
        e.push(if xs.is_empty() {
            Some(k as f64)
        } else {
            Some(quantile(xs, k as f64 / n as f64))
        });
    }
    e.push(None);
    e
}

/// Interval `k` of `n` cut at the quantiles of sorted `xs`, and the same grown by `margin`
/// of its share on each bounded side: out to the quantile `margin / n` further, so that a
/// margin holds `margin` × the core's points whatever their density (in world units it is
/// thin where the points are dense and wide where they thin out). A side grown past the
/// first or last value is unbounded.
fn interval(xs: &[f64], n: usize, k: usize, margin: f64) -> (Interval, Interval) {
    let e = edges(xs, n);
    let core = Interval {
        lo: e[k],
        hi: e[k + 1],
    };
    if xs.is_empty() {
        return (core, core);
    }
    let q_lo = k as f64 / n as f64 - margin / n as f64;
    let q_hi = (k + 1) as f64 / n as f64 + margin / n as f64;
    let region = Interval {
        lo: core.lo.and((q_lo > 0.0).then(|| quantile(xs, q_lo))),
        hi: core.hi.and((q_hi < 1.0).then(|| quantile(xs, q_hi))),
    };
    (core, region)
}

/// The cores of a `columns × rows` grid balanced over `ground` positions, column-major
/// (`[c * rows + r]`), each with its region: the core grown by `margin` (a share of the
/// core's points on each side, [`interval`]).
pub fn balanced_cores(
    ground: &[[f64; 2]],
    columns: usize,
    rows: usize,
    margin: f64,
) -> Vec<(Rect, Rect)> {
    let mut us: Vec<f64> = ground.iter().map(|g| g[0]).collect();
    us.sort_by(f64::total_cmp);
    let mut cells = Vec::with_capacity(columns * rows);
    for c in 0..columns {
        let (cu, ru) = interval(&us, columns, c, margin);
        let mut vs: Vec<f64> = ground
            .iter()
            .filter(|g| cu.contains(g[0]))
            .map(|g| g[1])
            .collect();
        vs.sort_by(f64::total_cmp);
        for r in 0..rows {
            let (cv, rv) = interval(&vs, rows, r, margin);
            cells.push((Rect { u: cu, v: cv }, Rect { u: ru, v: rv }));
        }
    }
    cells
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn cores_tile_the_plane_and_balance_the_points() {
        let mut s = 7;
        // A skewed cloud: dense near the origin, sparse far out.
        let ground: Vec<[f64; 2]> = (0..4000)
            .map(|_| [lcg(&mut s).powi(3) * 100.0, lcg(&mut s) * 30.0 - 15.0])
            .collect();
        for (c, r) in [(1, 1), (2, 1), (2, 2), (3, 2), (4, 3)] {
            let cores: Vec<Rect> = balanced_cores(&ground, c, r, 0.2)
                .into_iter()
                .map(|(c, _)| c)
                .collect();
            assert_eq!(cores.len(), c * r);
            // Every position, on the ground or far off it, is in exactly one core.
            let mut probes = ground.clone();
            probes.extend([[-1e9, 0.0], [1e9, 1e9], [50.0, -1e9], [0.0, 0.0]]);
            for p in &probes {
                let n = cores.iter().filter(|k| k.contains(*p)).count();
                assert_eq!(n, 1, "{p:?} in {n} cores of {c}x{r}");
            }
            let share = ground.len() as f64 / (c * r) as f64;
            for k in &cores {
                let n = ground.iter().filter(|p| k.contains(**p)).count() as f64;
                assert!((n - share).abs() <= 0.02 * share + 2.0, "{n} vs {share}");
            }
        }
    }

    #[test]
    fn margins_hold_a_share_of_the_core_points_on_each_bounded_side() {
        let mut s = 11;
        let ground: Vec<[f64; 2]> = (0..10000)
            .map(|_| [lcg(&mut s).powi(2) * 50.0, lcg(&mut s)])
            .collect();
        let cells = balanced_cores(&ground, 4, 1, 0.2);
        let count = |r: &Rect| ground.iter().filter(|p| r.contains(**p)).count() as f64;
        // An inner core (two bounded sides) gains 0.2 of its points on each; an outer one on
        // its inner side only, and stays unbounded outside.
        for (k, (core, region)) in cells.iter().enumerate() {
            let sides = if k == 0 || k == 3 { 1.0 } else { 2.0 };
            let want = count(core) * (1.0 + 0.2 * sides);
            assert!(
                (count(region) - want).abs() < 0.01 * want + 2.0,
                "{k}: {} vs {want}",
                count(region)
            );
            assert!(ground
                .iter()
                .all(|p| !core.contains(*p) || region.contains(*p)));
        }
        assert_eq!(cells[0].1.u.lo, None);
        assert_eq!(cells[3].1.u.hi, None);
        // A margin past the last value leaves the side unbounded.
        let wide = balanced_cores(&ground, 2, 1, 2.0);
        assert_eq!(wide[0].1.u.hi, None);
    }
}
