//! The training loop: one command buffer per iteration (forward, loss, backward, density
//! statistics and Adam), density control at its schedule, evaluation on the test views.
//!
//! Order within an iteration follows the reference trainer: render, loss, backward, statistics,
//! then densify / prune / reset when due, then the optimizer step. At a densify iteration the
//! reference replaces every parameter tensor, which leaves them without gradients, so torch's
//! Adam skips that iteration; we do the same (and keep one step counter for all groups: at an
//! opacity reset, which always coincides with a densify step, nothing steps either).
//!
//! The host waits for each iteration's fence (it reads the loss and the intersection count from
//! host-visible copies made at the end of the command buffer; no other readback). With
//! [`Trainer::step_ahead`] it records the next iteration while the current one runs, wherever the
//! current one leaves the host nothing to do (no density control, reset or snapshot, no GPU work of
//! the strategy or the model's rules), so the GPU waits only for the submission, not for the
//! recording; the next iteration's command buffer starts with a barrier against everything before
//! it, a buffer its recording replaces is freed only after the current iteration's fence
//! ([`HoldFrees`]), and a streaming image cache alternates between two halves of its staging
//! buffer. When a frame needed more intersections than the buffers hold, the pairs past the
//! capacity (the farthest Gaussians) were dropped for that one iteration; the buffers then grow to
//! 1.5× the need, and it does not happen again for that view size.
//!
//! Determinism: the backward pass sums gradients with float atomics, so on a device that runs
//! workgroups concurrently the order of those sums, and with it the last bits of the gradients,
//! varies from run to run (lavapipe: thousands of words differ after one iteration, and the
//! runs drift apart chaotically). With `LP_NUM_THREADS=1` lavapipe runs workgroups in order and
//! identical runs are bitwise equal. A checkpoint (`super::checkpoint`) restores everything the
//! next iteration reads, so a resumed run is bitwise equal to a straight one wherever straight
//! runs are reproducible (`tests/train/end_to_end.rs`).

use std::sync::Arc;

use anyhow::Context;

use super::adam::{Adam, SplatState};
use super::batch::{batch_partners, GradBlend};
use super::data::{scene_cameras, ViewSchedule};
use super::density::{DensifyOutcome, DensityControl};
use super::image_cache::{CacheStats, ImageCache, ImageSlot};
use super::loss::{Loss, LOSS_SLOT_FLOATS};
use super::loss_mask::GpuLossMasks;
use super::passes::{FrameArgs, GradArgs, ModelPasses, ModelTraining};
use super::schedule::sh_degree_at;
use super::strategy::{Adc, DensityStrategy, IterationView, ModelRule, StrategyEvent};
use crate::gpu::{
    BufferKind, GpuBuffer, GpuContext, HoldFrees, Recorder, StageTimes, TimestampPool,
};
use crate::render::forward::Capacity;
use crate::render::layout::{CameraGpu, RenderConstants};
use crate::scene::image_source::TrainImages;
use crate::scene::loss_masks::LossMasks;
use crate::scene::Scene;
use crate::splats::gpu::{grown_capacity, GpuSplats};
use crate::splats::GaussianParams;

pub use super::config::{Background, TrainConfig};
pub use evaluation::ViewMetrics;
use step_ahead::Prepared;
pub use step_ahead::RecordingStats;

mod density_step;
mod evaluation;
mod step_ahead;

/// What one iteration reports.
#[derive(Debug, Clone, Default)]
pub struct StepReport {
    pub iteration: u32,
    /// The view whose render density control saw (the last of `views`).
    pub view: usize,
    /// Every view of the step, the scheduled one first (`batch_views` of them when its time has
    /// that many).
    pub views: Vec<usize>,
    /// The last view's L1, SSIM and loss.
    pub l1: f32,
    pub ssim: f32,
    pub loss: f32,
    /// SSIM of each view of `views`, in order (a model's own rules read them).
    pub view_ssim: Vec<f32>,
    pub gaussians: usize,
    pub densified: Option<DensifyOutcome>,
    pub stages: Option<StageTimes>,
    /// What the density strategy reported at this iteration, if anything.
    pub strategy: Option<Arc<dyn StrategyEvent>>,
    /// What the base model's own rules reported (guided sampling's choices and points).
    pub model_events: Vec<Arc<dyn StrategyEvent>>,
}

