//! Recording the next iteration while the current one runs (`Trainer::step_ahead`): the same
//! run as `step`, bit for bit under one lavapipe thread, for every still base model, through
//! density control (where nothing is prepared) and an intersection overflow (the first frame
//! overflows: the prepared iteration is dropped and recorded again); a prepared iteration is
//! really recorded on quiet iterations; what would change it is refused while it waits; a
//! strategy that misjudges its quiet steps changes nothing either. (LPM and SpacetimeGaussians
//! through a streaming image cache: `tests/train/lpm_train.rs`, `tests/train/image_cache.rs`.) Scene:
//! `tests/data/lego_small` (100×100, 8 training views). Validation on.

use crate::child_run;

use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::models::BaseModel;
use lpmsplat::scene::{images, Image, LoadOptions, Scene};
use lpmsplat::splats::{init::random_init, GaussianParams};
use lpmsplat::train::density::append::{append_gaussians, NewGaussian};
use lpmsplat::train::density::{DensifyArgs, DensifyOutcome};
use lpmsplat::train::strategy::{
    Adc, DensityContext, DensityStrategy, IterationView, StrategyEvent,
};
use lpmsplat::train::trainer::{Background, TrainConfig, Trainer};
use std::path::Path;
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn lego() -> Scene {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lego_small");
    Scene::load(&dir, &LoadOptions::default()).unwrap()
}

/// Densifying every 5 iterations (5, 10, 15, 20), an opacity reset at 15.
fn config(model: BaseModel, iterations: u32) -> TrainConfig {
    let mut c = TrainConfig {
        iterations,
        seed: 3,
        sh_degree: 1,
        background: Background::Fixed([0.0; 3]),
        ..TrainConfig::default()
    };
    model.configure(&mut c);
    c.schedule.densify_from = 3;
    c.schedule.interval = 5;
    c.schedule.densify_until = iterations;
    c.schedule.opacity_reset_interval = 15;
    c.density.grad_threshold = 2e-6;
    c
}

/// 3,000 Gaussians wide enough to cover most of lego's 49 tiles: up to 147k intersections,
/// past the ~98k the renderer starts with at this count, so the first frame overflows.
fn big_gaussians(scene: &Scene) -> GaussianParams {
    let mut p = random_init(3_000, [0.0; 3], [0.9; 3], 11, 1).unwrap();
    for s in p.log_scales.iter_mut().flatten() {
        *s = 0.4f32.ln();
    }
    // Placed in lego's own frame (around its object at the origin), trained in the scene's.
    p.map_frame(scene.frame.stored_to_train([0.0; 3]), &[], false);
    p
}

/// What a run leaves: every float of the final model (as bits), each step's loss (as bits),
/// the dropped frames and on how many steps the next iteration was prepared.
struct Run {
    model: Vec<u32>,
    losses: Vec<u32>,
    gaussians: usize,
    dropped: u32,
    prepared: u32,
    /// Prepared iterations dropped and recorded again.
    redone: u32,
}

fn train(ctx: &Arc<GpuContext>, scene: &Scene, gt: &[Image], model: BaseModel, ahead: bool) -> Run {
    let n = 24;
    let init = model.initialise(big_gaussians(scene), 11);
    let mut t = Trainer::new(ctx, scene, gt, &init, config(model, n)).unwrap();
    let (mut losses, mut prepared) = (Vec::new(), 0);
    for k in 1..=n {
        let r = t.step_ahead(ahead && k < n).unwrap();
        assert_eq!(r.iteration, k);
        assert_eq!(
            t.iteration, k,
            "the trainer's iteration is the last completed one"
        );
        losses.push(r.loss.to_bits());
        prepared += t.has_prepared() as u32;
    }
    assert!(!t.has_prepared());
    let m = t.export_model().unwrap();
    let mut floats: Vec<f32> = Vec::new();
    floats.extend(m.positions.iter().flatten());
    floats.extend(m.log_scales.iter().flatten());
    floats.extend(m.rotations.iter().flatten());
    floats.extend(&m.opacity_logits);
    floats.extend(m.sh_dc.iter().flatten());
    floats.extend(&m.sh_rest);
    Run {
        model: floats.iter().map(|x| x.to_bits()).collect(),
        losses,
        gaussians: m.len(),
        dropped: t.dropped_frames,
        prepared,
        redone: t.recording.dropped,
    }
}

