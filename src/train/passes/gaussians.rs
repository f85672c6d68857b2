//! The passes of 3D Gaussian models: 3DGS's forward and backward, Pixel-GS's per-Gaussian pixel
//! counts, and Mip-Splatting's 3D smoothing filter (a per-Gaussian buffer recomputed after every
//! density step and every 100 iterations after densification, never in the last 100, as the
//! official code; the opacity reset acts on the filtered opacity) with its 2D Mip filter.

use std::sync::Arc;

use anyhow::{Context, Result};

use super::{FrameArgs, GradArgs, ModelPasses};
use crate::gpu::{BufferKind, GpuBuffer, GpuContext, Recorder, TimestampPool};
use crate::render::backward::{AtomicMode, Backward, BackwardArgs, FeatureGrads};
use crate::render::filter3d::SmoothingFilter;
use crate::render::forward::{Capacity, FeatureChannels, FrameSettings, Renderer};
use crate::render::layout::{CameraGpu, ProjectedBoundsGpu, RenderConstants};
use crate::splats::gpu::GpuSplats;
use crate::splats::GaussianParams;
use crate::train::adam::SplatState;
use crate::train::config::TrainConfig;
use crate::train::density::DensityControl;
use crate::train::strategy::Primitive;

pub struct GaussianPasses {
    ctx: Arc<GpuContext>,
    renderer: Renderer,
    backward: Backward,
    constants: RenderConstants,
    /// Pixels each Gaussian contributed to this iteration (only for statistics that use them).
    pixel_count: Option<GpuBuffer<u32>>,
    /// Each Gaussian's absolute-gradient statistic this iteration (with `density.abs_grad`).
    abs_grad: Option<GpuBuffer<f32>>,
    /// Mip-Splatting's 3D filter: it comes with the 2D Mip filter, whose bit the model's
    /// constants carry ([`RenderConstants::MIP_2D`]).
    filter: Option<SmoothingFilter>,
    /// The filter does not hold the current model's values (after density control).
    filter_stale: bool,
    /// The iteration whose evaluation model the filter was last computed for.
    filter_eval_at: Option<u32>,
}

impl GaussianPasses {
    pub fn new(
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        cameras: &[CameraGpu],
        train_views: &[usize],
        capacity: usize,
        frame: Capacity,
    ) -> Result<Self> {
        let mut renderer = Renderer::new(
            ctx,
            Capacity {
                gaussians: capacity,
                intersections: (capacity * 8).max(1 << 16),
                ..frame
            },
        )?;
        let counts = config.density.statistic.needs_pixel_counts();
        let mut backward = match config.raster_pixels {
            Some(p) => {
                let why = || format!("raster_pixels {p} (train --raster-pixels)");
                renderer = renderer.with_raster_pixels(p).with_context(why)?;
                Backward::with_pixels(ctx, capacity, AtomicMode::Auto, p).with_context(why)?
            }
            None => Backward::new(ctx, capacity)?,
        };
        if counts {
            backward = backward.with_pixel_counts(ctx)?;
        }
        let abs = config.density.abs_grad;
        if abs {
            backward = backward.with_abs_grad(ctx)?;
        }
        let constants = config.render_constants();
        let filter = if constants.flags & RenderConstants::MIP_2D != 0 {
            Some(SmoothingFilter::new(ctx, cameras, train_views, capacity)?)
        } else {
            None
        };
        Ok(Self {
            ctx: ctx.clone(),
            renderer,
            backward,
            constants,
            pixel_count: counts
                .then(|| GpuBuffer::new(ctx, "pixel count", capacity, BufferKind::DeviceLocal))
                .transpose()?,
            abs_grad: abs
                .then(|| GpuBuffer::new(ctx, "abs grad", capacity, BufferKind::DeviceLocal))
                .transpose()?,
            filter,
            filter_stale: true,
            filter_eval_at: None,
        })
    }

    /// Feature channels blended beside a raw base colour (SpacetimeGaussians' full model): the
    /// backward gets their variant and the DC coefficients are drawn raw
    /// ([`RenderConstants::RAW_COLOUR`]). The channels' values come with each frame
    /// ([`GaussianPasses::record_forward_with`]).
    pub fn with_features(mut self, channels: u32) -> Result<Self> {
        self.backward = self.backward.with_feature_channels(&self.ctx, channels)?;
        self.constants.flags |= RenderConstants::RAW_COLOUR;
        Ok(self)
    }