impl StepReport {
    /// The strategy's event of this iteration as its own type (e.g. LPM's step report).
    pub fn event<T: StrategyEvent>(&self) -> Option<&T> {
        self.strategy.as_ref()?.as_any().downcast_ref::<T>()
    }
}

pub struct Trainer {
    pub ctx: Arc<GpuContext>,
    /// Whether the current step's main command buffer was submitted (see [`Trainer::step`]).
    step_submitted: bool,
    pub config: TrainConfig,
    pub extent: f64,
    cameras_host: Vec<CameraGpu>,
    cameras: GpuBuffer<CameraGpu>,
    pub(super) images: ImageCache,
    /// `scene.views` index → image in `images` (training views only).
    image_of_view: Vec<Option<usize>>,
    pub state: SplatState,
    grads: GpuSplats,
    /// A later view's gradients in a batched step (allocated on the first batched step).
    batch_grads: Option<GpuSplats>,
    blend: GradBlend,
    /// The training views and, for a video, every view's time (batch partners).
    train_views: Vec<usize>,
    view_times: Option<Vec<f64>>,
    view_grad_norm: GpuBuffer<f32>,
    /// The base model's forward, backward, own losses and per-Gaussian buffers.
    pub(super) passes: Box<dyn ModelPasses>,
    loss: Loss,
    adam: Adam,
    pub density: DensityControl,
    dl_dimage: GpuBuffer<f32>,
    /// Which pixels of each view are learned (`loss_masks.json`); `None`: all of them.
    loss_masks: Option<GpuLossMasks>,
    loss_out: GpuBuffer<f32>,
    loss_host: GpuBuffer<f32>,
    pub views: ViewSchedule,
    pub iteration: u32,
    pub adam_step: u32,
    pub(super) rec: Recorder,
    pool: TimestampPool,
    /// The prepared iteration's recorder and timestamps (see [`Trainer::step_ahead`]).
    rec_ahead: Recorder,
    pool_ahead: TimestampPool,
    prepared: Option<Prepared>,
    pub recording: RecordingStats,
    pub dropped_frames: u32,
    /// Decides clone / split / prune / reset ([`Adc`] unless [`Trainer::set_strategy`]).
    strategy: Box<dyn DensityStrategy>,
    /// The base model's own density rules, run after the strategy every step.
    pub(super) model_rules: Vec<Box<dyn ModelRule>>,
    /// Set by [`Trainer::snapshot_next_step`]: the next step copies the model before its
    /// density control into `snapshot`.
    snapshot_requested: bool,
    snapshot: Option<GpuSplats>,
    /// The iteration whose pre-density-control model `snapshot` holds.
    snapshot_iteration: Option<u32>,
    /// After a resume: the strategy settings saved in the checkpoint (null: plain ADC).
    pub(super) resumed_strategy: Option<serde_json::Value>,
}

/// An iteration recorded into a command buffer, with what finishing it needs.
struct Recorded {
    iteration: u32,
    views: Vec<usize>,
    background: [f32; 3],
    count: usize,
}

/// Steps ahead whose images a streaming cache decodes while the GPU works on the current one.
const LOOKAHEAD_STEPS: u32 = 2;

/// Per-iteration background colour for `Background::Random`: a hash of (seed, iteration), so a
/// resumed run draws the same colours.
fn random_background(seed: u64, iteration: u32) -> [f32; 3] {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ ((iteration as u64) << 20) ^ 0xB6);
    [rng.gen(), rng.gen(), rng.gen()]
}

