//! SpacetimeGaussians' guided error sampling (`train::passes::guided_sampling`): the seed
//! pixels of hand-made error patterns (patches, the even-pixel skip, the border, patches cut by
//! a misaligned error), points on the seeds' rays at the jittered depths, the view depth as the
//! largest median depth of the reference render, and the whole rule through the trainer on the
//! video fixture (choice, sampling, the new rows, checkpoint state, the same run a step ahead).
//! Validation layer on.

use crate::child_run;

use std::path::Path;
use std::sync::Arc;

use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::models::BaseModel;
use lpmsplat::scene::{images, LoadOptions, Scene};
use lpmsplat::splats::{random_init, ExtraGroup, ExtraValues, GaussianParams, SH_C0};
use lpmsplat::train::passes::guided_sampling::{error_seeds, ray_points, view_depths};
use lpmsplat::train::passes::spacetime_settings::GuidedSamplingSettings;
use lpmsplat::train::trainer::{TrainConfig, Trainer};
use rand::SeedableRng;

fn fixture() -> Scene {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    Scene::load(&dir, &LoadOptions::default()).unwrap()
}

/// A black `w × h` render and truth, the truth grey (0.5) on the pixels `inside` says.
fn pattern(w: u32, h: u32, inside: impl Fn(u32, u32) -> bool) -> (Vec<f32>, Vec<f32>) {
    let render = vec![0.0; (3 * w * h) as usize];
    let mut truth = render.clone();
    for y in 0..h {
        for x in 0..w {
            if inside(x, y) {
                let k = 3 * (y * w + x) as usize;
                truth[k..k + 3].copy_from_slice(&[0.5; 3]);
            }
        }
    }
    (render, truth)
}

#[test]
fn seeds_are_the_odd_pixels_of_whole_error_patches_away_from_the_border() {
    let s = GuidedSamplingSettings::default();
    // One whole 16×16 patch of error (x, y in 16..32): every pixel but the 64 with both
    // coordinates even.
    let (r, g) = pattern(64, 48, |x, y| {
        (16..32).contains(&x) && (16..32).contains(&y)
    });
    let seeds = error_seeds(&r, &g, 64, 48, &s);
    assert_eq!(seeds.len(), 256 - 64);
    assert!(seeds.iter().all(|&[x, y]| (16..32).contains(&x)
        && (16..32).contains(&y)
        && (x % 2 == 1 || y % 2 == 1)));
    // Row-major order.
    assert!(seeds
        .windows(2)
        .all(|p| (p[0][1], p[0][0]) < (p[1][1], p[1][0])));
    // The same amount of error across four patches (64 pixels each, under 85 %): no seed.
    let (r, g) = pattern(64, 48, |x, y| (8..24).contains(&x) && (8..24).contains(&y));
    assert!(error_seeds(&r, &g, 64, 48, &s).is_empty());
    // A patch at the left edge: the tenth of the width (6 px) and height (4 px) is left out.
    let (r, g) = pattern(64, 48, |x, y| x < 16 && (16..32).contains(&y));
    let seeds = error_seeds(&r, &g, 64, 48, &s);
    assert!(!seeds.is_empty() && seeds.iter().all(|&[x, _]| x >= 6));
    assert_eq!(
        seeds.len(),
        10 * 16 - 5 * 8,
        "x 6..16: 10 columns, 5 of them even"
    );
    // 85 % is a strict bound: 217 error pixels of 256 keep no patch, 218 do.
    for (n, kept) in [(217usize, false), (218, true)] {
        let (r, g) = pattern(64, 48, |x, y| {
            (16..32).contains(&x) && (16..32).contains(&y) && ((y - 16) * 16 + (x - 16)) < n as u32
        });
        assert_eq!(
            !error_seeds(&r, &g, 64, 48, &s).is_empty(),
            kept,
            "{n} error pixels"
        );
    }
    // The quantile: with error everywhere (two levels), only the upper 40 % are error pixels.
    let (w, h) = (64u32, 48u32);
    let render = vec![0.0f32; (3 * w * h) as usize];
    let mut truth = render.clone();
    for y in 0..h {
        for x in 0..w {
            let v = if y < 16 { 0.9 } else { 0.1 };
            truth[(3 * (y * w + x)) as usize..(3 * (y * w + x) + 3) as usize].fill(v);
        }
    }
    let seeds = error_seeds(&render, &truth, w, h, &s);
    assert!(
        !seeds.is_empty() && seeds.iter().all(|&[_, y]| y < 16),
        "{seeds:?}"
    );
    // Too small for a border (under ten pixels): the official slicing keeps nothing.
    let (r, g) = pattern(16, 9, |_, _| true);
    assert!(error_seeds(&r, &g, 16, 9, &s).is_empty());
}

