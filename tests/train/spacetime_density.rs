//! SpacetimeGaussians' rule for the Gaussians density control creates: clones and split
//! children get a temporal centre uniform over the segment (the official densify_and_clone /
//! densify_and_splitv2), drawn on the GPU exactly as `random_child_centre` says, while the
//! survivors keep theirs; `--child-time parent` keeps the parent's. Validation layer on.

use std::path::Path;

use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::models::BaseModel;
use lpmsplat::scene::{images, LoadOptions, Scene};
use lpmsplat::splats::{random_init, GaussianParams};
use lpmsplat::train::density::{DensifyArgs, DensifyPhase, DensityConfig, Thresholds};
use lpmsplat::train::passes::spacetime::random_child_centre;
use lpmsplat::train::passes::spacetime_settings::ChildTime;
use lpmsplat::train::trainer::{TrainConfig, Trainer};

fn centres(p: &GaussianParams) -> Vec<f32> {
    p.extra
        .iter()
        .find(|e| e.group.name == "trbf_center")
        .expect("the temporal centres")
        .values
        .clone()
}

/// Trains two iterations with a densify step at the second that clones (or, with
/// a tiny `percent_dense`, splits) every visible Gaussian; returns the centres before, after, and the step's (kept, after).
fn densify_once(
    child_time: ChildTime,
    seed: u64,
    percent_dense: f64,
) -> (Vec<f32>, Vec<f32>, usize, usize) {
    let ctx = GpuContext::new(&GpuOptions::for_tests()).unwrap();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    let scene = Scene::load(&dir, &LoadOptions::default()).unwrap();
    let train_images = images::load_images(&scene, &scene.train).unwrap();
    let mut cfg = TrainConfig {
        iterations: 2,
        seed,
        ..TrainConfig::default()
    };
    BaseModel::SpacetimeLite.configure(&mut cfg);
    assert!(cfg.update_model_settings(
        |s: &mut lpmsplat::train::passes::spacetime::SpacetimeTraining| s.child_time = child_time
    ));
    cfg.schedule.densify_from = 0;
    cfg.schedule.interval = 2;
    cfg.density.grad_threshold = 1e-12;
    // Every Gaussian is "small" (cloned) with a huge percent_dense, "large" (split) with a tiny one.
    cfg.density.percent_dense = percent_dense;
    let (center, half) = scene.random_init_box();
    let init = BaseModel::SpacetimeLite
        .initialise(random_init(400, center, [half; 3], seed, 0).unwrap(), seed);
    let mut t = Trainer::new(&ctx, &scene, &train_images, &init, cfg).unwrap();
    t.step().unwrap();
    let before = centres(&t.export_model().unwrap());
    let r = t.step().unwrap();
    let o = r.densified.expect("iteration 2 densifies");
    let after = centres(&t.export_model().unwrap());
    ctx.check_validation().unwrap();
    (before, after, o.kept, o.after)
}

#[test]
fn clones_and_children_get_random_temporal_centres() {
    let seed = 5;
    // Clones: the parents survive as the first rows, in order, with their centres.
    let (before, after, kept, end) = densify_once(ChildTime::Random, seed, 100.0);
    assert_eq!(kept, before.len(), "every parent survives its clone");
    assert!(end > kept + 100, "clones: kept {kept}, after {end}");
    assert_eq!(after.len(), end);
    assert_eq!(&after[..kept], &before[..]);
    let check_new = |after: &[f32], kept: usize| {
        for (row, &c) in after.iter().enumerate().skip(kept) {
            assert_eq!(c, random_child_centre(seed, 2, row as u32), "row {row}");
            assert!(c > 0.0 && c < 1.0, "row {row}: {c}");
        }
        // Spread over the segment, not at the parents' centres.
        let new = &after[kept..];
        let mean = new.iter().map(|&c| c as f64).sum::<f64>() / new.len() as f64;
        assert!((mean - 0.5).abs() < 0.1, "mean new centre {mean}");
    };
    check_new(&after, kept);
    // Splits: the parents are replaced by two children each.
    let (_, after, kept, end) = densify_once(ChildTime::Random, seed, 1e-9);
    assert!(end > kept + 100, "splits: kept {kept}, after {end}");
    check_new(&after, kept);

    // The parent's centre on request.
    for percent_dense in [100.0, 1e-9] {
        let (before, after, kept, end) = densify_once(ChildTime::Parent, seed, percent_dense);
        assert!(end > kept + 100);
        for (row, c) in after.iter().enumerate().skip(kept) {
            assert!(before.contains(c), "row {row}: {c} is no parent's centre");
        }
    }
}