/// The snapshot if it was taken at `iteration` (the current one), else `state`.
pub(super) fn snapshot_or<'a>(
    snapshot: &'a Option<GpuSplats>,
    taken_at: Option<u32>,
    iteration: u32,
    state: &'a GpuSplats,
) -> &'a GpuSplats {
    match (snapshot, taken_at) {
        (Some(s), Some(it)) if it == iteration => s,
        _ => state,
    }
}

impl Trainer {
    /// Sets up training of `init`, a model of `model`, on the training views of `scene`
    /// (image `k` of `train_images` is that of `scene.train[k]`: a `&Vec<Image>` in memory, or
    /// [`TrainImages::streamed`] from the files). `Trainer::new` (in `models/`) picks `model`
    /// from the config.
    pub fn with_model(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        init: &GaussianParams,
        config: TrainConfig,
        model: &dyn ModelTraining,
    ) -> anyhow::Result<Self> {
        Self::set_up(ctx, scene, train_images, init, config, model, true)
    }

    /// [`Trainer::with_model`]; `fresh`: a new run, whose initial model the base model's own
    /// rules may edit first ([`ModelRule::prepare_initial`]); a resumed run's model is the
    /// checkpoint's as it is.
    pub(super) fn set_up(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        init: &GaussianParams,
        config: TrainConfig,
        model: &dyn ModelTraining,
        fresh: bool,
    ) -> anyhow::Result<Self> {
        let train_images = train_images.into();
        anyhow::ensure!(
            train_images.source.count() == scene.train.len(),
            "trainer: {} images for {} training views",
            train_images.source.count(),
            scene.train.len()
        );
        anyhow::ensure!(
            !init.is_empty(),
            "the initial model has no Gaussians. Fix: give a scene with SfM points or a PLY \
             with at least one Gaussian"
        );
        let init = init.clone().with_sh_degree(config.sh_degree)?;
        let cameras_host = scene_cameras(scene);
        let cameras = GpuBuffer::from_slice(ctx, "cameras", &cameras_host)?;
        let images = ImageCache::new(ctx, &train_images, config.batch_views.max(1) as usize)?;
        let mut image_of_view = vec![None; scene.views.len()];
        for (k, &v) in scene.train.iter().enumerate() {
            image_of_view[v] = Some(k);
        }
        // The passes see the configuration's world lengths in the scene's training frame.
        let frame_config = config.in_training_frame(&scene.frame);
        let mut model_rules = model.rules(ctx, &frame_config, scene, &init)?;
        let mut init = init;
        if fresh {
            for rule in model_rules.iter_mut() {
                init = rule.prepare_initial(init)?;
            }
        }
        let capacity = grown_capacity(init.len());
        let params = GpuSplats::upload(ctx, &init, capacity)?;
        let state = SplatState::new(ctx, params)?;
        let grads = GpuSplats::zeroed_shape(ctx, "grad ", &state.shape(), init.len(), capacity)?;
        let view_grad_norm =
            GpuBuffer::new(ctx, "view grad norm", capacity, BufferKind::DeviceLocal)?;
        let (mut max_w, mut max_h, mut max_tiles) = (1u32, 1u32, 1u32);
        for &v in &scene.train {
            let c = &cameras_host[v];
            max_w = max_w.max(c.width());
            max_h = max_h.max(c.height());
            max_tiles = max_tiles.max(c.tile_count());
        }
        let pixels = (max_w * max_h) as usize;
        // The growth region in the training frame, like every other world length.
        let mut density = frame_config.density;
        density.seed = config.seed;
        let passes = model.passes(
            ctx,
            &frame_config,
            &cameras_host,
            &scene.train,
            scene.view_times.as_deref(),
            capacity,
            Capacity {
                gaussians: capacity,
                intersections: 0,
                pixels,
                tiles: max_tiles as usize,
            },
        )?;
        Ok(Self {
            ctx: ctx.clone(),
            extent: scene.extent,
            cameras_host,
            cameras,
            images,
            image_of_view,
            grads,
            batch_grads: None,
            blend: GradBlend::new(ctx)?,
            train_views: scene.train.clone(),
            view_times: scene.view_times.clone(),
            view_grad_norm,
            passes,
            loss: match config.loss_layout {
                Some(layout) => Loss::with_layout(ctx, max_w, max_h, layout)?,
                None => Loss::new(ctx, max_w, max_h)?,
            },
            adam: Adam::new(ctx)?,
            density: DensityControl::new(ctx, capacity, density)?,
            dl_dimage: GpuBuffer::new(ctx, "dL/dimage", pixels * 3, BufferKind::DeviceLocal)?,
            loss_masks: None,
            // One loss slot per view of a step.
            loss_out: GpuBuffer::new(
                ctx,
                "loss",
                LOSS_SLOT_FLOATS * config.batch_views.max(1) as usize,
                BufferKind::DeviceLocal,
            )?,
            loss_host: GpuBuffer::new(
                ctx,
                "loss (host)",
                LOSS_SLOT_FLOATS * config.batch_views.max(1) as usize,
                BufferKind::Readback,
            )?,
            views: ViewSchedule::new(scene.train.clone(), config.seed)?,
            iteration: 0,
            adam_step: 0,
            rec: Recorder::new(ctx)?,
            // About a dozen stamps per view of a step, plus density statistics and Adam.
            pool: TimestampPool::new(ctx, 16 + 16 * config.batch_views.max(1))?,
            rec_ahead: Recorder::new(ctx)?,
            pool_ahead: TimestampPool::new(ctx, 16 + 16 * config.batch_views.max(1))?,
            prepared: None,
            recording: RecordingStats::default(),
            dropped_frames: 0,
            strategy: Box::new(Adc),
            model_rules,
            snapshot_requested: false,
            step_submitted: false,
            snapshot: None,
            snapshot_iteration: None,
            resumed_strategy: None,
            state,
            config,
        })
    }

