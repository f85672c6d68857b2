//! The trainer end to end on lavapipe-sized problems: fitting a fixed set of Gaussians to
//! renders of a known model, exact resume from a checkpoint, bad checkpoints and outputs, the
//! NaN check, and the `train` / `eval` subcommands on a tiny run (including Ctrl-C).
//!
//! Scenes: `tests/data/lego_small` (100×100, 8 train + 3 val views). Validation layer on.

use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::scene::{images, Image, LoadOptions, Scene};
use lpmsplat::splats::{init::random_init, read_ply, ExtraGroup, GaussianParams};
use lpmsplat::train::checkpoint::{Checkpoint, FORMAT_VERSION};
use lpmsplat::train::nan_check::NonFiniteCheck;
use lpmsplat::train::schedule::LearningRates;
use lpmsplat::train::trainer::{Background, TrainConfig, Trainer};
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn lego() -> Scene {
    Scene::load(&data("lego_small"), &LoadOptions::default()).unwrap()
}

/// A random model inside lego's ±1.3 box, opaque enough to cover the views.
fn ground_truth_model(seed: u64, n: usize) -> GaussianParams {
    let mut p = random_init(n, [0.0; 3], [0.9; 3], seed, 0).unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x51);
    for o in &mut p.opacity_logits {
        *o = rng.gen_range(0.5..3.0);
    }
    // Colours away from 0, where the SH-to-colour clamp would cut the gradient.
    for c in p.sh_dc.iter_mut().flatten() {
        *c = (rng.gen_range(0.2..0.8) - 0.5) / SH_C0;
    }
    p
}

/// Learning rates of zero: steps then only measure the loss.
fn frozen() -> LearningRates {
    LearningRates {
        position_init: 0.0,
        position_final: 0.0,
        scaling: 0.0,
        rotation: 0.0,
        opacity: 0.0,
        sh_dc: 0.0,
        sh_rest: 0.0,
        ..LearningRates::default()
    }
}

const SH_C0: f32 = 0.282_094_8;

/// No densification, no opacity reset: the Gaussian set stays fixed.
fn fixed_config(iterations: u32) -> TrainConfig {
    let mut c = TrainConfig {
        iterations,
        seed: 7,
        sh_degree: 0,
        background: Background::Fixed([0.0; 3]),
        ..TrainConfig::default()
    };
    c.schedule.densify_until = 0;
    c.schedule.densify_from = 0;
    // Faster colour and opacity rates than the reference's so a few dozen steps converge.
    c.lr.sh_dc = 0.04;
    c.lr.opacity = 0.1;
    c
}

/// Renders `model` from every training view of `scene` (the ground truth of the fit test).
fn render_training_views(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    model: &GaussianParams,
) -> Vec<Image> {
    let placeholder = images::load_images(scene, &scene.train).unwrap();
    let mut t = Trainer::new(ctx, scene, &placeholder, model, fixed_config(1)).unwrap();
    scene
        .train
        .iter()
        .map(|&v| {
            let cam = &scene.views[v].camera;
            Image {
                width: cam.width,
                height: cam.height,
                rgb: t
                    .render_view(v, [0.0; 3])
                    .unwrap()
                    .iter()
                    .map(|x| x.clamp(0.0, 1.0))
                    .collect(),
                alpha: None,
            }
        })
        .collect()
}

fn perturb(model: &GaussianParams, seed: u64) -> GaussianParams {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut p = model.clone();
    for c in p.sh_dc.iter_mut().flatten() {
        let colour = (0.5 + SH_C0 * *c + rng.gen_range(-0.35..0.35)).clamp(0.05, 0.95);
        *c = (colour - 0.5) / SH_C0;
    }
    for o in &mut p.opacity_logits {
        *o += rng.gen_range(-1.5..1.5);
    }
    for x in p.positions.iter_mut().flatten() {
        *x += rng.gen_range(-0.01..0.01);
    }
    p
}

/// Fits a perturbed copy of a random model to renders of the model: one frozen epoch (all
/// learning rates 0) measures the start, 7 epochs train, 4 more at a tenth of the rates, and a
/// frozen epoch measures the end. Measured on lavapipe: 0.09 → 0.0062 (loss), 40.8 dB.
#[test]
fn fitting_fixed_gaussians_lowers_the_loss_tenfold() {
    let ctx = ctx();
    let scene = lego();
    let truth = ground_truth_model(11, 400);
    let gt = render_training_views(&ctx, &scene, &truth);
    let start = perturb(&truth, 12);
    let n = scene.train.len() as u32;
    let epochs = 13;
    let mut t = Trainer::new(&ctx, &scene, &gt, &start, fixed_config(epochs * n)).unwrap();
    let training = t.config.lr;
    let mut annealed = training;
    for r in [
        &mut annealed.position_init,
        &mut annealed.position_final,
        &mut annealed.sh_dc,
        &mut annealed.opacity,
        &mut annealed.scaling,
        &mut annealed.rotation,
    ] {
        *r /= 10.0;
    }
    let mut epoch_loss = Vec::new();
    for e in 0..epochs {
        t.config.lr = match e {
            0 => frozen(),
            e if e == epochs - 1 => frozen(),
            e if e >= 8 => annealed,
            _ => training,
        };
        let mut sum = 0.0;
        for _ in 0..n {
            let r = t.step().unwrap();
            assert!(r.densified.is_none());
            assert_eq!(r.gaussians, truth.len());
            sum += r.loss;
        }
        epoch_loss.push(sum / n as f32);
    }
    let (first, last) = (epoch_loss[0], *epoch_loss.last().unwrap());
    eprintln!("loss per epoch {epoch_loss:?}: ratio {:.1}", first / last);
    assert!(
        first >= 10.0 * last,
        "the loss fell only from {first} to {last}"
    );
    // The views come to the callback in order, each render the truth's size.
    let mut seen = Vec::new();
    let metrics = t
        .evaluate(&scene, &scene.train, &gt, |k, m, render, truth| {
            assert_eq!(render.len(), truth.rgb.len());
            assert_eq!(m.view, scene.views[scene.train[k]].name);
            seen.push(k);
            Ok(())
        })
        .unwrap();
    assert_eq!(seen, (0..scene.train.len()).collect::<Vec<_>>());
    let psnr = metrics.iter().map(|m| m.psnr).sum::<f64>() / metrics.len() as f64;
    eprintln!("PSNR against the ground-truth renders: {psnr:.2} dB");
    assert!(psnr >= 37.0, "PSNR {psnr} dB after the fit");
    ctx.check_validation().unwrap();
}

/// The parameters and moments of a checkpoint file.
fn checkpoint_floats(path: &Path) -> Vec<f32> {
    let ck = Checkpoint::read(path).unwrap();
    ck.sets
        .iter()
        .flatten()
        .chain(ck.stats.iter())
        .flatten()
        .copied()
        .collect()
}

/// `train` on lego_small under one lavapipe thread (identical runs are bitwise equal): 300
/// random initial points at SH degree `sh`, densifying every 5 iterations from 2 with a low
/// threshold, so a few iterations grow the model.
fn densifying_lego_run(sh: u32) -> Command {
    let mut c = lpmsplat();
    c.env("LP_NUM_THREADS", "1")
        .arg("train")
        .arg(data("lego_small"))
        .args(["--init-points", "300", "--sh-degree", &sh.to_string()])
        .args(["--densify-from", "2", "--densify-interval", "5"])
        .args(["--densify-grad-threshold", "0.000002"]);
    c
}

