//! A base model's GPU passes, as the trainer drives them: the frame (forward), the gradients
//! (backward, with the model's own losses), the buffers the model keeps per Gaussian beside the
//! optimised parameters, and the renders for evaluation and export. The trainer loop knows only
//! this trait; the base model makes it ([`ModelTraining::passes`]). The implementations:
//!
//! - [`gaussians::GaussianPasses`]: 3D Gaussians (3DGS, Pixel-GS's pixel counts, Mip-Splatting's
//!   filters);
//! - [`surfels::SurfelPasses`]: 2DGS's surfels with the normal-consistency and distortion
//!   regularisers;
//! - [`spacetime::SpacetimePasses`]: SpacetimeGaussians (lite), the 3DGS passes on the model
//!   at each view's time.

pub mod gaussians;
pub mod guided_sampling;
pub mod omega_freeze;
pub mod spacetime;
pub mod spacetime_settings;
pub mod surfel_settings;
pub mod surfels;
pub mod world_culls;

use std::sync::Arc;

use anyhow::Result;

use super::adam::SplatState;
use super::config::TrainConfig;
use super::density::DensityControl;
use super::strategy::{FramePositions, ModelRule, Primitive};
use crate::gpu::{GpuBuffer, GpuContext, Recorder, TimestampPool};
use crate::render::forward::Capacity;
use crate::render::layout::{CameraGpu, ProjectedBoundsGpu};
use crate::splats::gpu::GpuSplats;
use crate::splats::GaussianParams;

/// One frame: which model, seen from which camera, how.
pub struct FrameArgs<'a> {
    pub params: &'a GpuSplats,
    pub cameras: &'a GpuBuffer<CameraGpu>,
    pub view: u32,
    /// Host copy of `cameras[view]`.
    pub camera: &'a CameraGpu,
    pub sh_degree: u32,
    pub background: [f32; 3],
    pub iteration: u32,
}

/// The gradients of one frame: `dl_dimage` is the photometric loss's; the model adds its own
/// losses' and writes every parameter's gradient of Gaussians `0..count` into `grads`, and the
/// densification statistic of this view into `view_grad_norm`.
pub struct GradArgs<'a> {
    pub frame: FrameArgs<'a>,
    pub dl_dimage: &'a GpuBuffer<f32>,
    pub grads: &'a GpuSplats,
    pub view_grad_norm: &'a GpuBuffer<f32>,
    pub count: usize,
    /// This view's place in the step's batch (`0..views`): a model's own parameters sum the
    /// views' gradients / `views` (the trainer does so for the per-Gaussian ones).
    pub view_in_step: usize,
    pub views_in_step: usize,
}

