//! `train`'s density-strategy flags: which strategy, the Gaussian budget and its curve, MCMC's
//! settings. Parsing only; the strategies and their rules live in the library.

use clap::{Args, ValueEnum};
use lpmsplat::mcmc::McmcConfig;
use lpmsplat::splats::budget_draw::Draw;
use lpmsplat::taming::BlendConfig;
use lpmsplat::train::density::growth::{Budget, BudgetCurve, Growth};
use lpmsplat::train::schedule::DensitySchedule;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum StrategyName {
    /// Adaptive density control: clone and split what crosses the gradient threshold.
    Adc,
    /// ADC at an exact budget: every densify step keeps the best-scoring candidates (the
    /// statistic over the threshold) the budget curve has room for, whatever the threshold.
    AdcExact,
    /// 3DGS as Markov chain Monte Carlo: dead Gaussians move onto live ones, growth to the
    /// budget by 5 % a refinement, position noise, opacity and scale regularisers.
    Mcmc,
}

/// How the exact budget ranks its candidates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BudgetScore {
    /// The gradient statistic over the threshold.
    Gradient,
    /// Taming-3DGS's blended score over a few sampled training views: coverage, blending
    /// weight, the error and edges of the pixels covered, opacity, size and gradient.
    Blend,
}

#[derive(Args, Debug, Clone)]
pub struct StrategyArgs {
    /// The density strategy (--lpm guides any of them: ADC's candidates by a lowered threshold
    /// and a score weight in its zones, MCMC's draws by the weight).
    #[arg(long, value_enum, default_value_t = StrategyName::Adc)]
    pub strategy: StrategyName,
    /// Gaussians at the end of densification: a count (500000, 500k, 2.5M) or a multiple of
    /// the initial model's (3x). adc-exact and mcmc end exactly there; adc treats it as a
    /// cap (as --max-gaussians).
    #[arg(long, value_name = "N", value_parser = Budget::parse)]
    pub budget: Option<Budget>,
    /// How the count grows to the budget: taming (quadratic, most growth early; adc-exact's
    /// default), linear, or mcmc (5 % a step; mcmc's default).
    #[arg(long, value_name = "CURVE", value_parser = Growth::parse)]
    pub budget_growth: Option<Growth>,
    /// How a start above --budget is brought down to it: keep (mcmc only, and its default:
    /// nothing drawn; the count falls from the start to the budget along the densify window,
    /// the least opaque removed at each refinement), random (uniformly: the cloud's density
    /// kept alike everywhere; the default of adc-exact and adc, and of mcmc with
    /// --budget-refit-scales), or spread (one Gaussian from each cell of the finest grid the
    /// budget allows, the rest at random: sparse regions keep their points).
    #[arg(long, value_enum, value_name = "DRAW")]
    pub budget_draw: Option<Draw>,
    /// With a start above --budget: rescale each kept Gaussian by how far its nearest
    /// neighbours moved in the draw (its scales were set from the whole cloud's spacing). For
    /// a start from points; a trained --init-ply keeps its own scales.
    #[arg(long)]
    pub budget_refit_scales: bool,
    /// adc-exact: how candidates are ranked for the budget's room (blend: 3DGS and Pixel-GS;
    /// two renders a sampled view a densify step).
    #[arg(long, value_enum, default_value_t = BudgetScore::Gradient)]
    pub budget_score: BudgetScore,
    /// --budget-score blend: training views drawn a densify step.
    #[arg(long, value_name = "N", default_value_t = 10)]
    pub budget_score_views: usize,
    /// mcmc: the position noise's learning rate (× the position learning rate).
    #[arg(long, default_value_t = 5e5)]
    pub mcmc_noise_lr: f64,
    /// mcmc: weight of the mean opacity in the loss.
    #[arg(long, default_value_t = 0.01)]
    pub mcmc_opacity_reg: f64,
    /// mcmc: weight of the mean scale in the loss.
    #[arg(long, default_value_t = 0.01)]
    pub mcmc_scale_reg: f64,
}

impl StrategyArgs {
    /// How a start above the budget is brought down to it: as named, or by the strategy's
    /// default. MCMC keeps the start whole (measured ahead of a drawn start by 0.9 dB on Truck
    /// and 2.4 dB on bonsai at a quarter of ADC's count, docs/results/budget.md) unless the
    /// scales are to be refitted, which only a draw can use; the other strategies cannot
    /// remove Gaussians, so they draw at random.
    pub fn draw(&self) -> Draw {
        self.budget_draw.unwrap_or(
            if self.strategy == StrategyName::Mcmc && !self.budget_refit_scales {
                Draw::Keep
            } else {
                Draw::Random
            },
        )
    }

