//! [`McmcStrategy`]: the refinement, the regularisers and the noise as a density strategy.

use std::any::Any;
use std::sync::Arc;

use super::config::McmcConfig;
use super::gpu::McmcKernels;
use super::plan::{
    dead_rows, logit, lowest_opacity_rows, plan_growth, plan_relocation_of, plan_rng, plan_seeded,
    Plan,
};
use crate::gpu::{GpuContext, Recorder};
use crate::splats::gpu::{grown_capacity, GpuSplats};
use crate::train::adam::SplatState;
use crate::train::density::append::stage_rows;
use crate::train::density::rng::fold_seed;
use crate::train::density::{DensifyArgs, DensifyOutcome};
use crate::train::strategy::{
    DensityContext, DensityStrategy, Guide, IterationView, Primitive, StrategyEvent,
};

/// What one refinement did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct McmcEvent {
    pub iteration: u32,
    /// Dead Gaussians moved onto live ones.
    pub relocated: usize,
    /// Dead Gaussians moved onto a guide's surface samples instead.
    pub seeded: usize,
    /// New Gaussians (copies of live ones).
    pub added: usize,
    /// The least opaque removed (a falling budget curve, `--budget-draw keep`).
    pub removed: usize,
    /// The count after the refinement.
    pub gaussians: usize,
}

impl StrategyEvent for McmcEvent {
    fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "iteration": self.iteration, "relocated": self.relocated, "seeded": self.seeded,
            "added": self.added, "removed": self.removed,
            "gaussians": self.gaussians,
        })
    }
    fn describe(&self) -> String {
        format!(
            "mcmc: {} relocated, {} onto surface samples, {} added, {} removed, {} Gaussians",
            self.relocated, self.seeded, self.added, self.removed, self.gaussians
        )
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Totals over a run (metrics.json).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct McmcTotals {
    pub refinements: usize,
    pub relocated: usize,
    pub seeded: usize,
    pub added: usize,
    pub removed: usize,
}

impl McmcTotals {
    /// As metrics.json and `bench trade` rows record them.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "refinements": self.refinements,
            "relocated": self.relocated,
            "seeded": self.seeded,
            "added": self.added,
            "removed": self.removed,
        })
    }
}

pub struct McmcStrategy {
    pub config: McmcConfig,
    kernels: McmcKernels,
    /// Log-scales the corrections and the regulariser act on (3; 2 for surfels).
    axes: u32,
    last: Option<McmcEvent>,
    pub totals: McmcTotals,
}

impl McmcStrategy {
    pub fn new(
        ctx: &Arc<GpuContext>,
        config: McmcConfig,
        primitive: Primitive,
    ) -> anyhow::Result<Self> {
        config.validate()?;
        Ok(Self {
            config,
            kernels: McmcKernels::new(ctx)?,
            axes: match primitive {
                Primitive::Gaussian => 3,
                Primitive::Surfel => 2,
            },
            last: None,
            totals: McmcTotals::default(),
        })
    }