    pub fn gaussians(&self) -> usize {
        self.eval_params().count
    }

    /// Asks the next [`Trainer::step`] to keep a copy of the model as it stands before that
    /// iteration's density control (clone, split, prune, opacity resets, LPM), for evaluation
    /// and export. The Inria reference evaluates and saves at iteration k before densifying at
    /// k; a model evaluated right after densification carries clones, samples of splits and
    /// reset opacities no gradient step has corrected yet, and scores several dB lower. The
    /// training state itself (and so a checkpoint) is unaffected. Nothing is copied when the
    /// step runs no density control: the model is then already the one to evaluate.
    pub fn snapshot_next_step(&mut self) {
        self.assert_nothing_prepared("snapshot_next_step");
        self.snapshot_requested = true;
    }

    /// The model evaluation and export use: the snapshot taken in the last step, if any, else
    /// the training state.
    pub fn eval_params(&self) -> &GpuSplats {
        snapshot_or(
            &self.snapshot,
            self.snapshot_iteration,
            self.iteration,
            &self.state.params,
        )
    }

    /// Records copies of every parameter group of the first `count` Gaussians into a snapshot
    /// allocated for this iteration (exactly the model's size: it adds to the run's peak of
    /// device memory; freed at the next step) inside the iteration's command buffer.
    fn record_snapshot(&mut self, count: usize) -> anyhow::Result<()> {
        let shape = self.state.shape();
        // Every row below `count` is copied in before anything reads it.
        let snap = self.snapshot.insert(GpuSplats::allocate_shape(
            &self.ctx,
            "snapshot ",
            &shape,
            count.max(1),
        )?);
        snap.count = count;
        self.rec.barrier();
        for ((src, stride), (dst, _)) in self.state.params.groups().into_iter().zip(snap.groups()) {
            self.rec.copy(src, dst, count * stride);
        }
        Ok(())
    }

