//! Density strategies: what decides clone / split / prune / reset, as a plug-in of the trainer.
//!
//! The trainer loop calls a [`DensityStrategy`] at three points of an iteration and knows
//! nothing else about it:
//! 1. [`DensityStrategy::densify`] on the schedule's densify iterations (the command buffer is
//!    begun; the strategy may submit and begin again, and leaves it begun);
//! 2. [`DensityStrategy::after_density`] after the densify step, the trainer's capacity
//!    follow-up and the global opacity reset, in the same command stream;
//! 3. [`DensityStrategy::after_iteration`] at the end of every iteration, with the recorder
//!    idle (for work on an interval of the strategy's own, e.g. LPM's opacity reset).
//!
//! [`Adc`] is plain adaptive density control over the trainer's [`super::density::DensityControl`]
//! (whose statistic, gradient or Pixel-GS's pixel-weighted one, is part of its config). LPM
//! wraps ADC from `crate::lpm::strategy`; dependencies run from the strategy to the trainer,
//! never back.

use std::any::Any;
use std::fmt::Debug;
use std::sync::Arc;

use super::adam::SplatState;
use super::density::{DensifyArgs, DensifyOutcome, DensityControl};
use crate::gpu::{GpuBuffer, GpuContext, Recorder};
use crate::render::filter3d::SmoothingFilter;
use crate::render::layout::CameraGpu;
use crate::splats::gpu::GpuSplats;
use crate::splats::GaussianParams;

/// What a strategy reports for one iteration (telemetry; typed access through `as_any`).
pub trait StrategyEvent: Any + Debug + Send + Sync {
    fn to_json(&self) -> serde_json::Value;
    /// One line for the console.
    fn describe(&self) -> String {
        self.to_json().to_string()
    }
    fn as_any(&self) -> &dyn Any;
}

/// What a strategy works on: the trainer's model state, its ADC engine and this iteration's
/// render (lent by the trainer for one call; the strategy never sees the trainer itself).
/// After every call the trainer grows its own per-Gaussian buffers (gradients, renderer) to the
/// state's capacity, so a strategy that adds Gaussians only grows `state` and `density`.
/// The shape of the model's primitives, for strategies that create them from nothing (LPM's
/// added points).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Primitive {
    /// 3D Gaussians: three scales.
    Gaussian,
    /// 2DGS surfels: two scales in the plane, the third stored but unused
    /// ([`crate::train::passes::surfels::UNUSED_LOG_SCALE`]); the rotation's third column is
    /// the normal.
    Surfel,
}

/// Where the Gaussians are in the frame being trained, for a model whose Gaussians move (a video
/// model): strategies that test positions against the frame (LPM's zones) use these centres
/// instead of the stored ones.
pub trait FramePositions {
    /// Records into `rec` the centres of Gaussians `0..count` of `params` at the time of the
    /// frame rendered last into `out` (3 floats each), NaN for a Gaussian absent from that frame
    /// (NaN is outside every zone). No barriers.
    fn record_frame_positions(
        &self,
        rec: &mut Recorder,
        params: &GpuSplats,
        count: usize,
        out: &GpuBuffer<f32>,
    ) -> anyhow::Result<()>;
}

/// A Gaussian to append: SH DC only, fresh optimizer state; isotropic for 3D Gaussians, a disc
/// facing `camera_center` for surfels ([`new_point_shape`](super::density::append::new_point_shape)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewGaussian {
    pub position: [f32; 3],
    /// World-space standard deviation (all three axes; both in-plane axes of a surfel).
    pub scale: f32,
    /// Linear RGB in [0, 1].
    pub color: [f32; 3],
    pub opacity: f64,
    /// The centre of the camera whose error created the point.
    pub camera_center: [f32; 3],
}

/// What a guide (LPM) gives the strategy it steers at a density step
/// ([`DensityStrategy::densify_guided`]).
pub struct Guide<'a> {
    /// A weight for each of the current Gaussians (`≥ 0`, 1 where the guide has no preference).
    pub weight: &'a GpuBuffer<f32>,
    /// Points on the surfaces the guide wants covered (SfM points inside its zones, coloured
    /// from the ground truth): a strategy that moves Gaussians may move some onto them.
    pub samples: &'a [NewGaussian],
    /// The largest share of the Gaussians a step moves that may go to `samples` (0: none).
    pub sample_share: f64,
}

