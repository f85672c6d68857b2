//! The absolute-gradient densification test's threshold (Gaussian Opacity Fields, as
//! Mip-Splatting's official code runs it; docs/algorithms/base-models.md §2.5): with `ratio` the fraction of
//! Gaussians whose averaged usual statistic reaches the gradient threshold, the threshold on
//! the averaged absolute gradient is their `(1 − ratio)` quantile, so the second test selects
//! about as many Gaussians as the first, chosen by a statistic that signed sums cannot cancel.
//!
//! Computed on the host from the statistics read back once per densify step (12 bytes a
//! Gaussian: 12 MB for a million, every 100 iterations), with the averages formed as the decide
//! kernel forms them (f32 `accum / denom`, 0 when never seen).

/// `stat = accum / denom` in f32, 0 when `denom` is 0 (as `decide.comp`).
pub fn average(accum: f32, denom: f32) -> f32 {
    if denom > 0.0 {
        accum / denom
    } else {
        0.0
    }
}

/// The quantile `q` ∈ [0, 1] of `values` with linear interpolation between the order
/// statistics at `q · (n − 1)` (torch.quantile's default). `values` is reordered. NaN sorts
/// last; an empty slice gives +∞ (no Gaussian passes).
pub fn quantile_linear(values: &mut [f32], q: f64) -> f32 {
    let n = values.len();
    if n == 0 {
        return f32::INFINITY;
    }
    let pos = q.clamp(0.0, 1.0) * (n - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(n - 1);
    let order = |a: &f32, b: &f32| a.total_cmp(b);
    let (_, &mut v_lo, upper) = values.select_nth_unstable_by(lo, order);
    // The next order statistic is the smallest of the values above the lo-th.
    let v_hi = if hi == lo {
        v_lo
    } else {
        upper.iter().copied().min_by(order).unwrap_or(v_lo)
    };
    (v_lo as f64 + (v_hi as f64 - v_lo as f64) * (pos - lo as f64)) as f32
}

/// The absolute-gradient threshold `Q` for `n` Gaussians' statistics (all slices of length n).
pub fn abs_grad_threshold(
    grad_accum: &[f32],
    denom: &[f32],
    abs_accum: &[f32],
    grad_threshold: f32,
) -> f32 {
    let n = denom.len();
    let passing = (0..n)
        .filter(|&i| average(grad_accum[i], denom[i]) >= grad_threshold)
        .count();
    let ratio = if n == 0 {
        0.0
    } else {
        passing as f64 / n as f64
    };
    let mut abs: Vec<f32> = (0..n).map(|i| average(abs_accum[i], denom[i])).collect();
    quantile_linear(&mut abs, 1.0 - ratio)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The definition: sort, interpolate.
    fn by_sorting(values: &[f32], q: f64) -> f32 {
        let mut v = values.to_vec();
        v.sort_by(f32::total_cmp);
        let pos = q * (v.len() - 1) as f64;
        let lo = pos.floor() as usize;
        let hi = (lo + 1).min(v.len() - 1);
        (v[lo] as f64 + (v[hi] as f64 - v[lo] as f64) * (pos - lo as f64)) as f32
    }

    #[test]
    fn quantile_matches_sorting_and_torch_examples() {
        // torch.quantile(torch.tensor([0., 1., 2., 3.]), q) = 3q (linear interpolation).
        for (q, want) in [(0.0, 0.0), (0.5, 1.5), (1.0, 3.0), (0.9, 2.7)] {
            let got = quantile_linear(&mut [3.0, 0.0, 2.0, 1.0], q);
            assert!((got - want).abs() < 1e-6, "q {q}: {got}");
        }
        let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
        for n in [1usize, 2, 7, 100, 1001] {
            let v: Vec<f32> = (0..n)
                .map(|_| match rng.gen_range(0..4) {
                    0 => 0.0,
                    _ => rng.gen_range(0.0f32..1e-3),
                })
                .collect();
            for q in [0.0, 0.13, 0.5, 0.999, 1.0] {
                assert_eq!(
                    quantile_linear(&mut v.clone(), q),
                    by_sorting(&v, q),
                    "{n} {q}"
                );
            }
        }
        assert_eq!(quantile_linear(&mut [], 0.5), f32::INFINITY);
    }

    #[test]
    fn threshold_selects_as_many_as_the_usual_test() {
        // Usual averages: 4e-4, 0, 3e-4, 0 (never seen), 1e-4, 1e-5, 0, 1e-4, 0, 0: two reach
        // 2e-4, so Q is the 0.8 quantile of the absolute averages (i + 1)·1e-3 (0 for the
        // never-seen one): 8.2e-3, which two of them reach.
        let denom = [2.0f32, 2.0, 1.0, 0.0, 4.0, 1.0, 1.0, 2.0, 1.0, 3.0];
        let grad = [8e-4f32, 0.0, 3e-4, 5.0, 4e-4, 1e-5, 0.0, 2e-4, 0.0, 0.0];
        let abs: Vec<f32> = (0..10)
            .map(|i| (i as f32 + 1.0) * denom[i] * 1e-3)
            .collect();
        let q = abs_grad_threshold(&grad, &denom, &abs, 2e-4);
        let avgs: Vec<f32> = (0..10).map(|i| average(abs[i], denom[i])).collect();
        assert_eq!(q, by_sorting(&avgs, 0.8));
        assert!((q - 8.2e-3).abs() < 1e-6, "{q}");
        assert_eq!(avgs.iter().filter(|&&a| a >= q).count(), 2);
    }
}
