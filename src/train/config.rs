//! What decides a training run: the background, the learning rates, density control, the
//! schedule and the base model's section (`config.json`, and the checkpoint's key).

use std::sync::Arc;

use super::density::{DensityConfig, Statistic};
use super::model_section::{write_section, ModelSection, NamedModel};
use super::schedule::{DensitySchedule, LearningRates};
use crate::render::layout::RenderConstants;

/// The background the model is trained against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Background {
    Fixed([f32; 3]),
    /// A new uniform random colour every iteration (evaluation then uses black).
    Random,
}

impl Background {
    pub fn describe(&self) -> String {
        match self {
            Background::Fixed(c) => format!("{},{},{}", c[0], c[1], c[2]),
            Background::Random => "random".into(),
        }
    }
    /// The colour used for evaluation and saved renders.
    pub fn eval_colour(&self) -> [f32; 3] {
        match self {
            Background::Fixed(c) => *c,
            Background::Random => [0.0; 3],
        }
    }

    /// The background a `--background` choice names: `black`, `white`, `random` or `R,G,B` in
    /// [0, 1]; without one, the scene's own (NeRF-synthetic's white) or black.
    pub fn choose(
        choice: Option<&str>,
        scene_background: Option<[f32; 3]>,
    ) -> anyhow::Result<Self> {
        Ok(match choice {
            None => Background::Fixed(scene_background.unwrap_or([0.0; 3])),
            Some("black") => Background::Fixed([0.0; 3]),
            Some("white") => Background::Fixed([1.0; 3]),
            Some("random") => Background::Random,
            Some(s) => {
                Background::Fixed(parse_rgb(s).map_err(|e| {
                    anyhow::anyhow!("--background {e}; or use black, white or random")
                })?)
            }
        })
    }
}

/// A colour as three numbers in [0, 1], comma separated (`1,1,1`).
pub fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("'{s}': {e}; give three numbers like 1,1,1"))?;
    match v[..] {
        [r, g, b] if v.iter().all(|x| (0.0..=1.0).contains(x)) => Ok([r, g, b]),
        _ => Err(format!("'{s}': give three numbers in [0, 1] like 0,0,0")),
    }
}

/// Everything that decides a training run (written to `config.json`).
#[derive(Debug, Clone)]
pub struct TrainConfig {
    pub iterations: u32,
    pub seed: u64,
    pub sh_degree: u32,
    pub background: Background,
    pub lr: LearningRates,
    pub density: DensityConfig,
    pub schedule: DensitySchedule,
    pub ssim_weight: f32,
    /// Collect per-stage GPU timestamps every iteration.
    pub timestamps: bool,
    /// The base model's section: which model trains, with its own settings
    /// ([`super::model_section`]; set by `models::BaseModel::configure`, read back by a model's
    /// passes with [`TrainConfig::model_settings`]).
    pub model: Arc<dyn ModelSection>,
    /// Views per optimizer step: the scheduled view and `batch_views − 1` other training views
    /// of its time, their gradients averaged (`train::batch`; SpacetimeGaussians: 2).
    pub batch_views: u32,
    /// Pixels per invocation of the tile rasterizers, forward and backward (`None`: the
    /// device's defaults, 1 on GPUs; on CPU drivers 8, and 16 for the 2DGS backward); one of
    /// [`crate::render::backward::pixel_layouts`]. A tuning knob: benchmarks compare layouts.
    pub raster_pixels: Option<u32>,
    /// The loss kernels' layout (`None`: [`crate::train::loss::Loss::new`]'s). A tuning knob
    /// like `raster_pixels`.
    pub loss_layout: Option<crate::train::loss::LossLayout>,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            iterations: 30_000,
            seed: 0,
            sh_degree: 3,
            background: Background::Fixed([0.0; 3]),
            lr: LearningRates::default(),
            density: DensityConfig::default(),
            schedule: DensitySchedule::default(),
            ssim_weight: 0.2,
            timestamps: false,
            model: Arc::new(NamedModel::DEFAULT),
            batch_views: 1,
            raster_pixels: None,
            loss_layout: None,
        }
    }
}

