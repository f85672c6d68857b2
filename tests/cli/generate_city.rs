//! `generate-city`: a district whose truth is known, written as a scene `train`, `eval` and
//! `partition` read; a whole run under a memory limit refused, and the plan that fits it.

use crate::cli_support::{lpmsplat, run, run_ok};
use std::path::Path;

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn generate(out: &Path) -> std::process::Command {
    let mut c = lpmsplat();
    c.arg("generate-city").arg(out).args([
        "--lots",
        "4x3",
        "--gaussians",
        "60k",
        "--views",
        "48",
        "--size",
        "128x96",
        "--points",
        "6k",
        "--seed",
        "2",
    ]);
    c
}

#[test]
fn a_generated_district_renders_back_from_its_truth_and_plans_into_blocks_that_fit() {
    let dir = tempfile::tempdir().unwrap();
    let city = dir.path().join("city");
    run_ok(&mut generate(&city));
    let report = json(&city.join("city.json"));
    let n = report["gaussians"].as_f64().unwrap();
    assert!((n / 60_000.0 - 1.0).abs() < 0.05, "{report}");
    assert_eq!(report["views"], 48);
    assert_eq!(report["test_views"], 6);
    let pngs = std::fs::read_dir(city.join("images")).unwrap().count();
    assert_eq!(pngs, 48);
    assert!(report["sfm_points"].as_u64().unwrap() > 1000, "{report}");
    assert!(report["mean_track"].as_f64().unwrap() >= 2.0, "{report}");

    // The truth scores against its own renders up to their 8-bit rounding: the images, poses
    // and intrinsics written are the ones rendered (a pose or focal length off by a pixel
    // would cost tens of dB on these edges).
    let scores = dir.path().join("truth.json");
    run_ok(
        lpmsplat()
            .arg("eval")
            .arg(&city)
            .arg("--ply")
            .arg(city.join("truth.ply"))
            .arg("--json")
            .arg(&scores),
    );
    let psnr = json(&scores)["psnr"].as_f64().unwrap();
    assert!(psnr > 45.0, "the truth renders back at {psnr} dB");

    // A second run into the folder destroys nothing.
    let before = std::fs::read(city.join("truth.ply")).unwrap();
    let (ok, text) = run(&mut generate(&city));
    assert!(!ok && text.contains("not empty"), "{text}");
    assert_eq!(std::fs::read(city.join("truth.ply")).unwrap(), before);

    // The whole scene under a limit too small for it stops at set-up and names the ways out,
    // partitioning among them.
    let (ok, text) = run(lpmsplat()
        .args(["--memory-limit", "2", "train"])
        .arg(&city)
        .args(["--iterations", "10", "-o"])
        .arg(dir.path().join("whole")));
    assert!(!ok, "{text}");
    assert!(
        text.contains("--memory-limit") && text.contains("partition"),
        "{text}"
    );

    // At a budget of 150k the whole run needs more than 100 MiB; the plan for 100 MiB a block
    // has several blocks, each under it, sharing the budget.
    let plan_dir = dir.path().join("plan");
    run_ok(
        lpmsplat()
            .arg("partition")
            .arg(&city)
            .args(["--budget", "150k", "--memory", "100", "-o"])
            .arg(&plan_dir),
    );
    let plan = json(&plan_dir.join("plan.json"));
    assert!(
        plan["whole"]["memory_mib"].as_f64().unwrap() > 100.0,
        "{plan}"
    );
    let blocks = plan["blocks"].as_array().unwrap();
    assert!(blocks.len() >= 2, "{plan}");
    let mut shared = 0;
    for b in blocks {
        assert!(b["memory_mib"].as_f64().unwrap() <= 100.0, "{b}");
        assert!(!b["train_views"].as_array().unwrap().is_empty(), "{b}");
        shared += b["expected_gaussians"].as_u64().unwrap();
    }
    assert!(
        shared >= 150_000,
        "the blocks' budgets cover the whole's: {shared}"
    );
}
