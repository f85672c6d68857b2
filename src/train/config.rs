//! What decides a training run: the background, the learning rates, density control, the
//! schedule and the base model's own settings (`config.json`, and the checkpoint's key).

use super::density::{DensityConfig, Statistic};
use super::schedule::{DensitySchedule, LearningRates};
use crate::render::layout::RenderConstants;
use crate::render::surfel::regularise::RegulariserWeights;

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
    /// Mip-Splatting's filters: the 2D Mip filter (eps2d 0.1 with the opacity compensation)
    /// and the 3D smoothing filter (recomputed after every density step and every 100
    /// iterations after densification, as the official code; the opacity reset acts on the
    /// filtered opacity).
    pub mip_filters: bool,
    /// 2DGS: the model is surfels, with these regulariser settings (`None`: 3D Gaussians).
    pub surfels: Option<SurfelTraining>,
    /// SpacetimeGaussians (lite): the model has the temporal groups, trained at these rates
    /// (`None`: still scenes).
    pub spacetime: Option<SpacetimeTraining>,
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
            mip_filters: false,
            surfels: None,
            spacetime: None,
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
        if let Some(t) = &self.surfels {
            ensure!(
                t.normal_weight >= 0.0 && t.distortion_weight >= 0.0,
                "--lambda-normal {} and --lambda-dist {} must be ≥ 0",
                t.normal_weight,
                t.distortion_weight
            );
            ensure!(
                (0.0..=1.0).contains(&t.depth_ratio),
                "--depth-ratio {} must lie in [0, 1] (0: expected depth, 1: median depth)",
                t.depth_ratio
            );
        }
        ensure!(
            (1..=16).contains(&self.batch_views),
            "--batch-views {}: choose 1 to 16 views per step",
            self.batch_views
        );
        Ok(())
    }

    /// This configuration with its lengths in world units (the angular-velocity split's
    /// motion and scale thresholds) moved into a scene's training frame
    /// ([`crate::scene::frame`]; the world culls' z is moved by their pass, which reports it
    /// in the user's units). The configuration a run records keeps the user's units; the
    /// passes are built from this one.
    pub fn in_training_frame(&self, frame: &crate::scene::SceneFrame) -> TrainConfig {
        let mut c = self.clone();
        if let Some(st) = c.spacetime.as_mut() {
            if let Some(f) = st.omega_freeze.as_mut() {
                f.motion_above = frame.length_to_train(f.motion_above);
                f.scale_between = f.scale_between.map(|l| frame.length_to_train(l));
            }
        }
        c
    }

    /// The rasterizer constants of this run: Mip-Splatting's 2D filter with `mip_filters`,
    /// SpacetimeGaussians' near plane for video models
    /// ([`crate::render::spacetime::SPACETIME_NEAR`]), else the 3DGS defaults.
    pub fn render_constants(&self) -> RenderConstants {
        let constants = RenderConstants::for_mip(self.mip_filters);
        match self.spacetime {
            Some(_) => constants.with_near(crate::render::spacetime::SPACETIME_NEAR),
            None => constants,
        }
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
        // Only when on, so checkpoints from before the key still resume.
        if self.mip_filters {
            j["mip_filters"] = serde_json::json!(true);
        }
        // Only for surfels, so checkpoints from before the key still resume.
        if let Some(t) = &self.surfels {
            j["surfels"] = serde_json::json!({
                "normal_weight": t.normal_weight, "normal_from": t.normal_from,
                "distortion_weight": t.distortion_weight, "distortion_from": t.distortion_from,
                "depth_ratio": t.depth_ratio,
            });
        }
        if let Some(r) = &self.spacetime {
            j["spacetime"] = serde_json::json!({
                "lr_motion": r.motion, "lr_omega": r.omega, "lr_t_center": r.t_center,
                "lr_t_log_scale": r.t_log_scale, "child_time": r.child_time.name(),
            });
            // Always written: a checkpoint from before guided sampling existed was trained
            // without it, and resuming it with the sampler on is a different run.
            j["spacetime"]["guided_sampling"] = match &r.guided {
                Some(g) => serde_json::json!({
                    "from": g.from, "select_below": g.select_below, "cameras": g.cameras,
                    "gap": g.gap, "sample_below": g.sample_below, "quantile": g.quantile,
                    "patch": g.patch, "patch_fraction": g.patch_fraction, "border": g.border,
                    "depth_ratios": g.depth_ratios, "jitter": g.jitter, "opacity": g.opacity,
                }),
                None => serde_json::Value::Null,
            };
            // Always written, as guided sampling: a checkpoint from before the split existed was
            // trained without it.
            j["spacetime"]["omega_freeze"] = match &r.omega_freeze {
                Some(f) => serde_json::json!({
                    "from": f.from, "motion_above": f.motion_above,
                    "scale_between": f.scale_between, "opacity_above": f.opacity_above,
                }),
                None => serde_json::Value::Null,
            };
            // Only when on, so checkpoints from before the culls existed still resume.
            if let Some(w) = &r.world_culls {
                j["spacetime"]["world_culls"] = serde_json::json!({
                    "below_z": w.below_z,
                    "later": w.later.map(|l| serde_json::json!({
                        "from": l.from, "every": l.every, "offset": l.offset, "box_at": l.box_at,
                    })),
                });
            }
            // Only for the full model, so lite checkpoints from before the key still resume.
            if let Some(f) = &r.full {
                j["spacetime"]["full"] = serde_json::json!({
                    "lr_features": f.features, "lr_time_features": f.time_features,
                    "lr_decoder": f.decoder,
                });
            }
        }
        // Only when set, so checkpoints from before the key still resume.
        if let Some(n) = d.max_gaussians {
            j["density"]["max_gaussians"] = serde_json::json!(n);
        }
        // Only when set, so checkpoints from before the keys still resume.
        if let Some(b) = d.exact_budget {
            j["density"]["exact_budget"] = b.to_json();
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
}

/// 2DGS's training settings (official `arguments/__init__.py`, `train.py`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfelTraining {
    /// λ of the normal consistency (0.05), active for iterations > `normal_from` (7000).
    pub normal_weight: f32,
    pub normal_from: u32,
    /// λ of the depth distortion (0 in the official code; its DTU script uses 1000), active
    /// for iterations > `distortion_from` (3000).
    pub distortion_weight: f32,
    pub distortion_from: u32,
    /// The surface depth: 0 the expected depth (official default), 1 the median (DTU, TnT).
    pub depth_ratio: f32,
}

