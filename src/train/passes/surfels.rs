//! The passes of 2DGS's surfels (docs/algorithms/base-models.md §1): the surfel forward and backward, and the
//! normal-consistency and depth-distortion regularisers with the official weights and start
//! iterations ([`SurfelTraining`]).
//!
//! Storage: surfels live in the same parameter buffers as 3D Gaussians, with log-scales three
//! floats apart; the surfel kernels read the first two and never the third, which starts at
//! [`UNUSED_LOG_SCALE`] (it gets a zero gradient, so Adam never moves it; a split shrinks it
//! by ln 1.6 like the others, so it only gets smaller). That keeps 3DGS's
//! density control right for surfels unchanged: a split samples its children with the third
//! standard deviation e^−20, i.e. in the surfel's plane as the official 2DGS split does
//! (`std = (s_u, s_v, 0)`), shrinks every scale by the same factor, and the largest-scale
//! tests see max(s_u, s_v). A PLY export is an ordinary 3DGS PLY whose third scale is that
//! tiny value: 3DGS viewers show the surfels as flat discs.

use std::sync::Arc;

use anyhow::{Context, Result};

use super::{FrameArgs, GradArgs, ModelPasses};
use crate::gpu::{BufferKind, GpuBuffer, GpuContext, Recorder, TimestampPool};
use crate::render::forward::Capacity;
use crate::render::layout::{CameraGpu, ProjectedBoundsGpu};
use crate::render::surfel::backward::{SurfelBackward, SurfelBackwardArgs, MAP_GRADS_STRIDE};
use crate::render::surfel::forward::{SurfelFrameSettings, SurfelRenderer};
use crate::render::surfel::layout::SurfelConstants;
use crate::render::surfel::regularise::SurfelRegularisers;
use crate::splats::gpu::GpuSplats;
use crate::splats::GaussianParams;
use crate::train::adam::SplatState;
use crate::train::config::TrainConfig;
use crate::train::density::DensityControl;
use crate::train::strategy::Primitive;

/// The third log-scale of a surfel in the 3-float storage (module docs): e^−20 ≈ 2e-9.
pub const UNUSED_LOG_SCALE: f32 = -20.0;

pub use super::surfel_settings::SurfelTraining;

pub struct SurfelPasses {
    ctx: Arc<GpuContext>,
    renderer: SurfelRenderer,
    backward: SurfelBackward,
    regularisers: SurfelRegularisers,
    dl_dmaps: GpuBuffer<f32>,
    constants: SurfelConstants,
}

impl SurfelPasses {
    /// `raster_pixels`: [`TrainConfig::raster_pixels`].
    pub fn new(
        ctx: &Arc<GpuContext>,
        capacity: usize,
        frame: Capacity,
        raster_pixels: Option<u32>,
    ) -> Result<Self> {
        let mut renderer = SurfelRenderer::new(
            ctx,
            Capacity {
                gaussians: capacity,
                intersections: (capacity * 8).max(1 << 16),
                ..frame
            },
        )?;
        let backward = match raster_pixels {
            Some(p) => {
                let why = || format!("raster_pixels {p} (train --raster-pixels)");
                renderer = renderer.with_raster_pixels(p).with_context(why)?;
                SurfelBackward::with_pixels(ctx, capacity, false, p).with_context(why)?
            }
            None => SurfelBackward::new(ctx, capacity, false)?,
        };
        Ok(Self {
            ctx: ctx.clone(),
            renderer,
            backward,
            regularisers: SurfelRegularisers::new(ctx, frame.pixels)?,
            dl_dmaps: GpuBuffer::new(
                ctx,
                "dL/dmaps",
                frame.pixels.max(1) * MAP_GRADS_STRIDE,
                BufferKind::DeviceLocal,
            )?,
            constants: SurfelConstants::default(),
        })
    }

