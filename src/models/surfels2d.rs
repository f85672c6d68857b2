//! 2D Gaussian Splatting (Huang et al., SIGGRAPH 2024): surfels with the normal-consistency
//! and depth-distortion regularisers, the official densification statistic and its 0.05
//! opacity prune; their own passes ([`crate::train::passes::surfels`]) and renderer.

use std::path::Path;
use std::sync::Arc;

use super::model::Model;
use super::options::{ModelOptions, ModelSetting};
use crate::gpu::GpuContext;
use crate::render::forward::Capacity;
use crate::render::layout::{CameraGpu, RenderConstants};
use crate::render::view::{SurfelView, ViewRenderer};
use crate::splats::GaussianParams;
use crate::train::density::Statistic;
use crate::train::passes::surfels::{SurfelPasses, SurfelTraining, UNUSED_LOG_SCALE};
use crate::train::passes::{ModelPasses, ModelTraining};
use crate::train::strategy::Primitive;
use crate::train::trainer::TrainConfig;

pub struct Surfels2d;

impl ModelTraining for Surfels2d {
    fn passes(
        &self,
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        _cameras: &[CameraGpu],
        _train_views: &[usize],
        _view_times: Option<&[f64]>,
        capacity: usize,
        frame: Capacity,
    ) -> anyhow::Result<Box<dyn ModelPasses>> {
        Ok(Box::new(SurfelPasses::new(
            ctx,
            capacity,
            frame,
            config.raster_pixels,
        )?))
    }

    fn primitive(&self) -> Primitive {
        Primitive::Surfel
    }

    fn fixed_third_scale(&self) -> bool {
        true
    }
}

impl Model for Surfels2d {
    fn name(&self) -> &'static str {
        "2dgs"
    }

    fn configure(&self, config: &mut TrainConfig) {
        config.density.statistic = Statistic::Gradient;
        let own = config.model_settings::<SurfelTraining>().copied();
        config.set_model(own.unwrap_or_default());
    }

    fn default_min_opacity(&self) -> f64 {
        0.05
    }

    /// Its regularisers; its statistic is its own (the official 2DGS one), not combined with
    /// the absolute-gradient test.
    fn settings(&self) -> &'static [ModelSetting] {
        &[ModelSetting::SurfelRegularisers]
    }

    fn apply_settings(&self, o: &ModelOptions, config: &mut TrainConfig) -> anyhow::Result<()> {
        let mut t = config
            .model_settings::<SurfelTraining>()
            .copied()
            .unwrap_or_default();
        t.normal_weight = o.lambda_normal.unwrap_or(t.normal_weight);
        t.normal_from = o.normal_from.unwrap_or(t.normal_from);
        t.distortion_weight = o.lambda_dist.unwrap_or(t.distortion_weight);
        t.distortion_from = o.dist_from.unwrap_or(t.distortion_from);
        t.depth_ratio = o.depth_ratio.unwrap_or(t.depth_ratio);
        config.set_model(t);
        Ok(())
    }

    /// The regularisers' starts (official 7000 and 3000 of 30k).
    fn rescale_calendar(&self, config: &mut TrainConfig, scale: &dyn Fn(u32) -> u32) {
        config.update_model_settings(|t: &mut SurfelTraining| {
            t.normal_from = scale(t.normal_from);
            t.distortion_from = scale(t.distortion_from);
        });
    }

    /// Random rotations (the official `torch.rand(N, 4)`, here seeded) and the unused third
    /// log-scale ([`UNUSED_LOG_SCALE`]).
    fn initialise(&self, mut params: GaussianParams, seed: u64) -> GaussianParams {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x2D65);
        for (l, q) in params.log_scales.iter_mut().zip(&mut params.rotations) {
            l[2] = UNUSED_LOG_SCALE;
            *q = [0; 4].map(|_| rng.gen_range(0.0..1.0f32).max(1e-3));
        }
        params
    }

    /// Ours keep the marker as a third scale; the official layout has two scales.
    fn read_ply(&self, path: &Path) -> anyhow::Result<GaussianParams> {
        crate::splats::ply::read_ply_two_scales(path, UNUSED_LOG_SCALE)
    }

    fn view_renderer(
        &self,
        ctx: &Arc<GpuContext>,
        gaussians: usize,
        camera: &CameraGpu,
        _times: Option<Vec<f32>>,
        _ply: Option<&Path>,
        _constants: RenderConstants,
    ) -> anyhow::Result<Box<dyn ViewRenderer>> {
        Ok(Box::new(SurfelView::new(ctx, gaussians, camera)?))
    }
}