#[test]
fn points_lie_on_the_seed_rays_at_the_jittered_depths() {
    let scene = fixture();
    let v = &scene.views[scene.train[3]];
    let seeds = [[3u32, 5u32], [40, 20], [63, 47]];
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let depth = 2.5;
    let pts = ray_points(
        &v.camera,
        &v.pose,
        &seeds,
        depth,
        &[0.7, 7.5],
        0.1,
        &mut rng,
    );
    assert_eq!(pts.len(), 6);
    for (i, p) in pts.iter().enumerate() {
        let [x, y] = seeds[i % 3];
        let r = if i < 3 { 0.7 } else { 7.5 };
        let c = v.pose.transform(*p);
        assert!(
            c[2] >= depth * r * 0.95 - 1e-9 && c[2] <= depth * r * 1.05 + 1e-9,
            "point {i}: depth {} for {}",
            c[2],
            depth * r
        );
        let uv = v.camera.project(c);
        assert!(
            (uv[0] - (x as f64 + 0.5)).abs() < 1e-9 && (uv[1] - (y as f64 + 0.5)).abs() < 1e-9,
            "point {i} projects to {uv:?}, not pixel {x},{y}'s centre"
        );
    }
    // The jitter differs point to point.
    let d: Vec<f64> = pts.iter().map(|p| v.pose.transform(*p)[2]).collect();
    assert!(d[0] != d[1] && d[1] != d[2]);
}

fn blob(p: &mut GaussianParams, at: [f64; 3], scale: f32, opacity: f64) {
    p.positions.push(at.map(|v| v as f32));
    p.log_scales.push([scale.ln(); 3]);
    p.rotations.push([1.0, 0.0, 0.0, 0.0]);
    p.opacity_logits
        .push((opacity / (1.0 - opacity)).ln() as f32);
    p.sh_dc.push([(0.5 / SH_C0) as f32; 3]);
}