    /// The last frame's feature image, when it had feature channels.
    pub fn feature_image(&self) -> Option<&GpuBuffer<f32>> {
        self.renderer.feature_image()
    }

    /// [`ModelPasses::record_forward`] with feature channels.
    pub fn record_forward_with(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        features: Option<FeatureChannels>,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        let settings = FrameSettings {
            sh_degree: f.sh_degree,
            background: f.background,
            constants: self.constants,
            filter3d: self.filter.as_ref().map(|f| f.values()),
            features,
        };
        self.renderer.record(
            rec, f.params, f.cameras, f.view, f.camera, &settings, timestamps,
        )
    }

    /// [`ModelPasses::record_backward`] with the feature channels' gradients.
    pub fn record_backward_with(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        g: &GradArgs,
        features: Option<FeatureGrads>,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        // The backward reads the frame's tile lists, which a frame drawn in bands lacks.
        self.renderer.whole_frame()?;
        let fr = &self.renderer.frame;
        let f = &g.frame;
        self.backward.record_timed(
            ctx,
            rec,
            &BackwardArgs {
                cameras: f.cameras,
                camera_index: f.view,
                camera: f.camera,
                projected: &fr.projected,
                tile_ranges: &fr.tile_ranges,
                sorted_ids: self.renderer.sorted_ids(),
                final_t: &fr.final_t,
                last_index: &fr.last_index,
                dl_dimage: g.dl_dimage,
                splats: f.params,
                grads: g.grads,
                view_grad_norm: g.view_grad_norm,
                pixel_count: self.pixel_count.as_ref(),
                abs_grad: self.abs_grad.as_ref(),
                count: g.count,
                sh_degree: f.sh_degree,
                constants: self.constants,
                background: f.background,
                filter3d: self.filter.as_ref().map(|f| f.values()),
                features,
            },
            timestamps,
        )
    }

    /// Renders one view with feature channels and waits, leaving the base image
    /// ([`ModelPasses::image`]) and the feature image on the GPU.
    pub fn render_frame_with(&mut self, f: &FrameArgs, features: FeatureChannels) -> Result<()> {
        let cam = f.camera;
        self.renderer.fit_camera(cam)?;
        let settings = FrameSettings {
            sh_degree: f.sh_degree,
            background: f.background,
            constants: self.constants,
            filter3d: None,
            features: Some(features),
        };
        self.renderer
            .render_blocking(f.params, f.cameras, f.view, cam, &settings)
    }

    /// Computes the 3D filter of `params` (waits), when the run has one, for an evaluation at
    /// `iteration`. The buffer then belongs to that model: the next step recomputes it.
    fn filter_for_eval(
        &mut self,
        params: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        iteration: u32,
    ) -> Result<()> {
        if self.filter_eval_at == Some(iteration) {
            return Ok(());
        }
        let Some(f) = self.filter.as_mut() else {
            return Ok(());
        };
        f.reserve(params.count)?;
        let mut rec = Recorder::new(&self.ctx)?;
        f.record_update(&mut rec, &params.positions, cameras, params.count)?;
        rec.submit_and_wait()?;
        self.filter_stale = true;
        self.filter_eval_at = Some(iteration);
        Ok(())
    }
}

impl ModelPasses for GaussianPasses {
    fn primitive(&self) -> Primitive {
        Primitive::Gaussian
    }

    fn reserve(&mut self, capacity: usize) -> Result<()> {
        if self.backward.capacity() < capacity {
            if self.pixel_count.is_some() {
                self.pixel_count = Some(GpuBuffer::new(
                    &self.ctx,
                    "pixel count",
                    capacity,
                    BufferKind::DeviceLocal,
                )?);
            }
            if self.abs_grad.is_some() {
                self.abs_grad = Some(GpuBuffer::new(
                    &self.ctx,
                    "abs grad",
                    capacity,
                    BufferKind::DeviceLocal,
                )?);
            }
            self.backward.reserve(&self.ctx, capacity)?;
        }
        let c = self.renderer.capacity();
        self.renderer.ensure_capacity(Capacity {
            gaussians: capacity,
            ..c
        })?;
        if let Some(f) = self.filter.as_mut() {
            let before = f.values().len();
            f.reserve(capacity)?;
            self.filter_stale |= f.values().len() != before;
        }
        Ok(())
    }