    /// Grows the per-Gaussian buffers the trainer owns to the state's capacity.
    pub(super) fn follow_capacity(&mut self) -> anyhow::Result<()> {
        let cap = self.state.capacity();
        if self.grads.capacity < cap {
            // Nothing in the old buffers is kept: free them before allocating the bigger ones
            // (both at once were a training run's peak of device memory).
            let shape = self.state.shape();
            self.grads = GpuSplats::allocate_shape(&self.ctx, "grad ", &shape, 0)?;
            self.grads = GpuSplats::zeroed_shape(&self.ctx, "grad ", &shape, 0, cap)?;
            self.view_grad_norm =
                GpuBuffer::new(&self.ctx, "view grad norm", 0, BufferKind::DeviceLocal)?;
            self.view_grad_norm =
                GpuBuffer::new(&self.ctx, "view grad norm", cap, BufferKind::DeviceLocal)?;
        }
        self.passes.reserve(cap)?;
        self.grads.count = self.state.count();
        if self.batch_grads.as_ref().is_some_and(|b| b.capacity < cap) {
            self.batch_grads = None;
            self.ensure_batch_grads()?;
        }
        Ok(())
    }

    /// The second gradient set of batched steps, at the state's capacity and shape.
    fn ensure_batch_grads(&mut self) -> anyhow::Result<()> {
        let (cap, shape) = (self.state.capacity(), self.state.shape());
        if self
            .batch_grads
            .as_ref()
            .is_none_or(|b| b.capacity < cap || b.shape() != shape)
        {
            self.batch_grads = Some(GpuSplats::zeroed_shape(
                &self.ctx,
                "batch grad ",
                &shape,
                self.state.count(),
                cap,
            )?);
        }
        Ok(())
    }

    /// Where the ground truth of training view `view` lives on the GPU.
    pub(super) fn image_slot(&self, view: usize) -> anyhow::Result<ImageSlot> {
        let k = self.train_image(view)?;
        self.images
            .slot(k)
            .with_context(|| format!("trainer: the image of view {view} is not on the GPU"))
    }

    /// The training image number of scene view `view`.
    fn train_image(&self, view: usize) -> anyhow::Result<usize> {
        self.image_of_view
            .get(view)
            .copied()
            .flatten()
            .context("trainer: scheduled a non-training view")
    }

    /// The base model's own rules' states, by name (what a checkpoint saves of them).
    pub fn model_rule_states(&self) -> Vec<(&'static str, serde_json::Value)> {
        self.model_rules
            .iter()
            .map(|r| (r.name(), r.state_json()))
            .collect()
    }

    /// What the ground-truth cache has done (slots, uploads, time spent waiting for frames).
    pub fn image_cache_stats(&self) -> CacheStats {
        self.images.stats()
    }

    /// The training images of the `steps` steps after iteration `iteration` (each step's
    /// scheduled view and its batch partners), for the cache to decode ahead.
    fn upcoming_images(&self, iteration: u32, steps: u32) -> anyhow::Result<Vec<usize>> {
        let mut schedule = self.views.clone();
        let mut out = Vec::new();
        for s in 1..=steps {
            let first = schedule.next_view();
            for v in std::iter::once(first).chain(batch_partners(
                first,
                &self.train_views,
                self.view_times.as_deref(),
                self.config.batch_views,
                self.config.seed,
                iteration + s,
            )) {
                out.push(self.train_image(v)?);
            }
        }
        Ok(out)
    }

    /// Records iteration `self.iteration + 1` into `self.rec` (idle) with `self.pool`.
    fn record_step(&mut self) -> anyhow::Result<Recorded> {
        let t0 = std::time::Instant::now();
        let r = self.record_step_timed();
        self.recording.seconds += t0.elapsed().as_secs_f64();
        r
    }

