//! One cell of the benchmark, a run at a seed and budget: its configuration (the calendar's,
//! with the run's own rules and budget) and its trainer, from its seed's initial model.

use super::run_config::{abs_grad_applies, apply_budget, run_draw, run_look, run_lpm_config};
use super::TradeSettings;
use crate::bench::budget::Cell;
use crate::bench::runs::RUNS;
use crate::gpu::GpuContext;
use crate::lpm::config::LpmConfig;
use crate::mcmc::McmcConfig;
use crate::scene::image_source::TrainImages;
use crate::scene::Scene;
use crate::splats::budget_draw::Draw;
use crate::splats::init::Look;
use crate::splats::GaussianParams;
use crate::taming::BlendConfig;
use crate::train::trainer::{TrainConfig, Trainer};
use std::borrow::Cow;
use std::sync::Arc;

/// One cell of the benchmark (a run at a seed and budget) as it trains.
pub(super) struct Run {
    pub(super) k: usize,
    /// The name its rows carry (`mcmc@0.5x-adc` in a grid) and its colour in the plots.
    pub(super) name: String,
    pub(super) colour: [u8; 3],
    pub(super) seed: u64,
    /// Index of the run's initial model (one per seed).
    pub(super) init: usize,
    /// Its budget's count (the initial model is drawn down to it where above).
    target: Option<usize>,
    /// A free adc run that budgets relative to adc's count wait for.
    pub(super) reference: bool,
    cfg: TrainConfig,
    lpm: Option<LpmConfig>,
    /// MCMC's settings, for the mcmc run.
    mcmc: Option<McmcConfig>,
    /// The blended score's settings, for the adc-exact-blend runs.
    blend: Option<BlendConfig>,
    /// How a start above its budget is drawn down to it, and whether the scales are refitted.
    draw: (Draw, bool),
    /// How its start from points looks (opacity, scale factor).
    look: Look,
    pub(super) trainer: Option<Trainer>,
    pub(super) seconds: f64,
    /// The Gaussian counts after each iteration so far, summed (for the mean model size).
    pub(super) count_sum: f64,
    /// The base model's own rules' events so far.
    pub(super) model_events: Vec<serde_json::Value>,
}

impl Run {
    /// Cell `c` at `seed` (its initial model's count and budget: `initial`, `target`), on the
    /// calendar's configuration `base` of `calendar` iterations; `grid`: the cells span a grid
    /// of budgets.
    pub(super) fn configure(
        c: &Cell,
        seed: u64,
        (initial, target): (usize, Option<usize>),
        base: &TrainConfig,
        calendar: u32,
        grid: bool,
        settings: &TradeSettings,
    ) -> anyhow::Result<Run> {
        let name = RUNS[c.k].name;
        let mut cfg = base.clone();
        cfg.seed = seed;
        if name == "adc-threshold-1e-4" {
            cfg.density.grad_threshold = 1e-4;
        }
        if name == "adc-abs-grad" {
            abs_grad_applies(settings.model)?;
            cfg.density.abs_grad = true;
        }
        let lpm = run_lpm_config(name, &cfg, settings);
        if let Some(c) = &lpm {
            c.validate()?;
        }
        // A kept start (mcmc's by default) falls from the initial count to the budget.
        let draw = run_draw(name, settings.mcmc_draw());
        let start = match draw.0 {
            Draw::Keep => initial,
            _ => target.map_or(initial, |t| t.min(initial)),
        };
        let mcmc = apply_budget(name, &mut cfg, settings, (start, target), calendar)?;
        Ok(Run {
            k: c.k,
            name: c.name.clone(),
            colour: cell_colour(RUNS[c.k].colour, c.budget, settings.budget.len(), grid),
            seed,
            init: c.seed,
            target,
            reference: c.reference,
            cfg,
            lpm,
            mcmc,
            blend: name.starts_with("adc-exact-blend").then(|| BlendConfig {
                seed,
                ..BlendConfig::default()
            }),
            draw,
            look: run_look(name),
            trainer: None,
            seconds: 0.0,
            count_sum: 0.0,
            model_events: Vec::new(),
        })
    }

    /// Builds the run's trainer (and its density strategy) from `init`, its seed's initial
    /// model, drawn down to its budget where above it and given the run's look.
    pub(super) fn start(
        &mut self,
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: &TrainImages,
        init: &GaussianParams,
        settings: &TradeSettings,
    ) -> anyhow::Result<()> {
        let drawn = match self.target {
            Some(t) if t < init.len() => Cow::Owned(crate::splats::budget_draw::draw_down(
                init.clone(),
                t,
                self.seed,
                self.draw.0,
                self.draw.1,
            )),
            _ => Cow::Borrowed(init),
        };
        let start = if self.look != Look::STANDARD {
            let mut own = drawn.into_owned();
            self.look.apply(&mut own);
            Cow::Owned(own)
        } else {
            drawn
        };
        let mut t = Trainer::new(ctx, scene, train_images.clone(), &start, self.cfg.clone())?;
        let strategy = crate::strategies::assemble(
            ctx,
            scene,
            train_images,
            &self.cfg,
            self.lpm.clone(),
            crate::strategies::Base::of(self.mcmc, self.blend),
            &settings.out,
        )?;
        if let Some(s) = strategy {
            t.set_strategy(s);
        }
        self.trainer = Some(t);
        Ok(())
    }
}

/// A cell's colour: its run's, lightened along the budgets in a grid so that one run's cells
/// stay one hue and can still be told apart in the curves.
fn cell_colour(colour: [u8; 3], budget: Option<usize>, budgets: usize, grid: bool) -> [u8; 3] {
    match budget {
        Some(b) if grid && budgets > 1 => {
            let f = 0.55 * b as f64 / (budgets - 1) as f64;
            colour.map(|c| (c as f64 + (255.0 - c as f64) * f).round() as u8)
        }
        _ => colour,
    }
}