/// The view depth is the largest median depth of the engine's render (f32 camera depths), for
/// a still model as for a video model at a time; a view of faint blobs has none. The median
/// depth pass itself is held to the f64 reference in tests/gpu/forward.rs.
#[test]
fn view_depth_is_the_largest_median_depth() {
    let ctx = ctx();
    let scene = fixture();
    let v = &scene.views[scene.train[0]];
    let view = [(v.camera, v.pose)];
    let world = |x: f64, y: f64, z: f64| v.pose.inverse_transform([x, y, z]);
    let near = |d: Option<f64>, want: f64| d.is_some_and(|d| (d - want).abs() < 1e-5 * want);
    // One opaque blob straight ahead at depth 3, another at depth 6 off to the side.
    let mut p = GaussianParams::empty(0);
    blob(&mut p, world(0.0, 0.0, 3.0), 0.3, 0.99);
    let one = view_depths(&ctx, &p, 0.0, &view).unwrap();
    assert!(near(one[0], 3.0), "{one:?}");
    blob(&mut p, world(2.0, 0.0, 6.0), 0.6, 0.99);
    // The same view twice: one depth each.
    let two = view_depths(&ctx, &p, 0.0, &[view[0], view[0]]).unwrap();
    assert!(
        two.len() == 2 && two.iter().all(|&d| near(d, 6.0)),
        "{two:?}"
    );
    // Faint blobs never take a pixel below ½ transmittance: no depth.
    let mut faint = GaussianParams::empty(0);
    blob(&mut faint, world(0.0, 0.0, 3.0), 0.3, 0.3);
    assert_eq!(view_depths(&ctx, &faint, 0.0, &view).unwrap(), vec![None]);
    // A video model is drawn at the time asked for: a blob at depth 3 whose motion carries it
    // to depth 5 at t = 1 (m₁ along the camera's z in world coordinates).
    let mut video = GaussianParams::empty(0);
    blob(&mut video, world(0.0, 0.0, 3.0), 0.3, 0.99);
    let dz = {
        let a = world(0.0, 0.0, 3.0);
        let b = world(0.0, 0.0, 5.0);
        [0, 1, 2].map(|c| (b[c] - a[c]) as f32)
    };
    let mut motion = vec![0.0f32; 9];
    motion[..3].copy_from_slice(&dz);
    // A temporal log-scale of 10 keeps the blob opaque at every time in [0, 1].
    video.extra = [
        ("motion", motion),
        ("omega", vec![0.0; 4]),
        ("trbf_center", vec![0.0]),
        ("trbf_scale", vec![10.0]),
    ]
    .into_iter()
    .map(|(name, values)| ExtraValues {
        group: ExtraGroup::new(name, values.len()),
        values,
    })
    .collect();
    ctx.check_validation().unwrap();
    let at = |t: f64| view_depths(&ctx, &video, t, &view).unwrap()[0];
    assert!(near(at(0.0), 3.0), "{:?}", at(0.0));
    assert!(near(at(1.0), 5.0), "{:?}", at(1.0));
    ctx.check_validation().unwrap();
}

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn extra<'a>(p: &'a GaussianParams, name: &str) -> &'a [f32] {
    p.extra_values(name).expect("the model has the group")
}

/// The last `added` rows of `m`, just added: centres uniform in [0, 1), no motion or spin,
/// temporal log-scale 0, opacity 0.1, identity rotation, isotropic positive scale.
fn new_rows_are_official(m: &GaussianParams, added: usize) {
    let first = m.len() - added;
    let centres = &extra(m, "trbf_center")[first..];
    assert!(
        centres.iter().all(|c| (0.0..1.0).contains(c)),
        "{centres:?}"
    );
    if added >= 20 {
        let mean = centres.iter().sum::<f32>() / added as f32;
        assert!(
            (0.2..0.8).contains(&mean),
            "centres not spread: mean {mean}"
        );
    }
    assert!(extra(m, "motion")[9 * first..].iter().all(|&v| v == 0.0));
    assert!(extra(m, "omega")[4 * first..].iter().all(|&v| v == 0.0));
    assert!(extra(m, "trbf_scale")[first..].iter().all(|&v| v == 0.0));
    let logit = (0.1f64 / 0.9).ln() as f32;
    for i in first..m.len() {
        assert!((m.opacity_logits[i] - logit).abs() < 1e-6);
        assert_eq!(m.rotations[i], [1.0, 0.0, 0.0, 0.0]);
        let l = m.log_scales[i];
        assert!(
            l[0] == l[1] && l[1] == l[2] && (-10.0..=1.0).contains(&l[0]),
            "{l:?}"
        );
    }
}