    fn settings(&self, f: &FrameArgs) -> SurfelFrameSettings {
        SurfelFrameSettings {
            sh_degree: f.sh_degree,
            background: f.background,
            constants: self.constants,
        }
    }
}

impl ModelPasses for SurfelPasses {
    fn primitive(&self) -> Primitive {
        Primitive::Surfel
    }

    fn reserve(&mut self, capacity: usize) -> Result<()> {
        self.backward.reserve(&self.ctx, capacity)?;
        let c = self.renderer.base.capacity();
        self.renderer.ensure_capacity(Capacity {
            gaussians: capacity,
            ..c
        })?;
        Ok(())
    }

    fn record_prepare(&mut self, _: &mut Recorder, _: &FrameArgs, _: &TrainConfig) -> Result<()> {
        Ok(())
    }

    fn record_forward(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        let settings = self.settings(f);
        self.renderer.record(
            rec, f.params, 3, f.cameras, f.view, f.camera, &settings, timestamps,
        )
    }

    fn image(&self) -> &GpuBuffer<f32> {
        &self.renderer.base.frame.image
    }

    fn projected_bounds(&self) -> &GpuBuffer<ProjectedBoundsGpu> {
        &self.renderer.base.frame.projected.bounds
    }

    fn pixel_count(&self) -> Option<&GpuBuffer<u32>> {
        None
    }

    fn record_backward(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        g: &GradArgs,
        config: &TrainConfig,
        mut timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        // The backward reads the frame's tile lists, which a frame drawn in bands lacks.
        self.renderer.base.whole_frame()?;
        let f = &g.frame;
        let training = config
            .model_settings::<SurfelTraining>()
            .copied()
            .unwrap_or_default();
        self.regularisers.record(
            rec,
            &self.renderer,
            f.cameras,
            f.view,
            f.camera,
            &training.weights_at(f.iteration),
            &self.dl_dmaps,
        )?;
        if let Some(p) = timestamps.as_deref_mut() {
            rec.timestamp(p, "regularisers");
        }
        self.backward.record(
            ctx,
            rec,
            &self.renderer,
            &SurfelBackwardArgs {
                cameras: f.cameras,
                camera_index: f.view,
                camera: f.camera,
                dl_dimage: g.dl_dimage,
                dl_dmaps: &self.dl_dmaps,
                splats: f.params,
                scale_stride: 3,
                grads: g.grads,
                view_grad_norm: g.view_grad_norm,
                count: g.count,
                sh_degree: f.sh_degree,
                constants: self.constants,
                background: f.background,
            },
            timestamps,
        )
    }

    fn frame_need(&self) -> Result<Option<usize>> {
        let r = &self.renderer.base;
        Ok(if r.last_frame_complete()? {
            None
        } else {
            Some(r.last_intersections()? as usize)
        })
    }

    fn intersection_capacity(&self) -> usize {
        self.renderer.base.capacity().intersections
    }

    fn reserve_intersections(&mut self, n: usize) -> Result<()> {
        let c = self.renderer.base.capacity();
        self.renderer.ensure_capacity(Capacity {
            intersections: n,
            ..c
        })?;
        Ok(())
    }

    fn model_changed(&mut self) {}

    fn record_opacity_reset(
        &mut self,
        rec: &mut Recorder,
        density: &DensityControl,
        state: &SplatState,
        _: &GpuBuffer<CameraGpu>,
    ) -> Result<()> {
        density.record_opacity_reset(rec, state)
    }

    fn render_view(&mut self, f: &FrameArgs) -> Result<Vec<f32>> {
        let settings = self.settings(f);
        self.renderer
            .render_blocking(f.params, 3, f.cameras, f.view, f.camera, &settings)?;
        self.renderer.base.read_image()
    }

    fn export(
        &mut self,
        _: &GpuSplats,
        _: &GpuBuffer<CameraGpu>,
        _: u32,
        model: GaussianParams,
    ) -> Result<GaussianParams> {
        Ok(model)
    }
}
