//! SpacetimeGaussians' culls by world position on Neural 3D Video
//! ([`crate::train::passes::spacetime_settings::WorldCulls`]; docs/algorithms/base-models.md §4.6): the official code removes every
//! Gaussian with world z < 4.5 before training (its `densify` modes 1 and 2, which the N3DV
//! configs use), and in mode 1 repeats that after densification and once removes the Gaussians
//! outside the bounding box of the initial points. These are the official rules for that
//! dataset's world frame, not general ones: the CLI turns them on for the official N3DV scenes
//! only ([`for_scene`]).
//!
//! The pre-training cull runs on the host before the model is uploaded
//! ([`ModelRule::prepare_initial`]); the later ones write removal decisions on the GPU
//! (`glsl/density/prune_outside_box.comp`, host reference
//! [`crate::reference::density::prune_outside_box`]) that density control applies like
//! any prune, so every per-Gaussian buffer follows. The bounding box is that of the initial
//! model before the z cull, as the official code takes it (train.py computes it from the loaded
//! points before pruning them), and checkpoints keep it.

use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::spacetime_settings::{SpacetimeTraining, WorldCulls};
use crate::splats::GaussianParams;
use crate::train::config::TrainConfig;
use crate::train::density::{DensifyArgs, DensifyPhase};
use crate::train::strategy::{DensityContext, ModelRule, StepSeen, StrategyEvent};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum N3dvCulls {
    /// The official rule of the scene: on for the six Neural 3D Video scenes (by folder name,
    /// beside poses_bounds.npy), with the later culls where their config uses them; off
    /// elsewhere.
    Auto,
    /// The cull before training and the later ones (the official `densify: 1`).
    Official,
    /// Only the cull before training (the official `densify: 2`: coffee_martini,
    /// flame_salmon_1).
    Initial,
    Off,
}

/// Sets `config`'s culls for the scene at `root` as `--n3dv-culls` asks (`train` and `bench
/// trade`), after the model and the schedule are set: `per_thousand` iterations stand for the
/// official 1000 (1000 at full length).
pub fn apply_choice(
    choice: N3dvCulls,
    root: &Path,
    model_name: &str,
    config: &mut TrainConfig,
    per_thousand: u32,
) -> anyhow::Result<()> {
    let until = config.schedule.densify_until;
    let Some(mut st) = config.model_settings::<SpacetimeTraining>().copied() else {
        anyhow::ensure!(
            matches!(choice, N3dvCulls::Auto | N3dvCulls::Off),
            "--n3dv-culls applies to the spacetime models only (this run trains {}). Fix: drop \
             the flag",
            model_name
        );
        return Ok(());
    };
    let later = match choice {
        N3dvCulls::Auto => for_scene(root),
        N3dvCulls::Official => Some(true),
        N3dvCulls::Initial => Some(false),
        N3dvCulls::Off => None,
    };
    st.world_culls = later.map(|l| WorldCulls::n3dv(l, until, per_thousand));
    config.set_model(st);
    Ok(())
}

/// The six Neural 3D Video scenes and whether their official config uses `densify` mode 1
/// (the later culls too) or 2 (only the cull before training: coffee_martini and
/// flame_salmon_1, `configs/n3d_*/*.json`).
const N3DV_SCENES: [(&str, bool); 6] = [
    ("coffee_martini", false),
    ("cook_spinach", true),
    ("cut_roasted_beef", true),
    ("flame_salmon_1", false),
    ("flame_steak", true),
    ("sear_steak", true),
];

/// Whether the official culls apply to the scene at `root` and in which mode (`Some(true)`:
/// mode 1, with the later culls): a Neural 3D Video layout (`poses_bounds.npy`) in a folder
/// named after one of the six N3DV scenes (a suffix such as `_r2` is allowed).
pub fn for_scene(root: &Path) -> Option<bool> {
    if !root.join("poses_bounds.npy").is_file() {
        return None;
    }
    let name = root
        .canonicalize()
        .ok()?
        .file_name()?
        .to_string_lossy()
        .to_lowercase();
    N3DV_SCENES
        .iter()
        .find(|(scene, _)| name.starts_with(scene))
        .map(|&(_, later)| later)
}

/// What one cull removed.
#[derive(Debug, Clone, Serialize)]
pub struct Cull {
    /// 0 for the cull before training (reported with the first step).
    pub iteration: u32,
    /// `"z"` (world z below the threshold) or `"box"` (outside the initial bounding box).
    pub cull: &'static str,
    pub before: usize,
    pub removed: usize,
}

/// The culls of one step (the console prints them; `metrics.json` keeps them).
#[derive(Debug, Clone)]
pub struct CullEvent {
    pub culls: Vec<Cull>,
}