impl TrainConfig {
    /// The values no run can train with, refused with the `train` flag that sets each and the
    /// fix. `train` calls it on the configuration its flags made; a library caller that builds
    /// a configuration by hand can call it the same way.
    pub fn validate(&self) -> anyhow::Result<()> {
        use anyhow::ensure;
        ensure!(
            self.sh_degree <= 3,
            "--sh-degree {}: the engine supports 0..=3. Fix: pass 0, 1, 2 or 3",
            self.sh_degree
        );
        ensure!(
            self.iterations > 0,
            "--iterations 0: nothing to train. Fix: pass at least 1"
        );
        ensure!(
            self.schedule.densify_from <= self.schedule.densify_until,
            "--densify-from {} is after --densify-until {}. Fix: make from ≤ until",
            self.schedule.densify_from,
            self.schedule.densify_until
        );
        ensure!(
            (0.0..=1.0).contains(&self.ssim_weight),
            "--ssim-weight {} must lie in [0, 1]",
            self.ssim_weight
        );
        self.model.validate()?;
        ensure!(
            (1..=16).contains(&self.batch_views),
            "--batch-views {}: choose 1 to 16 views per step",
            self.batch_views
        );
        Ok(())
    }

    /// This configuration with its lengths in world units (those of the model's section,
    /// [`ModelSection::in_training_frame`], and the growth region) moved into a scene's training frame
    /// ([`crate::scene::frame`]). The configuration a run records keeps the user's units; the
    /// passes are built from this one.
    pub fn in_training_frame(&self, frame: &crate::scene::SceneFrame) -> TrainConfig {
        let mut c = self.clone();
        if let Some(moved) = self.model.in_training_frame(frame) {
            c.model = moved;
        }
        c.density.grow_within = self.density.grow_within.map(|r| r.in_training_frame(frame));
        c
    }

    /// The rasterizer constants of this run: the model's ([`ModelSection::render_constants`];
    /// Mip-Splatting's filters, SpacetimeGaussians' near plane, else the 3DGS defaults).
    pub fn render_constants(&self) -> RenderConstants {
        self.model.render_constants()
    }

    /// The model section's own settings as the type `T` its model keeps them in (`None` when
    /// the section is another model's).
    pub fn model_settings<T: ModelSection>(&self) -> Option<&T> {
        self.model.as_any().downcast_ref()
    }

    /// Makes `section` this configuration's model section.
    pub fn set_model(&mut self, section: impl ModelSection) {
        self.model = Arc::new(section);
    }

    /// Changes the model section's settings of type `T` with `change`; false (and nothing
    /// changed) when the section is another model's.
    pub fn update_model_settings<T: ModelSection + Clone>(
        &mut self,
        change: impl FnOnce(&mut T),
    ) -> bool {
        let Some(mut settings) = self.model_settings::<T>().cloned() else {
            return false;
        };
        change(&mut settings);
        self.set_model(settings);
        true
    }