/// N iterations straight against N/2, checkpoint, resume, N/2, with densification (a densify
/// step falls after the resume and uses the statistics the checkpoint carried).
///
/// Determinism: lavapipe runs workgroups on several threads, so the float atomics of the
/// backward pass sum in a varying order and two identical runs differ from the first
/// iteration on (measured: thousands of differing words after one step). With
/// `LP_NUM_THREADS=1` it runs them in order, and identical runs are bitwise equal; the test
/// runs the CLI that way and then demands a bitwise-equal resume. On a device where even that
/// is not reproducible it falls back to: resumed-vs-straight differs no more than
/// straight-vs-straight (×4).
#[test]
fn resume_continues_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, iterations: u32, resume: bool| {
        let out = dir.path().join(name);
        let mut c = densifying_lego_run(0);
        c.args(["--iterations", &iterations.to_string(), "-o"])
            .arg(&out);
        if resume {
            c.arg("--resume").arg(out.join("checkpoint.bin"));
        }
        run_ok(&mut c);
        out.join("checkpoint.bin")
    };
    let a = checkpoint_floats(&run("a", 12, false));
    let b = checkpoint_floats(&run("b", 12, false));
    run("c", 6, false);
    let mid = Checkpoint::read(&dir.path().join("c/checkpoint.bin")).unwrap();
    assert!(
        mid.stats[1].iter().any(|&d| d > 0.0),
        "no statistics in flight"
    );
    let c = checkpoint_floats(&run("c", 12, true));
    let ck = Checkpoint::read(&dir.path().join("c/checkpoint.bin")).unwrap();
    assert_eq!(ck.iteration, 12);
    assert!(ck.count > 300, "the run never densified");
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    if bits(&a) == bits(&b) {
        assert!(
            bits(&a) == bits(&c),
            "a resumed run differs from a straight run"
        );
    } else {
        assert_eq!(a.len(), c.len(), "resumed and straight runs differ in size");
        let diff = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0, f32::max)
        };
        let (noise, got) = (diff(&a, &b), diff(&a, &c));
        eprintln!("straight runs differ by {noise:e}, resumed by {got:e}");
        assert!(got <= 4.0 * noise, "resume differs by {got}, noise {noise}");
    }
}

/// `train --record-ahead on` (the default) and `off` train the same model, bit for bit under one
/// lavapipe thread, with an evaluation and a checkpoint in between (where nothing is prepared);
/// metrics.json says how many iterations were recorded ahead, and the --timestamps table says
/// so too.
#[test]
fn record_ahead_on_and_off_train_the_same_model() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, ahead: &str| {
        let out = dir.path().join(name);
        let mut c = densifying_lego_run(1);
        c.args([
            "--iterations",
            "16",
            "--eval-every",
            "8",
            "--checkpoint-every",
            "6",
        ])
        .args(["--timestamps", "--record-ahead", ahead, "-o"])
        .arg(&out);
        let text = run_ok(&mut c);
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap())
                .unwrap();
        (checkpoint_floats(&out.join("checkpoint.bin")), m, text)
    };
    let (on, m_on, text_on) = run("on", "on");
    let (off, m_off, text_off) = run("off", "off");
    let ahead = |m: &serde_json::Value| m["recording"]["ahead"].as_u64().unwrap();
    assert_eq!(m_on["recording"]["iterations"], 16);
    assert_eq!(ahead(&m_off), 0, "{}", m_off["recording"]);
    // Not after a densify step (5, 10, 15), an evaluation (8) or a checkpoint (6, 12), nor
    // before the snapshot of an evaluation (at 8, 16) or the end.
    assert!(ahead(&m_on) >= 4, "{}", m_on["recording"]);
    assert!(text_on.contains("recorded while the one before ran (--record-ahead on)"));
    assert!(text_off.contains("0 of 16 iterations recorded while the one before ran"));
    assert_eq!(on.len(), off.len());
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    if bits(&on) == bits(&off) {
        assert_eq!(m_on["psnr"], m_off["psnr"]);
    } else {
        // Only a driver that ignores LP_NUM_THREADS (a GPU's float atomics) may differ.
        let device = m_on["device"].as_str().unwrap_or_default();
        assert!(
            !device.contains("llvmpipe"),
            "on and off differ on {device}"
        );
    }
}

fn expect_err_contains(r: anyhow::Result<impl Sized>, parts: &[&str]) -> String {
    let msg = match r {
        Ok(_) => panic!("expected an error mentioning {parts:?}"),
        Err(e) => format!("{e:#}"),
    };
    for p in parts {
        assert!(msg.contains(p), "error '{msg}' does not mention '{p}'");
    }
    msg
}

