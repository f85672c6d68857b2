//! What one MCMC refinement does, planned on the host from the opacities (read back once per
//! refinement): which dead Gaussians move onto which live ones, which live ones are copied into
//! new rows, and every touched row's new opacity and scale.
//!
//! # Relocation (Kheradmand et al. 2024, their eq. 9, in our words)
//! A Gaussian of opacity `o` and scale `s` that is sampled `n − 1` times becomes `n` identical
//! Gaussians (itself and `n − 1` copies) of opacity `o' = 1 − (1 − o)^(1/n)` (so that `n` of them
//! stacked let as little light through as the one did) and scale `s' = c·s` with
//! `c = o / Σ_{i=1..n} Σ_{k=0..i−1} C(i−1, k) (−1)^k o'^(k+1) / √(k+1)` (so that the stack
//! composites to the same opacity profile integrated along a ray through its centre). Here
//! the double sum is formed in f64; [`crate::reference::mcmc`] checks it against a quadrature
//! of the integral it stands for, `∫ 1 − (1 − o' g(x))^n dx / √(2π)`, `g(x) = exp(−x²/2)`.
//!
//! # Clamps (numerical extremes, tested)
//! - `n` is clamped to [`MAX_RATIO`] (51, as the peers do): a Gaussian drawn more often than
//!   that keeps the opacity of a 51-way split in each copy (the stack is then a little more
//!   opaque than the original). The alternating sum loses about `C(50, 25)·ε₆₄ ≈ 1e−2` of
//!   relative precision only when `o'` approaches 1, which the next clamp rules out.
//! - `o'` is clamped to `[min_opacity, 1 − 2⁻²³]` before `c` is formed: a copy that would be
//!   dead at once would be moved again at the next refinement; an opacity of 1 has no logit.
//!
//! # Sampling
//! Sources are drawn with replacement ∝ opacity (× a guide's weight) among the live Gaussians
//! (relocation) or all of them (growth), by binary search in the cumulative sums, from a PCG
//! stream keyed by (seed, iteration, which plan): a run is deterministic for a seed.

use rand::{Rng, SeedableRng};

/// The most copies one Gaussian is split into at one refinement.
pub const MAX_RATIO: u32 = 51;

/// One plan: copy rows (`dst ← src`, parameters copied, moments of both zeroed), then set every
/// listed row's opacity logit and add its log-scale change.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Plan {
    /// `(dst, src)`: destinations are distinct and never a source.
    pub copies: Vec<(u32, u32)>,
    /// `(row, new opacity logit, log-scale change)`, each row once: every copied source and
    /// destination.
    pub updates: Vec<(u32, f32, f32)>,
}

impl Plan {
    pub fn is_empty(&self) -> bool {
        self.copies.is_empty()
    }
}

pub fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

pub fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// The opacity and scale factor of each of `n` copies of a Gaussian of opacity `o` (see the
/// module docs; `n` clamped to `1..=MAX_RATIO`, the new opacity to `[min_opacity, 1 − 2⁻²³]`).
pub fn relocation(o: f64, n: u32, min_opacity: f64) -> (f64, f64) {
    let n = n.clamp(1, MAX_RATIO);
    let top = 1.0 - f32::EPSILON as f64;
    let o_new = (1.0 - (1.0 - o).powf(1.0 / n as f64)).clamp(min_opacity, top);
    let mut denom = 0.0f64;
    for i in 1..=n {
        // Σ_k C(i−1, k) (−o')^k / √(k+1), the binomial coefficient built up term by term.
        let mut binom = 1.0f64;
        let mut power = o_new;
        for k in 0..i {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            denom += sign * binom * power / ((k + 1) as f64).sqrt();
            binom = binom * (i - 1 - k) as f64 / (k + 1) as f64;
            power *= o_new;
        }
    }
    (o_new, o / denom)
}

/// Draws `m` indices of `weights` (≥ 0, not all zero) with replacement ∝ weight.
pub fn sample_weighted(weights: &[f64], m: usize, rng: &mut impl Rng) -> Vec<u32> {
    let mut cumulative = Vec::with_capacity(weights.len());
    let mut total = 0.0f64;
    for &w in weights {
        total += w.max(0.0);
        cumulative.push(total);
    }
    // NaN-explicit: a NaN total (never: weights are clamped at 0) draws nothing.
    if total.is_nan() || total <= 0.0 {
        return Vec::new();
    }
    (0..m)
        .map(|_| {
            let u = rng.gen::<f64>() * total;
            // First index whose cumulative sum exceeds u (a zero weight is never drawn).
            cumulative
                .partition_point(|&c| c <= u)
                .min(weights.len() - 1) as u32
        })
        .collect()
}