    fn record_step_timed(&mut self) -> anyhow::Result<Recorded> {
        let it = self.iteration + 1;
        let cfg = self.config.clone();
        let first = self.views.next_view();
        // The step's views: the scheduled one, then its batch partners; the last one's render
        // stays in the passes (the density strategy's error map) and gives the statistics.
        let views: Vec<usize> = std::iter::once(first)
            .chain(batch_partners(
                first,
                &self.train_views,
                self.view_times.as_deref(),
                cfg.batch_views,
                cfg.seed,
                it,
            ))
            .collect();
        let bg = match cfg.background {
            Background::Fixed(c) => c,
            Background::Random => random_background(cfg.seed, it),
        };
        let sh = sh_degree_at(it, cfg.sh_degree);
        let densifies = cfg.schedule.densifies(it);
        let count = self.state.count();
        self.grads.count = count;
        if views.len() > 1 {
            self.ensure_batch_grads()?;
        }
        if let Some(b) = self.batch_grads.as_mut() {
            b.count = count;
        }

        self.rec.begin()?;
        // The previous iteration may still be running when this one is submitted
        // (`step_ahead`): everything here comes after all of it.
        self.rec.barrier();
        if cfg.timestamps {
            self.rec.start_timestamps(&mut self.pool);
        }
        let needed = views
            .iter()
            .map(|&v| self.train_image(v))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let upcoming = if self.images.streams() {
            self.upcoming_images(it, LOOKAHEAD_STEPS)?
        } else {
            Vec::new()
        };
        self.images.prepare(&mut self.rec, &needed, &upcoming)?;
        for (k, &v) in views.iter().enumerate() {
            let img = self
                .images
                .slot(needed[k])
                .context("trainer: image not prepared")?;
            let cam = self.cameras_host[v];
            if k > 0 {
                // The previous view's backward reads the image and dL/dimage this view rewrites.
                self.rec.barrier();
            }
            let frame = FrameArgs {
                params: &self.state.params,
                cameras: &self.cameras,
                view: v as u32,
                camera: &cam,
                sh_degree: sh,
                background: bg,
                iteration: it,
            };
            if k == 0 {
                self.passes.record_prepare(&mut self.rec, &frame, &cfg)?;
            }
            self.passes.record_forward(
                &mut self.rec,
                &frame,
                if cfg.timestamps {
                    Some(&mut self.pool)
                } else {
                    None
                },
            )?;
            self.loss.record(
                &mut self.rec,
                self.passes.image(),
                self.images.buffer(&img),
                img.offset_px,
                img.width,
                img.height,
                bg,
                &self.dl_dimage,
                &self.loss_out,
                k as u32,
                cfg.ssim_weight,
            )?;
            if let Some(m) = &self.loss_masks {
                m.record(&mut self.rec, v, img.width, img.height, &self.dl_dimage)?;
            }
            if cfg.timestamps {
                self.rec.timestamp(&mut self.pool, "loss");
            }
            // The first view writes the step's gradients; later ones write theirs aside and
            // are added in, the last scaling the sum to the mean.
            let grads = match (k, &self.batch_grads) {
                (0, _) => &self.grads,
                (_, Some(b)) => b,
                (_, None) => anyhow::bail!("trainer: batch gradients missing"),
            };
            self.passes.record_backward(
                &self.ctx,
                &mut self.rec,
                &GradArgs {
                    frame,
                    dl_dimage: &self.dl_dimage,
                    grads,
                    view_grad_norm: &self.view_grad_norm,
                    count,
                    view_in_step: k,
                    views_in_step: views.len(),
                },
                &cfg,
                if cfg.timestamps {
                    Some(&mut self.pool)
                } else {
                    None
                },
            )?;
            if k > 0 {
                let scale = if k + 1 == views.len() {
                    1.0 / views.len() as f32
                } else {
                    1.0
                };
                self.blend
                    .record(&mut self.rec, &self.grads, grads, count, scale)?;
            }
        }
        if cfg.schedule.accumulates(it) {
            self.density.record_accumulate(
                &mut self.rec,
                &self.view_grad_norm,
                self.passes.projected_bounds(),
                self.passes.pixel_count(),
                self.passes.abs_grad(),
                self.extent,
                count,
            )?;
        }
        if cfg.timestamps {
            self.rec.timestamp(&mut self.pool, "density stats");
        }
        if !densifies {
            self.record_adam_step(it)?;
        }
        if cfg.timestamps {
            self.rec.timestamp(&mut self.pool, "adam");
        }
        // A snapshot serves only the iteration it was taken at: free it rather than hold a
        // copy of the parameters (236 bytes a Gaussian) to the next evaluation.
        self.snapshot_iteration = None;
        self.snapshot = None;
        if std::mem::take(&mut self.snapshot_requested)
            && (densifies || cfg.schedule.resets_opacity(it))
        {
            self.record_snapshot(count)?;
            self.snapshot_iteration = Some(it);
        }
        self.rec.copy(
            &self.loss_out,
            &self.loss_host,
            LOSS_SLOT_FLOATS * views.len(),
        );
        Ok(Recorded {
            iteration: it,
            views,
            background: bg,
            count,
        })
    }