#[test]
fn bad_checkpoints_give_clear_errors_and_destroy_nothing() {
    let ctx = ctx();
    let scene = lego();
    let images = images::load_images(&scene, &scene.train).unwrap();
    let init = ground_truth_model(31, 200);
    let mut t = Trainer::new(&ctx, &scene, &images, &init, fixed_config(10)).unwrap();
    for _ in 0..3 {
        t.step().unwrap();
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("checkpoint.bin");
    t.save_checkpoint(&scene, &path).unwrap();
    let good = std::fs::read(&path).unwrap();
    let p = path.display().to_string();

    // Saving into a folder that cannot exist fails and leaves the old checkpoint alone.
    let blocker = dir.path().join("a-file");
    std::fs::write(&blocker, b"x").unwrap();
    expect_err_contains(
        t.save_checkpoint(&scene, &blocker.join("checkpoint.bin")),
        &["a-file"],
    );
    assert_eq!(std::fs::read(&path).unwrap(), good);

    // Another scene: same views, another resolution; and another SH degree.
    let half = Scene::load(
        &data("lego_small"),
        &LoadOptions {
            resolution_factor: Some(2),
            ..LoadOptions::default()
        },
    )
    .unwrap();
    let half_images = images::load_images(&half, &half.train).unwrap();
    expect_err_contains(
        Trainer::resume(&ctx, &half, &half_images, fixed_config(10), &path),
        &[&p, "views[0].size", "Fix:"],
    );
    let mut deg1 = fixed_config(10);
    deg1.sh_degree = 1;
    expect_err_contains(
        Trainer::resume(&ctx, &scene, &images, deg1, &path),
        &[&p, "sh_degree", "Fix:"],
    );
    // Other settings.
    let mut other = fixed_config(10);
    other.lr.opacity = 0.01;
    expect_err_contains(
        Trainer::resume(&ctx, &scene, &images, other, &path),
        &[&p, "lr.opacity", "Fix:"],
    );

    // Corruptions: a flipped byte in the body, truncation, another version, not a checkpoint.
    let write = |bytes: &[u8]| {
        let q = dir.path().join("bad.bin");
        std::fs::write(&q, bytes).unwrap();
        q
    };
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let mut flipped = good.clone();
    let at = rng.gen_range(12..good.len() - 8);
    flipped[at] ^= 0x10;
    let q = write(&flipped);
    expect_err_contains(
        Trainer::resume(&ctx, &scene, &images, fixed_config(10), &q),
        &["bad.bin", "checksum", "Fix:"],
    );
    assert_eq!(
        std::fs::read(&q).unwrap(),
        flipped,
        "a failed resume changed the file"
    );
    let q = write(&good[..good.len() / 2]);
    expect_err_contains(Checkpoint::read(&q), &["bad.bin", "Fix:"]);
    let mut v2 = good.clone();
    v2[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    let q = write(&v2);
    expect_err_contains(Checkpoint::read(&q), &["bad.bin", "format version", "Fix:"]);
    let q = write(b"ply\nformat binary_little_endian 1.0\n");
    expect_err_contains(Checkpoint::read(&q), &["bad.bin", "magic", "Fix:"]);
    // Truncations at every field boundary region are caught (the hash covers the body; with a
    // recomputed hash, the parser itself must notice).
    for cut in [13usize, 40, 200, good.len() - 9] {
        expect_err_contains(Checkpoint::from_bytes(&path, &good[..cut]), &[&p, "Fix:"]);
    }
    // The original is intact and still resumes.
    assert_eq!(std::fs::read(&path).unwrap(), good);
    let r = Trainer::resume(&ctx, &scene, &images, fixed_config(10), &path).unwrap();
    assert_eq!(r.iteration, 3);
    ctx.check_validation().unwrap();
}

#[test]
fn checkpoint_round_trips_and_parser_rejects_inconsistent_lengths() {
    let ctx = ctx();
    let scene = lego();
    let images = images::load_images(&scene, &scene.train).unwrap();
    let init = ground_truth_model(41, 150);
    let mut t = Trainer::new(&ctx, &scene, &images, &init, fixed_config(5)).unwrap();
    t.step().unwrap();
    let ck = t.checkpoint(&scene).unwrap();
    let bytes = ck.to_bytes();
    let back = Checkpoint::from_bytes(Path::new("mem"), &bytes).unwrap();
    assert_eq!(back.to_bytes(), bytes);
    assert_eq!(back.count as usize, init.len());
    assert_eq!(back.iteration, 1);
    assert_eq!(back.adam_step, 1);
    // A count that disagrees with the arrays, with a valid hash: the parser names the field.
    let mut bad = ck.clone();
    bad.count += 1;
    let msg = format!(
        "{:#}",
        Checkpoint::from_bytes(Path::new("mem"), &bad.to_bytes()).unwrap_err()
    );
    assert!(msg.contains("params.positions"), "{msg}");
    // A model's extra groups travel with the checkpoint, named in its errors.
    let mut ex = ck.clone();
    let n = ex.count as usize;
    ex.fingerprint.extra = vec![ExtraGroup::new("motion", 9), ExtraGroup::new("t_center", 1)];
    for set in &mut ex.sets {
        set.push((0..9 * n).map(|i| i as f32 * 0.5).collect());
        set.push((0..n).map(|i| -(i as f32)).collect());
    }
    let back = Checkpoint::from_bytes(Path::new("mem"), &ex.to_bytes()).unwrap();
    let p = back.params();
    assert_eq!(p.extra.len(), 2);
    assert_eq!(p.extra[0].group, ExtraGroup::new("motion", 9));
    assert_eq!(p.extra[0].values, ex.sets[0][6]);
    assert_eq!(p.extra[1].values, ex.sets[0][7]);
    p.validate().unwrap();
    ex.sets[2][7].pop();
    let msg = format!(
        "{:#}",
        Checkpoint::from_bytes(Path::new("mem"), &ex.to_bytes()).unwrap_err()
    );
    assert!(msg.contains("adam v.t_center"), "{msg}");
    ctx.check_validation().unwrap();
}

#[test]
fn nan_check_names_group_and_gaussian() {
    let ctx = ctx();
    let scene = lego();
    let images = images::load_images(&scene, &scene.train).unwrap();
    let init = ground_truth_model(51, 500);
    let mut t = Trainer::new(&ctx, &scene, &images, &init, fixed_config(5)).unwrap();
    t.step().unwrap();
    let mut check = NonFiniteCheck::new(&ctx).unwrap();
    // One entry per stored buffer: five groups and the SH rest planes.
    assert_eq!(
        check.scan(&t.state.params).unwrap(),
        [None; 5 + lpmsplat::splats::sh_planes::PLANES]
    );
    check.check(&t.state.params, 1).unwrap();

    // Inject non-finite values into the trained state at random places.
    let mut rng = rand_pcg::Pcg64::seed_from_u64(52);
    let (k1, k2) = (rng.gen_range(100..500usize), rng.gen_range(0..100usize));
    let pos = &t.state.params.positions;
    let mut p = pos.read().unwrap();
    p[3 * k1 + 2] = f32::NAN;
    pos.upload(&p).unwrap();
    let sh = &t.state.params.sh_dc;
    let mut s = sh.read().unwrap();
    s[3 * k1 + 1] = f32::INFINITY;
    s[3 * k2] = f32::NEG_INFINITY;
    sh.upload(&s).unwrap();
    let found = check.scan(&t.state.params).unwrap();
    let mut want = vec![None; found.len()];
    (want[0], want[4]) = (Some(k1), Some(k2));
    assert_eq!(found.to_vec(), want);
    let msg = format!("{:#}", check.check(&t.state.params, 17).unwrap_err());
    for part in [
        "iteration 17",
        "'positions'",
        &format!("Gaussian {k1}"),
        "Fix:",
    ] {
        assert!(msg.contains(part), "'{msg}' lacks '{part}'");
    }
    // A NaN past the count is not the model's and is ignored.
    let mut fresh = t.state.params.positions.read().unwrap();
    fresh[3 * k1 + 2] = 0.0;
    let beyond = 3 * t.state.count();
    if beyond < fresh.len() {
        fresh[beyond] = f32::NAN;
    }
    pos.upload(&fresh).unwrap();
    assert_eq!(
        check.first(&t.state.params).unwrap().unwrap().group,
        "sh_dc"
    );
    ctx.check_validation().unwrap();
}

fn lpmsplat() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lpmsplat"));
    c.env("LPMSPLAT_VALIDATION", "1");
    c
}

fn run_ok(c: &mut Command) -> String {
    let out = c.output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{c:?} failed:\n{text}");
    text
}

fn run_err(c: &mut Command) -> String {
    let out = c.output().unwrap();
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "{c:?} should have failed");
    text
}

/// An LPIPS weights file with the right tensors and random values.
fn random_lpips_weights(dir: &Path) -> PathBuf {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let convs: [(usize, usize, usize, usize); 5] = [
        (0, 64, 3, 11),
        (3, 192, 64, 5),
        (6, 384, 192, 3),
        (8, 256, 384, 3),
        (10, 256, 256, 3),
    ];
    let mut tensors: Vec<(String, Vec<usize>, Vec<f32>)> = Vec::new();
    for (index, out_c, in_c, k) in convs {
        let bound = 1.0 / ((in_c * k * k) as f32).sqrt();
        let w = (0..out_c * in_c * k * k)
            .map(|_| rng.gen_range(-bound..bound))
            .collect();
        tensors.push((
            format!("features.{index}.weight"),
            vec![out_c, in_c, k, k],
            w,
        ));
        let b = (0..out_c).map(|_| rng.gen_range(-bound..bound)).collect();
        tensors.push((format!("features.{index}.bias"), vec![out_c], b));
    }
    for (i, c) in [64, 192, 384, 256, 256].into_iter().enumerate() {
        let w = (0..c).map(|_| rng.gen_range(0.0..0.1)).collect();
        tensors.push((format!("lin{i}.weight"), vec![1, c, 1, 1], w));
    }
    let path = dir.join("lpips.safetensors");
    let refs: Vec<(&str, &[usize], &[f32])> = tensors
        .iter()
        .map(|(n, s, v)| (n.as_str(), s.as_slice(), v.as_slice()))
        .collect();
    lpmsplat::lpips::weights::write_f32(&path, &refs).unwrap();
    path
}

