//! SpacetimeGaussians' Neural 3D Video culls by world position (`train::passes::world_culls`):
//! the GPU box cull against the host reference (`prune_outside_box`, `kept_rows`) on every
//! per-Gaussian buffer, the official scenes recognised by folder, and a training run that culls
//! before training, after densification and outside the initial box, with a resumed run keeping
//! the original box. Validation layer on.

use std::sync::Arc;

use lpmsplat::gpu::{GpuContext, GpuOptions, Recorder};
use lpmsplat::models::BaseModel;
use lpmsplat::reference::density::{kept_rows, prune_outside_box};
use lpmsplat::scene::{images, LoadOptions, Scene};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::{random_init, GaussianParams};
use lpmsplat::train::adam::SplatState;
use lpmsplat::train::config::TrainConfig;
use lpmsplat::train::density::{
    DensifyArgs, DensifyPhase, DensityConfig, DensityControl, DECIDE_REMOVE,
};
use lpmsplat::train::passes::spacetime_settings::{LaterCulls, WorldCulls};
use lpmsplat::train::passes::world_culls::{for_scene, CullEvent};
use lpmsplat::train::trainer::Trainer;
use rand::{Rng, SeedableRng};

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn fixture() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny")
}

/// Every row of `a` and `b` equal bit for bit (parameters and extra groups).
fn assert_same(a: &GaussianParams, b: &GaussianParams, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: count");
    let bits = |p: &GaussianParams| {
        let mut v: Vec<u32> = Vec::new();
        v.extend(p.positions.iter().flatten().map(|x| x.to_bits()));
        v.extend(p.log_scales.iter().flatten().map(|x| x.to_bits()));
        v.extend(p.rotations.iter().flatten().map(|x| x.to_bits()));
        v.extend(p.opacity_logits.iter().map(|x| x.to_bits()));
        v.extend(p.sh_dc.iter().flatten().map(|x| x.to_bits()));
        v.extend(p.sh_rest.iter().map(|x| x.to_bits()));
        for e in &p.extra {
            v.extend(e.values.iter().map(|x| x.to_bits()));
        }
        v
    };
    assert!(bits(a) == bits(b), "{what}: rows differ");
}

#[test]
fn the_box_cull_removes_exactly_the_gaussians_outside_and_carries_every_buffer() {
    let ctx = ctx();
    let n = 3000;
    let finite =
        BaseModel::SpacetimeLite.initialise(random_init(n, [0.0; 3], [1.0; 3], 0, 0).unwrap(), 3);
    let mut p = finite.clone();
    let (lo, hi) = ([-0.5, f32::NEG_INFINITY, -0.25], [0.5, 0.75, f32::INFINITY]);
    for (i, q) in p.positions.iter_mut().enumerate() {
        // Centres on the bounds (kept: the comparisons are strict) and non-finite ones (a
        // diverged Gaussian: NaN is kept, as the official masks keep it; written into the
        // buffer below, since an upload refuses them) besides the random ones.
        match i % 50 {
            0 => *q = [lo[0], 0.0, 0.0],
            1 => *q = [0.0, hi[1], 0.0],
            2 => *q = [0.0, 0.0, f32::NAN],
            3 => *q = [f32::NEG_INFINITY, 0.0, 0.0],
            _ => {}
        }
    }
    let moments = |seed: u64| {
        let mut m = p.clone();
        let mut r = rand_pcg::Pcg64::seed_from_u64(seed);
        for q in m.positions.iter_mut() {
            *q = [r.gen(), r.gen(), r.gen()];
        }
        for o in m.opacity_logits.iter_mut() {
            *o = r.gen();
        }
        m
    };
    let (m, v) = (moments(7), moments(8));
    let cap = n + 100;
    let mut state = SplatState {
        params: GpuSplats::upload(&ctx, &finite, cap).unwrap(),
        m: GpuSplats::upload(&ctx, &m, cap).unwrap(),
        v: GpuSplats::upload(&ctx, &v, cap).unwrap(),
    };
    let flat: Vec<f32> = p.positions.iter().flatten().copied().collect();
    state.params.positions.upload(&flat).unwrap();
    let mut dc = DensityControl::new(&ctx, cap, DensityConfig::default()).unwrap();
    // Poisoned decisions: the kernel must write every one.
    dc.decisions().upload(&vec![0xDEAD_BEEF; cap]).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    dc.record_prune_outside(&mut rec, &state, lo, hi).unwrap();
    rec.submit_and_wait().unwrap();
    let got = dc.decisions().read_range(0, n).unwrap();
    let want = prune_outside_box(&p.positions, lo, hi);
    assert_eq!(got, want);
    let removed = want.iter().filter(|&&d| d == DECIDE_REMOVE).count();
    assert!(removed > n / 4 && removed < 3 * n / 4, "{removed} of {n}");
    assert_eq!(want[2], 0, "a NaN centre is kept");
    assert_eq!(want[0], 0, "a centre on the lower bound is kept");
    assert_eq!(want[1], 0, "a centre on the upper bound is kept");
    assert_eq!(want[3], DECIDE_REMOVE, "−∞ is below every finite bound");
    // Applied like any prune: parameters, both moments and the extra groups follow.
    rec.begin().unwrap();
    let args = DensifyArgs {
        extent: 1.0,
        prune_large: false,
        iteration: 100,
        phase: DensifyPhase::PruneOnly,
    };
    let out = dc.apply(&mut rec, &mut state, &args).unwrap();
    rec.submit_and_wait().unwrap();
    assert_eq!(out.after, n - removed);
    assert_eq!((out.clones, out.split_children), (0, 0));
    assert_same(
        &state.params.download().unwrap(),
        &kept_rows(&p, &want),
        "params",
    );
    assert_same(&state.m.download().unwrap(), &kept_rows(&m, &want), "m");
    assert_same(&state.v.download().unwrap(), &kept_rows(&v, &want), "v");
    ctx.check_validation().unwrap();
}