    pub fn to_json(&self) -> serde_json::Value {
        let lr = &self.lr;
        let d = &self.density;
        let s = &self.schedule;
        let mut j = serde_json::json!({
            "iterations": self.iterations,
            "seed": self.seed,
            "sh_degree": self.sh_degree,
            "background": self.background.describe(),
            "ssim_weight": self.ssim_weight,
            "lr": {
                "position_init": lr.position_init, "position_final": lr.position_final,
                "position_max_steps": lr.position_max_steps, "scaling": lr.scaling,
                "rotation": lr.rotation, "opacity": lr.opacity, "sh_dc": lr.sh_dc,
                "sh_rest": lr.sh_rest,
            },
            "density": {
                "grad_threshold": d.grad_threshold, "percent_dense": d.percent_dense,
                "min_opacity": d.min_opacity, "max_world_fraction": d.max_world_fraction,
                "split_shrink": d.split_shrink, "screen_size_limit": d.screen_size_limit,
                "opacity_reset_value": d.opacity_reset_value,
                "densify_from": s.densify_from, "densify_until": s.densify_until,
                "interval": s.interval, "opacity_reset_interval": s.opacity_reset_interval,
                "white_background_reset": s.white_background,
            },
        });
        // Only when set, so checkpoints from before the key still resume.
        if let Some(n) = s.growth_rounds {
            j["density"]["growth_rounds"] = serde_json::json!(n);
        }
        // Only when batched, so checkpoints from before the key still resume.
        if self.batch_views != 1 {
            j["batch_views"] = serde_json::json!(self.batch_views);
        }
        write_section(self.model.as_ref(), &mut j);
        // Only when set, so checkpoints from before the key still resume.
        if let Some(n) = d.max_gaussians {
            j["density"]["max_gaussians"] = serde_json::json!(n);
        }
        // Only when set, so checkpoints from before the keys still resume.
        if let Some(b) = d.exact_budget {
            j["density"]["exact_budget"] = b.to_json();
        }
        // Only when set, so checkpoints from before the key still resume.
        if let Some(r) = d.grow_within {
            j["density"]["grow_within"] = r.to_json();
        }
        if d.rank_lowered {
            j["density"]["rank_lowered"] = serde_json::json!(true);
        }
        // Only when on, so checkpoints from before the key still resume.
        if d.abs_grad {
            j["density"]["abs_grad"] = serde_json::json!(true);
        }
        // Only when not the 3DGS default, so checkpoints from before the key still resume.
        if let Statistic::PixelWeighted { depth_threshold } = d.statistic {
            j["density"]["statistic"] = serde_json::json!({
                "kind": d.statistic.name(), "depth_threshold": depth_threshold,
            });
        }
        j
    }

    /// [`TrainConfig::to_json`] as it was written before the config had a model section: no
    /// model name, the model's settings under their old top-level keys
    /// ([`ModelSection::legacy_json`]). Resuming a checkpoint of that time compares this.
    pub fn to_legacy_json(&self) -> serde_json::Value {
        let mut j = self.to_json();
        if let Some(o) = j.as_object_mut() {
            o.remove("model");
            o.remove("model_settings");
            o.extend(self.model.legacy_json());
        }
        j
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::passes::surfels::SurfelTraining;

    /// Every value `validate` refuses is refused naming the flag that sets it; the defaults
    /// and the edges of each range pass.
    #[test]
    fn validate_refuses_each_bad_value_by_its_flag() {
        let ok = TrainConfig::default();
        ok.validate().unwrap();
        let surfels = || TrainConfig {
            model: Arc::new(SurfelTraining::default()),
            ..TrainConfig::default()
        };
        surfels().validate().unwrap();
        let edges = TrainConfig {
            sh_degree: 0,
            iterations: 1,
            ssim_weight: 1.0,
            batch_views: 16,
            ..TrainConfig::default()
        };
        edges.validate().unwrap();
        let cases: Vec<(TrainConfig, &str)> = vec![
            (
                TrainConfig {
                    sh_degree: 4,
                    ..ok.clone()
                },
                "--sh-degree",
            ),
            (
                TrainConfig {
                    iterations: 0,
                    ..ok.clone()
                },
                "--iterations",
            ),
            (
                TrainConfig {
                    schedule: DensitySchedule {
                        densify_from: 16_000,
                        ..DensitySchedule::default()
                    },
                    ..ok.clone()
                },
                "--densify-from",
            ),
            (
                TrainConfig {
                    ssim_weight: 1.5,
                    ..ok.clone()
                },
                "--ssim-weight",
            ),
            (
                TrainConfig {
                    ssim_weight: f32::NAN,
                    ..ok.clone()
                },
                "--ssim-weight",
            ),
            (
                TrainConfig {
                    batch_views: 0,
                    ..ok.clone()
                },
                "--batch-views",
            ),
            (
                TrainConfig {
                    batch_views: 17,
                    ..ok.clone()
                },
                "--batch-views",
            ),
        ];
        let mut cases = cases;
        let mut s = surfels();
        assert!(s.update_model_settings(|t: &mut SurfelTraining| t.normal_weight = -0.1));
        cases.push((s, "--lambda-normal"));
        let mut s = surfels();
        assert!(s.update_model_settings(|t: &mut SurfelTraining| t.depth_ratio = 1.5));
        cases.push((s, "--depth-ratio"));
        for (c, flag) in cases {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(flag), "{flag}: {e}");
        }
    }
}