#[test]
fn cli_train_resume_eval_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let scene = data("lego_small");
    let common = |c: &mut Command| {
        c.arg("train")
            .arg(&scene)
            .args(["--init-points", "300", "--sh-degree", "0", "--nan-check"])
            .arg("-o")
            .arg(&out);
    };
    let mut c = lpmsplat();
    common(&mut c);
    run_ok(c.args([
        "--iterations",
        "6",
        "--checkpoint-every",
        "3",
        "--eval-every",
        "2",
    ]));
    let model = read_ply(&out.join("point_cloud.ply")).unwrap();
    assert_eq!(model.len(), 300);
    for v in ["r_0", "r_33", "r_66"] {
        assert!(out.join(format!("renders/test/{v}.png")).is_file(), "{v}");
    }
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["per_view"].as_array().unwrap().len(), 3);
    assert!(metrics["psnr"].as_f64().unwrap().is_finite());
    // The wall time includes the intermediate evaluations and checkpoints; their time and the
    // rate without them are reported beside it.
    let (wall, paused) = (
        metrics["train_seconds"].as_f64().unwrap(),
        metrics["paused_seconds"].as_f64().unwrap(),
    );
    assert!(paused > 0.0 && paused < wall, "{wall} {paused}");
    let unpaused = metrics["iterations_per_second_unpaused"].as_f64().unwrap();
    assert!(
        (unpaused * (wall - paused) - 6.0).abs() < 1e-6,
        "{unpaused}"
    );
    // The periodic evaluations (2 and 4; 6 is the final one) keep their per-view scores, whose
    // mean is the evaluation's PSNR.
    let evals = metrics["evaluations"].as_array().unwrap();
    assert_eq!(
        evals
            .iter()
            .map(|e| e["iteration"].as_u64().unwrap())
            .collect::<Vec<_>>(),
        [2, 4]
    );
    for e in evals {
        let views = e["per_view"].as_array().unwrap();
        assert_eq!(views.len(), 3, "{e}");
        let mean = views
            .iter()
            .map(|v| v["psnr"].as_f64().unwrap())
            .sum::<f64>()
            / 3.0;
        assert!((mean - e["psnr"].as_f64().unwrap()).abs() < 1e-9, "{e}");
    }
    // The pictures and the compact export: training.png (3 × 2 panels of 520 × 300), the
    // curves' samples in metrics.json, point_cloud.splat (32 bytes a Gaussian), which `export`
    // reproduces from the PLY.
    let plot = images::decode_image(&out.join("training.png")).unwrap();
    assert_eq!((plot.width, plot.height), (1040, 900));
    let history = metrics["history"].as_array().unwrap();
    assert_eq!(
        history.len(),
        1,
        "every 10 iterations and the last: {history:?}"
    );
    assert_eq!(history[0]["iteration"], 6);
    assert_eq!(history[0]["gaussians"], 300);
    // No density step in 6 iterations: the count over the run is the count.
    assert_eq!(metrics["mean_gaussians"].as_f64().unwrap(), 300.0);
    let splat = std::fs::read(out.join("point_cloud.splat")).unwrap();
    assert_eq!(splat.len(), 300 * 32);
    let exported = dir.path().join("exported.splat");
    let text = run_ok(
        lpmsplat()
            .arg("export")
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .arg("--splat")
            .arg(&exported),
    );
    assert!(text.contains("300 Gaussians"), "{text}");
    assert_eq!(std::fs::read(&exported).unwrap(), splat);
    let e = run_err(
        lpmsplat()
            .arg("export")
            .arg("--ply")
            .arg(dir.path().join("missing.ply")),
    );
    assert!(e.contains("missing.ply") && e.contains("Fix:"), "{e}");

    // render --orbit: a looping GIF of N frames at the training cameras' size.
    let orbit = dir.path().join("orbit");
    let text = run_ok(
        lpmsplat()
            .arg("render")
            .arg(&scene)
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .arg("--out")
            .arg(&orbit)
            .args(["--orbit", "5"]),
    );
    assert!(text.contains("Inward"), "lego is a 360° capture: {text}");
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut dec = opts
        .read_info(std::fs::File::open(orbit.join("orbit.gif")).unwrap())
        .unwrap();
    assert_eq!((dec.width(), dec.height()), (100, 100));
    let mut frames = 0;
    let mut lit = 0;
    while let Some(f) = dec.read_next_frame().unwrap() {
        frames += 1;
        lit += f.buffer.chunks(4).filter(|p| p[..3] != [0, 0, 0]).count();
    }
    assert_eq!(frames, 5);
    assert!(lit > 0, "the orbit frames show the model");

    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["iterations"], 6);
    assert_eq!(config["init_points"], 300);
    assert!(config.get("resumed_from").is_none());
    assert_eq!(
        Checkpoint::read(&out.join("checkpoint.bin"))
            .unwrap()
            .iteration,
        6
    );

    // Resume to 10; the flags must match, --init-ply cannot be combined.
    let ck = out.join("checkpoint.bin");
    let mut c = lpmsplat();
    common(&mut c);
    let text = run_ok(c.args(["--iterations", "10", "--resume"]).arg(&ck));
    assert!(text.contains("at iteration 6"), "{text}");
    assert_eq!(Checkpoint::read(&ck).unwrap().iteration, 10);
    // The resumed run's config says where it resumed, not a bogus initial count.
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert!(config.get("init_points").is_none(), "{config}");
    assert_eq!(config["resumed_from"]["iteration"], 6);
    assert_eq!(config["resumed_from"]["gaussians"], 300);
    let mut c = lpmsplat();
    common(&mut c);
    let e = run_err(
        c.args(["--iterations", "20", "--resume"])
            .arg(&ck)
            .arg("--init-ply")
            .arg(out.join("point_cloud.ply")),
    );
    assert!(e.contains("--init-ply") && e.contains("Fix:"), "{e}");
    let mut c = lpmsplat();
    common(&mut c);
    let e = run_err(c.args(["--iterations", "10", "--resume"]).arg(&ck));
    assert!(
        e.contains("already at iteration 10") && e.contains("Fix:"),
        "{e}"
    );
    let mut c = lpmsplat();
    common(&mut c);
    let e = run_err(
        c.args(["--iterations", "20", "--lr-opacity", "0.3", "--resume"])
            .arg(&ck),
    );
    assert!(
        e.contains("lr.opacity") && e.contains("checkpoint.bin"),
        "{e}"
    );

    // An output folder that cannot be created.
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    let e = run_err(
        lpmsplat()
            .arg("train")
            .arg(&scene)
            .args(["--iterations", "2", "--init-points", "100", "-o"])
            .arg(blocker.join("out")),
    );
    assert!(e.contains("output folder") && e.contains("Fix:"), "{e}");

    // eval: the same numbers as the training run's final evaluation, JSON and side-by-side.
    let json = dir.path().join("eval.json");
    let sbs = dir.path().join("sbs");
    let text = run_ok(
        lpmsplat()
            .arg("eval")
            .arg(&scene)
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .arg("--json")
            .arg(&json)
            .arg("--side-by-side")
            .arg(&sbs),
    );
    assert!(text.contains("mean") && text.contains("LPIPS"), "{text}");
    let ev: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    let (pe, pt) = (
        ev["psnr"].as_f64().unwrap(),
        metrics["psnr"].as_f64().unwrap(),
    );
    assert!((pe - pt).abs() < 1e-6, "eval PSNR {pe} vs train {pt}");
    assert!(ev["lpips"].is_null());
    assert_eq!(ev["per_view"].as_array().unwrap().len(), 3);
    let img = images::decode_image(&sbs.join("r_0.png")).unwrap();
    assert_eq!((img.width, img.height), (200, 100));
    assert_eq!(ev["split"], "test");

    // eval --lpips-weights: a network with random weights (the numbers are checked against the
    // reference package in tests/gpu/lpips.rs; here, the wiring): a score per view, their mean, and
    // the same PSNR as without it. Bad weights stop eval before it renders anything.
    let weights = random_lpips_weights(dir.path());
    let json_lp = dir.path().join("eval_lpips.json");
    let text = run_ok(
        lpmsplat()
            .arg("eval")
            .arg(&scene)
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .arg("--json")
            .arg(&json_lp)
            .arg("--lpips-weights")
            .arg(&weights),
    );
    assert!(!text.contains("not computed"), "{text}");
    let ev_lp: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&json_lp).unwrap()).unwrap();
    let lp = ev_lp["lpips"].as_f64().expect("an LPIPS mean");
    let views: Vec<f64> = ev_lp["per_view"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["lpips"].as_f64().unwrap())
        .collect();
    assert_eq!(views.len(), 3);
    assert!(views.iter().all(|d| d.is_finite() && *d > 0.0), "{views:?}");
    assert!((views.iter().sum::<f64>() / 3.0 - lp).abs() < 1e-12);
    assert_eq!(ev_lp["psnr"], ev["psnr"]);
    assert!(ev_lp["lpips_note"].is_null());
    let bad = dir.path().join("bad.safetensors");
    std::fs::write(&bad, b"not a safetensors file").unwrap();
    let e = run_err(
        lpmsplat()
            .arg("eval")
            .arg(&scene)
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .arg("--lpips-weights")
            .arg(&bad),
    );
    assert!(e.contains("bad.safetensors"), "{e}");

    // eval --split train scores the 8 training views instead (none of the 3 val views).
    let json_train = dir.path().join("eval_train.json");
    run_ok(
        lpmsplat()
            .arg("eval")
            .arg(&scene)
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .args(["--split", "train", "--json"])
            .arg(&json_train),
    );
    let ev_train: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&json_train).unwrap()).unwrap();
    assert_eq!(ev_train["split"], "train");
    let train_views = ev_train["per_view"].as_array().unwrap();
    assert_eq!(train_views.len(), 8);
    let test_names: Vec<&str> = ev["per_view"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["view"].as_str().unwrap())
        .collect();
    for v in train_views {
        let name = v["view"].as_str().unwrap();
        assert!(!test_names.contains(&name), "{name} is a test view");
        assert!(v["psnr"].as_f64().unwrap().is_finite(), "{v}");
    }
}