pub struct DensityContext<'a> {
    pub ctx: &'a Arc<GpuContext>,
    pub rec: &'a mut Recorder,
    pub state: &'a mut SplatState,
    pub density: &'a mut DensityControl,
    /// Scene extent (as in [`DensifyArgs::extent`]).
    pub extent: f64,
    /// This iteration's render of the view (RGB interleaved, `width × height`).
    pub render: &'a GpuBuffer<f32>,
    /// Its ground truth: RGBA8 words from `truth_offset_px` in `truth`.
    pub truth: &'a GpuBuffer<u32>,
    pub truth_offset_px: u32,
    pub width: u32,
    pub height: u32,
    /// What a new primitive looks like in this model.
    pub primitive: Primitive,
    /// New Gaussians store their colour as it is in the DC coefficients (no SH encoding;
    /// `ModelPasses::raw_colour`).
    pub raw_colour: bool,
    /// The model's extra groups' values for a new Gaussian, one row per group
    /// (`ModelPasses::new_gaussian_extras`).
    pub new_extras: Vec<Vec<f32>>,
    /// The model's centres at the frame's time, when its Gaussians move; `None`: the stored
    /// positions are where they are.
    pub moving: Option<&'a dyn FramePositions>,
    /// Mip-Splatting's 3D filter, when the renderer multiplies every opacity by its ρ: a
    /// strategy that sets opacities acts on the drawn ones through it.
    pub opacity_filter: Option<OpacityFilter<'a>>,
}

/// The model's 3D smoothing filter and the cameras it is computed from.
pub struct OpacityFilter<'a> {
    pub filter: &'a SmoothingFilter,
    pub cameras: &'a GpuBuffer<CameraGpu>,
}

impl OpacityFilter<'_> {
    /// Records the filter of the first `count` Gaussians at `positions` (the state as it is
    /// now, after any density step) and returns its values, valid once the work has run.
    pub fn record_fresh(
        &self,
        rec: &mut Recorder,
        positions: &GpuBuffer<f32>,
        count: usize,
    ) -> anyhow::Result<&GpuBuffer<f32>> {
        self.filter
            .record_update(rec, positions, self.cameras, count)?;
        Ok(self.filter.values())
    }
}

/// The iteration's inputs a strategy may use.
#[derive(Debug, Clone, Copy)]
pub struct IterationView {
    pub iteration: u32,
    /// The training view rendered this iteration (its render is still in the renderer).
    pub view: usize,
    /// The background that render used.
    pub background: [f32; 3],
}

pub trait DensityStrategy: Any {
    /// A short name for logs ("adc", "lpm").
    fn name(&self) -> &'static str;

