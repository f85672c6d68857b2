//! A Gaussian budget with a growth curve (`train --budget N --budget-growth CURVE`): how many
//! Gaussians each density step may end with, so that a strategy that fills its room exactly
//! (the exact-budget ADC, MCMC) reaches the budget at the end of densification and not before.
//!
//! The curves, for densify step `k` of `n` (1-based) from the initial count `s` to the budget
//! `B`:
//! - `taming`: `s + (B − s)·(2x − x²)` with `x = k / n`: the quadratic that starts twice as steep
//!   as the straight line and arrives flat (Taming-3DGS's schedule, in our words: most of the
//!   growth early, while the position learning rate is high, and the last steps refine);
//! - `linear`: `s + (B − s)·x`;
//! - `mcmc`: the current count × 1.05, at most `B` (the MCMC paper's 5 % per refinement: the
//!   budget is reached when the model has grown into it, which may be before the last step).
//!
//! Every curve is at most `B`, never below the count it started from, and exactly `B` from the
//! last densify step on. A step cannot remove Gaussians to meet its target: a target below the
//! survivors adds nothing (and MCMC never prunes, so its count only grows).

use anyhow::bail;

/// A budget: a count, or a multiple of the initial model's (`2.5x`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Budget {
    Count(usize),
    TimesInitial(f64),
}

impl Budget {
    pub fn resolve(self, initial: usize) -> usize {
        match self {
            Budget::Count(n) => n,
            Budget::TimesInitial(f) => ((initial as f64) * f).round().max(1.0) as usize,
        }
    }

    /// `500000`, `500k`, `2.5M`, or `3x` (times the initial Gaussians): `--budget`'s forms.
    pub fn parse(s: &str) -> Result<Budget, String> {
        let t = s.trim();
        let bad = || {
            format!(
                "'{s}' is not a Gaussian budget. Fix: give a count (500000, 500k, 2.5M) or a \
                 multiple of the initial model's count (3x)"
            )
        };
        if let Some(f) = t.strip_suffix('x') {
            return match f.parse::<f64>() {
                Ok(v) if v > 0.0 && v.is_finite() => Ok(Budget::TimesInitial(v)),
                _ => Err(bad()),
            };
        }
        let (num, mult) = match t.chars().last() {
            Some('k' | 'K') => (&t[..t.len() - 1], 1e3),
            Some('M' | 'm') => (&t[..t.len() - 1], 1e6),
            _ => (t, 1.0),
        };
        match num.parse::<f64>() {
            Ok(v) if v > 0.0 && (v * mult).is_finite() && (v * mult).round() >= 1.0 => {
                Ok(Budget::Count((v * mult).round() as usize))
            }
            _ => Err(bad()),
        }
    }

    /// A Gaussian count in `--budget`'s count forms (`500000`, `500k`, `2.5M`), not a multiple:
    /// what `--max-gaussians` and the other count flags take.
    pub fn parse_count(s: &str) -> Result<usize, String> {
        match Budget::parse(s) {
            Ok(Budget::Count(n)) => Ok(n),
            _ => Err(format!(
                "'{s}' is not a Gaussian count. Fix: give a positive count, e.g. 500000, 500k or \
                 2.5M"
            )),
        }
    }
}

/// How the room grows from the initial count to the budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Growth {
    #[default]
    Taming,
    Linear,
    /// × 1.05 a step.
    Mcmc,
}

impl Growth {
    pub fn parse(s: &str) -> anyhow::Result<Growth> {
        Ok(match s {
            "taming" => Growth::Taming,
            "linear" => Growth::Linear,
            "mcmc" => Growth::Mcmc,
            _ => bail!(
                "'{s}' is not a growth curve. Fix: pass taming (quadratic, the default), linear \
                 or mcmc (5 % a step)"
            ),
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Growth::Taming => "taming",
            Growth::Linear => "linear",
            Growth::Mcmc => "mcmc",
        }
    }
}

/// The budget and its curve, with the count the curve starts from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BudgetCurve {
    /// Gaussians at the end of densification.
    pub target: usize,
    pub growth: Growth,
    /// The model's count when training started (the curve's origin).
    pub initial: usize,
    /// The densify window the curve spans: steps at the multiples of `interval` in
    /// `(from, until)` (the schedule's).
    pub window: (u32, u32, u32),
}

/// MCMC's growth per step.
pub const MCMC_GROWTH: f64 = 1.05;

impl BudgetCurve {
    /// The count the densify step at `iteration` may end with, for a model of `current`
    /// Gaussians before it.
    pub fn target_at(&self, iteration: u32, current: usize) -> usize {
        let (from, until, interval) = self.window;
        let (k, n) = step_index(iteration, from, until, interval);
        self.step_target(k, n, current)
    }