/// Ctrl-C, and SIGTERM (what Slurm sends a pre-empted or timed-out task first), alike.
#[test]
fn ctrl_c_saves_a_checkpoint_and_says_how_to_resume() {
    for signal in [libc::SIGINT, libc::SIGTERM] {
        stopped_by(signal);
    }
}

fn stopped_by(signal: libc::c_int) {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut child = lpmsplat()
        .arg("train")
        .arg(data("lego_small"))
        .args([
            "--init-points",
            "200",
            "--sh-degree",
            "0",
            "--iterations",
            "1000000",
        ])
        .arg("-o")
        .arg(&out)
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut text = String::new();
    // The first line is printed just before training starts; the handler is installed then.
    err.read_line(&mut text).unwrap();
    assert!(text.contains("initial Gaussians"), "{text}");
    std::thread::sleep(std::time::Duration::from_millis(1500));
    unsafe {
        libc::kill(child.id() as libc::pid_t, signal);
    }
    let status = child.wait().unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut err, &mut rest).unwrap();
    assert!(
        !status.success(),
        "an interrupted run must exit non-zero (signal {signal})"
    );
    assert!(
        rest.contains("interrupted") && rest.contains("--resume"),
        "{rest}"
    );
    let ck = Checkpoint::read(&out.join("checkpoint.bin")).unwrap();
    assert!(ck.iteration > 0 && ck.iteration < 1_000_000);
    assert_eq!(read_ply(&out.join("point_cloud.ply")).unwrap().len(), 200);
}

/// Evaluation and export see the model as it stands before the iteration's density control
/// (the reference evaluates and saves before densifying), while the training state densifies.
#[test]
fn snapshot_holds_the_model_before_density_control() {
    let ctx = ctx();
    let scene = lego();
    let train = images::load_images(&scene, &scene.train).unwrap();
    let init = random_init(300, [0.0; 3], [1.3; 3], 3, 0).unwrap();
    let mut cfg = TrainConfig {
        iterations: 20,
        seed: 5,
        sh_degree: 0,
        background: Background::Fixed([1.0; 3]),
        ..TrainConfig::default()
    };
    cfg.schedule.densify_from = 2;
    cfg.schedule.interval = 5;
    cfg.density.grad_threshold = 2e-6;
    let mut t = Trainer::new(&ctx, &scene, &train, &init, cfg).unwrap();
    for _ in 0..9 {
        t.step().unwrap();
    }
    let before = t.model().unwrap();
    let view = scene.train[0];
    let render_before = t.render_view(view, [1.0; 3]).unwrap();

    // Iteration 10 densifies (and skips Adam, as the reference does on densify iterations).
    t.snapshot_next_step();
    let r = t.step().unwrap();
    assert!(r.densified.is_some());
    assert_ne!(t.state.count(), before.len(), "the step did not densify");
    let snap = t.model().unwrap();
    assert_eq!(snap.len(), before.len());
    assert_eq!(t.gaussians(), before.len());
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let model_bits = |p: &GaussianParams| {
        let mut v: Vec<f32> = p.positions.iter().flatten().copied().collect();
        v.extend(p.log_scales.iter().flatten());
        v.extend(p.rotations.iter().flatten());
        v.extend(&p.opacity_logits);
        v.extend(p.sh_dc.iter().flatten());
        v.extend(&p.sh_rest);
        bits(&v)
    };
    assert_eq!(model_bits(&snap), model_bits(&before));
    let render_snap = t.render_view(view, [1.0; 3]).unwrap();
    assert_eq!(bits(&render_snap), bits(&render_before));

    // The next step (no request) evaluates the training state again.
    t.step().unwrap();
    assert_eq!(t.model().unwrap().len(), t.state.count());
    // A request on an iteration without density control copies nothing: the state is the model.
    t.snapshot_next_step();
    let r = t.step().unwrap();
    assert!(r.densified.is_none());
    assert_eq!(
        model_bits(&t.model().unwrap()),
        model_bits(&t.state.params.download().unwrap())
    );
    ctx.check_validation().unwrap();
}

/// The largest per-channel difference of two RGB images.
fn max_difference_rgb(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs()))
        .fold(0.0, f64::max)
}

/// Mip-Splatting in the trainer: a render is the f64 reference render of the model with the
/// reference 3D filter (from the training cameras) folded in and the 2D filter on; the exported
/// (fused) model rendered with only the 2D filter shows the same image; training through
/// density steps and an opacity reset keeps the filter in step with the growing model.
#[test]
fn mip_splatting_renders_trains_and_exports_like_the_reference() {
    use lpmsplat::reference::{self, mip, RefGaussians, RenderSettings};
    let ctx = ctx();
    let scene = lego();
    let train = images::load_images(&scene, &scene.train).unwrap();
    // Small Gaussians: the filters (a fraction of a pixel's footprint) then change them a lot.
    let mut model = ground_truth_model(21, 300);
    for l in model.log_scales.iter_mut().flatten() {
        *l -= 3.0;
    }
    let mut cfg = fixed_config(1);
    lpmsplat::models::BaseModel::MipSplatting.configure(&mut cfg);
    let mut t = Trainer::new(&ctx, &scene, &train, &model, cfg.clone()).unwrap();
    let exact = RefGaussians::from_params(&model);
    let cams: Vec<_> = scene
        .train
        .iter()
        .map(|&v| (scene.views[v].camera, scene.views[v].pose))
        .collect();
    let filter = mip::filter3d(&exact.positions, &cams).unwrap();
    assert!(filter.iter().all(|&f| f > 0.0));
    let fused = mip::fuse(&exact, &filter).unwrap();
    let v = scene.train[1];
    let (camera, pose) = (scene.views[v].camera, scene.views[v].pose);
    let want = reference::render(
        &fused,
        &camera,
        &pose,
        0,
        [0.0; 3],
        &RenderSettings::mip_splatting(),
    )
    .unwrap();
    let got: Vec<[f64; 3]> = t
        .render_view(v, [0.0; 3])
        .unwrap()
        .chunks(3)
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let worst = max_difference_rgb(&got, &want.raster.image);
    assert!(
        worst < 2e-3,
        "Mip render vs reference: max difference {worst}"
    );
    // Without the filters the image differs visibly (the test would not notice a missing one).
    let plain = reference::render(
        &exact,
        &camera,
        &pose,
        0,
        [0.0; 3],
        &RenderSettings::default(),
    )
    .unwrap();
    let apart = max_difference_rgb(&plain.raster.image, &want.raster.image);
    assert!(
        apart > 0.02,
        "the filters changed the image by only {apart}"
    );
    // The export folds the 3D filter in: rendered with the 2D filter alone, the same image.
    let exported = t.export_model().unwrap();
    let again = reference::render(
        &RefGaussians::from_params(&exported),
        &camera,
        &pose,
        0,
        [0.0; 3],
        &RenderSettings::mip_splatting(),
    )
    .unwrap();
    let drift = max_difference_rgb(&again.raster.image, &want.raster.image);
    assert!(drift < 1e-3, "exported model renders {drift} away");

    // Training with density steps and an opacity reset.
    cfg.iterations = 12;
    cfg.schedule.densify_from = 2;
    cfg.schedule.densify_until = 10;
    cfg.schedule.interval = 3;
    cfg.schedule.opacity_reset_interval = 6;
    cfg.density.grad_threshold = 1e-7;
    let mut t = Trainer::new(&ctx, &scene, &train, &model, cfg).unwrap();
    let mut grew = false;
    for _ in 0..12 {
        let r = t.step().unwrap();
        assert!(r.loss.is_finite());
        grew |= r.densified.is_some_and(|d| d.after > d.before);
    }
    assert!(grew, "no density step added Gaussians");
    let out = t.export_model().unwrap();
    assert_eq!(out.len(), t.gaussians());
    out.validate().unwrap();
    ctx.check_validation().unwrap();
}

