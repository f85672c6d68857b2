//! What decides what MCMC does (the paper's and the peers' numbers by default).

use crate::train::density::growth::{BudgetCurve, Growth};
use anyhow::ensure;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct McmcConfig {
    /// The count at the end of refinement and the curve to it (MCMC's 5 % a step by default).
    pub budget: BudgetCurve,
    /// A Gaussian at or below this opacity is dead and is moved at the next refinement.
    pub min_opacity: f64,
    /// The noise's learning rate (× the position learning rate).
    pub noise_lr: f64,
    /// The noise gate `1 / (1 + exp(k (o − t)))`: its sharpness k and centre t.
    pub gate_k: f64,
    pub gate_t: f64,
    /// Weight of the mean opacity in the loss.
    pub opacity_reg: f64,
    /// Weight of the mean scale (world units over the extent) in the loss.
    pub scale_reg: f64,
    pub seed: u64,
}

impl McmcConfig {
    /// The defaults around a budget.
    pub fn with_budget(budget: BudgetCurve) -> McmcConfig {
        McmcConfig {
            budget,
            min_opacity: 0.005,
            noise_lr: 5e5,
            gate_k: 100.0,
            gate_t: 0.005,
            opacity_reg: 0.01,
            scale_reg: 0.01,
            seed: 0,
        }
    }

    pub fn validate(&self) -> anyhow::Result<()> {
        ensure!(
            self.budget.target > 0,
            "MCMC: the budget is 0 Gaussians. Fix: pass --budget N with N ≥ 1"
        );
        ensure!(
            self.min_opacity > 0.0 && self.min_opacity < 0.5,
            "MCMC: the dead opacity {} must lie in (0, 0.5)",
            self.min_opacity
        );
        for (name, v) in [
            ("--mcmc-noise-lr", self.noise_lr),
            ("--mcmc-opacity-reg", self.opacity_reg),
            ("--mcmc-scale-reg", self.scale_reg),
            ("the gate's sharpness", self.gate_k),
        ] {
            ensure!(
                v >= 0.0 && v.is_finite(),
                "MCMC: {name} is {v}; it must be ≥ 0 and finite"
            );
        }
        Ok(())
    }

    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "budget": self.budget.to_json(),
            "min_opacity": self.min_opacity,
            "noise_lr": self.noise_lr,
            "gate_k": self.gate_k,
            "gate_t": self.gate_t,
            "opacity_reg": self.opacity_reg,
            "scale_reg": self.scale_reg,
            "seed": self.seed,
        })
    }
}

/// MCMC's default growth.
pub const DEFAULT_GROWTH: Growth = Growth::Mcmc;

/// MCMC's schedule on a calendar of `calendar` iterations (the official one is 30 000):
/// refinement to the peers' 25 000 of 30 000, scaled to the calendar, unless the run gave its
/// own end (`until`); no opacity reset, so neither ADC's reset rhythm nor its white-background
/// reset applies. `train` and `bench trade` both set MCMC's runs up here.
pub fn apply_schedule(
    schedule: &mut crate::train::schedule::DensitySchedule,
    calendar: u32,
    until: Option<u32>,
) {
    schedule.densify_until =
        until.unwrap_or(((REFINE_UNTIL_OF_30K as u64 * calendar as u64) / 30_000) as u32);
    schedule.opacity_reset_interval = 0;
    schedule.white_background = false;
}

/// The peers' last refinement on the 30 000-iteration calendar.
pub const REFINE_UNTIL_OF_30K: u32 = 25_000;

#[cfg(test)]
mod schedule_tests {
    use super::*;
    use crate::train::schedule::DensitySchedule;

    #[test]
    fn the_refinement_window_scales_with_the_calendar_and_keeps_a_given_end() {
        let mut s = DensitySchedule::default();
        apply_schedule(&mut s, 30_000, None);
        assert_eq!((s.densify_until, s.opacity_reset_interval), (25_000, 0));
        assert!(!s.white_background);
        apply_schedule(&mut s, 1_200, None);
        assert_eq!(s.densify_until, 1_000);
        apply_schedule(&mut s, 30_000, Some(7_000));
        assert_eq!(s.densify_until, 7_000);
    }
}