    /// Reads back the submitted, completed iteration `step` and runs its density control.
    fn finish_step(&mut self, step: Recorded) -> anyhow::Result<StepReport> {
        // Only these two settings are read here (the recording cloned the whole config).
        let (schedule, timestamps) = (self.config.schedule, self.config.timestamps);
        let Recorded {
            iteration: it,
            views,
            background: bg,
            count,
        } = step;
        let view = *views.last().expect("at least the scheduled view");
        let densifies = schedule.densifies(it);
        let stages = if timestamps {
            Some(self.pool.read()?)
        } else {
            None
        };

        if self.prepared.is_some() && self.passes.frame_need()?.is_some() {
            // The next iteration was recorded against the buffers this frame overflowed: drop
            // it, so that it is recorded again after they grow, as `step` would have.
            self.discard_prepared();
        }
        if self.passes.after_frame()? {
            self.dropped_frames += 1;
        }
        let slots = self
            .loss_host
            .read_range(0, LOSS_SLOT_FLOATS * views.len())?;
        let l = &slots[LOSS_SLOT_FLOATS * (views.len() - 1)..];
        anyhow::ensure!(
            slots.iter().all(|v| v.is_finite()),
            "iteration {it}: the loss is not finite (L1 {}, SSIM {}); the model diverged. \
             Fix: lower the learning rates or report the scene",
            l[0],
            l[1]
        );
        let mut report = StepReport {
            iteration: it,
            view,
            views: views.clone(),
            l1: l[0],
            ssim: l[1],
            loss: l[2],
            view_ssim: slots.chunks(LOSS_SLOT_FLOATS).map(|c| c[1]).collect(),
            gaussians: count,
            densified: None,
            stages,
            strategy: None,
            model_events: Vec::new(),
        };

        let control_start = std::time::Instant::now();
        let at = IterationView {
            iteration: it,
            view,
            background: bg,
        };
        // With the next iteration prepared, the strategy and the model's rules said they have
        // nothing to do here (`Trainer::quiet`). Should one change the model or replace a
        // buffer all the same, the prepared iteration, recorded against the old ones, is
        // dropped (and recorded again by the next step); the guard keeps what it names alive
        // until then.
        let hold = self.prepared.is_some().then(|| HoldFrees::new(&self.ctx));
        let shape = (self.state.count(), self.state.capacity());
        // The strategy is taken out while it runs, as it drives the trainer's buffers.
        let mut strategy = std::mem::replace(&mut self.strategy, Box::new(Adc));
        let result = self.run_density_control(strategy.as_mut(), &at, &mut report);
        self.strategy = strategy;
        if let Some(hold) = hold {
            if result.is_err()
                || hold.retired_any()
                || (self.state.count(), self.state.capacity()) != shape
            {
                self.discard_prepared();
            }
        }
        result?;
        // Density control runs in its own submissions with count readbacks, so its cost is the
        // host wall time of that part (GPU work, waits and host logic), not a GPU interval.
        if let Some(st) = report.stages.as_mut() {
            let ms = if densifies || schedule.resets_opacity(it) {
                1e3 * control_start.elapsed().as_secs_f64()
            } else {
                0.0
            };
            st.stages.push(("density control".into(), ms));
        }
        Ok(report)
    }

