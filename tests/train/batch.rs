//! Several views per optimizer step (`train::batch`, SpacetimeGaussians' two-camera batch): the
//! blend kernel exactly against the host, the partners (same time, other cameras, reproducible),
//! and a batched step's gradients against the mean of the two single-view steps' gradients on
//! the video fixture. Validation layer on.

use std::path::Path;
use std::sync::Arc;

use lpmsplat::gpu::{GpuContext, GpuOptions, Recorder};
use lpmsplat::models::BaseModel;
use lpmsplat::scene::{images, LoadOptions, Scene};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::random_init;
use lpmsplat::train::batch::{batch_partners, GradBlend};
use lpmsplat::train::data::ViewSchedule;
use lpmsplat::train::trainer::{TrainConfig, Trainer};

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// Every group's floats (buffer contents, extra groups included), with its stride.
fn groups(s: &GpuSplats) -> Vec<(Vec<f32>, usize)> {
    s.groups()
        .into_iter()
        .map(|(b, stride)| (b.read().unwrap(), stride))
        .collect()
}

#[test]
fn blend_is_the_sum_then_the_scale_exactly() {
    let ctx = ctx();
    let blend = GradBlend::new(&ctx).unwrap();
    let a = BaseModel::SpacetimeLite
        .initialise(random_init(1_003, [0.0; 3], [2.0; 3], 1, 0).unwrap(), 1);
    let b = BaseModel::SpacetimeLite
        .initialise(random_init(1_003, [0.5; 3], [3.0; 3], 2, 0).unwrap(), 2);
    for scale in [1.0f32, 0.5, 1.0 / 3.0] {
        let ga = GpuSplats::upload(&ctx, &a, 1_100).unwrap();
        let gb = GpuSplats::upload(&ctx, &b, 1_100).unwrap();
        let (before_a, before_b) = (groups(&ga), groups(&gb));
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        // Only the first 1000 Gaussians: the rest must stay as they were.
        let n = 1_000;
        blend.record(&mut rec, &ga, &gb, n, scale).unwrap();
        rec.submit_and_wait().unwrap();
        let after = groups(&ga);
        assert_eq!(
            after.len(),
            5 + lpmsplat::splats::sh_planes::PLANES + 4,
            "five 3DGS groups, the SH rest planes, four temporal"
        );
        for (g, ((got, stride), ((x, _), (y, _)))) in
            after.iter().zip(before_a.iter().zip(&before_b)).enumerate()
        {
            for i in 0..got.len() {
                let want = if i < n * stride {
                    (x[i] + y[i]) * scale
                } else {
                    x[i]
                };
                assert_eq!(got[i].to_bits(), want.to_bits(), "group {g} float {i}");
            }
        }
    }
    ctx.check_validation().unwrap();
}

fn fixture() -> Scene {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    Scene::load(&dir, &LoadOptions::default()).unwrap()
}

#[test]
fn partners_are_other_cameras_at_the_same_time() {
    let scene = fixture();
    let times = scene.view_times.clone().unwrap();
    for &v in &scene.train {
        for it in [1u32, 2, 977] {
            let p = batch_partners(v, &scene.train, Some(&times), 2, 3, it);
            assert_eq!(p.len(), 1, "view {v}: four other cameras at its time");
            assert!(p[0] != v && times[p[0]] == times[v]);
            assert!(scene.train.contains(&p[0]));
            // Reproducible from (seed, iteration).
            assert_eq!(p, batch_partners(v, &scene.train, Some(&times), 2, 3, it));
        }
        let all = batch_partners(v, &scene.train, Some(&times), 16, 3, 5);
        assert_eq!(
            all.len(),
            3,
            "only three other training cameras share a time"
        );
        let mut dedup = all.clone();
        dedup.sort_unstable();
        dedup.dedup();
        assert_eq!(dedup.len(), all.len(), "no view twice");
        assert!(batch_partners(v, &scene.train, Some(&times), 1, 3, 5).is_empty());
    }
    // The draw moves with the iteration (not always the same partner).
    let v = scene.train[0];
    let picks: std::collections::BTreeSet<usize> = (1..40)
        .map(|it| batch_partners(v, &scene.train, Some(&times), 2, 3, it)[0])
        .collect();
    assert!(picks.len() >= 2, "{picks:?}");
    // A still scene: any other training view.
    let p = batch_partners(v, &scene.train, None, 3, 3, 1);
    assert_eq!(p.len(), 2);
    assert!(p.iter().all(|&o| o != v && scene.train.contains(&o)) && p[0] != p[1]);
    // Without times some draw pairs views of different times (what the video rule forbids).
    assert!((1..40).any(|it| {
        let p = batch_partners(v, &scene.train, None, 2, 3, it);
        times[p[0]] != times[v]
    }));
}