    /// The count densify step `k` of `n` (1-based; `k ≥ n` is the last) may end with, for a
    /// model of `current` Gaussians before the step.
    pub fn step_target(&self, k: u32, n: u32, current: usize) -> usize {
        let b = self.target;
        if self.initial > b {
            return self.falling_target(k, n);
        }
        let s = self.initial.min(b);
        if k >= n || n == 0 {
            return match self.growth {
                Growth::Mcmc => grow_mcmc(current, b),
                _ => b,
            };
        }
        let x = k as f64 / n as f64;
        let room = (b - s) as f64;
        match self.growth {
            Growth::Taming => s + (room * (2.0 * x - x * x)).round() as usize,
            Growth::Linear => s + (room * x).round() as usize,
            Growth::Mcmc => grow_mcmc(current, b),
        }
        .min(b)
    }

    /// A curve from above its budget (a start kept whole, `--budget-draw keep`) falls to it:
    /// taming removes most early (`initial − room·(2x − x²)`), linear and mcmc evenly
    /// (`initial − room·x`), with `x = k/n`, the budget from step `n` on.
    fn falling_target(&self, k: u32, n: u32) -> usize {
        let (b, s) = (self.target, self.initial);
        if k >= n || n == 0 {
            return b;
        }
        let x = k as f64 / n as f64;
        let room = (s - b) as f64;
        let fallen = match self.growth {
            Growth::Taming => room * (2.0 * x - x * x),
            Growth::Linear | Growth::Mcmc => room * x,
        };
        (s - fallen.round() as usize).max(b)
    }

    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "target": self.target,
            "growth": self.growth.name(),
            "initial": self.initial,
            "window": [self.window.0, self.window.1, self.window.2],
        })
    }

    pub fn from_json(j: &serde_json::Value) -> anyhow::Result<BudgetCurve> {
        let n = |k: &str| -> anyhow::Result<usize> {
            j[k].as_u64().map(|v| v as usize).ok_or_else(|| {
                anyhow::anyhow!("budget: field '{k}' is missing or not a count in {j}")
            })
        };
        let w = |k: usize| j["window"][k].as_u64().map(|v| v as u32);
        let (Some(from), Some(until), Some(interval)) = (w(0), w(1), w(2)) else {
            bail!("budget: field 'window' is missing or not [from, until, interval] in {j}");
        };
        Ok(BudgetCurve {
            window: (from, until, interval),
            target: n("target")?,
            initial: n("initial")?,
            growth: Growth::parse(j["growth"].as_str().unwrap_or(""))?,
        })
    }
}

/// `current × 1.05` (rounded down, at least one more while below the budget), at most `b`.
fn grow_mcmc(current: usize, b: usize) -> usize {
    if current >= b {
        return current;
    }
    let grown = ((current as f64) * MCMC_GROWTH).floor() as usize;
    grown.max(current + 1).min(b)
}