    /// Densify-and-prune at a densify iteration. `t.rec` is begun; leave it begun. An outcome
    /// with `skipped` means the model and its gradients are untouched, so the trainer still runs
    /// the iteration's optimizer step.
    fn densify(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome>;

    /// Whether the strategy takes a guide's per-Gaussian weights
    /// ([`DensityStrategy::densify_guided`]): LPM then steers it by its zones.
    fn takes_guide(&self) -> bool {
        false
    }

    /// [`DensityStrategy::densify`] steered by a [`Guide`]: where the strategy's room goes,
    /// never how much there is. Only called when [`DensityStrategy::takes_guide`].
    fn densify_guided(
        &mut self,
        _t: &mut DensityContext,
        _at: &IterationView,
        _args: &DensifyArgs,
        _guide: &Guide,
    ) -> anyhow::Result<DensifyOutcome> {
        anyhow::bail!("density strategy {}: takes no guide", self.name())
    }

    /// After [`DensityStrategy::densify`] and the global opacity reset (recorded, not yet
    /// submitted). `t.rec` is begun; leave it begun.
    fn after_density(
        &mut self,
        _t: &mut DensityContext,
        _at: &IterationView,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        Ok(None)
    }

    /// At the end of every iteration, with `t.rec` idle; `reported` says whether this
    /// iteration already produced an event.
    fn after_iteration(
        &mut self,
        _t: &mut DensityContext,
        _at: &IterationView,
        _reported: bool,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        Ok(None)
    }

    /// Whether [`DensityStrategy::after_iteration`] at `iteration`, a step without densify or
    /// opacity reset, will record no GPU work and change no buffer (host bookkeeping is
    /// fine): the trainer then records the next iteration while this one runs. `false`, the
    /// default, is always safe. A wrong `true` is caught when the model's size or a buffer
    /// changes (the prepared iteration is dropped), but the work then sees the model passes'
    /// per-frame state of the next iteration (a video model's frame time), so answer exactly.
    fn quiet_after(&self, _iteration: u32) -> bool {
        false
    }

    /// Records work into the iteration's own command buffer once its gradients are complete,
    /// before the optimizer step: terms the strategy adds to them (MCMC's regularisers). Runs
    /// on every iteration with an optimizer step; record barriers around the work. Default:
    /// nothing.
    fn record_gradient_terms(
        &self,
        _rec: &mut Recorder,
        _state: &SplatState,
        _grads: &GpuSplats,
        _iteration: u32,
    ) -> anyhow::Result<()> {
        Ok(())
    }

    /// Records work into the same command buffer after the optimizer step (MCMC's position
    /// noise); `position_lr` is that step's position learning rate (world units), `extent`
    /// the scene's. Default: nothing.
    fn record_after_optimizer(
        &self,
        _rec: &mut Recorder,
        _state: &SplatState,
        _iteration: u32,
        _position_lr: f64,
        _extent: f64,
    ) -> anyhow::Result<()> {
        Ok(())
    }

    /// The settings that decide results (saved in checkpoints; a resumed run must match).
    /// `Null` for plain ADC, whose settings are part of the trainer's config.
    fn settings_json(&self) -> serde_json::Value {
        serde_json::Value::Null
    }

    fn as_any(&self) -> &dyn Any;
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

/// What a step did, for a base model's own rules.
#[derive(Debug, Clone, Copy)]
pub struct StepSeen<'a> {
    pub iteration: u32,
    /// The step's views (the last one's render and ground truth are in the context).
    pub views: &'a [usize],
    /// Each view's SSIM against its ground truth this step.
    pub view_ssim: &'a [f32],
    pub background: [f32; 3],
}

/// A base model's own density rule, run by the trainer after every step besides the density
/// strategy (SpacetimeGaussians' guided error sampling); made by the model's `passes::ModelTraining::rules`.
pub trait ModelRule {
    fn name(&self) -> &'static str;
    /// Edits the initial model of a fresh run before it is uploaded (not called when a run
    /// resumes from a checkpoint); the result must keep at least one Gaussian.
    fn prepare_initial(&mut self, init: GaussianParams) -> anyhow::Result<GaussianParams> {
        Ok(init)
    }
    /// After the step and the strategy's work, with `t.rec` idle (begin it to record, and
    /// submit and wait before returning).
    fn after_step(
        &mut self,
        t: &mut DensityContext,
        step: &StepSeen,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>>;
    /// Whether [`ModelRule::after_step`] at `iteration`, on a step of `views`, will record no
    /// GPU work and change no buffer (host bookkeeping is fine), asked before the step has
    /// run: the trainer then records the next iteration while this one runs. `false`, the
    /// default, is always safe; a wrong `true` is caught as for
    /// [`DensityStrategy::quiet_after`], with the same caveat.
    fn quiet_after(&self, _iteration: u32, _views: &[usize]) -> bool {
        false
    }
    /// Its state, saved in checkpoints so a resumed run goes on where it stopped.
    fn state_json(&self) -> serde_json::Value;
    fn restore_state(&mut self, state: &serde_json::Value) -> anyhow::Result<()>;
}

/// Plain adaptive density control (the Inria rules), with whatever statistic the trainer's
/// density config names.
#[derive(Debug, Default, Clone, Copy)]
pub struct Adc;

impl DensityStrategy for Adc {
    fn name(&self) -> &'static str {
        "adc"
    }

    fn densify(
        &mut self,
        t: &mut DensityContext,
        _at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        t.density.step(t.rec, t.state, args, None)
    }

    /// ADC works only on densify steps.
    fn quiet_after(&self, _iteration: u32) -> bool {
        true
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}