impl Default for SurfelTraining {
    fn default() -> Self {
        Self {
            normal_weight: 0.05,
            normal_from: 7000,
            distortion_weight: 0.0,
            distortion_from: 3000,
            depth_ratio: 0.0,
        }
    }
}

impl SurfelTraining {
    /// The regularisers' weights at `iteration`.
    pub fn weights_at(&self, iteration: u32) -> RegulariserWeights {
        RegulariserWeights {
            normal: if iteration > self.normal_from {
                self.normal_weight
            } else {
                0.0
            },
            distortion: if iteration > self.distortion_from {
                self.distortion_weight
            } else {
                0.0
            },
            depth_ratio: self.depth_ratio,
        }
    }
}

/// The temporal centre of a Gaussian that density control creates by cloning or splitting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChildTime {
    /// Uniform in [0, 1), the whole segment: the official `densify_and_clone` and
    /// `densify_and_splitv2` (docs/algorithms/base-models.md §4.6), so detail found at one time can serve any.
    #[default]
    Random,
    /// The parent's centre (what every other per-Gaussian group does).
    Parent,
}

impl ChildTime {
    pub fn parse(s: &str) -> anyhow::Result<ChildTime> {
        Ok(match s {
            "random" => ChildTime::Random,
            "parent" => ChildTime::Parent,
            other => anyhow::bail!(
                "--child-time {other:?} is unknown. Fix: choose random (the official rule) or parent"
            ),
        })
    }
    pub fn name(&self) -> &'static str {
        match self {
            ChildTime::Random => "random",
            ChildTime::Parent => "parent",
        }
    }
}