/// SpacetimeGaussians lite on the fixture for 60 iterations, with no density steps and a
/// guided sampling that starts early, gates every camera and samples twice.
fn sampling_config() -> TrainConfig {
    let mut cfg = TrainConfig {
        iterations: 60,
        seed: 9,
        ..TrainConfig::default()
    };
    BaseModel::SpacetimeLite.configure(&mut cfg);
    // No density steps: every new row comes from the sampler.
    cfg.schedule.densify_from = 10_000;
    cfg.schedule.densify_until = 10_000;
    let mut st = *cfg
        .model_settings::<lpmsplat::train::passes::spacetime::SpacetimeTraining>()
        .unwrap();
    // Gates every camera passes, an early start and short gap, smaller and laxer patches (a
    // 64×48 image holds few 16-pixel patches of 85 % error).
    st.guided = Some(GuidedSamplingSettings {
        from: 4,
        gap: 3,
        select_below: 2.0,
        sample_below: 2.0,
        patch: 8,
        patch_fraction: 0.5,
        ..GuidedSamplingSettings::default()
    });
    cfg.set_model(st);
    cfg
}

fn sampling_init(scene: &Scene) -> GaussianParams {
    let (center, half) = scene.random_init_box();
    BaseModel::SpacetimeLite.initialise(random_init(3_000, center, [half; 3], 4, 0).unwrap(), 4)
}

#[test]
fn the_trainer_chooses_two_cameras_and_adds_their_points() {
    let ctx = ctx();
    let scene = fixture();
    let gt = images::load_images(&scene, &scene.train).unwrap();
    let init = sampling_init(&scene);
    let mut t = Trainer::new(&ctx, &scene, &gt, &init, sampling_config()).unwrap();
    let states = t.model_rule_states();
    assert_eq!(states.len(), 1);
    assert_eq!(states[0].0, "guided_sampling");
    let depths = states[0].1["depth"].as_array().unwrap().clone();
    assert_eq!(depths.len(), 4, "four training cameras");
    assert!(
        depths.iter().all(|d| d.as_f64().is_some_and(|d| d > 0.0)),
        "{depths:?}"
    );

    let mut chosen = None;
    let mut sampled = Vec::new();
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("checkpoint.bin");
    let mut saved_state = None;
    for _ in 0..60 {
        let before = t.gaussians();
        let r = t.step().unwrap();
        for e in &r.model_events {
            let j = e.to_json();
            if let Some(c) = j.get("selected") {
                assert!(chosen.is_none(), "chosen twice");
                assert!(r.iteration >= 4);
                chosen = Some(c.as_array().unwrap().len());
                // Saved right after the choice: a resumed run keeps it.
                t.save_checkpoint(&scene, &ck).unwrap();
                saved_state = Some(t.model_rule_states()[0].1.clone());
            } else {
                let added = j["added"].as_u64().unwrap() as usize;
                assert_eq!(added, r.gaussians - before, "{j}");
                new_rows_are_official(&t.export_model().unwrap(), added);
                sampled.push(j);
            }
        }
    }
    assert_eq!(chosen, Some(2), "the two lowest-SSIM cameras");
    assert_eq!(sampled.len(), 2, "each chosen camera once: {sampled:?}");
    let added: u64 = sampled.iter().map(|j| j["added"].as_u64().unwrap()).sum();
    assert!(added > 0, "{sampled:?}");
    let gap = sampled[1]["iteration"].as_u64().unwrap() - sampled[0]["iteration"].as_u64().unwrap();
    assert!(gap > 3, "{sampled:?}");
    for j in &sampled {
        assert_eq!(
            j["added"].as_u64().unwrap(),
            2 * j["seeds"].as_u64().unwrap()
        );
    }

    // Trained on with the new rows: still finite.
    let m = t.export_model().unwrap();
    assert!(m.positions.iter().flatten().all(|v| v.is_finite()));

    // The state resumes: the checkpoint's sampler has the choice and depths.
    let resumed = Trainer::resume(&ctx, &scene, &gt, t.config.clone(), &ck).unwrap();
    assert_eq!(resumed.model_rule_states()[0].1, saved_state.unwrap());
    ctx.check_validation().unwrap();
}

