//! Recording the next iteration while the current one runs ([`Trainer::step_ahead`]): when it
//! is safe (the current iteration leaves the host nothing to do), how a prepared iteration is
//! kept, submitted, or dropped and its host state undone.

use super::{Recorded, StepReport, Trainer};
use crate::gpu::HoldFrees;
use crate::train::data::ViewSchedule;
use crate::train::image_cache::CacheBook;

/// How the iterations were recorded: the host's recording time, and how many iterations were
/// recorded while the previous one ran (`Trainer::step_ahead`) rather than between them.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct RecordingStats {
    /// Iterations submitted.
    pub iterations: u32,
    /// Of those, recorded while the previous iteration ran on the GPU.
    pub ahead: u32,
    /// Prepared iterations dropped and recorded again (after a frame overflowed the
    /// intersection buffers, or a strategy or rule that claimed a quiet step changed the model).
    pub dropped: u32,
    /// Host time spent recording iterations (prepared ones that were dropped included).
    pub seconds: f64,
}

/// An iteration recorded ahead (not submitted) and what recording it changed on the host.
pub(super) struct Prepared {
    step: Recorded,
    undo: Undo,
}

/// The host state a recording advances, as it was before (to drop a prepared iteration).
struct Undo {
    views: ViewSchedule,
    adam_step: u32,
    images: CacheBook,
    snapshot_requested: bool,
}

impl Trainer {
    /// Runs one training iteration and waits for it. When it fails before the iteration's
    /// work was submitted (out of device memory while a buffer grows for it, say), the
    /// iteration is not counted, so a checkpoint saved then resumes with it.
    pub fn step(&mut self) -> anyhow::Result<StepReport> {
        self.step_ahead(false)
    }

    /// [`Trainer::step`], and with `prepare_next` the next iteration's command buffer is
    /// recorded while this one runs on the GPU, so that the next call only submits it and the
    /// GPU does not wait for the host's recording between iterations. Pass `prepare_next` only
    /// when the next call on this trainer is `step` or `step_ahead`: in between, reading the
    /// model (`state`, a non-finite check) is fine, since the prepared iteration is not
    /// submitted before that call, but evaluating, exporting, checkpointing, snapshotting or
    /// changing the strategy is refused (a panic: a caller's bug). Nothing is prepared after an
    /// iteration that leaves work for the host (see `Trainer::quiet`), and a prepared
    /// iteration is dropped and recorded again when the one before it overflowed the
    /// intersection buffers, so the results are those of `step`.
    pub fn step_ahead(&mut self, prepare_next: bool) -> anyhow::Result<StepReport> {
        self.step_submitted = false;
        let r = self.step_inner(prepare_next);
        if r.is_err() {
            // A failed step leaves nothing prepared (its recording may hold what failed).
            self.discard_prepared();
        }
        r
    }

    fn step_inner(&mut self, prepare_next: bool) -> anyhow::Result<StepReport> {
        let step = match self.prepared.take() {
            Some(p) => {
                // The prepared command buffer is in `rec_ahead`: make it the current one.
                std::mem::swap(&mut self.rec, &mut self.rec_ahead);
                std::mem::swap(&mut self.pool, &mut self.pool_ahead);
                self.recording.ahead += 1;
                p.step
            }
            None => self.record_step()?,
        };
        self.rec.submit()?;
        self.recording.iterations += 1;
        self.iteration = step.iteration;
        self.step_submitted = true;
        if prepare_next && self.quiet(&step) {
            self.prepare_ahead()?;
        } else {
            self.rec.wait()?;
        }
        self.finish_step(step)
    }

    /// Whether the host has nothing to do after `step` that could change how the next
    /// iteration is recorded: no density control, opacity reset or snapshot, a strategy and
    /// model rules with no GPU work due, and (when images stream) room in the image cache for
    /// two steps' images, so that the next step's uploads evict none of this one's. Should a
    /// strategy or rule misjudge, `finish_step` notices the change and drops what was prepared.
    fn quiet(&self, step: &Recorded) -> bool {
        let it = step.iteration;
        let schedule = &self.config.schedule;
        !schedule.densifies(it)
            && !schedule.resets_opacity(it)
            && self.snapshot.is_none()
            && self
                .images
                .holds_two_steps(self.config.batch_views.max(1) as usize)
            && self.strategy.quiet_after(it)
            && self
                .model_rules
                .iter()
                .all(|r| r.quiet_after(it, &step.views))
    }

    /// Records the next iteration into `rec_ahead` while the current one (submitted in
    /// `rec`) runs, then waits for the current one. A recording that fails is undone and left
    /// to the next step, which records it again (and meets the failure where it belongs).
    fn prepare_ahead(&mut self) -> anyhow::Result<()> {
        let undo = Undo {
            views: self.views.clone(),
            adam_step: self.adam_step,
            images: self.images.book(),
            snapshot_requested: self.snapshot_requested,
        };
        std::mem::swap(&mut self.rec, &mut self.rec_ahead);
        std::mem::swap(&mut self.pool, &mut self.pool_ahead);
        // A buffer the recording replaces may still be bound in the running iteration.
        let hold = HoldFrees::new(&self.ctx);
        let recorded = self.record_step();
        std::mem::swap(&mut self.rec, &mut self.rec_ahead);
        std::mem::swap(&mut self.pool, &mut self.pool_ahead);
        let waited = self.rec.wait();
        drop(hold);
        waited?;
        match recorded {
            Ok(step) => self.prepared = Some(Prepared { step, undo }),
            Err(_) => self.undo(undo),
        }
        Ok(())
    }

    /// Drops a prepared iteration (never submitted) and restores what recording it changed.
    pub(super) fn discard_prepared(&mut self) {
        if let Some(p) = self.prepared.take() {
            self.undo(p.undo);
            self.recording.dropped += 1;
        }
    }

    fn undo(&mut self, undo: Undo) {
        self.views = undo.views;
        self.adam_step = undo.adam_step;
        self.images.restore_book(undo.images);
        self.snapshot_requested = undo.snapshot_requested;
    }

    /// Whether an iteration is prepared (see [`Trainer::step_ahead`]).
    pub fn has_prepared(&self) -> bool {
        self.prepared.is_some()
    }

    /// Panics when an iteration is prepared: `what` would change or read what it was recorded
    /// against (see [`Trainer::step_ahead`]).
    pub(in crate::train) fn assert_nothing_prepared(&self, what: &str) {
        assert!(
            self.prepared.is_none(),
            "Trainer::{what} called while the next iteration is prepared (step_ahead(true)); \
             step it first"
        );
    }
}
