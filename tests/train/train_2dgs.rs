//! 2DGS end to end through the CLI on the bundled real scene: `train --model 2dgs` (with the
//! regularisers switched on early so a short run exercises them) learns and writes surfels
//! with the unused third log-scale; `eval` and `render --depth --normals` read the model
//! back; flags that only mean something for 2DGS are refused elsewhere. Validation layer on.

use std::path::{Path, PathBuf};
use std::process::Command;

use lpmsplat::scene::images::read_pfm;
use lpmsplat::splats::read_ply;
use lpmsplat::train::passes::surfels::UNUSED_LOG_SCALE;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
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

fn test_psnr(metrics: &serde_json::Value) -> f64 {
    metrics["psnr"]
        .as_f64()
        .unwrap_or_else(|| panic!("no test PSNR in {metrics}"))
}

#[test]
fn train_2dgs_learns_and_renders_depth_and_normals() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    // -r 4: 81×121. Densification from 50 every 50 iterations, the normal regulariser from
    // 60 and the distortion from 40 (official 7000 / 3000), so 160 iterations use them all.
    run_ok(lpmsplat().args([
        "train",
        data("lund_door_small").to_str().unwrap(),
        "-r",
        "4",
        "--model",
        "2dgs",
        "--iterations",
        "160",
        "--densify-from",
        "50",
        "--densify-interval",
        "50",
        "--normal-from",
        "60",
        "--lambda-dist",
        "100",
        "--dist-from",
        "40",
        "--depth-ratio",
        "1",
        "--eval-every",
        "0",
        "-o",
        out.to_str().unwrap(),
    ]));
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    let psnr = test_psnr(&metrics);
    assert!(psnr > 20.0, "2DGS after 160 iterations: {psnr} dB");
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(config["model"], "2dgs", "{config}");
    assert_eq!(config["model_settings"]["normal_from"], 60, "{config}");
    assert_eq!(config["density"]["min_opacity"], 0.05, "{config}");

    let ply = out.join("point_cloud.ply");
    let model = read_ply(&ply).unwrap();
    // The unused third log-scale starts at UNUSED_LOG_SCALE and only splits move it (down by
    // ln 1.6 each): it never grows into a real extent.
    assert!(model
        .log_scales
        .iter()
        .all(|l| l[2] <= UNUSED_LOG_SCALE && l[0] > UNUSED_LOG_SCALE + 5.0));
    assert!(model.log_scales.iter().any(|l| l[2] == UNUSED_LOG_SCALE));

    // eval reads it back as surfels and reproduces the training run's test PSNR.
    let text = run_ok(lpmsplat().args([
        "eval",
        data("lund_door_small").to_str().unwrap(),
        "-r",
        "4",
        "--ply",
        ply.to_str().unwrap(),
        "--model",
        "2dgs",
    ]));
    let mean = text
        .lines()
        .find(|l| l.starts_with("mean"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or_else(|| panic!("no mean row in\n{text}"));
    assert!((mean - psnr).abs() < 1e-3, "eval {mean} vs train {psnr}");

    let renders = dir.path().join("renders");
    run_ok(lpmsplat().args([
        "render",
        data("lund_door_small").to_str().unwrap(),
        "-r",
        "4",
        "--ply",
        ply.to_str().unwrap(),
        "--model",
        "2dgs",
        "--depth",
        "--normals",
        "--depth-ratio",
        "1",
        "--out",
        renders.to_str().unwrap(),
    ]));
    let stems: Vec<String> = std::fs::read_dir(&renders)
        .unwrap()
        .filter_map(|e| {
            let name = e.unwrap().file_name().to_string_lossy().to_string();
            name.strip_suffix("_depth.pfm").map(str::to_string)
        })
        .collect();
    assert_eq!(stems.len(), 2, "one depth map per test view");
    for stem in &stems {
        let (w, h, c, depth) = read_pfm(&renders.join(format!("{stem}_depth.pfm"))).unwrap();
        assert_eq!((w, h, c), (81, 121, 1));
        // The door is 3–9 units from the cameras (its SfM points); nearly every pixel is
        // covered after training.
        let covered: Vec<f32> = depth.iter().copied().filter(|&d| d > 0.0).collect();
        assert!(
            covered.len() * 10 > depth.len() * 9,
            "{} covered",
            covered.len()
        );
        assert!(depth.iter().all(|d| d.is_finite()));
        let (_, _, c, normals) = read_pfm(&renders.join(format!("{stem}_normal.pfm"))).unwrap();
        assert_eq!(c, 3);
        assert!(normals.iter().all(|v| v.is_finite()));
        for ext in ["_depth.png", "_normal.png", ".png"] {
            assert!(
                renders.join(format!("{stem}{ext}")).is_file(),
                "{stem}{ext}"
            );
        }
    }
}

#[test]
fn surfel_only_flags_are_refused_for_other_models() {
    let dir = tempfile::tempdir().unwrap();
    let err = run_err(lpmsplat().args([
        "train",
        data("lund_door_small").to_str().unwrap(),
        "--lambda-normal",
        "0.1",
        "-o",
        dir.path().join("x").to_str().unwrap(),
    ]));
    assert!(
        err.contains("--lambda-normal") && err.contains("--model 2dgs"),
        "{err}"
    );
    let err = run_err(lpmsplat().args([
        "train",
        data("lund_door_small").to_str().unwrap(),
        "--model",
        "2dgs",
        "--depth-ratio",
        "2",
        "-o",
        dir.path().join("y").to_str().unwrap(),
    ]));
    assert!(err.contains("--depth-ratio"), "{err}");
}

#[test]
fn depth_and_normals_need_a_surfel_model() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("one.ply");
    let mut p = lpmsplat::splats::GaussianParams::empty(0);
    p.positions.push([0.0; 3]);
    p.log_scales.push([-2.0; 3]);
    p.rotations.push([1.0, 0.0, 0.0, 0.0]);
    p.opacity_logits.push(0.0);
    p.sh_dc.push([0.0; 3]);
    lpmsplat::splats::write_ply(&ply, &p).unwrap();
    let err = run_err(lpmsplat().args([
        "render",
        data("lund_door_small").to_str().unwrap(),
        "--ply",
        ply.to_str().unwrap(),
        "--depth",
        "--out",
        dir.path().join("r").to_str().unwrap(),
    ]));
    assert!(err.contains("--model 2dgs"), "{err}");
}