/// The sampler's GPU work falls on steps the trainer asks it about beforehand
/// (`ModelRule::quiet_after`): training a step ahead (`Trainer::step_ahead`) samples at the same
/// iterations and ends bit for bit where plain steps end, with most steps prepared ahead.
#[test]
fn sampling_a_step_ahead_changes_nothing() {
    if child_run::rerun_single_threaded(module_path!(), "sampling_a_step_ahead_changes_nothing") {
        return;
    }
    let ctx = ctx();
    let scene = fixture();
    let gt = images::load_images(&scene, &scene.train).unwrap();
    let init = sampling_init(&scene);
    let run = |ahead: bool| {
        let mut t = Trainer::new(&ctx, &scene, &gt, &init, sampling_config()).unwrap();
        let mut events = Vec::new();
        for k in 1..=60 {
            let r = t.step_ahead(ahead && k < 60).unwrap();
            events.extend(r.model_events.iter().map(|e| e.to_json().to_string()));
        }
        let m = t.model().unwrap();
        let bits: Vec<u32> = m.positions.iter().flatten().map(|v| v.to_bits()).collect();
        (events, bits, t.recording)
    };
    let (plain, again, ahead) = (run(false), run(false), run(true));
    assert_eq!(
        plain.0.len(),
        3,
        "a choice and two samplings: {:?}",
        plain.0
    );
    // Every sampling was foreseen: nothing prepared had to be dropped.
    assert!(ahead.2.ahead >= 40 && ahead.2.dropped == 0, "{:?}", ahead.2);
    assert_eq!(plain.2.ahead, 0);
    if plain.1 == again.1 {
        assert_eq!(plain.0, ahead.0, "the sampler's events differ");
        assert!(plain.1 == ahead.1, "the models differ");
    } else {
        // A driver that ignores LP_NUM_THREADS: the same events at least.
        assert!(
            !ctx.info.device_type.starts_with("CPU"),
            "{}",
            ctx.info.name
        );
        assert_eq!(plain.0.len(), ahead.0.len());
    }
    ctx.check_validation().unwrap();
}

fn cli_train(extra_args: &[&str], out: &Path) -> std::process::Output {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    std::process::Command::new(env!("CARGO_BIN_EXE_lpmsplat"))
        .env("LPMSPLAT_VALIDATION", "1")
        .arg("train")
        .arg(&fixture)
        .args(["--init-points", "1000", "-o"])
        .arg(out)
        .args(extra_args)
        .output()
        .unwrap()
}

#[test]
fn cli_guided_sampling_reports_its_choice_and_can_be_turned_off() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("on");
    let o = cli_train(
        &[
            "--model",
            "spacetime-lite",
            "--iterations",
            "120",
            "--guided-from",
            "3",
        ],
        &out,
    );
    let text = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{text}");
    assert!(text.contains("guided sampling: "), "{text}");
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    let events = m["model_events"].as_array().unwrap();
    assert!(
        events[0]["rule"] == "guided_sampling" && events[0]["selected"].is_array(),
        "{events:?}"
    );
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["model_settings"]["guided_sampling"]["from"], 3);
    // The official schedule's end of densification, and no N3DV culls on the fixture's world.
    assert_eq!(config["density"]["densify_until"], 9000);
    assert!(config["model_settings"].get("world_culls").is_none());

    let off = dir.path().join("off");
    let o = cli_train(
        &[
            "--model",
            "spacetime-lite",
            "--iterations",
            "20",
            "--guided-sampling",
            "off",
        ],
        &off,
    );
    assert!(o.status.success());
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(off.join("config.json")).unwrap()).unwrap();
    assert!(config["model_settings"]["guided_sampling"].is_null());
    // Only for the video model.
    let o = cli_train(&["--guided-sampling", "off", "--iterations", "5"], &off);
    let text = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(
        !o.status.success()
            && text.contains(
                "--guided-sampling applies to --model spacetime-lite or spacetime-full only"
            ),
        "{text}"
    );
}
