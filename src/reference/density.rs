//! Host reference of density control on [`GaussianParams`]-shaped data: the same decisions
//! (same f32 arithmetic, same thresholds), the same layout, the same RNG. Split children's
//! positions are computed in f64 (the GPU's `exp`/`log`/`cos` are not correctly rounded), every
//! other value is reproduced exactly.

use super::project::{normalize_quat, quat_to_rotation};
use crate::splats::{ExtraValues, GaussianParams};
use crate::train::density::rng::rng_normal;
use crate::train::density::{
    ScoreInput, Thresholds, DECIDE_CLONE, DECIDE_LOWERED, DECIDE_REMOVE, DECIDE_SPLIT,
};

/// Parameters and their Adam moments (the moments use the parameter layout).
#[derive(Debug, Clone, PartialEq)]
pub struct HostState {
    pub params: GaussianParams,
    pub m: GaussianParams,
    pub v: GaussianParams,
}

/// The statistics of [`crate::train::density::DensityStats`] on the host.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HostStats {
    pub grad_accum: Vec<f32>,
    pub denom: Vec<f32>,
    pub max_radii: Vec<f32>,
    pub abs_accum: Vec<f32>,
}

impl HostStats {
    pub fn zeros(n: usize) -> Self {
        Self {
            grad_accum: vec![0.0; n],
            denom: vec![0.0; n],
            max_radii: vec![0.0; n],
            abs_accum: vec![0.0; n],
        }
    }

    /// [`HostStats::accumulate`] with the absolute-gradient statistic as well.
    pub fn accumulate_with_abs(&mut self, view_grad_norm: &[f32], radii: &[f32], abs: &[f32]) {
        for (i, &r) in radii.iter().enumerate() {
            if r > 0.0 {
                self.abs_accum[i] += abs[i];
            }
        }
        self.accumulate(view_grad_norm, radii);
    }

    /// One view: visible (radius > 0) Gaussians add their norm, count the view, keep the max
    /// radius.
    pub fn accumulate(&mut self, view_grad_norm: &[f32], radii: &[f32]) {
        for (i, &r) in radii.iter().enumerate() {
            if r > 0.0 {
                self.grad_accum[i] += view_grad_norm[i];
                self.denom[i] += 1.0;
                self.max_radii[i] = self.max_radii[i].max(r);
            }
        }
    }
}

impl HostStats {
    /// One view under Pixel-GS's statistic (`accumulate.comp` mode 1, the same f32 operations
    /// in the same order): visible Gaussians add n·φ·norm and n, with n their pixel count and
    /// φ = min(1, (depth · depth_scale)²).
    pub fn accumulate_pixel_weighted(
        &mut self,
        view_grad_norm: &[f32],
        radii: &[f32],
        pixel_count: &[u32],
        depth: &[f32],
        depth_scale: f32,
    ) {
        for (i, &r) in radii.iter().enumerate() {
            if r > 0.0 {
                let n = pixel_count[i] as f32;
                let z = depth[i] * depth_scale;
                let phi = (z * z).min(1.0);
                self.grad_accum[i] += n * phi * view_grad_norm[i];
                self.denom[i] += n;
                self.max_radii[i] = self.max_radii[i].max(r);
            }
        }
    }
}

/// Gaussian `i`'s averaged statistic (0 when never seen) and its threshold (× its scale), as
/// `decide.comp` forms them.
fn statistic_and_threshold(
    t: &Thresholds,
    stats: &HostStats,
    threshold_scale: Option<&[f32]>,
    i: usize,
) -> (f32, f32) {
    let dn = stats.denom[i];
    let stat = if dn > 0.0 {
        stats.grad_accum[i] / dn
    } else {
        0.0
    };
    let thr = match threshold_scale {
        Some(s) => t.grad_threshold * s[i],
        None => t.grad_threshold,
    };
    (stat, thr)
}

/// The decision word of every Gaussian (`DECIDE_*` bits), as `decide.comp` computes it.
pub fn decide(
    t: &Thresholds,
    stats: &HostStats,
    params: &GaussianParams,
    threshold_scale: Option<&[f32]>,
) -> Vec<u32> {
    decide_with_abs(t, stats, params, threshold_scale, None)
}