/// The Mip-Splatting path a user takes: train with `--model mip-splatting`, then `eval` the
/// exported (3D-filter-fused) PLY with `--model mip-splatting` at the training scale, which must
/// reproduce the run's own final evaluation, and at another scale (`-r 2`), which must run.
#[test]
fn cli_mip_splatting_trains_and_evaluates_at_other_scales() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("mip");
    let scene = data("lego_small");
    run_ok(
        lpmsplat()
            .arg("train")
            .arg(&scene)
            .args(["--model", "mip-splatting", "--init-points", "300"])
            .args(["--sh-degree", "0", "--iterations", "6", "-o"])
            .arg(&out),
    );
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["model"], "mip-splatting");
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    let trained = metrics["psnr"].as_f64().unwrap();
    let eval_at = |extra: &[&str]| -> f64 {
        let json = dir.path().join("eval.json");
        run_ok(
            lpmsplat()
                .arg("eval")
                .arg(&scene)
                .arg("--ply")
                .arg(out.join("point_cloud.ply"))
                .args(extra)
                .arg("--json")
                .arg(&json),
        );
        let ev: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        ev["psnr"].as_f64().unwrap()
    };
    let same = eval_at(&["--model", "mip-splatting"]);
    assert!(
        (same - trained).abs() < 0.01,
        "eval of the export {same} dB vs the run's own {trained} dB"
    );
    // Without --model, the model its header records: the same score.
    let recorded = eval_at(&[]);
    assert!((recorded - trained).abs() < 0.01, "{recorded} vs {trained}");
    // Read as plain 3DGS (0.3 px² dilation, no compensation) it would be another image, and
    // scored silently it gave a wrong table: refused, naming both models.
    let text = run_err(
        lpmsplat()
            .arg("eval")
            .arg(&scene)
            .arg("--ply")
            .arg(out.join("point_cloud.ply"))
            .args(["--model", "3dgs"]),
    );
    assert!(
        text.contains("mip-splatting") && text.contains("--model 3dgs"),
        "{text}"
    );
    let half = eval_at(&["--model", "mip-splatting", "-r", "2"]);
    assert!(half.is_finite() && half > 5.0, "{half}");
}

#[test]
fn a_repeated_train_flag_takes_its_last_value() {
    // scripts/demo.sh appends the user's flags after its own defaults.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    run_ok(
        lpmsplat()
            .arg("train")
            .arg(data("lego_small"))
            .args(["--init-points", "100", "--sh-degree", "0"])
            .args(["--iterations", "40", "--iterations", "2", "-o"])
            .arg(&out),
    );
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["iterations"], 2);
}

/// `--raster-pixels`: the rasterizers' layouts train the same model (each pixel's arithmetic is
/// the same; only the backward's sums add in another order), the run records the layout, and a
/// layout the device cannot run is refused naming the flag and this device's choices, before
/// anything of an earlier run in the output folder is touched.
#[test]
fn raster_pixels_layouts_train_alike_and_bad_ones_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let train = |out: &Path, extra: &[&str]| {
        run_ok(
            lpmsplat()
                .arg("train")
                .arg(data("lego_small"))
                // A short run that densifies twice, so the layouts' gradients steer it.
                .args("--init-points 300 --sh-degree 1 --iterations 60".split(' '))
                .args("--densify-from 20 --densify-interval 20 -o".split(' '))
                .arg(out)
                .args(extra),
        );
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
        m
    };
    let default = train(&dir.path().join("default"), &[]);
    assert!(default["raster_pixels"].is_null());
    for p in ["1", "4"] {
        let m = train(&dir.path().join(p), &["--raster-pixels", p]);
        assert_eq!(m["raster_pixels"].to_string(), p);
        let (a, b) = (
            m["psnr"].as_f64().unwrap(),
            default["psnr"].as_f64().unwrap(),
        );
        assert!(
            (a - b).abs() < 0.05,
            "{p} pixels an invocation: {a} dB against {b}"
        );
        let (n, n0) = (
            m["gaussians"].as_f64().unwrap(),
            default["gaussians"].as_f64().unwrap(),
        );
        assert!(
            (n - n0).abs() <= 0.02 * n0,
            "{p} pixels: {n} Gaussians against {n0}"
        );
    }
    let kept = std::fs::read(dir.path().join("1").join("metrics.json")).unwrap();
    let err = run_err(
        lpmsplat()
            .arg("train")
            .arg(data("lego_small"))
            .args(["--iterations", "2", "--raster-pixels", "3", "-o"])
            .arg(dir.path().join("1")),
    );
    assert!(
        err.contains("--raster-pixels") && err.contains("this device takes 1, 2"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(dir.path().join("1").join("metrics.json")).unwrap(),
        kept
    );
}

/// `--densify-abs-grad` (Mip-Splatting's official densification): the run records it, its
/// statistic densifies more Gaussians than the paper's rule on the same run, and it resumes
/// from a checkpoint that carries the absolute-gradient sums; models with another statistic
/// refuse it.
#[test]
fn cli_abs_grad_densification_densifies_more_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let scene = data("lund_door_small");
    let train = |out: &Path, extra: &[&str]| {
        let o = lpmsplat()
            .arg("train")
            .arg(&scene)
            .args(["-r", "2", "--model", "mip-splatting", "--sh-degree", "0"])
            .args(["--iterations", "60", "--densify-from", "20"])
            .args(["--densify-interval", "20", "-o"])
            .arg(out)
            .args(extra)
            .output()
            .unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let count = |out: &Path| -> u64 {
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
        m["gaussians"].as_u64().unwrap()
    };
    let (plain, abs) = (dir.path().join("plain"), dir.path().join("abs"));
    let (ok, err) = train(&plain, &[]);
    assert!(ok, "{err}");
    let (ok, err) = train(&abs, &["--densify-abs-grad", "--checkpoint-every", "30"]);
    assert!(ok, "{err}");
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(abs.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["density"]["abs_grad"], true);
    let plain_config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(plain.join("config.json")).unwrap()).unwrap();
    assert!(plain_config["density"].get("abs_grad").is_none());
    let (a, p) = (count(&abs), count(&plain));
    assert!(
        a > p,
        "absolute-gradient test: {a} Gaussians, paper's rule: {p}"
    );
    // The checkpoint holds the absolute-gradient sums of the run; resuming it continues.
    let ck = Checkpoint::read(&abs.join("checkpoint.bin")).unwrap();
    assert_eq!(ck.stats.len(), 4);
    let resumed = dir.path().join("resumed");
    std::fs::create_dir_all(&resumed).unwrap();
    let (ok, err) = train(
        &abs,
        &[
            "--densify-abs-grad",
            "--iterations",
            "80",
            "--resume",
            abs.join("checkpoint.bin").to_str().unwrap(),
        ],
    );
    assert!(ok, "{err}");
    assert_eq!(
        Checkpoint::read(&abs.join("checkpoint.bin"))
            .unwrap()
            .iteration,
        80
    );
    // Resuming without the flag is a different run: refused by the settings check.
    let ck_path = abs.join("checkpoint.bin");
    let (ok, err) = train(
        &resumed,
        &["--iterations", "90", "--resume", ck_path.to_str().unwrap()],
    );
    assert!(!ok && err.contains("abs_grad"), "{err}");
    for model in ["pixel-gs", "2dgs"] {
        let o = lpmsplat()
            .arg("train")
            .arg(&scene)
            .args(["--model", model, "--densify-abs-grad", "-o"])
            .arg(dir.path().join(model))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains("--densify-abs-grad") && err.contains("Fix:"),
            "{err}"
        );
    }
}