#[test]
fn the_official_scenes_are_recognised_by_folder_beside_their_poses() {
    let dir = tempfile::tempdir().unwrap();
    for (name, poses, want) in [
        ("cook_spinach", true, Some(true)),
        ("sear_steak_r2", true, Some(true)),
        ("coffee_martini", true, Some(false)),
        ("flame_salmon_1", true, Some(false)),
        ("my_kitchen", true, None),
        ("flame_steak", false, None),
    ] {
        let root = dir.path().join(name);
        std::fs::create_dir_all(&root).unwrap();
        if poses {
            std::fs::write(root.join("poses_bounds.npy"), b"").unwrap();
        }
        assert_eq!(for_scene(&root), want, "{name}");
    }
    assert_eq!(
        for_scene(&fixture()),
        None,
        "the bundled fixture is not N3DV's world"
    );
}

fn culls_of(report: &lpmsplat::train::trainer::StepReport) -> Vec<(u32, String, usize)> {
    report
        .model_events
        .iter()
        .filter_map(|e| e.as_any().downcast_ref::<CullEvent>())
        .flat_map(|e| e.culls.iter())
        .map(|c| (c.iteration, c.cull.to_string(), c.removed))
        .collect()
}

#[test]
fn training_culls_before_after_densification_and_outside_the_initial_box() {
    let ctx = ctx();
    let scene = Scene::load(&fixture(), &LoadOptions::default()).unwrap();
    let images = images::load_images(&scene, &scene.train).unwrap();
    let (center, half) = scene.random_init_box();
    let init =
        BaseModel::SpacetimeLite.initialise(random_init(1500, center, [half; 3], 0, 0).unwrap(), 0);
    // A threshold inside the fixture's points (N3DV's 4.5 would remove all of them).
    let mut zs: Vec<f32> = init.positions.iter().map(|p| p[2]).collect();
    zs.sort_by(f32::total_cmp);
    let below_z = zs[zs.len() / 3] as f64;
    // Given in the scene's own units, as a user (or the official config) gives it.
    let user_below_z = scene.frame.to_user([0.0, 0.0, below_z])[2];
    let mut cfg = TrainConfig {
        iterations: 40,
        ..Default::default()
    };
    BaseModel::SpacetimeLite.configure(&mut cfg);
    cfg.schedule.densify_from = 5;
    cfg.schedule.densify_until = 20;
    cfg.schedule.interval = 5;
    let later = LaterCulls {
        from: 20,
        every: 10,
        offset: 5,
        box_at: 30,
    };
    let mut st = *cfg
        .model_settings::<lpmsplat::train::passes::spacetime::SpacetimeTraining>()
        .unwrap();
    st.guided = None;
    st.omega_freeze = None;
    st.world_culls = Some(WorldCulls {
        below_z: user_below_z,
        later: Some(later),
    });
    cfg.set_model(st);
    let mut t = Trainer::new(&ctx, &scene, &images, &init, cfg.clone()).unwrap();
    let below = init
        .positions
        .iter()
        .filter(|p| (p[2] as f64) < below_z)
        .count();
    assert_eq!(
        t.state.count(),
        init.len() - below,
        "the cull before training"
    );
    let first = t.step().unwrap();
    assert_eq!(culls_of(&first), vec![(0, "z".to_string(), below)]);
    let mut seen = Vec::new();
    let mut checkpoint = None;
    while t.iteration < 40 {
        let r = t.step().unwrap();
        let culls = culls_of(&r);
        let now = t.state.params.download().unwrap();
        match t.iteration {
            25 | 35 => {
                assert_eq!(culls.len(), 1, "iteration {}: {culls:?}", t.iteration);
                assert!(
                    now.positions.iter().all(|p| (p[2] as f64) >= below_z),
                    "iteration {}: a Gaussian below the threshold survived",
                    t.iteration
                );
            }
            30 => {
                assert_eq!(culls.len(), 1, "iteration 30: {culls:?}");
                // The box of the initial model before the z cull.
                for a in 0..3 {
                    let lo = init
                        .positions
                        .iter()
                        .map(|p| p[a])
                        .fold(f32::INFINITY, f32::min);
                    let hi = init
                        .positions
                        .iter()
                        .map(|p| p[a])
                        .fold(f32::NEG_INFINITY, f32::max);
                    assert!(
                        now.positions.iter().all(|p| p[a] >= lo && p[a] <= hi),
                        "axis {a}: a Gaussian outside the initial box survived"
                    );
                }
            }
            i => assert!(culls.is_empty(), "iteration {i}: {culls:?}"),
        }
        seen.extend(culls);
        if t.iteration == 27 {
            checkpoint = Some(t.checkpoint(&scene).unwrap());
        }
    }
    let kinds: Vec<(u32, &str)> = seen.iter().map(|c| (c.0, c.1.as_str())).collect();
    assert_eq!(kinds, vec![(25, "z"), (30, "box"), (35, "z")]);
    // A resumed run keeps the original box and does not cull its model again on setup.
    let ck = checkpoint.unwrap();
    let r = Trainer::restore(&ctx, &scene, &images, cfg, &ck, std::path::Path::new("ck")).unwrap();
    assert_eq!(r.state.count(), ck.count as usize);
    let states = |t: &Trainer| {
        t.model_rule_states()
            .into_iter()
            .find(|(n, _)| *n == "world_culls")
            .map(|(_, s)| s)
            .unwrap()
    };
    let bound = |f: fn(f32, f32) -> f32, start: f32| {
        [0, 1, 2].map(|a| init.positions.iter().map(|p| p[a]).fold(start, f))
    };
    assert_eq!(
        states(&t)["lo"],
        serde_json::json!(bound(f32::min, f32::INFINITY))
    );
    assert_eq!(
        states(&t)["hi"],
        serde_json::json!(bound(f32::max, f32::NEG_INFINITY))
    );
    assert_eq!(states(&r)["lo"], states(&t)["lo"]);
    assert_eq!(states(&r)["hi"], states(&t)["hi"]);
    ctx.check_validation().unwrap();
}