    fn record_prepare(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        config: &TrainConfig,
    ) -> Result<()> {
        self.filter_eval_at = None;
        let Some(filter) = &self.filter else {
            return Ok(());
        };
        let it = f.iteration;
        let refresh = it > config.schedule.densify_until
            && it.is_multiple_of(100)
            && it + 100 <= config.iterations;
        if self.filter_stale || refresh {
            filter.record_update(rec, &f.params.positions, f.cameras, f.params.count)?;
            self.filter_stale = false;
        }
        Ok(())
    }

    fn record_forward(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        self.record_forward_with(rec, f, None, timestamps)
    }

    fn image(&self) -> &GpuBuffer<f32> {
        &self.renderer.frame.image
    }

    fn projected_bounds(&self) -> &GpuBuffer<ProjectedBoundsGpu> {
        &self.renderer.frame.projected.bounds
    }

    fn pixel_count(&self) -> Option<&GpuBuffer<u32>> {
        self.pixel_count.as_ref()
    }

    fn abs_grad(&self) -> Option<&GpuBuffer<f32>> {
        self.abs_grad.as_ref()
    }

    fn smoothing_filter(&self) -> Option<&crate::render::filter3d::SmoothingFilter> {
        self.filter.as_ref()
    }

    fn record_backward(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        g: &GradArgs,
        _config: &TrainConfig,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        self.record_backward_with(ctx, rec, g, None, timestamps)
    }

    fn frame_need(&self) -> Result<Option<usize>> {
        let r = &self.renderer;
        Ok(if r.last_frame_complete()? {
            None
        } else {
            Some(r.last_intersections()? as usize)
        })
    }

    fn intersection_capacity(&self) -> usize {
        self.renderer.capacity().intersections
    }

    fn reserve_intersections(&mut self, n: usize) -> Result<()> {
        let c = self.renderer.capacity();
        self.renderer.ensure_capacity(Capacity {
            intersections: n,
            ..c
        })?;
        Ok(())
    }

    fn model_changed(&mut self) {
        self.filter_stale = true;
    }

    fn record_opacity_reset(
        &mut self,
        rec: &mut Recorder,
        density: &DensityControl,
        state: &SplatState,
        cameras: &GpuBuffer<CameraGpu>,
    ) -> Result<()> {
        match &self.filter {
            Some(f) => {
                if self.filter_stale {
                    f.record_update(rec, &state.params.positions, cameras, state.count())?;
                    self.filter_stale = false;
                }
                density.record_opacity_reset_filtered(rec, state, Some(f.values()))
            }
            None => density.record_opacity_reset(rec, state),
        }
    }

    fn render_view(&mut self, f: &FrameArgs) -> Result<Vec<f32>> {
        let cam = f.camera;
        self.renderer.fit_camera(cam)?;
        self.filter_for_eval(f.params, f.cameras, f.iteration)?;
        let settings = FrameSettings {
            sh_degree: f.sh_degree,
            background: f.background,
            constants: self.constants,
            filter3d: self.filter.as_ref().map(|f| f.values()),
            features: None,
        };
        self.renderer
            .render_blocking(f.params, f.cameras, f.view, cam, &settings)?;
        self.renderer.read_image()
    }

    /// With Mip-Splatting's 3D filter folded into scales and opacity (as the official
    /// `create_fused_ply.py`); the 2D filter cannot be folded, so render it with
    /// `--model mip-splatting`. Without the filter: `model` unchanged.
    fn export(
        &mut self,
        params: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        iteration: u32,
        model: GaussianParams,
    ) -> Result<GaussianParams> {
        if self.filter.is_none() {
            return Ok(model);
        }
        self.filter_for_eval(params, cameras, iteration)?;
        let f = self.filter.as_ref().expect("checked above");
        let values = f.values().read_range(0, model.len())?;
        crate::render::filter3d::fold_into(&model, &values)
    }
}