/// Checkpoints of format 2 (before the absolute-gradient statistic) and 3 (before the training
/// frame) are still read, with that statistic at zero; format 4 round-trips both. A checkpoint
/// from before the training frame holds its model in the scene files' own frame: resuming
/// moves it, and its Adam moments, into the scene's training frame.
#[test]
fn format_2_checkpoints_still_resume() {
    let ctx = ctx();
    let scene = lego();
    // Trained as before format 4: in the files' own frame.
    let files = Scene::load_in_file_frame(&data("lego_small"), &LoadOptions::default()).unwrap();
    assert!(files.frame.is_identity() && !scene.frame.is_identity());
    let images = images::load_images(&scene, &scene.train).unwrap();
    let init = ground_truth_model(43, 120);
    let mut t = Trainer::new(&ctx, &files, &images, &init, fixed_config(5)).unwrap();
    t.step().unwrap();
    let mut ck = t.checkpoint(&files).unwrap();
    let n = ck.count as usize;
    ck.stats[3] = (0..n).map(|i| i as f32 * 0.25).collect();
    let fnv = |bytes: &[u8]| {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        h
    };
    let v4 = ck.to_bytes();
    let back = Checkpoint::from_bytes(Path::new("v4"), &v4).unwrap();
    assert_eq!(back.stats[3], ck.stats[3]);
    assert_eq!(back.fingerprint.frame, Some(files.frame));
    // Format 3: the same bytes without the frame (four f64 after the training split), version
    // 3, the hash (64-bit FNV-1a of everything before it) recomputed.
    let frame_bytes: Vec<u8> = [0.0f64, 0.0, 0.0, 1.0]
        .iter()
        .flat_map(|v| v.to_bits().to_le_bytes())
        .collect();
    let at = v4.windows(32).position(|w| w == frame_bytes).unwrap();
    let mut v3 = [&v4[..at], &v4[at + 32..v4.len() - 8]].concat();
    v3[8..12].copy_from_slice(&3u32.to_le_bytes());
    v3.extend_from_slice(&fnv(&v3).to_le_bytes());
    let old3 = Checkpoint::from_bytes(Path::new("v3"), &v3).unwrap();
    assert_eq!(old3.fingerprint.frame, None);
    assert_eq!(old3.stats, ck.stats);
    // Format 2: format 3 without the abs_accum array (u64 length, n floats), version 2.
    let config_len = ck.config_json.len();
    let abs_at = v3.len() - 8 - (8 + config_len) - (8 + 4 * n);
    let mut v2 = v3[..abs_at].to_vec();
    v2.extend_from_slice(&v3[abs_at + 8 + 4 * n..v3.len() - 8]);
    v2[8..12].copy_from_slice(&2u32.to_le_bytes());
    v2.extend_from_slice(&fnv(&v2).to_le_bytes());
    let old = Checkpoint::from_bytes(Path::new("v2"), &v2).unwrap();
    assert_eq!(old.stats[..3], ck.stats[..3]);
    assert!(old.stats[3].iter().all(|&v| v == 0.0) && old.stats[3].len() == n);
    assert_eq!(old.sets, ck.sets);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v2.bin");
    std::fs::write(&path, &v2).unwrap();
    let mut r = Trainer::resume(&ctx, &scene, &images, fixed_config(5), &path).unwrap();
    assert_eq!(r.iteration, 1);
    // Resumed in the training frame: every Gaussian where the scene's frame puts it, its
    // scales with it.
    let resumed = r.export_model().unwrap();
    let f = scene.frame;
    for (i, (p, q)) in resumed
        .positions
        .iter()
        .zip(ck.sets[0][0].chunks(3))
        .enumerate()
    {
        let want = f.to_train([q[0] as f64, q[1] as f64, q[2] as f64]);
        for k in 0..3 {
            assert!(
                (p[k] as f64 - want[k]).abs() < 1e-5,
                "{i}: {p:?} vs {want:?}"
            );
        }
    }
    let ln = f.scale.ln();
    for (l, q) in resumed.log_scales.iter().zip(ck.sets[0][1].chunks(3)) {
        assert!((0..3).all(|k| (l[k] as f64 - (q[k] as f64 + ln)).abs() < 1e-4));
    }
    // The moments follow (an Adam step scales with the world): m / k, v / k².
    let mut moved = old.clone();
    moved.into_frame(&f, false, &[]);
    let k = f.scale as f32;
    for (a, b) in moved.sets[1][0].iter().zip(&old.sets[1][0]) {
        assert!((a - b / k).abs() <= 1e-6 * (b / k).abs().max(1e-30));
    }
    for (a, b) in moved.sets[2][0].iter().zip(&old.sets[2][0]) {
        assert!((a - b / (k * k)).abs() <= 1e-5 * (b / (k * k)).abs().max(1e-30));
    }
    assert_eq!(moved.sets[1][1], old.sets[1][1], "log-scale moments stay");
    // And it trains on.
    r.step().unwrap();
    ctx.check_validation().unwrap();
}

/// A checkpoint written before the config had a model section (its model's settings under
/// the old top-level keys, `mip_filters` and `surfels`, and no model name) resumes with the
/// flags it was trained with, and is refused, naming the old key, with another model's.
#[test]
fn checkpoints_from_before_the_model_section_still_resume() {
    use lpmsplat::models::BaseModel;
    let ctx = ctx();
    let scene = lego();
    let images = images::load_images(&scene, &scene.train).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for (model, key) in [
        (BaseModel::MipSplatting, "mip_filters"),
        (BaseModel::Surfels2d, "surfels"),
    ] {
        let config = || {
            let mut c = fixed_config(5);
            model.configure(&mut c);
            c
        };
        let init = model.initialise(ground_truth_model(43, 120), 0);
        let mut t = Trainer::new(&ctx, &scene, &images, &init, config()).unwrap();
        t.step().unwrap();
        let mut ck = t.checkpoint(&scene).unwrap();
        let mut j: serde_json::Value = serde_json::from_str(&ck.config_json).unwrap();
        assert_eq!(j["model"], model.name());
        // The layout of before: no model name, the settings at the top.
        let o = j.as_object_mut().unwrap();
        let settings = o.remove("model_settings");
        o.remove("model");
        o.insert(
            key.to_string(),
            settings.unwrap_or(serde_json::Value::Bool(true)),
        );
        ck.config_json = j.to_string();
        let path = dir.path().join(format!("{}.bin", model.name()));
        std::fs::write(&path, ck.to_bytes()).unwrap();
        let r = Trainer::resume(&ctx, &scene, &images, config(), &path).unwrap();
        assert_eq!((r.iteration, BaseModel::of(&r.config)), (1, model));
        let e = Trainer::resume(&ctx, &scene, &images, fixed_config(5), &path)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains(key) && e.contains("other settings"), "{e}");
    }
}