/// The PCG stream of the plan `which` (0 relocation, 1 growth) at `iteration`.
pub fn plan_rng(seed: u64, iteration: u32, which: u64) -> rand_pcg::Pcg64 {
    rand_pcg::Pcg64::seed_from_u64(
        seed ^ (iteration as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ which.rotate_left(61),
    )
}

/// For drawn `sources` (with repeats), the plan that gives each drawn source `n` copies in
/// `dsts` (one a draw, in order) with every member of each stack corrected for `n + 1`; the
/// opacities in `logits` are updated to the plan's result.
fn plan_copies(logits: &mut [f32], sources: &[u32], dsts: &[u32], min_opacity: f64) -> Plan {
    debug_assert_eq!(sources.len(), dsts.len());
    let mut drawn = std::collections::BTreeMap::<u32, u32>::new();
    for &s in sources {
        *drawn.entry(s).or_default() += 1;
    }
    let mut plan = Plan::default();
    let mut per_source = std::collections::HashMap::new();
    for (&s, &times) in &drawn {
        let o = sigmoid(logits[s as usize] as f64);
        let (o_new, c) = relocation(o, times + 1, min_opacity);
        let value = (logit(o_new) as f32, c.ln() as f32);
        per_source.insert(s, value);
        plan.updates.push((s, value.0, value.1));
    }
    for (&s, &d) in sources.iter().zip(dsts) {
        let value = per_source[&s];
        plan.copies.push((d, s));
        plan.updates.push((d, value.0, value.1));
    }
    for &(row, l, _) in &plan.updates {
        if let Some(x) = logits.get_mut(row as usize) {
            *x = l;
        }
    }
    plan
}

/// The dead Gaussians among `logits`: opacity ≤ `min_opacity`, or NaN.
pub fn dead_rows(logits: &[f32], min_opacity: f64) -> Vec<u32> {
    (0..logits.len() as u32)
        .filter(|&i| {
            let o = sigmoid(logits[i as usize] as f64);
            // A NaN opacity counts as dead (moved onto a live one).
            o.is_nan() || o <= min_opacity
        })
        .collect()
}

/// The `remove` rows of lowest opacity (a NaN opacity lowest of all; ties to the lower row), in
/// increasing order: what a falling budget curve takes away (`--budget-draw keep`). All rows
/// when `remove` is at least their number.
pub fn lowest_opacity_rows(logits: &[f32], remove: usize) -> Vec<u32> {
    // Every refinement asks, and on a rising curve the answer is none: no sort then.
    if remove == 0 {
        return Vec::new();
    }
    let mut order: Vec<u32> = (0..logits.len() as u32).collect();
    let key = |i: u32| {
        let l = logits[i as usize];
        if l.is_nan() {
            f32::NEG_INFINITY
        } else {
            l
        }
    };
    // The logit is monotonic in the opacity: rank by it.
    order.sort_by(|&a, &b| key(a).total_cmp(&key(b)).then(a.cmp(&b)));
    order.truncate(remove);
    order.sort_unstable();
    order
}

/// The relocation plan: every Gaussian of opacity ≤ `min_opacity` (among the first `logits.len()`)
/// moves onto a live one drawn ∝ opacity × `weight` (1 without a guide). `logits` is updated
/// to the opacities after the plan. No live Gaussian: an empty plan.
pub fn plan_relocation(
    logits: &mut [f32],
    weight: Option<&[f32]>,
    min_opacity: f64,
    rng: &mut impl Rng,
) -> Plan {
    let dead = dead_rows(logits, min_opacity);
    plan_relocation_of(logits, weight, min_opacity, &dead, rng)
}

/// [`plan_relocation`] of the dead rows `moving` only (a subset of [`dead_rows`]; the others
/// stay where they are, for the caller to fill).
pub fn plan_relocation_of(
    logits: &mut [f32],
    weight: Option<&[f32]>,
    min_opacity: f64,
    moving: &[u32],
    rng: &mut impl Rng,
) -> Plan {
    let opacity: Vec<f64> = logits.iter().map(|&l| sigmoid(l as f64)).collect();
    let live: Vec<u32> = (0..logits.len() as u32)
        .filter(|&i| opacity[i as usize] > min_opacity)
        .collect();
    if moving.is_empty() || live.is_empty() {
        return Plan::default();
    }
    let w: Vec<f64> = live
        .iter()
        .map(|&i| opacity[i as usize] * weight.map_or(1.0, |w| w[i as usize] as f64))
        .collect();
    let picks = sample_weighted(&w, moving.len(), rng);
    if picks.len() != moving.len() {
        return Plan::default();
    }
    let sources: Vec<u32> = picks.iter().map(|&k| live[k as usize]).collect();
    plan_copies(logits, &sources, moving, min_opacity)
}

/// Which dead rows take a guide's surface samples, and which sample each takes: at most
/// ⌊`share` · dead⌋ rows and at most one a sample, both chosen uniformly at random without
/// replacement. Returns `(row, sample index)` pairs, rows in increasing order; the rest of
/// `dead` is for [`plan_relocation_of`].
pub fn plan_seeded(
    dead: &[u32],
    samples: usize,
    share: f64,
    rng: &mut impl Rng,
) -> Vec<(u32, u32)> {
    let share = if share.is_finite() {
        share.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let k = ((share * dead.len() as f64).floor() as usize).min(samples);
    if k == 0 {
        return Vec::new();
    }
    let rows = rand::seq::index::sample(rng, dead.len(), k);
    let picks = rand::seq::index::sample(rng, samples, k);
    let mut out: Vec<(u32, u32)> = rows
        .iter()
        .zip(picks.iter())
        .map(|(r, p)| (dead[r], p as u32))
        .collect();
    out.sort_unstable();
    out
}

/// The growth plan: `m` new rows after the current `logits.len()`, each a copy of a Gaussian
/// drawn ∝ opacity × `weight` among all of them. `logits` is updated (the new rows' opacities
/// are the plan's `updates`).
pub fn plan_growth(
    logits: &mut [f32],
    weight: Option<&[f32]>,
    m: usize,
    min_opacity: f64,
    rng: &mut impl Rng,
) -> Plan {
    let n = logits.len() as u32;
    let w: Vec<f64> = (0..logits.len())
        .map(|i| sigmoid(logits[i] as f64) * weight.map_or(1.0, |w| w[i] as f64))
        .collect();
    let sources = sample_weighted(&w, m, rng);
    let dsts: Vec<u32> = (n..n + sources.len() as u32).collect();
    plan_copies(logits, &sources, &dsts, min_opacity)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_least_opaque_rows_go_first_nan_before_all_ties_to_the_lower_row() {
        let logits = [0.5, -3.0, f32::NAN, -3.0, 2.0, -7.0];
        assert_eq!(lowest_opacity_rows(&logits, 0), Vec::<u32>::new());
        assert_eq!(lowest_opacity_rows(&logits, 1), vec![2]);
        assert_eq!(lowest_opacity_rows(&logits, 2), vec![2, 5]);
        assert_eq!(lowest_opacity_rows(&logits, 3), vec![1, 2, 5]);
        assert_eq!(lowest_opacity_rows(&logits, 4), vec![1, 2, 3, 5]);
        assert_eq!(lowest_opacity_rows(&logits, 9), vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn one_copy_changes_nothing_and_two_halve_the_transmittance() {
        let (o, c) = relocation(0.7, 1, 0.005);
        assert!(
            (o - 0.7).abs() < 1e-12 && (c - 1.0).abs() < 1e-12,
            "{o} {c}"
        );
        let (o2, _) = relocation(0.75, 2, 0.005);
        assert!(((1.0 - o2) * (1.0 - o2) - 0.25).abs() < 1e-12);
        // Clamps: a faint source's copies stay alive; n above the clamp is the clamp.
        assert_eq!(relocation(0.006, 40, 0.005).0, 0.005);
        assert_eq!(
            relocation(0.9, 500, 0.005),
            relocation(0.9, MAX_RATIO, 0.005)
        );
    }

    #[test]
    fn relocation_moves_every_dead_gaussian_onto_a_live_one_and_keeps_rows_unique() {
        let mut rng = plan_rng(3, 700, 0);
        let mut logits: Vec<f32> = (0..400)
            .map(|i| {
                if i % 4 == 0 {
                    -8.0
                } else {
                    (i % 7) as f32 - 3.0
                }
            })
            .collect();
        let before = logits.clone();
        let plan = plan_relocation(&mut logits, None, 0.005, &mut rng);
        assert_eq!(plan.copies.len(), 100);
        let mut rows: Vec<u32> = plan.updates.iter().map(|u| u.0).collect();
        rows.sort();
        rows.dedup();
        assert_eq!(rows.len(), plan.updates.len(), "a row updated twice");
        for &(d, s) in &plan.copies {
            assert!(before[d as usize] == -8.0 && before[s as usize] > -8.0);
        }
        assert!(logits.iter().all(|&l| sigmoid(l as f64) >= 0.005 - 1e-9));
    }

    /// A guide's weights steer the draws: a live Gaussian of weight 0 is never a source, and
    /// sources follow opacity × weight.
    #[test]
    fn a_guides_weights_steer_relocation_and_growth() {
        let n = 1_000;
        let mut logits: Vec<f32> = (0..n).map(|i| if i < 200 { -9.0 } else { 1.0 }).collect();
        // Live Gaussians 200..600 weigh 0, 600..1000 weigh 3 (the zone).
        let weight: Vec<f32> = (0..n).map(|i| if i < 600 { 0.0 } else { 3.0 }).collect();
        let mut l = logits.clone();
        let plan = plan_relocation(&mut l, Some(&weight), 0.005, &mut plan_rng(0, 1, 0));
        assert_eq!(plan.copies.len(), 200);
        assert!(
            plan.copies.iter().all(|&(_, s)| s >= 600),
            "{:?}",
            plan.copies
        );
        let grow = plan_growth(
            &mut logits,
            Some(&weight),
            50,
            0.005,
            &mut plan_rng(0, 1, 1),
        );
        assert!(grow.copies.iter().all(|&(d, s)| s >= 600 && d >= n as u32));
    }

    /// The seeded rows: at most the share of the dead and one a sample, distinct rows among
    /// the dead and distinct samples, seeded; nothing at share 0 or without samples.
    #[test]
    fn seeded_rows_are_distinct_dead_rows_each_taking_a_distinct_sample() {
        let dead: Vec<u32> = (0..40).map(|i| 3 * i + 1).collect();
        let s = plan_seeded(&dead, 100, 0.5, &mut plan_rng(7, 3, 2));
        assert_eq!(s.len(), 20);
        let rows: std::collections::BTreeSet<u32> = s.iter().map(|p| p.0).collect();
        let picks: std::collections::BTreeSet<u32> = s.iter().map(|p| p.1).collect();
        assert_eq!((rows.len(), picks.len()), (20, 20));
        assert!(rows.iter().all(|r| dead.contains(r)));
        assert!(picks.iter().all(|&k| k < 100));
        assert!(s.windows(2).all(|w| w[0].0 < w[1].0), "rows in order");
        assert_eq!(s, plan_seeded(&dead, 100, 0.5, &mut plan_rng(7, 3, 2)));
        assert_eq!(plan_seeded(&dead, 5, 1.0, &mut plan_rng(7, 3, 2)).len(), 5);
        assert!(plan_seeded(&dead, 0, 1.0, &mut plan_rng(7, 3, 2)).is_empty());
        assert!(plan_seeded(&dead, 9, 0.0, &mut plan_rng(7, 3, 2)).is_empty());
        assert!(plan_seeded(&dead, 9, f64::NAN, &mut plan_rng(7, 3, 2)).is_empty());
        assert!(plan_seeded(&[], 9, 1.0, &mut plan_rng(7, 3, 2)).is_empty());
    }

    #[test]
    fn sampling_follows_the_weights() {
        let mut rng = plan_rng(1, 2, 3);
        let w = [0.0, 1.0, 3.0, 0.0, 4.0];
        let picks = sample_weighted(&w, 80_000, &mut rng);
        let mut n = [0usize; 5];
        for p in picks {
            n[p as usize] += 1;
        }
        assert_eq!((n[0], n[3]), (0, 0));
        for (k, want) in [(1, 0.125), (2, 0.375), (4, 0.5)] {
            let got = n[k] as f64 / 80_000.0;
            assert!((got - want).abs() < 0.006, "index {k}: {got} for {want}");
        }
    }
}