impl StrategyEvent for CullEvent {
    fn to_json(&self) -> serde_json::Value {
        serde_json::json!({ "rule": "world_culls", "culls": self.culls })
    }
    fn describe(&self) -> String {
        let lines: Vec<String> = self
            .culls
            .iter()
            .map(|c| {
                let what = match c.cull {
                    "z" => "world z below the N3DV threshold",
                    _ => "outside the initial points' bounding box",
                };
                let when = match c.iteration {
                    0 => "before training".to_string(),
                    i => format!("at iteration {i}"),
                };
                format!(
                    "world culls {when}: removed {} of {} Gaussians ({what})",
                    c.removed, c.before
                )
            })
            .collect();
        lines.join("; ")
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
struct State {
    /// The initial model's bounding box, before the z cull.
    lo: [f32; 3],
    hi: [f32; 3],
    /// The cull before training, until it is reported: (before, removed).
    unreported: Option<(usize, usize)>,
}

pub struct WorldCuller {
    /// The settings in the training frame.
    settings: WorldCulls,
    /// The z threshold in the scene's own units, as the user (and the official config) gave it.
    user_below_z: f64,
    state: State,
}

impl WorldCuller {
    /// For a run starting from `initial` (the bounding box is taken from it; a resumed run
    /// restores the original one from its checkpoint), on a scene held in `frame`: the z
    /// threshold, in the scene's own units, is moved into the training frame (the frame has
    /// no rotation, so a z plane stays a z plane).
    pub fn new(
        settings: WorldCulls,
        frame: &crate::scene::SceneFrame,
        initial: &GaussianParams,
    ) -> anyhow::Result<Self> {
        let user_below_z = settings.below_z;
        let mut settings = settings;
        settings.below_z = frame.to_train([0.0, 0.0, user_below_z])[2];
        anyhow::ensure!(
            settings.below_z.is_finite(),
            "world culls: the z threshold {} is not finite",
            settings.below_z
        );
        if let Some(l) = settings.later {
            anyhow::ensure!(
                l.every > 0 && l.offset < l.every,
                "world culls: the repeat every {} iterations at offset {} is not a schedule",
                l.every,
                l.offset
            );
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &initial.positions {
            for a in 0..3 {
                if p[a].is_finite() {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
        }
        Ok(Self {
            settings,
            user_below_z,
            state: State {
                lo,
                hi,
                unreported: None,
            },
        })
    }

    /// The z cull's box: every axis open but z's lower bound.
    fn z_box(&self) -> ([f32; 3], [f32; 3]) {
        (
            [
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                self.settings.below_z as f32,
            ],
            [f32::INFINITY; 3],
        )
    }

    /// Removes the Gaussians of the trainer's state outside `[lo, hi]` on the GPU.
    fn cull(
        &self,
        t: &mut DensityContext,
        iteration: u32,
        cull: &'static str,
        (lo, hi): ([f32; 3], [f32; 3]),
    ) -> anyhow::Result<Cull> {
        let before = t.state.count();
        t.rec.begin()?;
        t.density.record_prune_outside(t.rec, t.state, lo, hi)?;
        let args = DensifyArgs {
            extent: t.extent,
            prune_large: false,
            iteration,
            phase: DensifyPhase::PruneOnly,
        };
        let outcome = t.density.apply(t.rec, t.state, &args)?;
        t.rec.submit_and_wait()?;
        anyhow::ensure!(
            outcome.after > 0,
            "world culls at iteration {iteration}: every Gaussian lies outside the culled \
             region ({cull}): the scene's world frame is not Neural 3D Video's. Fix: \
             --n3dv-culls off"
        );
        Ok(Cull {
            iteration,
            cull,
            before,
            removed: before - outcome.after,
        })
    }
}

impl ModelRule for WorldCuller {
    fn name(&self) -> &'static str {
        "world_culls"
    }

    fn prepare_initial(&mut self, init: GaussianParams) -> anyhow::Result<GaussianParams> {
        let (lo, hi) = self.z_box();
        // Kept: every centre inside the box on all three axes (a NaN coordinate is kept, as
        // `prune_outside_box.comp` keeps it).
        let inside: Vec<usize> = (0..init.len())
            .filter(|&i| {
                let p = init.positions[i];
                !(0..3).any(|a| p[a] < lo[a] || p[a] > hi[a])
            })
            .collect();
        let kept = init.select_rows(&inside);
        anyhow::ensure!(
            !kept.is_empty(),
            "world culls: all {} initial Gaussians have world z below {} (the official Neural \
             3D Video cull, in the scene's own units): this scene's world frame is not N3DV's. \
             Fix: --n3dv-culls off",
            init.len(),
            self.user_below_z
        );
        self.state.unreported = Some((init.len(), init.len() - kept.len()));
        Ok(kept)
    }

    fn after_step(
        &mut self,
        t: &mut DensityContext,
        step: &StepSeen,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        let it = step.iteration;
        let mut culls = Vec::new();
        if let Some((before, removed)) = self.state.unreported.take() {
            culls.push(Cull {
                iteration: 0,
                cull: "z",
                before,
                removed,
            });
        }
        if let Some(l) = self.settings.later {
            if it >= l.from && it % l.every == l.offset {
                culls.push(self.cull(t, it, "z", self.z_box())?);
            }
            if it == l.box_at {
                culls.push(self.cull(t, it, "box", (self.state.lo, self.state.hi))?);
            }
        }
        Ok((!culls.is_empty()).then(|| Arc::new(CullEvent { culls }) as Arc<dyn StrategyEvent>))
    }

    /// The culls are GPU work on their schedule; the first step's report of the cull before
    /// training is host-only, but rare enough to count as work.
    fn quiet_after(&self, iteration: u32, _views: &[usize]) -> bool {
        self.state.unreported.is_none()
            && self.settings.later.is_none_or(|l| {
                !(iteration >= l.from && iteration % l.every == l.offset) && iteration != l.box_at
            })
    }

    fn state_json(&self) -> serde_json::Value {
        serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null)
    }

    fn restore_state(&mut self, state: &serde_json::Value) -> anyhow::Result<()> {
        self.state = serde_json::from_value(state.clone())
            .context("the checkpoint's world-cull state is malformed")?;
        Ok(())
    }
}