/// The default `--init auto` triangulates a video scene's points (the fixture's 64×48 frames
/// give too few, so it says so and falls back to random points) and leaves still scenes
/// without points (NeRF-synthetic) to random points; `--init random` never triangulates.
#[test]
fn auto_init_triangulates_video_scenes_only() {
    let out = tempfile::tempdir().unwrap();
    let train = |scene: &str, extra: &[&str]| {
        let scene = data(scene);
        let mut cmd = lpmsplat();
        cmd.args(["train", scene.to_str().unwrap(), "--iterations", "1"])
            .args(["--init-points", "300", "-o", out.path().to_str().unwrap()])
            .args(extra);
        run_ok(&mut cmd)
    };
    let video = train("n3v_tiny", &["--model", "spacetime-lite"]);
    assert!(video.contains("triangulated from"), "{video}");
    assert!(
        video.contains("fewer than 100 triangulated; 300 random points instead"),
        "{video}"
    );
    let random = train(
        "n3v_tiny",
        &["--model", "spacetime-lite", "--init", "random"],
    );
    assert!(!random.contains("triangulated"), "{random}");
    let still = train("lego_small", &[]);
    assert!(!still.contains("triangulated"), "{still}");
}

/// `--init triangulate` on a scene with SfM points uses the points and says so; an unknown
/// `--init` value is refused with the choices.
#[test]
fn init_triangulate_on_a_scene_with_points_says_the_points_win() {
    let out = tempfile::tempdir().unwrap();
    let scene = data("lund_door_small");
    let text = run_ok(lpmsplat().args([
        "train",
        scene.to_str().unwrap(),
        "-r",
        "4",
        "--iterations",
        "1",
        "--init",
        "triangulate",
        "-o",
        out.path().to_str().unwrap(),
    ]));
    assert!(
        text.contains(
            "--init triangulate: not used, the initial points come from the scene's SfM points"
        ),
        "{text}"
    );
    let err = run_err(lpmsplat().args([
        "train",
        scene.to_str().unwrap(),
        "--init",
        "bogus",
        "-o",
        out.path().to_str().unwrap(),
    ]));
    assert!(
        err.contains("random") && err.contains("triangulate"),
        "{err}"
    );
}

/// `--max-gaussians`: the run ends at the cap it would have passed (the metrics say how many
/// additions were dropped), the cap is a setting of the run (config.json), and a count that
/// is not one is refused naming the flag and the fix before anything is written.
#[test]
fn cli_gaussian_budget_caps_the_count() {
    let dir = tempfile::tempdir().unwrap();
    let scene = data("lund_door_small");
    let train = |out: &Path, extra: &[&str]| {
        lpmsplat()
            .arg("train")
            .arg(&scene)
            .args(["-r", "2", "--sh-degree", "0"])
            .args(["--iterations", "60", "--densify-from", "20"])
            .args(["--densify-interval", "20", "-o"])
            .arg(out)
            .args(extra)
            .output()
            .unwrap()
    };
    let metrics = |out: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap()
    };
    let free = dir.path().join("free");
    let o = train(&free, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let natural = metrics(&free)["gaussians"].as_u64().unwrap();
    assert!(metrics(&free)["max_gaussians"].is_null());
    // Iteration 10, before the first density step.
    let initial = metrics(&free)["history"][0]["gaussians"].as_u64().unwrap();
    assert!(
        natural > initial + 100,
        "the run must densify: {initial} → {natural}"
    );
    // The count after each iteration, averaged: the initial count until the first density
    // step (iteration 40, the first past --densify-from), then the count the history shows at
    // 50, which the run exports (the export's snapshot comes before the density step at 60),
    // and at 60 the count after that step.
    let history = &metrics(&free)["history"];
    assert_eq!(history[4]["iteration"], 50);
    assert_eq!(history[5]["iteration"], 60);
    let (after_40, after_60) = (
        history[4]["gaussians"].as_u64().unwrap(),
        history[5]["gaussians"].as_u64().unwrap(),
    );
    assert_eq!(after_40, natural);
    let mean = metrics(&free)["mean_gaussians"].as_f64().unwrap();
    let expected = (39 * initial + 20 * after_40 + after_60) as f64 / 60.0;
    assert!((mean - expected).abs() < 1e-6, "{mean} vs {expected}");
    let cap = initial + (natural - initial) / 2;
    let capped = dir.path().join("capped");
    let o = train(&capped, &["--max-gaussians", &cap.to_string()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = metrics(&capped);
    let got = m["gaussians"].as_u64().unwrap();
    assert!(
        got <= cap && got + 2 >= cap,
        "{got} Gaussians under a cap of {cap}"
    );
    assert_eq!(m["max_gaussians"]["cap"], cap);
    assert!(m["max_gaussians"]["dropped_additions"].as_u64().unwrap() > 0);
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(capped.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["density"]["max_gaussians"], cap);
    assert!(String::from_utf8_lossy(&o.stdout).contains("Gaussian budget"));

    let bad = dir.path().join("bad");
    for v in ["0", "-5", "lots"] {
        let o = train(&bad, &[&format!("--max-gaussians={v}")]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains("--max-gaussians") && err.contains("Fix:"),
            "{v}: {err}"
        );
        assert!(!bad.exists(), "{v}: nothing is written");
    }
}

/// A run whose density control prunes every Gaussian finishes, writes its (empty) model and
/// says why at the end; the commands that read a model refuse the empty one with a fix.
#[test]
fn a_run_that_prunes_every_gaussian_says_so_and_readers_refuse_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = data("lund_door_small");
    let out = dir.path().join("empty");
    let text = run_ok(
        lpmsplat()
            .arg("train")
            .arg(&scene)
            .args(["-r", "4", "--sh-degree", "0", "--iterations", "60"])
            .args(["--densify-from", "20", "--densify-interval", "20"])
            .args(["--min-opacity", "0.999", "-o"])
            .arg(&out),
    );
    assert!(
        text.contains("0 Gaussians") && text.contains("warning: the model ended with no Gaussians"),
        "{text}"
    );
    assert!(text.contains("--min-opacity 0.999"), "{text}");
    let ply = out.join("point_cloud.ply");
    assert!(ply.exists(), "the empty model is still written");
    let err = run_err(
        lpmsplat()
            .arg("eval")
            .arg(&scene)
            .args(["-r", "4", "--ply"])
            .arg(&ply),
    );
    assert!(
        err.contains("point_cloud.ply") && err.contains("no Gaussians") && err.contains("Fix:"),
        "{err}"
    );
}

/// `--init random` by name replaces a scene's SfM points with --init-points random ones (MCMC's
/// random start), and says so; without it the SfM points start the run.
#[test]
fn init_random_by_name_replaces_the_sfm_points() {
    let scene = data("lund_door_small");
    let count = |extra: &[&str]| {
        let out = tempfile::tempdir().unwrap();
        let text = run_ok(
            lpmsplat()
                .args([
                    "train",
                    scene.to_str().unwrap(),
                    "-r",
                    "8",
                    "--iterations",
                    "1",
                ])
                .args(["--init-points", "321", "-o"])
                .arg(out.path())
                .args(extra),
        );
        let ply = read_ply(&out.path().join("point_cloud.ply")).unwrap();
        (ply.len(), text)
    };
    let (random, text) = count(&["--init", "random"]);
    assert_eq!(random, 321, "{text}");
    assert!(
        text.contains("SfM points are not used; 321 random points instead"),
        "{text}"
    );
    let (sfm, text) = count(&[]);
    assert!(sfm > 1000, "{text}");
    assert!(!text.contains("random points"), "{text}");
}