/// [`decide`] with the absolute-gradient test at `abs_threshold` (when given).
pub fn decide_with_abs(
    t: &Thresholds,
    stats: &HostStats,
    params: &GaussianParams,
    threshold_scale: Option<&[f32]>,
    abs_threshold: Option<f32>,
) -> Vec<u32> {
    (0..params.len())
        .map(|i| {
            let (stat, thr) = statistic_and_threshold(t, stats, threshold_scale, i);
            let grows = t.grows_at(params.positions[i]);
            let (by_grad, by_abs) = candidacy(t, stats, stat, thr, abs_threshold, i, grows);
            let densify = by_grad || by_abs;
            let s = params.log_scales[i];
            let ls = s[0].max(s[1]).max(s[2]);
            let clone = densify && ls <= t.log_clone_max;
            let split = densify && ls > t.log_clone_max;
            let faint = params.opacity_logits[i] < t.min_opacity_logit;
            let big = t.prune_large && ls > t.log_world_max;
            let big_screen = t.screen_max >= 0.0 && stats.max_radii[i] > t.screen_max;
            let child_big = t.prune_large && (ls - t.log_split_shrink) > t.log_world_max;
            let mut d = 0;
            if faint || big || big_screen {
                d |= DECIDE_REMOVE;
            }
            if clone && !faint && !big {
                d |= DECIDE_CLONE;
            }
            if split {
                d |= if faint || child_big {
                    DECIDE_REMOVE
                } else {
                    DECIDE_SPLIT
                };
            }
            // Written as the kernel does (a NaN statistic never densifies, so it is never `lowered`).
            let at_global = stat >= t.grad_threshold;
            if (clone || split) && !at_global && !by_abs && !t.rank_all {
                d |= DECIDE_LOWERED;
            }
            d
        })
        .collect()
}

/// Whether Gaussian `i` is a candidate by the gradient test and by the absolute-gradient test,
/// as `decide.comp` forms them: over the (scaled) threshold, or under the exact budget
/// ([`Thresholds::rank_all`]) any positive statistic on a step that grows; neither where the
/// growth region does not hold the Gaussian (`grows` false).
fn candidacy(
    t: &Thresholds,
    stats: &HostStats,
    stat: f32,
    thr: f32,
    abs_threshold: Option<f32>,
    i: usize,
    grows: bool,
) -> (bool, bool) {
    let abs_stat = crate::train::density::abs_quantile::average(stats.abs_accum[i], stats.denom[i]);
    if !grows {
        return (false, false);
    }
    match t.rank_all {
        false => (stat >= thr, abs_threshold.is_some_and(|q| abs_stat >= q)),
        true => (
            stat > 0.0 && t.grad_threshold < f32::INFINITY,
            abs_threshold.is_some() && abs_stat > 0.0,
        ),
    }
}

/// Every Gaussian's score as `decide.comp` writes it (the same f32 operations): a candidate's
/// statistic over `grad_threshold` (over its own scaled threshold with
/// [`Thresholds::rank_lowered`]), the larger ratio when both tests pass, +∞ over a threshold
/// ≤ 0, times its `score` weight or replaced by its `score`; 0 for the others ([`crate::train::density::budget`] ranks additions by it).
/// `positions`: the Gaussians' centres (the growth region's test).
pub fn scores(
    t: &Thresholds,
    stats: &HostStats,
    positions: &[[f32; 3]],
    threshold_scale: Option<&[f32]>,
    score: Option<ScoreInput<&[f32]>>,
    abs_threshold: Option<f32>,
) -> Vec<f32> {
    let ratio = |pass: bool, v: f32, thr: f32| match (pass, thr > 0.0) {
        (false, _) => 0.0,
        (true, true) => v / thr,
        (true, false) => f32::INFINITY,
    };
    (0..stats.denom.len())
        .map(|i| {
            let dn = stats.denom[i];
            let (stat, thr) = statistic_and_threshold(t, stats, threshold_scale, i);
            let abs_stat = crate::train::density::abs_quantile::average(stats.abs_accum[i], dn);
            let grows = t.grows_at(positions[i]);
            let (by_grad, by_abs) = candidacy(t, stats, stat, thr, abs_threshold, i, grows);
            let over = if t.rank_lowered {
                thr
            } else {
                t.grad_threshold
            };
            let grad = ratio(by_grad, stat, over);
            let abs = ratio(by_abs, abs_stat, abs_threshold.unwrap_or(f32::INFINITY));
            let ratio = grad.max(abs);
            match score {
                Some(ScoreInput::Weight(w)) if by_grad || by_abs => ratio * w[i],
                Some(ScoreInput::Replace(w)) if by_grad || by_abs => w[i],
                _ => ratio,
            }
        })
        .collect()
}