    /// The budget's curve for a model starting at `initial` Gaussians, spanning the densify
    /// steps of `schedule` that run in `iterations` (`None` without --budget).
    /// `target`: the budget resolved against the model before it was drawn down to it
    /// ([`Budget::resolve`]; `None`: against `initial`).
    pub fn curve(
        &self,
        initial: usize,
        target: Option<usize>,
        schedule: &DensitySchedule,
        iterations: u32,
    ) -> Option<BudgetCurve> {
        let budget = self.budget?;
        let growth = self.budget_growth.unwrap_or(match self.strategy {
            StrategyName::Mcmc => Growth::Mcmc,
            _ => Growth::Taming,
        });
        Some(BudgetCurve {
            target: target.unwrap_or_else(|| budget.resolve(initial)),
            growth,
            initial,
            window: (
                schedule.densify_from,
                schedule.densify_until.min(iterations.saturating_add(1)),
                schedule.interval,
            ),
        })
    }

    /// The blended score's settings, when asked for (`seed` keys its draw of views).
    pub fn blend(&self, seed: u64) -> Option<BlendConfig> {
        (self.budget_score == BudgetScore::Blend).then(|| BlendConfig {
            views: self.budget_score_views,
            seed,
            ..BlendConfig::default()
        })
    }

    /// MCMC's settings around `curve`.
    pub fn mcmc(&self, curve: BudgetCurve, seed: u64) -> McmcConfig {
        McmcConfig {
            noise_lr: self.mcmc_noise_lr,
            opacity_reg: self.mcmc_opacity_reg,
            scale_reg: self.mcmc_scale_reg,
            seed,
            ..McmcConfig::with_budget(curve)
        }
    }
}

/// The `field` (`initial`, `target`) of the budget curve of the run that wrote `config_json` (a
/// checkpoint's), so a resumed run follows the same curve.
pub fn budget_from_checkpoint(config_json: &str, field: &str) -> Option<usize> {
    let j: serde_json::Value = serde_json::from_str(config_json).ok()?;
    [
        &j["density"]["exact_budget"][field],
        &j["strategy"]["mcmc"]["budget"][field],
    ]
    .iter()
    .find_map(|v| v.as_u64())
    .map(|v| v as usize)
}

impl StrategyArgs {
    /// Checks the flags against each other and the model.
    pub fn check(&self, model: lpmsplat::models::BaseModel) -> anyhow::Result<()> {
        use anyhow::ensure;
        ensure!(
            self.budget.is_some() || self.strategy == StrategyName::Adc,
            "--strategy {}: needs --budget N (the count at the end of densification). Fix: pass \
             e.g. --budget 500k or --budget 3x",
            self.strategy.to_possible_value().unwrap().get_name()
        );
        ensure!(
            self.budget_growth.is_none() || self.budget.is_some(),
            "--budget-growth without --budget: there is no budget to grow to. Fix: pass --budget"
        );
        ensure!(
            self.draw() != Draw::Keep || self.strategy == StrategyName::Mcmc,
            "--budget-draw keep: only mcmc removes Gaussians, to follow a curve that falls from \
             the start to the budget; {} would end above it. Fix: --strategy mcmc, or draw the \
             start down (--budget-draw random or spread)",
            self.strategy.to_possible_value().unwrap().get_name()
        );
        ensure!(
            self.draw() != Draw::Keep || !self.budget_refit_scales,
            "--budget-draw keep with --budget-refit-scales: nothing is drawn, so no scale is \
             refitted. Fix: drop --budget-refit-scales"
        );
        ensure!(
            self.budget_score == BudgetScore::Gradient || self.strategy == StrategyName::AdcExact,
            "--budget-score blend ranks the exact budget's candidates. Fix: --strategy adc-exact"
        );
        ensure!(
            self.budget_score_views > 0,
            "--budget-score-views 0: the blended score needs at least one view a step"
        );
        if self.strategy == StrategyName::Mcmc {
            ensure!(
                !model.is_spacetime(),
                "--strategy mcmc: {} Gaussians live in time, and MCMC's relocation and noise \
                 are defined for still ones. Fix: --strategy adc or adc-exact",
                model.name()
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Flags {
        #[command(flatten)]
        s: StrategyArgs,
    }

    fn draw(flags: &[&str]) -> Draw {
        let mut argv = vec!["train", "--budget", "0.5x"];
        argv.extend(flags);
        Flags::parse_from(argv).s.draw()
    }

    /// MCMC keeps its start whole unless told to draw or to refit scales (which only a draw
    /// uses); the strategies that cannot remove draw at random; a named draw always wins.
    #[test]
    fn each_strategy_has_its_own_default_draw() {
        assert_eq!(draw(&["--strategy", "mcmc"]), Draw::Keep);
        assert_eq!(
            draw(&["--strategy", "mcmc", "--budget-refit-scales"]),
            Draw::Random
        );
        assert_eq!(
            draw(&["--strategy", "mcmc", "--budget-draw", "random"]),
            Draw::Random
        );
        assert_eq!(draw(&["--strategy", "adc-exact"]), Draw::Random);
        assert_eq!(draw(&[]), Draw::Random);
        assert_eq!(
            draw(&["--strategy", "adc-exact", "--budget-draw", "spread"]),
            Draw::Spread
        );
    }
}