    /// One refinement: relocation (some dead Gaussians onto a guide's surface samples, the rest
    /// onto live ones), then growth to the curve's target, sources drawn ∝ opacity × the
    /// guide's weight (read back with the opacities).
    fn refine(
        &mut self,
        t: &mut DensityContext,
        args: &DensifyArgs,
        guide: Option<&Guide>,
    ) -> anyhow::Result<DensifyOutcome> {
        let it = args.iteration;
        let n = t.state.count();
        // The iteration's work (and a guide's, recorded into `t.rec`) completes here: the
        // opacities and weights are final.
        t.rec.submit_and_wait()?;
        t.rec.begin()?;
        let mut logits = t.state.params.opacity_logits.read_range(0, n)?;
        let weight = match guide {
            Some(g) => Some(g.weight.read_range(0, n)?),
            None => None,
        };
        let weight = weight.as_deref();
        let min = self.config.min_opacity;
        let seed = self.config.seed;
        // A falling curve (a start kept whole above the budget) first takes the least opaque
        // away: they neither move nor are drawn as sources (opacity 0 from here on).
        let target = self.config.budget.target_at(it, n);
        let removed = lowest_opacity_rows(&logits, n.saturating_sub(target));
        for &r in &removed {
            logits[r as usize] = f32::NEG_INFINITY;
        }
        let dead = match removed.is_empty() {
            true => dead_rows(&logits, min),
            false => {
                let gone: std::collections::HashSet<u32> = removed.iter().copied().collect();
                dead_rows(&logits, min)
                    .into_iter()
                    .filter(|r| !gone.contains(r))
                    .collect()
            }
        };
        let seeded = match guide {
            Some(g) if !g.samples.is_empty() && g.sample_share > 0.0 => plan_seeded(
                &dead,
                g.samples.len(),
                g.sample_share,
                &mut plan_rng(seed, it, 2),
            ),
            _ => Vec::new(),
        };
        let moving: Vec<u32> = match seeded.is_empty() {
            true => dead,
            false => {
                let taken: std::collections::HashSet<u32> = seeded.iter().map(|s| s.0).collect();
                dead.into_iter().filter(|r| !taken.contains(r)).collect()
            }
        };
        let relocation = plan_relocation_of(
            &mut logits,
            weight,
            min,
            &moving,
            &mut plan_rng(seed, it, 0),
        );
        let moved = self.kernels.upload(&relocation)?;
        self.kernels
            .record_plan(t.rec, t.state, &moved, self.axes)?;
        if let Some(g) = guide.filter(|_| !seeded.is_empty()) {
            // The samples are written after the last row (growing the buffers if need be),
            // then copied onto their dead rows with fresh moments; the count does not change.
            // Staging wants `t.rec` begun and empty: the relocation runs first.
            t.rec.submit_and_wait()?;
            t.rec.begin()?;
            let rows: Vec<_> = seeded.iter().map(|&(_, k)| g.samples[k as usize]).collect();
            let staged = stage_rows(t, &rows, None, rows.len())?;
            debug_assert_eq!(staged, rows.len());
            let copies = Plan {
                copies: seeded
                    .iter()
                    .enumerate()
                    .map(|(j, &(row, _))| (row, (n + j) as u32))
                    .collect(),
                updates: Vec::new(),
            };
            let up = self.kernels.upload(&copies)?;
            self.kernels.record_plan(t.rec, t.state, &up, self.axes)?;
            t.rec.submit_and_wait()?;
            t.rec.begin()?;
            for (&(row, _), r) in seeded.iter().zip(&rows) {
                logits[row as usize] = logit(r.opacity) as f32;
            }
        }
        if !removed.is_empty() {
            // The relocation recorded above runs first; then the rows are compacted (every
            // per-Gaussian buffer, moments included) and the statistics zeroed.
            drop(moved);
            t.density.record_remove_rows(t.state, &removed)?;
            let out = t.density.apply(t.rec, t.state, args)?;
            let event = McmcEvent {
                iteration: it,
                relocated: relocation.copies.len(),
                seeded: seeded.len(),
                added: 0,
                removed: removed.len(),
                gaussians: out.after,
            };
            self.totals.refinements += 1;
            self.totals.relocated += event.relocated;
            self.totals.seeded += event.seeded;
            self.totals.removed += event.removed;
            self.last = Some(event);
            return Ok(out);
        }
        let growth = plan_growth(
            &mut logits,
            weight,
            target.saturating_sub(n),
            min,
            &mut plan_rng(seed, it, 1),
        );
        let added = growth.copies.len();
        let after = n + added;
        let grew = after > t.state.capacity();
        if added > 0 {
            if grew {
                // The relocation first, then bigger buffers, rows kept (one at a time).
                t.rec.submit_and_wait()?;
                let capacity = grown_capacity(after);
                t.state.grow(t.ctx, t.rec, capacity)?;
                t.rec.begin()?;
                t.density.ensure_capacity(capacity)?;
            }
            t.state.set_count(after);
            let new = self.kernels.upload(&growth)?;
            self.kernels.record_plan(t.rec, t.state, &new, self.axes)?;
            t.density.record_reset_stats(t.rec);
            t.rec.submit_and_wait()?;
            t.rec.begin()?;
        } else {
            t.density.record_reset_stats(t.rec);
            t.rec.submit_and_wait()?;
            t.rec.begin()?;
        }
        drop(moved);
        let event = McmcEvent {
            iteration: it,
            relocated: relocation.copies.len(),
            seeded: seeded.len(),
            added,
            removed: 0,
            gaussians: after,
        };
        self.totals.refinements += 1;
        self.totals.relocated += event.relocated;
        self.totals.seeded += event.seeded;
        self.totals.added += added;
        self.last = Some(event);
        Ok(DensifyOutcome {
            before: n,
            after,
            kept: n,
            clones: added,
            split_children: 0,
            grew,
            capacity: t.state.capacity(),
            skipped: false,
            budget_dropped: 0,
        })
    }

    fn noise_seed(&self) -> u32 {
        // Apart from the split samples' stream of the same seed.
        fold_seed(self.config.seed) ^ 0x6d63_6d63
    }
}

impl DensityStrategy for McmcStrategy {
    fn name(&self) -> &'static str {
        "mcmc"
    }

    fn densify(
        &mut self,
        t: &mut DensityContext,
        _at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        self.refine(t, args, None)
    }

    fn takes_guide(&self) -> bool {
        true
    }

    /// Relocation targets and growth sources drawn ∝ opacity × the guide's weight; up to its
    /// share of the dead Gaussians moved onto its surface samples instead.
    fn densify_guided(
        &mut self,
        t: &mut DensityContext,
        _at: &IterationView,
        args: &DensifyArgs,
        guide: &Guide,
    ) -> anyhow::Result<DensifyOutcome> {
        self.refine(t, args, Some(guide))
    }

    fn after_density(
        &mut self,
        _t: &mut DensityContext,
        _at: &IterationView,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        Ok(self
            .last
            .take()
            .map(|e| Arc::new(e) as Arc<dyn StrategyEvent>))
    }

    fn quiet_after(&self, _iteration: u32) -> bool {
        true
    }

    fn record_gradient_terms(
        &self,
        rec: &mut Recorder,
        state: &SplatState,
        grads: &GpuSplats,
        _iteration: u32,
    ) -> anyhow::Result<()> {
        self.kernels.record_regularise(
            rec,
            &state.params,
            grads,
            state.count(),
            (self.config.opacity_reg, self.config.scale_reg),
            self.axes,
        );
        Ok(())
    }

    fn record_after_optimizer(
        &self,
        rec: &mut Recorder,
        state: &SplatState,
        iteration: u32,
        position_lr: f64,
        extent: f64,
    ) -> anyhow::Result<()> {
        let amount = position_lr * self.config.noise_lr / (extent * extent);
        self.kernels.record_noise(
            rec,
            &state.params,
            state.count(),
            self.noise_seed(),
            iteration,
            amount as f32,
            (self.config.gate_k as f32, self.config.gate_t as f32),
        );
        Ok(())
    }

    fn settings_json(&self) -> serde_json::Value {
        serde_json::json!({ "mcmc": self.config.to_json() })
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}