fn keeps(d: u32) -> bool {
    d & (DECIDE_REMOVE | DECIDE_SPLIT) == 0
}

/// Row `i` of every array of `p` appended to `out` (`zero`: zeros instead).
fn push_row(out: &mut GaussianParams, p: &GaussianParams, i: usize, zero: bool) {
    let z = |v: f32| if zero { 0.0 } else { v };
    out.positions.push(p.positions[i].map(z));
    out.log_scales.push(p.log_scales[i].map(z));
    out.rotations.push(p.rotations[i].map(z));
    out.opacity_logits.push(z(p.opacity_logits[i]));
    out.sh_dc.push(p.sh_dc[i].map(z));
    out.sh_rest
        .extend(p.sh_rest_of(i).unwrap_or(&[]).iter().map(|&v| z(v)));
    for (o, e) in out.extra.iter_mut().zip(&p.extra) {
        let s = e.group.stride;
        o.values
            .extend(e.values[i * s..(i + 1) * s].iter().map(|&v| z(v)));
    }
}

/// An empty model of `p`'s shape (its SH degree and extra groups).
fn empty_like(p: &GaussianParams) -> GaussianParams {
    let mut out = GaussianParams::empty(p.sh_degree);
    out.extra = p
        .extra
        .iter()
        .map(|e| ExtraValues {
            group: e.group.clone(),
            values: Vec::new(),
        })
        .collect();
    out
}

/// Position of split child `j` of Gaussian `i` (f64 math on the f32 inputs).
pub fn child_position(p: &GaussianParams, i: usize, j: u32, seed: u32, step: u32) -> [f32; 3] {
    let q = p.rotations[i].map(|v| v as f64);
    let r = match normalize_quat(q) {
        Some((u, _)) => quat_to_rotation(u),
        None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };
    let local: [f64; 3] = std::array::from_fn(|k| {
        (p.log_scales[i][k] as f64).exp() * rng_normal(seed, step, i as u32, 3 * j + k as u32)
    });
    std::array::from_fn(|a| {
        let off: f64 = (0..3).map(|k| r[a][k] * local[k]).sum();
        (p.positions[i][a] as f64 + off) as f32
    })
}

/// The decision word of every Gaussian under `prune_outside_box.comp`: `DECIDE_REMOVE` when a
/// coordinate of its centre is below `lo` or above `hi` (a NaN coordinate is kept), else 0.
pub fn prune_outside_box(positions: &[[f32; 3]], lo: [f32; 3], hi: [f32; 3]) -> Vec<u32> {
    positions
        .iter()
        .map(|p| {
            let outside = (0..3).any(|a| p[a] < lo[a] || p[a] > hi[a]);
            if outside {
                DECIDE_REMOVE
            } else {
                0
            }
        })
        .collect()
}

/// The rows of `p` whose decision keeps them (neither removed nor split), in order: what a
/// density step that only prunes leaves.
pub fn kept_rows(p: &GaussianParams, decisions: &[u32]) -> GaussianParams {
    let mut out = empty_like(p);
    for (i, &d) in decisions.iter().enumerate() {
        if keeps(d) {
            push_row(&mut out, p, i, false);
        }
    }
    out
}

/// The state after applying `decisions`: survivors in order, then clones, then two adjacent
/// children per split parent. New Gaussians get zero moments.
pub fn apply(
    state: &HostState,
    decisions: &[u32],
    seed: u32,
    step: u32,
    log_split_shrink: f32,
) -> HostState {
    let mut out = HostState {
        params: empty_like(&state.params),
        m: empty_like(&state.m),
        v: empty_like(&state.v),
    };
    let p = &state.params;
    for (i, &d) in decisions.iter().enumerate() {
        if keeps(d) {
            push_row(&mut out.params, p, i, false);
            push_row(&mut out.m, &state.m, i, false);
            push_row(&mut out.v, &state.v, i, false);
        }
    }
    for (i, &d) in decisions.iter().enumerate() {
        if d & DECIDE_CLONE != 0 {
            push_row(&mut out.params, p, i, false);
            push_row(&mut out.m, &state.m, i, true);
            push_row(&mut out.v, &state.v, i, true);
        }
    }
    for (i, &d) in decisions.iter().enumerate() {
        if d & DECIDE_SPLIT != 0 {
            for j in 0..2 {
                push_row(&mut out.params, p, i, false);
                let last = out.params.len() - 1;
                out.params.positions[last] = child_position(p, i, j, seed, step);
                out.params.log_scales[last] = p.log_scales[i].map(|v| v - log_split_shrink);
                push_row(&mut out.m, &state.m, i, true);
                push_row(&mut out.v, &state.v, i, true);
            }
        }
    }
    out
}