/// SpacetimeGaussians' training settings: the temporal groups' learning rates (the official
/// N3DV settings, docs/algorithms/base-models.md §4.2) and the temporal centre of new Gaussians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpacetimeTraining {
    /// Motion, relative to the scene extent, not decayed (1.6e-4 × 0.5 × 3.5).
    pub motion: f64,
    pub omega: f64,
    pub t_center: f64,
    pub t_log_scale: f64,
    /// Clones' and split children's temporal centre.
    pub child_time: ChildTime,
    /// The official guided error sampling (`None`: off).
    pub guided: Option<GuidedSamplingSettings>,
    /// The full model (9 feature channels and the per-pixel decoder); `None`: the lite model.
    pub full: Option<FullModelRates>,
    /// The official angular-velocity / rotation split from iteration 8001 (`None`: off).
    pub omega_freeze: Option<OmegaFreeze>,
    /// The official Neural 3D Video culls in world space (`None`: off; the CLI turns them on
    /// for the official N3DV scenes).
    pub world_culls: Option<WorldCulls>,
}

/// SpacetimeGaussians' culls of Gaussians by their world position on Neural 3D Video
/// (helper_train.py `controlgaussians`, `removeminmax`; train.py; docs/algorithms/base-models.md §4.6): before
/// training, every Gaussian with world z below `below_z` (4.5) is removed (the official
/// `densify` modes 1 and 2); mode 1 (`later`) also repeats that cull after densification and
/// once removes the Gaussians outside the initial points' bounding box. The threshold is in the
/// world of the scene's `poses_bounds.npy`, which the N3DV loader keeps as the official
/// conversion does (`train::passes::world_culls`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldCulls {
    pub below_z: f64,
    pub later: Option<LaterCulls>,
}

/// When mode 1's later culls run: the z cull at every iteration `≥ from` with
/// `iteration % every == offset` (official: from the end of densification, 9000, at …500 of
/// every 1000), the bounding-box cull at `box_at` (official 10000, a thousand after the end of
/// densification).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaterCulls {
    pub from: u32,
    pub every: u32,
    pub offset: u32,
    pub box_at: u32,
}

impl WorldCulls {
    /// The official z threshold in Neural 3D Video's world units.
    pub const N3DV_BELOW_Z: f64 = 4.5;

    /// The official mode 1 (`later`) or 2 on a schedule that densifies until
    /// `densify_until`, with `per_thousand` iterations standing for the official 1000 (1000 at
    /// full length; `bench trade` scales it to its calendar).
    pub fn n3dv(later: bool, densify_until: u32, per_thousand: u32) -> WorldCulls {
        let every = per_thousand.max(1);
        WorldCulls {
            below_z: Self::N3DV_BELOW_Z,
            later: later.then_some(LaterCulls {
                from: densify_until,
                every,
                offset: every / 2,
                box_at: densify_until + every,
            }),
        }
    }
}

/// SpacetimeGaussians' split of rotation and angular velocity (helper_train.py
/// `controlgaussians`, oursfull.py `zero_omegabymotion`, docs/algorithms/base-models.md §4.4): at `from` the
/// Gaussians that move (Σ|m₁| > `motion_above`), are mid-sized (`scale_between`, the largest
/// scale) and opaque (σ(o) > `opacity_above`) are marked; every other Gaussian's angular
/// velocity is set to 0 and the whole group's Adam moments are cleared; from then on only the
/// marked ones learn an angular velocity and only the others a rotation. The thresholds are
/// the official ones, in Neural 3D Video's world units (`train::passes::omega_freeze`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OmegaFreeze {
    pub from: u32,
    pub motion_above: f64,
    pub scale_between: [f64; 2],
    pub opacity_above: f64,
}