pub trait ModelPasses: Send {
    /// The shape of this model's primitives (for strategies that add some).
    fn primitive(&self) -> Primitive;
    /// Grows the per-Gaussian buffers the passes own to `capacity` Gaussians (only between
    /// submissions).
    fn reserve(&mut self, capacity: usize) -> Result<()>;
    /// Work before the iteration's frame (Mip-Splatting refreshes its 3D filter).
    fn record_prepare(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        config: &TrainConfig,
    ) -> Result<()>;
    fn record_forward(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()>;
    /// The last frame's image (RGB interleaved, background composited).
    fn image(&self) -> &GpuBuffer<f32>;
    /// The last frame's per-Gaussian screen bounds (radius > 0: visible), for the statistics.
    fn projected_bounds(&self) -> &GpuBuffer<ProjectedBoundsGpu>;
    /// Pixels each Gaussian covered in the last backward, when the statistic needs them.
    fn pixel_count(&self) -> Option<&GpuBuffer<u32>>;
    /// The absolute-gradient statistic of the last backward, when density control asks for
    /// it (models that cannot give it refuse the setting when they are built).
    fn abs_grad(&self) -> Option<&GpuBuffer<f32>> {
        None
    }
    /// Mip-Splatting's 3D filter, when the model's renders multiply opacities by its ρ.
    fn smoothing_filter(&self) -> Option<&crate::render::filter3d::SmoothingFilter> {
        None
    }
    fn record_backward(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        g: &GradArgs,
        config: &TrainConfig,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()>;
    /// After the frame's fence: the intersections it needed when it dropped some (more than
    /// the buffers hold), else `None`.
    fn frame_need(&self) -> Result<Option<usize>>;
    /// After the frame's fence: when it dropped intersections, grows the buffers and returns
    /// true (the frame is counted as dropped).
    fn after_frame(&mut self) -> Result<bool> {
        match self.frame_need()? {
            Some(need) => {
                self.reserve_intersections(need)?;
                Ok(true)
            }
            None => Ok(false),
        }
    }
    fn intersection_capacity(&self) -> usize;
    fn reserve_intersections(&mut self, n: usize) -> Result<()>;
    /// Density control changed the model (per-Gaussian derived data is stale).
    fn model_changed(&mut self);
    /// The global opacity reset on the opacity the renderer uses.
    fn record_opacity_reset(
        &mut self,
        rec: &mut Recorder,
        density: &DensityControl,
        state: &SplatState,
        cameras: &GpuBuffer<CameraGpu>,
    ) -> Result<()>;
    /// Renders one view of `f.params` and waits; RGB interleaved.
    fn render_view(&mut self, f: &FrameArgs) -> Result<Vec<f32>>;
    /// Learning rates of the model's extra parameter groups at `iteration`, in their order
    /// (none for the 3DGS groups alone).
    fn extra_lrs(&self, _iteration: u32, _extent: f64) -> Vec<f64> {
        Vec::new()
    }
    /// The extra groups' values of a Gaussian a strategy adds (LPM's new points), one row per
    /// group in their order.
    fn new_gaussian_extras(&self) -> Vec<Vec<f32>> {
        Vec::new()
    }
    /// Density control just created Gaussians `new` (clones and split children, rows after
    /// the survivors, which copied their parent's every group) at density step `iteration`:
    /// the model may re-initialise its own data of them. Recorded into the begun `rec`.
    fn record_new_gaussians(
        &mut self,
        _rec: &mut Recorder,
        _state: &SplatState,
        _new: std::ops::Range<usize>,
        _iteration: u32,
    ) -> Result<()> {
        Ok(())
    }
    /// The DC coefficients are the raw base colour (no SH encoding): new Gaussians store their
    /// colour as it is (SpacetimeGaussians' full model).
    fn raw_colour(&self) -> bool {
        false
    }
    /// Work on the step's gradients before the Gaussians' optimizer step at `iteration`
    /// (SpacetimeGaussians' angular-velocity split), recorded into the begun `rec`.
    fn record_before_step(
        &mut self,
        _rec: &mut Recorder,
        _state: &SplatState,
        _grads: &GpuSplats,
        _iteration: u32,
    ) -> Result<()> {
        Ok(())
    }
    /// The optimizer step of the model's own parameters, shared by all Gaussians (the full
    /// SpacetimeGaussians' decoder), at Adam step `step`; recorded into the begun `rec` after
    /// the Gaussians' step.
    fn record_model_step(
        &mut self,
        _ctx: &GpuContext,
        _rec: &mut Recorder,
        _step: u32,
        _iteration: u32,
    ) -> Result<()> {
        Ok(())
    }
    /// The model's own parameters and their optimizer state, for checkpoints (waits).
    fn model_state(&self) -> Result<Option<serde_json::Value>> {
        Ok(None)
    }
    /// Restores [`ModelPasses::model_state`] (between submissions).
    fn restore_model_state(&mut self, _state: &serde_json::Value) -> Result<()> {
        anyhow::bail!("this model keeps no parameters of its own; the checkpoint's are not for it")
    }
    /// Files written beside the exported PLY (extension, contents): what viewers need besides
    /// it, as `NAME.<extension>` for `NAME.ply`.
    fn export_files(&self) -> Result<Vec<(String, String)>> {
        Ok(Vec::new())
    }
    /// The centres at the current frame's time, for a model whose Gaussians move.
    fn frame_positions(&self) -> Option<&dyn FramePositions> {
        None
    }
    /// `model` (the download of `params`) as written for viewers.
    fn export(
        &mut self,
        params: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        iteration: u32,
        model: GaussianParams,
    ) -> Result<GaussianParams>;
}

/// What the trainer asks of a base model: the passes that draw and differentiate it, its own
/// density rules, and which of its parameters are lengths. Every model implements it in
/// `models/` (it is a supertrait of `models::Model`) and the trainer receives it
/// ([`super::trainer::Trainer::with_model`]), so the trainer names no model. The defaults are
/// 3D Gaussians' (3DGS, Pixel-GS and Mip-Splatting share the passes and differ in their
/// config: the statistic, the filters).
pub trait ModelTraining: Sync {
    /// The passes for `config`, sized for `capacity` Gaussians and the largest training view
    /// (`frame`: pixels and tiles); `view_times`: every view's time on a video scene.
    #[allow(clippy::too_many_arguments)]
    fn passes(
        &self,
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        cameras: &[CameraGpu],
        train_views: &[usize],
        _view_times: Option<&[f64]>,
        capacity: usize,
        frame: Capacity,
    ) -> Result<Box<dyn ModelPasses>> {
        Ok(Box::new(gaussians::GaussianPasses::new(
            ctx,
            config,
            cameras,
            train_views,
            capacity,
            frame,
        )?))
    }

    /// The model's own density rules besides the strategy, for `scene`'s training views from
    /// `initial` (SpacetimeGaussians' guided error sampling and Neural 3D Video culls).
    fn rules(
        &self,
        _ctx: &Arc<GpuContext>,
        _config: &TrainConfig,
        _scene: &crate::scene::Scene,
        _initial: &GaussianParams,
    ) -> Result<Vec<Box<dyn ModelRule>>> {
        Ok(Vec::new())
    }

    /// The shape of its primitives (for strategies that add some).
    fn primitive(&self) -> Primitive {
        Primitive::Gaussian
    }

    /// The extra groups that are lengths (moved and scaled with the frame, as positions).
    fn length_groups(&self) -> &'static [&'static str] {
        &[]
    }

    /// Whether its third log-scale is a fixed marker rather than a length (a surfel's).
    fn fixed_third_scale(&self) -> bool {
        false
    }
}