/// A trainer of the fixture whose schedule always gives `view` first.
fn trainer(ctx: &Arc<GpuContext>, scene: &Scene, view: usize, batch: u32) -> Trainer {
    let train_images = images::load_images(scene, &scene.train).unwrap();
    let mut cfg = TrainConfig {
        iterations: 1,
        seed: 11,
        ..TrainConfig::default()
    };
    BaseModel::SpacetimeLite.configure(&mut cfg);
    cfg.batch_views = batch;
    let (center, half) = scene.random_init_box();
    let init = BaseModel::SpacetimeLite
        .initialise(random_init(2_000, center, [half; 3], 4, 0).unwrap(), 4);
    let mut t = Trainer::new(ctx, scene, &train_images, &init, cfg).unwrap();
    t.views = ViewSchedule::new(vec![view], 0).unwrap();
    t
}

#[test]
fn a_batched_step_averages_the_views_gradients() {
    let ctx = ctx();
    let scene = fixture();
    let a = scene.train[5];
    let mut batched = trainer(&ctx, &scene, a, 2);
    assert_eq!(batched.config.batch_views, 2);
    let r = batched.step().unwrap();
    assert_eq!(r.views.len(), 2, "{:?}", r.views);
    assert_eq!(r.views[0], a);
    let b = r.views[1];
    assert_eq!(r.view, b, "density control sees the last view");
    let mean = groups_of(&batched.gradients().unwrap());
    let single = |v: usize| {
        let mut t = trainer(&ctx, &scene, v, 1);
        let r = t.step().unwrap();
        assert_eq!(r.views, vec![v]);
        groups_of(&t.gradients().unwrap())
    };
    let (ga, gb) = (single(a), single(b));
    let mut nonzero = 0;
    let largest = |v: &[f32]| v.iter().fold(0.0f32, |s, x| s.max(x.abs()));
    let global = ga
        .iter()
        .chain(&gb)
        .map(|g| largest(g))
        .fold(0.0f32, f32::max);
    for (g, (m, (x, y))) in mean.iter().zip(ga.iter().zip(&gb)).enumerate() {
        // Relative to the group's largest gradient, with a floor for groups that are only
        // rounding noise (rotations of isotropic Gaussians).
        let scale = largest(x).max(largest(y)).max(1e-3 * global);
        for i in 0..m.len() {
            let want = 0.5 * (x[i] + y[i]);
            // The backward sums with float atomics, whose order differs run to run.
            assert!(
                (m[i] - want).abs() <= 1e-4 * scale,
                "group {g} float {i}: batched {} vs mean {want} (views {a}, {b})",
                m[i]
            );
            nonzero += (want != 0.0) as usize;
        }
    }
    assert!(
        nonzero > 1000,
        "the gradients are not trivially zero: {nonzero}"
    );
    ctx.check_validation().unwrap();
}

/// A model's floats per group, in group order (the trainer's gradient download).
fn groups_of(p: &lpmsplat::splats::GaussianParams) -> Vec<Vec<f32>> {
    let mut g = vec![
        p.positions.iter().flatten().copied().collect::<Vec<f32>>(),
        p.log_scales.iter().flatten().copied().collect(),
        p.rotations.iter().flatten().copied().collect(),
        p.opacity_logits.clone(),
        p.sh_dc.iter().flatten().copied().collect(),
        p.sh_rest.clone(),
    ];
    g.extend(p.extra.iter().map(|e| e.values.clone()));
    g
}