    /// Learns each view only from the pixels of its cells `masks` marks (before the first
    /// step): the loss gradient is zeroed at the others.
    pub fn set_loss_masks(&mut self, masks: &LossMasks) -> anyhow::Result<()> {
        self.assert_nothing_prepared("set_loss_masks");
        anyhow::ensure!(
            masks.views.len() == self.image_of_view.len(),
            "loss masks for {} views, the scene has {}",
            masks.views.len(),
            self.image_of_view.len()
        );
        self.loss_masks = Some(GpuLossMasks::new(&self.ctx, masks)?);
        Ok(())
    }

    /// Replaces the density strategy (before the first step, or after a restore).
    pub fn set_strategy(&mut self, strategy: Box<dyn DensityStrategy>) {
        self.assert_nothing_prepared("set_strategy");
        self.strategy = strategy;
    }

    /// Changes the Gaussian budget (`DensityConfig::max_gaussians`; `None`: none) from the
    /// next density step on. Only density control reads it, so an iteration already recorded
    /// ahead is unaffected (`bench trade --match-adc-count` moves it every iteration).
    pub fn set_max_gaussians(&mut self, cap: Option<usize>) {
        self.config.density.max_gaussians = cap;
        self.density.config.max_gaussians = cap;
    }

    pub fn strategy(&self) -> &dyn DensityStrategy {
        self.strategy.as_ref()
    }

    /// The strategy as its own type, if it is a `T`.
    pub fn strategy_as<T: DensityStrategy>(&self) -> Option<&T> {
        self.strategy.as_any().downcast_ref::<T>()
    }

    /// Records the global opacity reset (into the begun `self.rec`), on the opacity the
    /// model's renderer uses (Mip-Splatting: the filtered one).
    fn record_opacity_reset(&mut self) -> anyhow::Result<()> {
        self.passes
            .record_opacity_reset(&mut self.rec, &self.density, &self.state, &self.cameras)
    }

    /// The rasterizer constants of this run ([`TrainConfig::render_constants`]).
    pub fn render_constants(&self) -> RenderConstants {
        self.config.render_constants()
    }

    /// Records iteration `it`'s Adam step into `self.rec` (begun).
    fn record_adam_step(&mut self, it: u32) -> anyhow::Result<()> {
        self.adam_step += 1;
        let mut lrs = self.config.lr.at(it, self.extent);
        lrs.0.extend(self.passes.extra_lrs(it, self.extent));
        self.passes
            .record_before_step(&mut self.rec, &self.state, &self.grads, it)?;
        self.strategy
            .record_gradient_terms(&mut self.rec, &self.state, &self.grads, it)?;
        // The render used SH up to this degree, so the planes above it have had zero
        // gradients since the start (the degree only grows): Adam skips them, exactly.
        let sh = sh_degree_at(it, self.config.sh_degree);
        let active_rest = ((sh + 1) * (sh + 1) - 1) as usize;
        self.adam.record_state(
            &self.ctx,
            &mut self.rec,
            &self.state,
            &self.grads,
            self.adam_step,
            &lrs,
            Some(active_rest),
        )?;
        self.passes
            .record_model_step(&self.ctx, &mut self.rec, self.adam_step, it)?;
        self.strategy
            .record_after_optimizer(&mut self.rec, &self.state, it, lrs.0[0], self.extent)
    }

    /// The base model's own parameters and optimizer state (a checkpoint's; waits).
    pub fn model_state(&self) -> anyhow::Result<Option<serde_json::Value>> {
        self.passes.model_state()
    }

    /// Files the model writes beside its exported PLY (name, contents).
    pub fn export_files(&self) -> anyhow::Result<Vec<(String, String)>> {
        self.passes.export_files()
    }

    /// The renderer's intersection capacity (saved in checkpoints: a frame that overflows it
    /// is dropped, so it is part of the state that decides results).
    pub fn intersection_capacity(&self) -> usize {
        self.passes.intersection_capacity()
    }

    /// Grows the intersection buffers to at least `n` pairs.
    pub fn reserve_intersections(&mut self, n: usize) -> anyhow::Result<()> {
        self.assert_nothing_prepared("reserve_intersections");
        self.passes.reserve_intersections(n)
    }
}
