//! SpacetimeGaussians' section of a run's config ([`SpacetimeTraining`]): the temporal groups'
//! learning rates, the temporal centre of new Gaussians, and the official rules it trains with
//! (guided sampling, the angular-velocity split, the Neural 3D Video culls), which the passes
//! beside this file read.

use std::any::Any;
use std::sync::Arc;

use crate::render::layout::RenderConstants;
use crate::scene::SceneFrame;
use crate::train::model_section::ModelSection;

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
impl ModelSection for SpacetimeTraining {
    fn model_name(&self) -> &'static str {
        match self.full {
            Some(_) => "spacetime-full",
            None => "spacetime-lite",
        }
    }

    fn settings_json(&self) -> serde_json::Value {
        let mut j = serde_json::json!({
            "lr_motion": self.motion, "lr_omega": self.omega, "lr_t_center": self.t_center,
            "lr_t_log_scale": self.t_log_scale, "child_time": self.child_time.name(),
        });
        // Always written: a checkpoint from before guided sampling existed was trained
        // without it, and resuming it with the sampler on is a different run.
        j["guided_sampling"] = match &self.guided {
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
        j["omega_freeze"] = match &self.omega_freeze {
            Some(f) => serde_json::json!({
                "from": f.from, "motion_above": f.motion_above,
                "scale_between": f.scale_between, "opacity_above": f.opacity_above,
            }),
            None => serde_json::Value::Null,
        };
        // Only when on, so checkpoints from before the culls existed still resume.
        if let Some(w) = &self.world_culls {
            j["world_culls"] = serde_json::json!({
                "below_z": w.below_z,
                "later": w.later.map(|l| serde_json::json!({
                    "from": l.from, "every": l.every, "offset": l.offset, "box_at": l.box_at,
                })),
            });
        }
        // Only for the full model, so lite checkpoints from before the key still resume.
        if let Some(f) = &self.full {
            j["full"] = serde_json::json!({
                "lr_features": f.features, "lr_time_features": f.time_features,
                "lr_decoder": f.decoder,
            });
        }
        j
    }

    fn legacy_json(&self) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::from_iter([("spacetime".to_string(), self.settings_json())])
    }

    /// SpacetimeGaussians' near plane ([`crate::render::spacetime::SPACETIME_NEAR`]).
    fn render_constants(&self) -> RenderConstants {
        RenderConstants::default().with_near(crate::render::spacetime::SPACETIME_NEAR)
    }

    /// The angular-velocity split's motion and scale thresholds; the world culls' z is moved
    /// by their pass, which reports it in the user's units.
    fn in_training_frame(&self, frame: &SceneFrame) -> Option<Arc<dyn ModelSection>> {
        let mut s = *self;
        let f = s.omega_freeze.as_mut()?;
        f.motion_above = frame.length_to_train(f.motion_above);
        f.scale_between = f.scale_between.map(|l| frame.length_to_train(l));
        Some(Arc::new(s))
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