/// One test a model (each in a single-threaded child, so the suite runs them beside others).
fn step_ahead_trains_bit_for_bit_like_step(name: &str, model: BaseModel) {
    if child_run::rerun_single_threaded(module_path!(), name) {
        return;
    }
    let ctx = ctx();
    let scene = lego();
    let gt = images::load_images(&scene, &scene.train).unwrap();
    let plain = train(&ctx, &scene, &gt, model, false);
    let again = train(&ctx, &scene, &gt, model, false);
    let ahead = train(&ctx, &scene, &gt, model, true);
    let label = model.name();
    eprintln!(
        "{label}: {} Gaussians, {} frames dropped, {} of 24 steps prepared the next",
        ahead.gaussians, ahead.dropped, ahead.prepared
    );
    assert_eq!(plain.prepared, 0);
    assert!(
        plain.gaussians > 3_000,
        "{label}: the run never densified, the test would prove little"
    );
    assert!(
        plain.dropped >= 1,
        "{label}: no frame overflowed (the first always should)"
    );
    // 24 steps: none prepares after a densify step (5, 10, 15, 20), the last, or a
    // frame that overflowed (the first at least): most steps prepare their successor.
    // The first frame overflowed with its successor prepared: that one was redone.
    assert!(ahead.redone >= 1, "{label}: nothing prepared was dropped");
    assert!(
        ahead.prepared >= 12,
        "{label}: only {} steps prepared the next",
        ahead.prepared
    );
    if plain.model != again.model {
        // A driver that ignores LP_NUM_THREADS: no bitwise claim is possible.
        assert!(
            !ctx.info.device_type.starts_with("CPU"),
            "{label}: identical runs differ on {}",
            ctx.info.name
        );
        assert_eq!(plain.gaussians, ahead.gaussians, "{label}");
    } else {
        assert_eq!(plain.losses, ahead.losses, "{label}: the losses differ");
        assert_eq!(
            plain.dropped, ahead.dropped,
            "{label}: dropped frames differ"
        );
        assert_eq!(plain.gaussians, ahead.gaussians, "{label}");
        assert!(plain.model == ahead.model, "{label}: the models differ");
    }
    ctx.check_validation().unwrap();
}

#[test]
fn step_ahead_trains_bit_for_bit_like_step_3dgs() {
    let name = "step_ahead_trains_bit_for_bit_like_step_3dgs";
    step_ahead_trains_bit_for_bit_like_step(name, BaseModel::Gaussians3d);
}

#[test]
fn step_ahead_trains_bit_for_bit_like_step_pixel_gs() {
    let name = "step_ahead_trains_bit_for_bit_like_step_pixel_gs";
    step_ahead_trains_bit_for_bit_like_step(name, BaseModel::PixelGs);
}

#[test]
fn step_ahead_trains_bit_for_bit_like_step_mip_splatting() {
    let name = "step_ahead_trains_bit_for_bit_like_step_mip_splatting";
    step_ahead_trains_bit_for_bit_like_step(name, BaseModel::MipSplatting);
}

#[test]
fn step_ahead_trains_bit_for_bit_like_step_2dgs() {
    let name = "step_ahead_trains_bit_for_bit_like_step_2dgs";
    step_ahead_trains_bit_for_bit_like_step(name, BaseModel::Surfels2d);
}