/// The opacity reset: logits capped at `max_logit`, opacity moments zeroed.
pub fn reset_opacity(state: &mut HostState, max_logit: f32) {
    for x in &mut state.params.opacity_logits {
        *x = x.min(max_logit);
    }
    state.m.opacity_logits.iter_mut().for_each(|v| *v = 0.0);
    state.v.opacity_logits.iter_mut().for_each(|v| *v = 0.0);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::density::{DensifyArgs, DensifyPhase, DensityConfig};

    fn one(log_scale: f32, opacity_logit: f32) -> GaussianParams {
        let mut p = GaussianParams::empty(0);
        p.positions.push([0.0; 3]);
        p.log_scales
            .push([log_scale - 1.0, log_scale, log_scale - 2.0]);
        p.rotations.push([1.0, 0.0, 0.0, 0.0]);
        p.opacity_logits.push(opacity_logit);
        p.sh_dc.push([0.0; 3]);
        p
    }

    #[test]
    fn rules_of_the_reference_on_single_gaussians() {
        let extent = 2.0;
        let args = |prune_large| DensifyArgs {
            extent,
            prune_large,
            iteration: 1000,
            phase: DensifyPhase::Both,
        };
        let t = Thresholds::new(&DensityConfig::default(), &args(false)).unwrap();
        let tl = Thresholds::new(&DensityConfig::default(), &args(true)).unwrap();
        let stats = |g: f32, n: f32| HostStats {
            grad_accum: vec![g * n],
            denom: vec![n],
            max_radii: vec![30.0],
            abs_accum: vec![0.0],
        };
        let small = (0.005f32 * extent as f32).ln(); // below 0.01·extent
        let mid = (0.05f32 * extent as f32).ln(); // between 0.01 and 0.1·extent
        let huge = (0.5f32 * extent as f32).ln(); // above 0.1·extent
        let opaque = 0.0; // opacity 0.5
        let faint = -6.0; // opacity 0.0025
        let d = |t: &Thresholds, s: &HostStats, p: &GaussianParams| decide(t, s, p, None)[0];
        assert_eq!(d(&t, &stats(3e-4, 4.0), &one(small, opaque)), DECIDE_CLONE);
        assert_eq!(d(&t, &stats(3e-4, 4.0), &one(mid, opaque)), DECIDE_SPLIT);
        assert_eq!(d(&t, &stats(1e-4, 4.0), &one(mid, opaque)), 0);
        assert_eq!(d(&t, &stats(3e-4, 0.0), &one(mid, opaque)), 0, "never seen");
        assert_eq!(d(&t, &stats(0.0, 0.0), &one(small, faint)), DECIDE_REMOVE);
        assert_eq!(
            d(&t, &stats(3e-4, 2.0), &one(small, faint)),
            DECIDE_REMOVE,
            "a faint clone is pruned with its parent"
        );
        assert_eq!(
            d(&t, &stats(3e-4, 2.0), &one(mid, faint)),
            DECIDE_REMOVE,
            "faint children are pruned"
        );
        assert_eq!(d(&t, &stats(0.0, 1.0), &one(huge, opaque)), 0);
        assert_eq!(d(&tl, &stats(0.0, 1.0), &one(huge, opaque)), DECIDE_REMOVE);
        // Children of a huge Gaussian are 1.6× smaller: still too big → nothing survives.
        assert_eq!(d(&tl, &stats(1.0, 1.0), &one(huge, opaque)), DECIDE_REMOVE);
        // A parent just above the limit has children below it.
        let above = (0.12f32 * extent as f32).ln();
        assert_eq!(
            d(&tl, &stats(1.0, 1.0), &one(above, opaque)),
            DECIDE_REMOVE | DECIDE_SPLIT
        );
        // Lowered threshold.
        let p = one(small, opaque);
        let s = stats(1.5e-4, 3.0);
        assert_eq!(decide(&t, &s, &p, Some(&[1.0]))[0], 0);
        assert_eq!(
            decide(&t, &s, &p, Some(&[0.5]))[0],
            DECIDE_CLONE | DECIDE_LOWERED
        );
    }
}
