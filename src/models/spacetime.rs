//! SpacetimeGaussians (Li et al., CVPR 2024), lite and full: 3D Gaussians with cubic motion,
//! linear rotation and a temporal opacity, trained on multi-view video with colour of SH
//! degree 0 (lite), or with 9 feature channels turned into RGB per pixel by a small MLP that
//! also sees the viewing ray (full). Four extra parameter groups (the full model: two more) and
//! the temporal step before the 3DGS passes ([`crate::train::passes::spacetime`]);
//! docs/algorithms/base-models.md §4.

use std::path::Path;
use std::sync::Arc;

use super::model::Model;
use super::options::{ModelOptions, ModelSetting};
use crate::gpu::GpuContext;
use crate::render::forward::Capacity;
use crate::render::layout::{CameraGpu, RenderConstants};
use crate::render::view::{SpacetimeView, ViewRenderer};
use crate::scene::Scene;
use crate::splats::GaussianParams;
use crate::train::density::Statistic;
use crate::train::passes::guided_sampling::GuidedSampler;
use crate::train::passes::spacetime::SpacetimePasses;
use crate::train::passes::spacetime_settings::{OmegaFreeze, SpacetimeTraining};
use crate::train::passes::world_culls::WorldCuller;
use crate::train::passes::{ModelPasses, ModelTraining};
use crate::train::strategy::ModelRule;
use crate::train::trainer::TrainConfig;

/// `full`: the full model (features and decoder); else the lite one.
pub struct Spacetime {
    pub full: bool,
}

impl ModelTraining for Spacetime {
    /// The 3DGS passes on the model at each view's time; a still scene is refused.
    fn passes(
        &self,
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        cameras: &[CameraGpu],
        train_views: &[usize],
        view_times: Option<&[f64]>,
        capacity: usize,
        frame: Capacity,
    ) -> anyhow::Result<Box<dyn ModelPasses>> {
        let Some(times) = view_times else {
            anyhow::bail!(
                "SpacetimeGaussians trains on a video scene (views with times); this scene is \
                 still. Fix: point at a Neural 3D Video or Panoptic scene folder"
            );
        };
        Ok(Box::new(SpacetimePasses::new(
            ctx,
            config,
            cameras,
            train_views,
            times,
            capacity,
            frame,
        )?))
    }

    /// Guided error sampling and the Neural 3D Video culls, when the config asks for them.
    fn rules(
        &self,
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        scene: &Scene,
        initial: &GaussianParams,
    ) -> anyhow::Result<Vec<Box<dyn ModelRule>>> {
        let mut rules: Vec<Box<dyn ModelRule>> = Vec::new();
        let section = config.model_settings::<SpacetimeTraining>();
        if let (Some(g), Some(times)) =
            (section.and_then(|s| s.guided), scene.view_times.as_deref())
        {
            rules.push(Box::new(GuidedSampler::new(
                ctx,
                g,
                config.seed,
                &scene.views,
                &scene.train,
                times,
                initial,
            )?));
        }
        if let Some(w) = section.and_then(|s| s.world_culls) {
            rules.push(Box::new(WorldCuller::new(w, &scene.frame, initial)?));
        }
        Ok(rules)
    }

    /// The motion coefficients are lengths per unit of time.
    fn length_groups(&self) -> &'static [&'static str] {
        &["motion"]
    }
}

impl Model for Spacetime {
    fn name(&self) -> &'static str {
        if self.full {
            "spacetime-full"
        } else {
            "spacetime-lite"
        }
    }

    fn configure(&self, config: &mut TrainConfig) {
        config.density.statistic = Statistic::Gradient;
        let mut st = config
            .model_settings::<SpacetimeTraining>()
            .copied()
            .unwrap_or_default();
        st.full = match (self.full, st.full) {
            (true, Some(f)) => Some(f),
            (true, None) => Some(Default::default()),
            (false, _) => None,
        };
        config.set_model(st);
        config.sh_degree = 0;
        // The official batch: two cameras at one time per step.
        config.batch_views = 2;
    }

    fn is_spacetime(&self) -> bool {
        true
    }

    fn settings(&self) -> &'static [ModelSetting] {
        &[
            ModelSetting::ChildTime,
            ModelSetting::GuidedSampling,
            ModelSetting::OmegaFreeze,
            ModelSetting::AbsGrad,
        ]
    }

    fn apply_settings(&self, o: &ModelOptions, config: &mut TrainConfig) -> anyhow::Result<()> {
        let mut st = config
            .model_settings::<SpacetimeTraining>()
            .copied()
            .expect("configure gives a spacetime model its section");
        if let Some(ct) = o.child_time {
            st.child_time = ct;
        }
        if o.guided_sampling == Some(false) {
            anyhow::ensure!(
                o.guided_from.is_none(),
                "--guided-from with --guided-sampling off: nothing would sample. Fix: drop one \
                 of them"
            );
            st.guided = None;
        } else if let (Some(g), Some(from)) = (st.guided.as_mut(), o.guided_from) {
            g.from = from;
        }
        if let Some(freeze) = o.omega_freeze {
            st.omega_freeze = freeze.map(|from| OmegaFreeze {
                from,
                ..st.omega_freeze.unwrap_or_default()
            });
        }
        config.set_model(st);
        if o.densify_abs_grad {
            config.density.abs_grad = true;
        }
        Ok(())
    }

    /// Guided sampling's start and gap (official 1600 and 100) and the angular-velocity split
    /// (official 8001 of 30k).
    fn rescale_calendar(&self, config: &mut TrainConfig, scale: &dyn Fn(u32) -> u32) {
        config.update_model_settings(|s: &mut SpacetimeTraining| {
            if let Some(g) = s.guided.as_mut() {
                g.from = scale(g.from);
                g.gap = scale(g.gap);
            }
            if let Some(f) = s.omega_freeze.as_mut() {
                f.from = scale(f.from);
            }
        });
    }

    /// Its `densify_until_iter`; its opacity resets then fall at 3000 and 6000 only.
    fn default_densify_until(&self) -> u32 {
        9000
    }

    /// The temporal groups ([`super::with_temporal_groups`]), and the full model's features.
    fn initialise(&self, params: GaussianParams, seed: u64) -> GaussianParams {
        super::with_temporal_groups(params, seed, self.full)
    }

    fn read_ply(&self, path: &Path) -> anyhow::Result<GaussianParams> {
        crate::splats::ply::read_ply_extras(
            path,
            &crate::train::passes::spacetime::extra_groups_of(self.full),
        )
    }

    /// The model at each camera's time; the full model's decoder from beside its PLY.
    fn view_renderer(
        &self,
        ctx: &Arc<GpuContext>,
        gaussians: usize,
        camera: &CameraGpu,
        times: Option<Vec<f32>>,
        ply: Option<&Path>,
        _constants: RenderConstants,
    ) -> anyhow::Result<Box<dyn ViewRenderer>> {
        let Some(times) = times else {
            anyhow::bail!(
                "--model {} renders a video model at each view's time; this scene is still (or \
                 these cameras have no time). Fix: point at the video scene the model was \
                 trained on",
                self.name()
            );
        };
        let decoder = match (self.full, ply) {
            (true, Some(p)) => Some(crate::splats::decoder_json::read_for(p)?),
            (true, None) => {
                anyhow::bail!("--model spacetime-full needs its PLY's path to find the decoder")
            }
            (false, _) => None,
        };
        Ok(Box::new(SpacetimeView::new(
            ctx, gaussians, camera, times, decoder,
        )?))
    }
}