#[test]
fn a_prepared_iteration_refuses_what_would_change_it_and_steps_on() {
    let ctx = ctx();
    let scene = lego();
    let gt = images::load_images(&scene, &scene.train).unwrap();
    let init = random_init(300, [0.0; 3], [0.9; 3], 4, 0).unwrap();
    let mut cfg = config(BaseModel::Gaussians3d, 10);
    cfg.schedule.densify_until = 0;
    let mut t = Trainer::new(&ctx, &scene, &gt[..], &init, cfg).unwrap();
    t.step().unwrap();
    t.step_ahead(true).unwrap();
    assert!(t.has_prepared(), "a quiet iteration prepared nothing");
    assert_eq!(t.iteration, 2);
    // Reading the model is fine: it is the one after iteration 2.
    let before = t.model().unwrap();
    for (what, f) in [
        (
            "evaluate",
            Box::new(|t: &mut Trainer| {
                let _ = t.render_view(scene.test[0], [0.0; 3]);
            }) as Box<dyn Fn(&mut Trainer)>,
        ),
        (
            "snapshot",
            Box::new(|t: &mut Trainer| t.snapshot_next_step()),
        ),
        ("export", Box::new(|t: &mut Trainer| drop(t.export_model()))),
        (
            "checkpoint",
            Box::new(|t: &mut Trainer| drop(t.checkpoint(&scene))),
        ),
    ] {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(&mut t)));
        let msg = r.expect_err(what);
        let msg = msg.downcast_ref::<String>().cloned().unwrap_or_default();
        assert!(
            msg.contains("prepared") && msg.contains("step it first"),
            "{what}: {msg}"
        );
    }
    // The prepared iteration is the next one, and after it everything works again.
    let r = t.step().unwrap();
    assert_eq!((r.iteration, t.iteration), (3, 3));
    assert!(!t.has_prepared());
    assert!(
        t.model().unwrap().positions != before.positions,
        "iteration 3 did nothing"
    );
    t.render_view(scene.test[0], [0.0; 3]).unwrap();
    t.checkpoint(&scene).unwrap();
    ctx.check_validation().unwrap();
}

/// A strategy that says it has nothing to do after any iteration (`quiet_after`) but adds 1,500
/// Gaussians after iterations 7 and 12, past the buffers' capacity the first time: the trainer
/// must notice (the model's size changed, buffers were replaced) and drop the iteration it
/// prepared against the old ones.
struct Liar;

impl DensityStrategy for Liar {
    fn name(&self) -> &'static str {
        "liar"
    }

    fn densify(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        Adc.densify(t, at, args)
    }

    fn after_iteration(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        _reported: bool,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        if at.iteration == 7 || at.iteration == 12 {
            let rows: Vec<NewGaussian> = (0..1_500)
                .map(|k| {
                    let a = k as f32 * 0.37;
                    NewGaussian {
                        position: [0.6 * a.cos(), 0.6 * a.sin(), 0.3 * (k % 7) as f32 - 0.9],
                        scale: 0.04,
                        color: [0.8, 0.3, 0.2],
                        opacity: 0.4,
                        camera_center: [0.0, 0.0, 4.0],
                    }
                })
                .collect();
            append_gaussians(t, &rows)?;
        }
        Ok(None)
    }

    fn quiet_after(&self, _iteration: u32) -> bool {
        true
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

#[test]
fn a_strategy_that_misjudges_its_quiet_steps_changes_nothing() {
    let name = "a_strategy_that_misjudges_its_quiet_steps_changes_nothing";
    if child_run::rerun_single_threaded(module_path!(), name) {
        return;
    }
    let ctx = ctx();
    let scene = lego();
    let gt = images::load_images(&scene, &scene.train).unwrap();
    let init = random_init(300, [0.0; 3], [0.9; 3], 4, 0).unwrap();
    let mut cfg = config(BaseModel::Gaussians3d, 16);
    cfg.schedule.densify_until = 0;
    let run = |ahead: bool| {
        let mut t = Trainer::new(&ctx, &scene, &gt[..], &init, cfg.clone()).unwrap();
        t.set_strategy(Box::new(Liar));
        let mut losses = Vec::new();
        for k in 1..=16 {
            losses.push(t.step_ahead(ahead && k < 16).unwrap().loss.to_bits());
        }
        let m = t.model().unwrap();
        let floats: Vec<u32> = m.positions.iter().flatten().map(|x| x.to_bits()).collect();
        (losses, floats, m.len(), t.recording)
    };
    let (plain, again, ahead) = (run(false), run(false), run(true));
    assert_eq!(plain.2, 300 + 3_000, "the liar added nothing");
    assert_eq!(ahead.2, plain.2);
    // Prepared after 7 and 12 and dropped: those two steps' successors were recorded again.
    assert_eq!(ahead.3.dropped, 2, "{:?}", ahead.3);
    assert!(ahead.3.ahead >= 8 && ahead.3.ahead <= 13, "{:?}", ahead.3);
    if plain.1 == again.1 {
        assert_eq!(plain.0, ahead.0, "the losses differ");
        assert!(plain.1 == ahead.1, "the models differ");
    }
    ctx.check_validation().unwrap();
}