fn cli_train(scene: &std::path::Path, extra: &[&str], out: &std::path::Path) -> (bool, String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_lpmsplat"))
        .env("LPMSPLAT_VALIDATION", "1")
        .arg("train")
        .arg(scene)
        .args(["--init-points", "500", "--iterations", "2", "-o"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

#[test]
fn cli_turns_the_culls_on_for_an_official_scene_and_explains_a_foreign_world() {
    let dir = tempfile::tempdir().unwrap();
    // The fixture under an official scene's name: `auto` applies mode 1, whose z threshold
    // removes every point of this world, which is refused with the fix.
    let scene = dir.path().join("cook_spinach");
    std::fs::create_dir_all(&scene).unwrap();
    for e in std::fs::read_dir(fixture()).unwrap().flatten() {
        let to = scene.join(e.file_name());
        if e.path().is_dir() {
            std::fs::create_dir_all(&to).unwrap();
            for f in std::fs::read_dir(e.path()).unwrap().flatten() {
                std::fs::copy(f.path(), to.join(f.file_name())).unwrap();
            }
        } else {
            std::fs::copy(e.path(), &to).unwrap();
        }
    }
    let out = dir.path().join("out");
    let (ok, text) = cli_train(&scene, &["--model", "spacetime-lite"], &out);
    assert!(
        !ok && text.contains("world z below 4.5") && text.contains("--n3dv-culls off"),
        "{text}"
    );
    let (ok, text) = cli_train(
        &scene,
        &["--model", "spacetime-lite", "--n3dv-culls", "off"],
        &out,
    );
    assert!(ok, "{text}");
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert!(config["model_settings"].get("world_culls").is_none());
    // A still model has no such rule.
    let (ok, text) = cli_train(&fixture(), &["--n3dv-culls", "official"], &out);
    assert!(
        !ok && text.contains("spacetime models only") && text.contains("Fix"),
        "{text}"
    );
}
