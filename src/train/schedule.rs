//! The Inria 3DGS schedules: per-group learning rates (with the log-linear decay of the position
//! rate), the SH degree ramp and the density-control calendar. Iterations are 1-based, as in the
//! reference trainer (`for iteration in 1..=max`), and every function here takes that number.

use super::adam::GroupLrs;

/// Learning rates of the six parameter groups, Inria's defaults. The position rate is relative
/// to the scene extent and decays log-linearly from `position_init` to `position_final` over
/// `position_max_steps` iterations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearningRates {
    pub position_init: f64,
    pub position_final: f64,
    /// Warm-up length of the position rate; 0 (the reference default) disables it.
    pub position_delay_steps: u32,
    /// Multiplier at the start of the warm-up (0.01 in the reference, unused while the delay is 0).
    pub position_delay_mult: f64,
    pub position_max_steps: u32,
    pub scaling: f64,
    pub rotation: f64,
    pub opacity: f64,
    pub sh_dc: f64,
    pub sh_rest: f64,
}

impl Default for LearningRates {
    fn default() -> Self {
        Self {
            position_init: 1.6e-4,
            position_final: 1.6e-6,
            position_delay_steps: 0,
            position_delay_mult: 0.01,
            position_max_steps: 30_000,
            scaling: 5e-3,
            rotation: 1e-3,
            opacity: 0.05,
            sh_dc: 2.5e-3,
            sh_rest: 2.5e-3 / 20.0,
        }
    }
}

/// Exponential (log-linear) interpolation from `init` at step 0 to `fin` at `max_steps`, held at
/// `fin` afterwards, optionally scaled by a sine warm-up from `delay_mult` to 1 over
/// `delay_steps`. Negative steps and an all-zero range give 0.
pub fn exponential_lr(
    step: i64,
    init: f64,
    fin: f64,
    delay_steps: u32,
    delay_mult: f64,
    max_steps: u32,
) -> f64 {
    if step < 0 || (init == 0.0 && fin == 0.0) {
        return 0.0;
    }
    let delay = if delay_steps > 0 {
        let r = (step as f64 / delay_steps as f64).clamp(0.0, 1.0);
        delay_mult + (1.0 - delay_mult) * (0.5 * std::f64::consts::PI * r).sin()
    } else {
        1.0
    };
    let t = (step as f64 / max_steps.max(1) as f64).clamp(0.0, 1.0);
    delay * (init.ln() * (1.0 - t) + fin.ln() * t).exp()
}

impl LearningRates {
    /// The position learning rate at `iteration` for a scene of extent `extent`.
    pub fn position_lr(&self, iteration: u32, extent: f64) -> f64 {
        exponential_lr(
            iteration as i64,
            self.position_init * extent,
            self.position_final * extent,
            self.position_delay_steps,
            self.position_delay_mult,
            self.position_max_steps,
        )
    }

    /// The six 3DGS groups' rates in `GpuSplats::groups()` order at `iteration` (a model with
    /// extra groups appends theirs).
    pub fn at(&self, iteration: u32, extent: f64) -> GroupLrs {
        GroupLrs(vec![
            self.position_lr(iteration, extent),
            self.scaling,
            self.rotation,
            self.opacity,
            self.sh_dc,
            self.sh_rest,
        ])
    }
}

/// Active SH degree at `iteration`: the reference raises it by one when the iteration number
/// reaches a multiple of 1000 (before rendering that iteration), up to `max_degree`.
pub fn sh_degree_at(iteration: u32, max_degree: u32) -> u32 {
    (iteration / 1000).min(max_degree)
}