/// Densify step number (1-based) of `iteration` and the number of densify steps in the window
/// `(from, until)` every `interval` (the schedule's `densifies`).
pub fn step_index(iteration: u32, from: u32, until: u32, interval: u32) -> (u32, u32) {
    if interval == 0 || until == 0 {
        return (1, 1);
    }
    let first = from / interval;
    let last = (until - 1) / interval;
    let n = last.saturating_sub(first).max(1);
    let k = (iteration / interval).saturating_sub(first).clamp(1, n);
    (k, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_count_parses_in_the_budgets_count_forms_and_refuses_a_multiple() {
        assert_eq!(Budget::parse_count("500000"), Ok(500_000));
        assert_eq!(Budget::parse_count(" 2.5M"), Ok(2_500_000));
        assert_eq!(Budget::parse_count("500k"), Ok(500_000));
        for bad in ["3x", "0", "-1", "", "k", "1e400"] {
            let e = Budget::parse_count(bad).unwrap_err();
            assert!(
                e.contains("not a Gaussian count") && e.contains("500k"),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn budgets_parse_as_counts_or_multiples_and_a_bad_one_says_the_forms() {
        assert_eq!(Budget::parse("500000"), Ok(Budget::Count(500_000)));
        assert_eq!(Budget::parse("500k"), Ok(Budget::Count(500_000)));
        assert_eq!(Budget::parse("2.5M"), Ok(Budget::Count(2_500_000)));
        assert_eq!(Budget::parse("3x"), Ok(Budget::TimesInitial(3.0)));
        assert_eq!(Budget::TimesInitial(0.5).resolve(1001), 501);
        for bad in ["", "0", "-3", "x", "1e400", "2.5Q", "0.0001"] {
            let e = Budget::parse(bad).unwrap_err();
            assert!(e.contains("500k") && e.contains("3x"), "{bad}: {e}");
        }
    }

    #[test]
    fn every_curve_starts_near_the_initial_count_and_ends_at_the_budget() {
        for growth in [Growth::Taming, Growth::Linear] {
            let c = BudgetCurve {
                target: 10_000,
                growth,
                initial: 1_000,
                window: (500, 15_000, 100),
            };
            let n = 145;
            let mut prev = 1_000;
            for k in 1..=n {
                let t = c.step_target(k, n, prev);
                assert!(
                    t >= prev && t <= 10_000,
                    "{growth:?} step {k}: {t} after {prev}"
                );
                prev = t;
            }
            assert_eq!(prev, 10_000);
            assert_eq!(c.step_target(n + 3, n, 10_000), 10_000);
        }
        // Taming: twice the linear slope at the start, flat at the end.
        let c = BudgetCurve {
            target: 1_001_000,
            growth: Growth::Taming,
            initial: 1_000,
            window: (500, 15_000, 100),
        };
        assert_eq!(c.step_target(1, 100, 0), 1_000 + 19_900);
        assert_eq!(c.step_target(50, 100, 0), 1_000 + 750_000);
        assert_eq!(c.step_target(99, 100, 0), 1_000 + 999_900);
    }

    #[test]
    fn mcmc_grows_five_percent_a_step_and_stops_at_the_budget() {
        let c = BudgetCurve {
            target: 1_200,
            growth: Growth::Mcmc,
            initial: 1_000,
            window: (500, 15_000, 100),
        };
        assert_eq!(c.step_target(1, 10, 1_000), 1_050);
        assert_eq!(c.step_target(2, 10, 1_050), 1_102);
        assert_eq!(c.step_target(3, 10, 1_190), 1_200);
        assert_eq!(c.step_target(4, 10, 1_200), 1_200);
        // At least one more while below; above the budget the target is the budget (a step adds
        // nothing then; it cannot remove).
        assert_eq!(c.step_target(4, 10, 10), 11);
        assert_eq!(c.step_target(4, 10, 1_500), 1_200);
    }

    #[test]
    fn a_budget_below_the_initial_count_is_fallen_to_by_the_last_step() {
        for growth in [Growth::Taming, Growth::Linear, Growth::Mcmc] {
            let c = BudgetCurve {
                target: 500,
                growth,
                initial: 1_000,
                window: (500, 15_000, 100),
            };
            let mut prev = 1_000;
            for k in 1..=10 {
                let t = c.step_target(k, 10, prev);
                assert!(
                    t <= prev && t >= 500,
                    "{growth:?} step {k}: {t} after {prev}"
                );
                prev = t;
            }
            assert_eq!(prev, 500);
            assert_eq!(c.step_target(12, 10, 500), 500);
        }
        let at = |growth, k| {
            BudgetCurve {
                target: 500,
                growth,
                initial: 1_000,
                window: (500, 15_000, 100),
            }
            .step_target(k, 10, 1_000)
        };
        // Linear: 50 a step; taming: 95 at the first (most early), 5 at the last.
        assert_eq!(at(Growth::Linear, 1), 950);
        assert_eq!(at(Growth::Mcmc, 4), 800);
        assert_eq!(at(Growth::Taming, 1), 905);
        assert_eq!(at(Growth::Taming, 9), 505);
    }

    #[test]
    fn step_index_counts_the_schedules_densify_steps() {
        // Inria: densify at 600, 700, …, 14 900: 144 steps.
        assert_eq!(step_index(600, 500, 15_000, 100), (1, 144));
        assert_eq!(step_index(14_900, 500, 15_000, 100), (144, 144));
        assert_eq!(step_index(7_000, 500, 15_000, 100), (65, 144));
    }

    #[test]
    fn the_curve_round_trips_through_json_and_names_a_bad_field() {
        let c = BudgetCurve {
            target: 123,
            growth: Growth::Linear,
            initial: 7,
            window: (1, 2, 3),
        };
        assert_eq!(BudgetCurve::from_json(&c.to_json()).unwrap(), c);
        let e = BudgetCurve::from_json(&serde_json::json!({"target": 1, "window": [1, 2, 3]}))
            .unwrap_err();
        assert!(e.to_string().contains("initial"), "{e}");
        assert!(Growth::parse("cubic")
            .unwrap_err()
            .to_string()
            .contains("taming"));
    }
}
