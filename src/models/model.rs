//! What one base model is, as one value: [`Model`], implemented once per model in this folder
//! (`gaussians3d.rs`, `pixel_gs.rs`, `mip_splatting.rs`, `surfels2d.rs`, `spacetime.rs`) and
//! listed once in [`super::BaseModel::model`], the registry. A model says what it changes in a
//! training run's config and how to tell a config of its own, its defaults, how its initial
//! model and its PLYs look, which renderer draws it, and which passes train it; the rest of
//! the engine asks the registry and names no model.

use std::path::Path;
use std::sync::Arc;

use super::options::{ModelOptions, ModelSetting};
use crate::gpu::GpuContext;
use crate::render::layout::{CameraGpu, RenderConstants};
use crate::render::view::{GaussianView, ViewRenderer};
use crate::splats::GaussianParams;
use crate::train::passes::ModelTraining;
use crate::train::trainer::TrainConfig;

/// One base model. Only `name` and `configure` have no default: the defaults are
/// 3DGS's (the Inria values, 3D Gaussians in the Inria PLY layout, drawn by the 3D-Gaussian
/// renderer). What the trainer asks of it (its passes, its own density rules, which of its
/// parameters are lengths) is its [`ModelTraining`], defined beside the trainer so that the
/// trainer names no model.
pub trait Model: ModelTraining {
    /// The command line's and the PLY header's name (`--model NAME`).
    fn name(&self) -> &'static str;

    /// Sets what this model changes in `config`, leaving the rest (the 3DGS defaults or the
    /// user's flags) alone: its section ([`TrainConfig::model`], whose name is this model's;
    /// a section of its own the config already holds is kept) and the shared settings it
    /// fixes.
    fn configure(&self, config: &mut TrainConfig);

    /// A video model: Gaussians in time, trained on multi-view video.
    fn is_spacetime(&self) -> bool {
        false
    }

    /// The iteration densification stops at in the model's official code.
    fn default_densify_until(&self) -> u32 {
        15_000
    }

    /// The prune threshold on opacity when the user gives none.
    fn default_min_opacity(&self) -> f64 {
        0.005
    }

    /// The model settings it takes (the flags of [`super::options::ModelOptions`]); the
    /// others are refused by name. The default: the absolute-gradient test, which combines
    /// with the mean gradient of 3D Gaussians (3DGS's statistic).
    fn settings(&self) -> &'static [ModelSetting] {
        &[ModelSetting::AbsGrad]
    }

    /// Applies the settings given in `o` (only those of [`Model::settings`], after
    /// [`Model::configure`]) to `config`.
    fn apply_settings(&self, o: &ModelOptions, config: &mut TrainConfig) -> anyhow::Result<()> {
        if o.densify_abs_grad {
            config.density.abs_grad = true;
        }
        Ok(())
    }

    /// Moves the iterations of its own section (regularisers' starts, rules' schedules) onto a
    /// shorter calendar: `scale` maps an iteration of the official 30,000 onto it (`bench
    /// trade`'s calendars).
    fn rescale_calendar(&self, _config: &mut TrainConfig, _scale: &dyn Fn(u32) -> u32) {}

    /// Turns a 3DGS-style initial model (from points) into this model's.
    fn initialise(&self, params: GaussianParams, _seed: u64) -> GaussianParams {
        params
    }

    /// Reads a trained PLY in this model's layout (after the header checks).
    fn read_ply(&self, path: &Path) -> anyhow::Result<GaussianParams> {
        crate::splats::read_ply(path)
    }

    /// A renderer for its trained models (eval, render, orbit). `times`: every camera's time
    /// (video scenes); `ply`: the model's file (for what sits beside it); `constants`: the
    /// rasterizer constants its training used.
    fn view_renderer(
        &self,
        ctx: &Arc<GpuContext>,
        gaussians: usize,
        camera: &CameraGpu,
        _times: Option<Vec<f32>>,
        _ply: Option<&Path>,
        constants: RenderConstants,
    ) -> anyhow::Result<Box<dyn ViewRenderer>> {
        Ok(Box::new(GaussianView::new(
            ctx, gaussians, camera, constants,
        )?))
    }
}