/// When density control runs (Inria's defaults: densify every 100 iterations for
/// 500 < t < 15000, opacity reset every 3000 while densifying).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DensitySchedule {
    pub densify_from: u32,
    pub densify_until: u32,
    pub interval: u32,
    pub opacity_reset_interval: u32,
    /// The reference also resets opacities at `densify_from` on white-background scenes.
    pub white_background: bool,
    /// Only the first N densify steps clone and split, without pruning; the later ones only
    /// prune (SpacetimeGaussians' `desicnt`, 6 in the official code). `None`: every densify
    /// step does both (3DGS).
    pub growth_rounds: Option<u32>,
}

impl Default for DensitySchedule {
    fn default() -> Self {
        Self {
            densify_from: 500,
            densify_until: 15_000,
            interval: 100,
            opacity_reset_interval: 3000,
            white_background: false,
            growth_rounds: None,
        }
    }
}

impl DensitySchedule {
    /// Whether gradient statistics are accumulated at `iteration` (the whole densification
    /// window, including its first 500 iterations).
    pub fn accumulates(&self, iteration: u32) -> bool {
        iteration < self.densify_until
    }

    /// Whether the densify-and-prune step runs at `iteration`.
    pub fn densifies(&self, iteration: u32) -> bool {
        iteration < self.densify_until
            && iteration > self.densify_from
            && self.interval > 0
            && iteration.is_multiple_of(self.interval)
    }

    /// What the densify step at `iteration` (a densify iteration) may do: with
    /// `growth_rounds` N, the first N densify steps grow only and the later ones prune only.
    pub fn phase(&self, iteration: u32) -> crate::train::density::DensifyPhase {
        use crate::train::density::DensifyPhase;
        let Some(n) = self.growth_rounds else {
            return DensifyPhase::Both;
        };
        if self.interval == 0 {
            return DensifyPhase::Both;
        }
        // 1-based index of this densify step: the multiples of the interval in (from, it].
        let round = iteration / self.interval - self.densify_from / self.interval;
        if round <= n {
            DensifyPhase::GrowOnly
        } else {
            DensifyPhase::PruneOnly
        }
    }

    /// Whether the world-size (and, when enabled, screen-size) pruning applies at a densify
    /// step: only after the first opacity reset.
    pub fn prunes_large(&self, iteration: u32) -> bool {
        iteration > self.opacity_reset_interval
    }

