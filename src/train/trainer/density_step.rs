//! An iteration's density control, after its command buffer ran: the strategy's densify step
//! and the global opacity reset on their schedules, then the strategy's and the base model's
//! end-of-iteration work, each followed by the buffers that track the model's capacity.

use super::{StepReport, Trainer};
use crate::train::density::DensifyArgs;
use crate::train::strategy::{
    DensityContext, DensityStrategy, IterationView, OpacityFilter, StepSeen,
};

impl Trainer {
    /// The iteration's density control: the strategy's densify step on densify iterations, the
    /// global opacity reset on its schedule, then the strategy's end-of-iteration work.
    pub(super) fn run_density_control(
        &mut self,
        strategy: &mut dyn DensityStrategy,
        at: &IterationView,
        report: &mut StepReport,
    ) -> anyhow::Result<()> {
        let it = at.iteration;
        let schedule = self.config.schedule;
        if schedule.densifies(it) {
            self.rec.begin()?;
            let args = DensifyArgs {
                extent: self.extent,
                prune_large: schedule.prunes_large(it),
                iteration: it,
                phase: schedule.phase(it),
            };
            let outcome = strategy.densify(&mut self.density_context(at.view)?, at, &args)?;
            self.follow_capacity()?;
            if !outcome.skipped && outcome.after > outcome.kept {
                self.passes.record_new_gaussians(
                    &mut self.rec,
                    &self.state,
                    outcome.kept..outcome.after,
                    it,
                )?;
            }
            // New and moved Gaussians need their derived per-Gaussian data (Mip-Splatting's 3D
            // filter: the official code recomputes it after every densification).
            if !outcome.skipped {
                self.passes.model_changed();
            }
            if schedule.resets_opacity(it) {
                self.record_opacity_reset()?;
            }
            let count = self.state.count();
            report.strategy = strategy.after_density(&mut self.density_context(at.view)?, at)?;
            self.follow_capacity()?;
            if self.state.count() != count {
                self.passes.model_changed();
            }
            if outcome.skipped {
                // Nothing was rebuilt, so this iteration's gradients still belong to the model:
                // its optimizer step runs as on any other iteration.
                self.record_adam_step(it)?;
            }
            self.rec.submit_and_wait()?;
            report.gaussians = self.state.count();
            report.densified = Some(outcome);
        } else if schedule.resets_opacity(it) {
            self.rec.begin()?;
            self.record_opacity_reset()?;
            self.rec.submit_and_wait()?;
        }
        let reported = report.strategy.is_some();
        if let Some(e) =
            strategy.after_iteration(&mut self.density_context(at.view)?, at, reported)?
        {
            report.strategy = Some(e);
        }
        self.follow_capacity()?;
        // A strategy may add or remove Gaussians between density steps (LPM's additions).
        report.gaussians = self.state.count();
        // The base model's own rules (taken out while they drive the trainer's buffers).
        let mut rules = std::mem::take(&mut self.model_rules);
        let views = report.views.clone();
        let view_ssim = report.view_ssim.clone();
        let seen = StepSeen {
            iteration: it,
            views: &views,
            view_ssim: &view_ssim,
            background: at.background,
        };
        let mut result = Ok(());
        for rule in rules.iter_mut() {
            let count = self.state.count();
            match rule.after_step(&mut self.density_context(at.view)?, &seen) {
                Ok(e) => report.model_events.extend(e),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
            if let Err(e) = self.follow_capacity() {
                result = Err(e);
                break;
            }
            if self.state.count() != count {
                self.passes.model_changed();
                report.gaussians = self.state.count();
            }
        }
        self.model_rules = rules;
        result
    }

    /// What a strategy gets to work on for training view `view` (see [`DensityContext`]).
    fn density_context(&mut self, view: usize) -> anyhow::Result<DensityContext<'_>> {
        let slot = self.image_slot(view)?;
        Ok(DensityContext {
            ctx: &self.ctx,
            rec: &mut self.rec,
            state: &mut self.state,
            density: &mut self.density,
            extent: self.extent,
            render: self.passes.image(),
            truth: self.images.buffer(&slot),
            truth_offset_px: slot.offset_px,
            width: slot.width,
            height: slot.height,
            primitive: self.passes.primitive(),
            raw_colour: self.passes.raw_colour(),
            new_extras: self.passes.new_gaussian_extras(),
            moving: self.passes.frame_positions(),
            opacity_filter: self.passes.smoothing_filter().map(|filter| OpacityFilter {
                filter,
                cameras: &self.cameras,
            }),
        })
    }
}