/// The prune-only rounds remove by opacity alone, as the official code's later rounds do: the
/// world- and screen-size prunes that 3DGS's combined step applies after the first opacity
/// reset are off there (and in the grow-only rounds, which prune nothing).
#[test]
fn prune_only_rounds_prune_by_opacity_alone() {
    let cfg = DensityConfig {
        screen_size_limit: Some(20.0),
        ..DensityConfig::default()
    };
    let at = |phase| {
        let args = DensifyArgs {
            extent: 3.0,
            prune_large: true,
            iteration: 5000,
            phase,
        };
        Thresholds::new(&cfg, &args).unwrap()
    };
    let both = at(DensifyPhase::Both);
    assert!(both.prune_large && both.screen_max == 20.0, "{both:?}");
    assert!(both.min_opacity_logit.is_finite() && both.grad_threshold.is_finite());
    let prune = at(DensifyPhase::PruneOnly);
    assert!(!prune.prune_large && prune.screen_max < 0.0, "{prune:?}");
    assert_eq!(prune.min_opacity_logit, both.min_opacity_logit);
    assert_eq!(prune.grad_threshold, f32::INFINITY);
    let grow = at(DensifyPhase::GrowOnly);
    assert!(!grow.prune_large && grow.screen_max < 0.0, "{grow:?}");
    assert_eq!(grow.min_opacity_logit, f32::NEG_INFINITY);
}

/// SpacetimeGaussians' rounds (`--growth-rounds`): the first densify steps clone and split and
/// prune nothing, even with every Gaussian below the opacity floor; the later ones prune and
/// never clone or split, even with every gradient above the threshold.
#[test]
fn growth_rounds_grow_first_then_only_prune() {
    let ctx = GpuContext::new(&GpuOptions::for_tests()).unwrap();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    let scene = Scene::load(&dir, &LoadOptions::default()).unwrap();
    let train_images = images::load_images(&scene, &scene.train).unwrap();
    let mut cfg = TrainConfig {
        iterations: 6,
        seed: 2,
        ..TrainConfig::default()
    };
    BaseModel::SpacetimeLite.configure(&mut cfg);
    cfg.schedule.densify_from = 0;
    cfg.schedule.interval = 2;
    cfg.schedule.growth_rounds = Some(2);
    cfg.density.grad_threshold = 1e-12;
    // Initial opacity 0.1: all of them under this floor.
    cfg.density.min_opacity = 0.5;
    let (center, half) = scene.random_init_box();
    let init =
        BaseModel::SpacetimeLite.initialise(random_init(300, center, [half; 3], 2, 0).unwrap(), 2);
    let mut t = Trainer::new(&ctx, &scene, &train_images, &init, cfg).unwrap();
    let mut outcomes = Vec::new();
    for _ in 0..6 {
        if let Some(o) = t.step().unwrap().densified {
            outcomes.push(o);
        }
    }
    assert_eq!(outcomes.len(), 3, "densify at 2, 4 and 6");
    for o in &outcomes[..2] {
        assert!(
            o.clones + o.split_children > 0,
            "a growth round grows: {o:?}"
        );
        // Only split parents leave (each replaced by two children): no prune.
        assert_eq!(o.before - o.kept, o.split_children / 2, "{o:?}");
    }
    let o = &outcomes[2];
    assert_eq!(
        o.clones + o.split_children,
        0,
        "a prune round never grows: {o:?}"
    );
    assert!(o.kept < o.before, "and prunes the faint Gaussians: {o:?}");
    ctx.check_validation().unwrap();
}