    /// Whether all opacities are reset at `iteration` (after densification in that iteration).
    pub fn resets_opacity(&self, iteration: u32) -> bool {
        iteration < self.densify_until
            && ((self.opacity_reset_interval > 0
                && iteration.is_multiple_of(self.opacity_reset_interval))
                || (self.white_background && iteration == self.densify_from))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    #[test]
    fn position_lr_decays_log_linearly_from_init_to_final_times_extent() {
        let lr = LearningRates::default();
        let extent = 3.7;
        assert!(rel(lr.position_lr(0, extent), 1.6e-4 * extent) < 1e-12);
        assert!(rel(lr.position_lr(30_000, extent), 1.6e-6 * extent) < 1e-12);
        // Held at the final value after max_steps.
        assert!(rel(lr.position_lr(45_000, extent), 1.6e-6 * extent) < 1e-12);
        // Halfway in log space: the geometric mean.
        assert!(rel(lr.position_lr(15_000, extent), 1.6e-5 * extent) < 1e-12);
        // A quarter of the way: ratio 100^(1/4) per quarter.
        let q = lr.position_lr(7_500, extent);
        assert!(rel(q, 1.6e-4 * extent / 100f64.powf(0.25)) < 1e-12);
        // Strictly decreasing.
        let mut prev = f64::INFINITY;
        for it in (0..=30_000).step_by(997) {
            let v = lr.position_lr(it, extent);
            assert!(v < prev, "iteration {it}");
            prev = v;
        }
    }

    #[test]
    fn exponential_lr_edge_cases_and_delay() {
        assert_eq!(exponential_lr(-1, 1.0, 0.1, 0, 0.01, 100), 0.0);
        assert_eq!(exponential_lr(5, 0.0, 0.0, 0, 0.01, 100), 0.0);
        // With a warm-up the rate starts at delay_mult × init and joins the plain curve.
        let start = exponential_lr(0, 1.0, 0.01, 50, 0.1, 100);
        assert!(rel(start, 0.1) < 1e-12);
        let plain = exponential_lr(60, 1.0, 0.01, 0, 0.1, 100);
        assert!(rel(exponential_lr(60, 1.0, 0.01, 50, 0.1, 100), plain) < 1e-12);
        let mid = exponential_lr(25, 1.0, 0.01, 50, 0.1, 100);
        let expect = (0.1 + 0.9 * (std::f64::consts::PI / 4.0).sin()) * 0.01f64.powf(0.25);
        assert!(rel(mid, expect) < 1e-12);
    }

    #[test]
    fn group_rates_follow_the_reference_defaults_in_group_order() {
        let lr = LearningRates::default();
        let g = lr.at(1, 2.0).0;
        assert!(rel(g[0], lr.position_lr(1, 2.0)) < 1e-15);
        assert_eq!(&g[1..], &[5e-3, 1e-3, 0.05, 2.5e-3, 2.5e-3 / 20.0]);
    }

    #[test]
    fn sh_degree_grows_every_thousand_iterations_up_to_the_maximum() {
        assert_eq!(sh_degree_at(1, 3), 0);
        assert_eq!(sh_degree_at(999, 3), 0);
        assert_eq!(sh_degree_at(1000, 3), 1);
        assert_eq!(sh_degree_at(2999, 3), 2);
        assert_eq!(sh_degree_at(3000, 3), 3);
        assert_eq!(sh_degree_at(29_000, 3), 3);
        assert_eq!(sh_degree_at(5000, 1), 1);
        assert_eq!(sh_degree_at(5000, 0), 0);
    }

    #[test]
    fn growth_rounds_grow_first_then_only_prune() {
        use crate::train::density::DensifyPhase;
        let mut s = DensitySchedule::default();
        assert_eq!(s.phase(600), DensifyPhase::Both);
        // SpacetimeGaussians: densify from 500 every 100, six rounds (600..=1100).
        s.growth_rounds = Some(6);
        let densify: Vec<u32> = (1..=3000).filter(|&t| s.densifies(t)).collect();
        let grow: Vec<u32> = densify
            .iter()
            .copied()
            .filter(|&t| s.phase(t) == DensifyPhase::GrowOnly)
            .collect();
        assert_eq!(grow, vec![600, 700, 800, 900, 1000, 1100]);
        assert!(densify
            .iter()
            .filter(|&&t| t > 1100)
            .all(|&t| s.phase(t) == DensifyPhase::PruneOnly));
        // A start that is not a multiple of the interval: rounds count from the first step.
        s.densify_from = 250;
        s.growth_rounds = Some(2);
        assert_eq!(s.phase(300), DensifyPhase::GrowOnly);
        assert_eq!(s.phase(400), DensifyPhase::GrowOnly);
        assert_eq!(s.phase(500), DensifyPhase::PruneOnly);
    }

    #[test]
    fn density_calendar_matches_the_reference_loop() {
        let s = DensitySchedule::default();
        let densify: Vec<u32> = (1..=30_000).filter(|&t| s.densifies(t)).collect();
        assert_eq!(densify.first(), Some(&600));
        assert_eq!(densify.last(), Some(&14_900));
        assert_eq!(densify.len(), 144);
        let resets: Vec<u32> = (1..=30_000).filter(|&t| s.resets_opacity(t)).collect();
        assert_eq!(resets, vec![3000, 6000, 9000, 12_000]);
        assert!(!s.prunes_large(3000) && s.prunes_large(3100));
        assert!(s.accumulates(14_999) && !s.accumulates(15_000));
        let white = DensitySchedule {
            growth_rounds: None,
            white_background: true,
            ..s
        };
        assert!(white.resets_opacity(500) && !s.resets_opacity(500));
    }
}