impl Default for OmegaFreeze {
    fn default() -> Self {
        Self {
            from: 8001,
            motion_above: 0.3,
            scale_between: [0.2, 0.6],
            opacity_above: 0.7,
        }
    }
}

/// SpacetimeGaussians' full model: the learning rates of its specular and time features and of
/// its decoder (docs/algorithms/base-models.md §4.2: 2.5e-3, 1e-3, 1e-4; the base colour keeps the DC rate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FullModelRates {
    pub features: f64,
    pub time_features: f64,
    pub decoder: f64,
}

impl Default for FullModelRates {
    fn default() -> Self {
        Self {
            features: 2.5e-3,
            time_features: 1e-3,
            decoder: 1e-4,
        }
    }
}

/// SpacetimeGaussians' guided error sampling (the official train.py "ems", docs/algorithms/base-models.md §4.6;
/// `train::passes::guided_sampling`): the official defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidedSamplingSettings {
    /// From this iteration the first SSIM of every training camera is recorded (1600).
    pub from: u32,
    /// Cameras whose first SSIM is below this are candidates (0.91) ...
    pub select_below: f32,
    /// ... the `cameras` lowest are chosen, none when fewer than that are below (2) ...
    pub cameras: usize,
    /// ... and each is sampled once, when it is a step's last view more than `gap` iterations
    /// after the previous sampling (100) and its SSIM there is below `sample_below` (0.88).
    pub gap: u32,
    pub sample_below: f32,
    /// Error pixels: above this quantile of the mean-normalised error (0.6).
    pub quantile: f64,
    /// Patches of this side (16) with more than `patch_fraction` error pixels (0.85) seed
    /// points; a `border` fraction of the image at each edge is left out (0.1).
    pub patch: u32,
    pub patch_fraction: f64,
    pub border: f64,
    /// Two points on each seed pixel's ray at these multiples of the view's depth (0.7, 7.5),
    /// each depth jittered by up to ± `jitter` / 2 of it (0.1).
    pub depth_ratios: [f64; 2],
    pub jitter: f64,
    /// The new points' opacity (0.1).
    pub opacity: f64,
}

impl Default for GuidedSamplingSettings {
    fn default() -> Self {
        Self {
            from: 1600,
            select_below: 0.91,
            cameras: 2,
            gap: 100,
            sample_below: 0.88,
            quantile: 0.6,
            patch: 16,
            patch_fraction: 0.85,
            border: 0.1,
            depth_ratios: [0.7, 7.5],
            jitter: 0.1,
            opacity: 0.1,
        }
    }
}

impl Default for SpacetimeTraining {
    fn default() -> Self {
        Self {
            motion: 1.6e-4 * 0.5 * 3.5,
            omega: 1e-4,
            t_center: 1e-4,
            t_log_scale: 0.03,
            child_time: ChildTime::Random,
            guided: Some(GuidedSamplingSettings::default()),
            full: None,
            omega_freeze: Some(OmegaFreeze::default()),
            world_culls: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value `validate` refuses is refused naming the flag that sets it; the defaults
    /// and the edges of each range pass.
    #[test]
    fn validate_refuses_each_bad_value_by_its_flag() {
        let ok = TrainConfig::default();
        ok.validate().unwrap();
        let surfels = || TrainConfig {
            surfels: Some(SurfelTraining::default()),
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
        s.surfels.as_mut().unwrap().normal_weight = -0.1;
        cases.push((s, "--lambda-normal"));
        let mut s = surfels();
        s.surfels.as_mut().unwrap().depth_ratio = 1.5;
        cases.push((s, "--depth-ratio"));
        for (c, flag) in cases {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(flag), "{flag}: {e}");
        }
    }
}
