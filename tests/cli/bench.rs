//! `bench trade`, `bench merge` and `bench fps` end to end through the CLI, under the validation
//! layer: the files they promise exist and hold consistent numbers, and bad `--runs` lists are
//! refused clearly.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::cli_support::{lpmsplat, run as output};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// `bench trade` on the bundled lund_door at `-r 8` (81×121), `iterations` a run, into `out`;
/// the caller adds the runs and settings under test.
fn door_trade(iterations: &str, out: &Path) -> Command {
    let mut c = lpmsplat();
    c.args(["bench", "trade"])
        .arg(data("lund_door_small"))
        .args(["-r", "8", "--iterations", iterations, "-o"])
        .arg(out);
    c
}

/// The trade.json a `bench trade` run wrote into `out`.
fn trade_json(out: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("trade.json")).unwrap()).unwrap()
}

#[test]
fn bench_trade_interleaved_writes_table_json_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("trade");
    let (ok, text) = output(
        door_trade("40", &out)
            .args([
                "--fps-frames",
                "1",
                "--eval-at",
                "20,0,99",
                "--calendar",
                "400",
            ])
            .args(["--runs", "lpm,adc"]),
    );
    assert!(ok, "{text}");
    let json = trade_json(&out);
    let runs = json["runs"].as_array().unwrap();
    // Rows by iteration, then in table order whatever order --runs named them in; --eval-at
    // values outside 1..iterations are ignored and the last iteration is always evaluated.
    let names: Vec<(&str, u64)> = runs
        .iter()
        .map(|r| (r["run"].as_str().unwrap(), r["iteration"].as_u64().unwrap()))
        .collect();
    assert_eq!(
        names,
        [("adc", 20), ("adc+lpm", 20), ("adc", 40), ("adc+lpm", 40)]
    );
    assert_eq!(json["calendar"], 400);
    assert_eq!(
        json["lpm_block"], 0,
        "the block follows the image size by default"
    );
    // 16 px at 1 MP scaled to a ~40×60 image is under the 4-px floor.
    assert_eq!(json["lpm_block_px"], serde_json::json!([4, 4]));
    let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
    assert!(
        md.contains("error blocks of the image's size (4 px here:"),
        "{md}"
    );
    assert!(
        runs[2]["train_seconds"].as_f64().unwrap() > runs[0]["train_seconds"].as_f64().unwrap()
    );
    for r in runs {
        let iterations = r["iteration"].as_f64().unwrap();
        let psnr = r["psnr"].as_f64().unwrap();
        assert!(psnr.is_finite() && psnr > 5.0, "{r}");
        assert!(r["gaussians"].as_u64().unwrap() > 0, "{r}");
        let secs = r["train_seconds"].as_f64().unwrap();
        let ms = r["ms_per_iteration"].as_f64().unwrap();
        assert!(
            (ms - 1e3 * secs / iterations).abs() < 1e-6 * ms.max(1.0),
            "{r}"
        );
        assert!(r["fps_1352x1014"].as_f64().unwrap() > 0.0, "{r}");
        let share = r["lpm_share"].as_f64().unwrap();
        assert!((0.0..1.0).contains(&share), "{r}");
    }
    assert_eq!(runs[0]["lpm_ms_per_iteration"].as_f64().unwrap(), 0.0);
    // LPM's activity: none for ADC; for LPM at most one added Gaussian per zone.
    for r in runs {
        let f = |k: &str| r[k].as_f64().unwrap();
        if r["run"] == "adc" {
            assert_eq!(
                [
                    f("lpm_zones"),
                    f("lpm_lowered"),
                    f("lpm_added"),
                    f("lpm_reset"),
                    f("lpm_pruned"),
                    f("lpm_radius")
                ],
                [0.0; 6]
            );
        } else {
            assert!(
                f("lpm_added") <= f("lpm_zones")
                    && f("lpm_reset") >= 0.0
                    && f("lpm_pruned") >= 0.0
                    && (f("lpm_zones") == 0.0 || f("lpm_radius") > 0.0),
                "{r}"
            );
        }
    }
    // Each run's final model is written, the size its row reports.
    for r in &runs[2..] {
        let ply = out.join(format!("{}.ply", r["run"].as_str().unwrap()));
        let model = lpmsplat::splats::read_ply(&ply).unwrap();
        assert_eq!(model.len() as u64, r["gaussians"].as_u64().unwrap(), "{r}");
    }
    assert!(!out.join("adc-threshold-1e-4.ply").exists());
    let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
    assert!(
        md.contains("interleaved")
            && md.contains("| adc+lpm |")
            && md.contains("LPM zones · densified · pruned · added · reset · zone radius"),
        "{md}"
    );
    assert!(
        md.contains("| adc | 20 | #282828 |") && md.contains("+0.000"),
        "{md}"
    );
    let png = image::open(out.join("trade.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1040, 680));
    // trade.html: the plot, the table, and the first test view's truth beside each run's final
    // render and error map (files it links, all present), also as one captioned picture.
    let html = std::fs::read_to_string(out.join("trade.html")).unwrap();
    let view = json["runs"][2]["view_psnr"]
        .as_f64()
        .expect("final rows carry the view's PSNR");
    assert!(view.is_finite(), "{view}");
    assert!(
        json["runs"][0]["view_psnr"].is_null(),
        "iteration 20 shows no render"
    );
    for link in [
        "trade.png",
        "report/truth.png",
        "report/adc.png",
        "report/adc-error.png",
        "report/adc+lpm.png",
        "report/adc+lpm-error.png",
        "report/side_by_side.png",
    ] {
        assert!(html.contains(&format!("\"{link}\"")), "{link} not linked");
        assert!(out.join(link).is_file(), "{link} missing");
    }
    assert!(
        html.contains("<td>+0.000</td>") || html.contains("+0.000"),
        "{html}"
    );
    let truth = image::open(out.join("report/truth.png")).unwrap();
    let error = image::open(out.join("report/adc-error.png")).unwrap();
    assert_eq!(
        (truth.width(), truth.height()),
        (error.width(), error.height())
    );
    let grid = image::open(out.join("report/side_by_side.png")).unwrap();
    assert!(grid.width() >= 3 * truth.width() && grid.height() >= 2 * truth.height());
    let e = {
        let (ok, text) = output(
            lpmsplat()
                .args(["bench", "trade"])
                .arg(data("lund_door_small"))
                .args([
                    "-r",
                    "8",
                    "--iterations",
                    "2",
                    "--report-view",
                    "nope",
                    "-o",
                ])
                .arg(dir.path().join("t2")),
        );
        assert!(!ok);
        text
    };
    assert!(e.contains("--report-view") && e.contains("Fix:"), "{e}");
}

#[test]
fn bench_trade_with_several_seeds_reports_means_and_paired_differences() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("trade");
    let (ok, text) = output(
        door_trade("12", &out)
            .args([
                "--fps-frames",
                "1",
                "--seeds",
                "2",
                "--seed",
                "5",
                "--runs",
                "adc,lpm",
            ])
            .args(["--lpm-block", "8", "--lpm-block-fraction", "0.5"]),
    );
    assert!(ok, "{text}");
    let json = trade_json(&out);
    assert_eq!(json["lpm_block"], 8);
    assert_eq!(json["lpm_block_px"], serde_json::json!([8, 8]));
    assert_eq!(json["lpm_block_fraction"], 0.5);
    let runs = json["runs"].as_array().unwrap();
    let keys: Vec<(&str, u64)> = runs
        .iter()
        .map(|r| (r["run"].as_str().unwrap(), r["seed"].as_u64().unwrap()))
        .collect();
    assert_eq!(
        keys,
        [("adc", 5), ("adc", 6), ("adc+lpm", 5), ("adc+lpm", 6)]
    );
    // The seed reaches training: the two ADC runs differ.
    assert_ne!(runs[0]["psnr"], runs[1]["psnr"]);
    let summary = json["summary"].as_array().unwrap();
    assert_eq!(summary.len(), 2);
    let psnr = |i: usize| runs[i]["psnr"].as_f64().unwrap();
    let (adc, lpm) = (&summary[0], &summary[1]);
    assert_eq!(adc["seeds"], 2);
    assert!((adc["psnr"].as_f64().unwrap() - 0.5 * (psnr(0) + psnr(1))).abs() < 1e-9);
    let d = [psnr(2) - psnr(0), psnr(3) - psnr(1)];
    let mean = 0.5 * (d[0] + d[1]);
    assert!(
        (lpm["delta_psnr"].as_f64().unwrap() - mean).abs() < 1e-9,
        "{lpm}"
    );
    // se = sd / √2 = |d0 − d1| / 2 for two values.
    let se = (d[0] - d[1]).abs() / 2.0;
    assert!(
        (lpm["delta_psnr_se"].as_f64().unwrap() - se).abs() < 1e-9,
        "{lpm}"
    );
    for name in ["adc-seed5", "adc-seed6", "adc+lpm-seed5", "adc+lpm-seed6"] {
        assert!(out.join(format!("{name}.ply")).is_file(), "{name}");
    }
    let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
    assert!(
        md.contains("mean over 2 seeds (5..6)") && md.contains(" ± "),
        "{md}"
    );

    // Each seed in its own file, as two processes write them, merged back by `bench merge`:
    // the pooled summary is the one-process summary, less the time ratio.
    assert_eq!(json["settings"]["lpm_block_fraction"], 0.5);
    assert!(json["settings"]["max_gaussians"].is_null());
    for seed in [5u64, 6] {
        let mut one = json.clone();
        one["runs"] =
            serde_json::Value::Array(runs.iter().filter(|r| r["seed"] == seed).cloned().collect());
        let d = dir.path().join(format!("seed{seed}"));
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("trade.json"), one.to_string()).unwrap();
    }
    let merged = dir.path().join("merged");
    let (ok, text) = output(
        lpmsplat()
            .args(["bench", "merge"])
            .arg(dir.path().join("seed5"))
            .arg(dir.path().join("seed6/trade.json"))
            .arg("-o")
            .arg(&merged),
    );
    assert!(ok, "{text}");
    let m = trade_json(&merged);
    assert_eq!(m["interleaved"], false);
    let ms = m["summary"].as_array().unwrap();
    assert_eq!(ms.len(), 2);
    for (a, b) in summary.iter().zip(ms) {
        assert_eq!(a["run"], b["run"]);
        assert_eq!(a["seeds"], b["seeds"]);
        for k in ["psnr", "ssim"] {
            assert!(
                (a[k].as_f64().unwrap() - b[k].as_f64().unwrap()).abs() < 1e-12,
                "{k}"
            );
        }
        assert!(b["time_vs_adc"].is_null(), "{b}");
    }
    for k in ["delta_psnr", "delta_psnr_se"] {
        let (a, b) = (lpm[k].as_f64().unwrap(), ms[1][k].as_f64().unwrap());
        assert!((a - b).abs() < 1e-12, "{k}: {a} vs {b}");
    }
    // Both tables list the per-seed differences.
    let pair = format!("| adc+lpm | 12 | 5: {:+.3}, 6: {:+.3} |", d[0], d[1]);
    assert!(md.contains(&pair), "{pair}\n{md}");
    let mmd = std::fs::read_to_string(merged.join("trade.md")).unwrap();
    assert!(mmd.contains(&pair), "{pair}\n{mmd}");
    assert!(merged.join("trade.png").is_file());
    // Its page pools the plot and tables and links the inputs' own pages where they exist.
    std::fs::copy(out.join("trade.html"), dir.path().join("seed5/trade.html")).unwrap();
    let (ok, text) = output(
        lpmsplat()
            .args(["bench", "merge", "--baseline", "adc+lpm"])
            .arg(dir.path().join("seed5"))
            .arg(dir.path().join("seed6"))
            .arg("-o")
            .arg(&merged),
    );
    assert!(ok, "{text}");
    let page = std::fs::read_to_string(merged.join("trade.html")).unwrap();
    assert!(
        page.contains("<a href=\"../seed5/trade.html\">")
            && page.contains("seed6/trade.json (no trade.html beside it)")
            && page.contains("ΔPSNR vs adc+lpm")
            && page.contains("trade.png")
            && !page.contains("report/truth.png"),
        "{page}"
    );
    // A `bench trade` result is never merged over.
    let before = std::fs::read(out.join("trade.json")).unwrap();
    let (ok, text) = output(
        lpmsplat()
            .args(["bench", "merge"])
            .arg(dir.path().join("seed5"))
            .arg("-o")
            .arg(&out),
    );
    assert!(
        !ok && text.contains("not a merge") && text.contains("Fix:"),
        "{text}"
    );
    assert_eq!(std::fs::read(out.join("trade.json")).unwrap(), before);
}

#[test]
fn bench_trade_rejects_unknown_or_repeated_runs() {
    let dir = tempfile::tempdir().unwrap();
    for (runs, seeds, needle) in [
        ("adc,fancy", "1", "unknown run"),
        ("adc,adc", "1", "twice"),
        ("adc", "0", "--seeds 0"),
        ("lpm,adc-1e-4", "match", "has no adc"),
    ] {
        let out = dir.path().join(runs.replace(',', "_"));
        let mut c = lpmsplat();
        c.args(["bench", "trade"])
            .arg(data("lund_door_small"))
            .args(["-r", "8", "--iterations", "5", "--runs", runs, "-o"])
            .arg(&out);
        if seeds == "match" {
            c.arg("--match-adc-count");
        } else {
            c.args(["--seeds", seeds]);
        }
        let (ok, text) = output(&mut c);
        assert!(!ok, "{runs}: {text}");
        assert!(text.contains(needle) && text.contains("Fix:"), "{text}");
        assert!(!out.join("trade.json").exists());
    }
}

/// `--match-adc-count`: a run that densifies more than ADC (the threshold halved) is held to
/// ADC's count at the same seed and iteration, and since the budget keeps the candidates
/// furthest over their own threshold, it keeps ADC's own; without the flag it ends far above.
#[test]
fn bench_trade_match_adc_count_holds_the_other_runs_to_adcs_count() {
    let dir = tempfile::tempdir().unwrap();
    let (mut counts, mut means) = (Vec::new(), Vec::new());
    for matched in [false, true] {
        let out = dir.path().join(format!("m{matched}"));
        let mut c = door_trade("101", &out);
        c.args(["--calendar", "600", "--runs", "adc,adc-1e-4"])
            .args(["--fps-frames", "1", "--seeds", "2"]);
        if matched {
            c.arg("--match-adc-count");
        }
        let (ok, text) = output(&mut c);
        assert!(ok, "{text}");
        let json = trade_json(&out);
        assert_eq!(json["settings"]["match_adc_count"], matched);
        assert_eq!(text.contains("--match-adc-count"), matched, "{text}");
        let runs = json["runs"].as_array().unwrap();
        let row = |run: &str, seed: u64| {
            runs.iter()
                .find(|r| r["run"] == run && r["seed"] == seed)
                .unwrap()
        };
        let count = |run: &str, seed: u64| row(run, seed)["gaussians"].as_u64().unwrap();
        let mean = |run: &str, seed: u64| row(run, seed)["mean_gaussians"].as_f64().unwrap();
        for seed in [0, 1] {
            counts.push((
                matched,
                count("adc", seed),
                count("adc-threshold-1e-4", seed),
            ));
            means.push((matched, mean("adc", seed), mean("adc-threshold-1e-4", seed)));
        }
    }
    for &(matched, adc, low) in &counts {
        if matched {
            assert!(low <= adc && low * 100 >= adc * 99, "{counts:?}");
        } else {
            assert!(
                low * 10 > adc * 11,
                "the lower threshold densifies more: {counts:?}"
            );
        }
    }
    // The model size over the run follows: held to adc's count at every iteration, never
    // above adc's mean; free, larger on average too (by far less than at the end: both start
    // from the same points and most of the growth comes late in this short run).
    for &(matched, adc, low) in &means {
        assert!(adc > 0.0 && low > 0.0, "{means:?}");
        if matched {
            assert!(low <= adc * (1.0 + 1e-9) && low >= adc * 0.99, "{means:?}");
        } else {
            assert!(low > adc, "{means:?}");
        }
    }
}

/// trade.json's `mean_gaussians` is the count averaged over the iterations so far: before
/// densification starts (the reference calendar's iteration 500) it is the initial count, which
/// is also the final one, exactly; the table shows it in brackets beside the final count.
#[test]
fn bench_trade_mean_count_is_the_count_over_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("trade");
    let (ok, text) = output(
        door_trade("12", &out)
            .args(["--eval-at", "5", "--calendar", "30000", "--runs", "adc"])
            .args(["--fps-frames", "1"]),
    );
    assert!(ok, "{text}");
    let json = trade_json(&out);
    let runs = json["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    for r in runs {
        let n = r["gaussians"].as_u64().unwrap();
        assert!(n > 0, "{r}");
        assert_eq!(r["mean_gaussians"].as_f64().unwrap(), n as f64, "{r}");
        let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
        assert!(md.contains(&format!("| {n} ({n}) |")), "{md}");
    }
}

/// A trained model's FPS from the scene's first test view (`--scene`), as `bench trade` times
/// its models, or from outside the model; the JSON says which camera it used.
#[test]
fn bench_fps_renders_a_ply_from_the_scene_test_view() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("model.ply");
    let model = lpmsplat::render::synthetic::random_scene(2000, 3);
    lpmsplat::splats::write_ply(&ply, &model).unwrap();
    let scene = data("lund_door_small");
    let run = |extra: &[&std::ffi::OsStr]| {
        let json = dir.path().join("fps.json");
        let _ = std::fs::remove_file(&json);
        let (ok, text) = output(
            lpmsplat()
                .args(["bench", "fps", "--ply"])
                .arg(&ply)
                .args(extra)
                .args([
                    "--width", "64", "--height", "48", "--frames", "1", "--warmup", "0",
                ])
                .arg("--json")
                .arg(&json),
        );
        let v = ok.then(|| {
            let v: serde_json::Value =
                serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
            v[0].clone()
        });
        (v, text)
    };
    let (from_view, text) = run(&["--scene".as_ref(), scene.as_os_str()]);
    let from_view = from_view.unwrap_or_else(|| panic!("{text}"));
    let camera = from_view["camera"].as_str().unwrap();
    assert!(camera.starts_with("test view "), "{from_view}");
    assert_eq!(from_view["gaussians"], 2000);
    let (outside, text) = run(&[]);
    assert_eq!(
        outside.unwrap_or_else(|| panic!("{text}"))["camera"],
        "outside the model"
    );
    let missing = dir.path().join("no-such-scene");
    let (none, text) = run(&["--scene".as_ref(), missing.as_os_str()]);
    assert!(none.is_none() && text.contains("Fix:"), "{text}");
    // --scene needs a PLY: a generated scene has its own camera.
    let (ok, text) = output(lpmsplat().args(["bench", "fps", "--scene"]).arg(&scene));
    assert!(!ok && text.contains("--ply"), "{text}");
}

#[test]
fn bench_fps_reports_each_count_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("fps.json");
    let (ok, text) = output(
        lpmsplat()
            .args(["bench", "fps", "--gaussians", "500,3000"])
            .args([
                "--width", "96", "--height", "64", "--frames", "3", "--warmup", "1",
            ])
            .arg("--json")
            .arg(&json),
    );
    assert!(ok, "{text}");
    assert!(
        text.contains("FPS back to back (two frames in flight"),
        "{text}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = v.as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for (r, n) in rows.iter().zip([500, 3000]) {
        assert_eq!(r["gaussians"], n);
        assert_eq!(
            (r["width"].as_u64(), r["height"].as_u64()),
            (Some(96), Some(64))
        );
        let ms = r["frame_ms_median"].as_f64().unwrap();
        assert!(ms > 0.0 && (r["fps_median"].as_f64().unwrap() * ms - 1e3).abs() < 1e-6);
        // Back to back: frames over wall time, the same relation.
        let piped = r["frame_ms_pipelined"].as_f64().unwrap();
        assert!(piped > 0.0 && (r["fps_pipelined"].as_f64().unwrap() * piped - 1e3).abs() < 1e-6);
        assert!(r["frame_ms_min"].as_f64().unwrap() <= ms);
        assert!(ms <= r["frame_ms_max"].as_f64().unwrap());
        assert!(r["intersections"].as_u64().unwrap() > 0);
        let stages: Vec<&str> = r["stages_ms"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s[0].as_str().unwrap())
            .collect();
        assert!(
            stages.contains(&"rasterize") && stages.contains(&"tile sort"),
            "{r}"
        );
    }
}

#[test]
fn bench_trade_rows_carry_lpm_per_step_telemetry_that_adds_up_to_the_totals() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("steps");
    // Density control (and LPM with it) runs every 100 iterations: one LPM step by 101. Small
    // blocks and a low fraction so that the 81x121 views give an error region.
    let (ok, text) = output(
        door_trade("101", &out)
            .args([
                "--fps-frames",
                "1",
                "--calendar",
                "600",
                "--runs",
                "adc,lpm",
            ])
            .args(["--lpm-block", "4", "--lpm-block-fraction", "0.5"]),
    );
    assert!(ok, "{text}");
    let json = trade_json(&out);
    let runs = json["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    assert!(runs[0]["lpm_steps"].is_null(), "ADC has no LPM steps");
    let lpm = &runs[1];
    let steps = lpm["lpm_steps"]
        .as_array()
        .expect("LPM's row has its steps");
    assert_eq!(
        steps
            .iter()
            .map(|s| s["iteration"].as_u64().unwrap())
            .collect::<Vec<_>>(),
        [100]
    );
    let sum = |k: &str| steps.iter().map(|s| s[k].as_f64().unwrap()).sum::<f64>();
    for (step, total) in [
        ("zones", "lpm_zones"),
        ("lowered", "lpm_lowered"),
        ("pruned_extra", "lpm_pruned"),
        ("opacity_reset", "lpm_reset"),
        ("added", "lpm_added"),
    ] {
        assert_eq!(sum(step), lpm[total].as_f64().unwrap(), "{step}: {lpm}");
    }
    assert!(sum("zones") > 0.0, "no zone to report: {lpm}");
    let s = &steps[0];
    assert_eq!(s["block"], 4);
    assert!(s["inside"].as_u64().unwrap() > 0, "{s}");
    assert!(
        (s["radius_mean_rel"].as_f64().unwrap() - lpm["lpm_radius"].as_f64().unwrap()).abs() < 1e-9,
        "{s}"
    );
}

/// `--lpm-threshold-ratio`: the LPM runs' multiplier inside zones. At 1 the zones are found as
/// before but nothing is densified by a lowered threshold (what is left of LPM is its resets,
/// prunes and additions); the setting is recorded and said; a ratio that is not positive is
/// refused naming the flag.
#[test]
fn bench_trade_lpm_threshold_ratio_one_lowers_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let mut lowered = Vec::new();
    for ratio in [None, Some("1")] {
        let out = dir.path().join(format!("r{}", ratio.unwrap_or("default")));
        let mut c = door_trade("101", &out);
        c.args(["--fps-frames", "1", "--calendar", "600", "--runs", "lpm"])
            .args(["--lpm-block", "4", "--lpm-block-fraction", "0.5"]);
        if let Some(r) = ratio {
            c.args(["--lpm-threshold-ratio", r]);
        }
        let (ok, text) = output(&mut c);
        assert!(ok, "{text}");
        let json = trade_json(&out);
        let r = &json["runs"][0];
        assert!(r["lpm_zones"].as_f64().unwrap() > 0.0, "no zone: {r}");
        lowered.push(r["lpm_lowered"].as_f64().unwrap());
        match ratio {
            None => assert!(json["settings"]["lpm_threshold_ratio"].is_null()),
            Some(_) => {
                assert_eq!(json["settings"]["lpm_threshold_ratio"], 1.0);
                assert!(
                    text.contains("gradient threshold × 1 inside zones"),
                    "{text}"
                );
            }
        }
    }
    assert!(lowered[0] > 0.0, "the default ratio lowers: {lowered:?}");
    assert_eq!(lowered[1], 0.0, "{lowered:?}");
    for bad in ["0", "-0.5", "inf"] {
        let (ok, text) = output(
            door_trade("2", &dir.path().join("bad"))
                .args(["--runs", "lpm"])
                .arg(format!("--lpm-threshold-ratio={bad}")),
        );
        assert!(
            !ok && text.contains("--lpm-threshold-ratio") && text.contains("Fix:"),
            "{bad}: {text}"
        );
        assert!(
            !dir.path().join("bad").exists(),
            "refused before -o is made"
        );
    }
}

#[test]
fn bench_trade_compares_the_absolute_gradient_test_side_by_side() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("abs");
    let (ok, text) = output(
        door_trade("120", &out)
            .args(["--fps-frames", "1", "--calendar", "600"])
            .args(["--runs", "adc-abs-grad,adc"]),
    );
    assert!(ok, "{text}");
    let json = trade_json(&out);
    let last: Vec<(&str, u64, f64)> = json["runs"]
        .as_array()
        .unwrap()
        .iter()
        // Density control runs every 100 iterations whatever the calendar: one step by 120.
        .filter(|r| r["iteration"] == 120)
        .map(|r| {
            (
                r["run"].as_str().unwrap(),
                r["gaussians"].as_u64().unwrap(),
                r["lpm_share"].as_f64().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        last.iter().map(|r| r.0).collect::<Vec<_>>(),
        ["adc", "adc-abs-grad"]
    );
    assert!(
        last[1].1 > last[0].1,
        "the abs test densified no more: {last:?}"
    );
    assert_eq!(last[1].2, 0.0, "adc-abs-grad is not an LPM run");
    // Models with another statistic refuse it before anything is written.
    let refused = dir.path().join("pixel");
    let (ok, text) =
        output(door_trade("5", &refused).args(["--model", "pixel-gs", "--runs", "adc-abs-grad"]));
    assert!(
        !ok && text.contains("absolute-gradient") && text.contains("Fix:"),
        "{text}"
    );
    assert!(!refused.join("trade.json").exists());
}

/// `--budget 0.5x-adc,1x-adc`: the Taming protocol's grid in one command. A free adc per seed
/// trains first (the reference); then every run at each budget, named RUN@BUDGET, the budget
/// being that share of the reference's final count at the same seed: the exact-budget runs end
/// on it, ADC capped at it stays under it, adc is not run again at 1x-adc, and each LPM-guided
/// run is paired with its unguided twin at the same budget.
#[test]
fn bench_trade_budget_grid_takes_its_budgets_from_adcs_own_count() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("grid");
    let mut c = door_trade("101", &out);
    c.args([
        "--calendar",
        "600",
        "--runs",
        "adc,adc-exact,adc-exact+lpm-local,mcmc",
    ])
    .args([
        "--budget",
        "0.5x-adc,1x-adc",
        "--fps-frames",
        "1",
        "--seed",
        "1",
    ]);
    let (ok, text) = output(&mut c);
    assert!(ok, "{text}");
    let json = trade_json(&out);
    assert_eq!(json["settings"]["budget"], "0.5x-adc,1x-adc");
    let runs = json["runs"].as_array().unwrap();
    let mut names: Vec<&str> = runs.iter().map(|r| r["run"].as_str().unwrap()).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(
        names,
        [
            "adc",
            "adc-exact+lpm-local@0.5x-adc",
            "adc-exact+lpm-local@1x-adc",
            "adc-exact@0.5x-adc",
            "adc-exact@1x-adc",
            "adc@0.5x-adc",
            "mcmc@0.5x-adc",
            "mcmc@1x-adc",
        ]
    );
    let count = |run: &str, seed: u64| {
        runs.iter()
            .find(|r| r["run"] == run && r["seed"] == seed && r["iteration"] == 101)
            .unwrap_or_else(|| panic!("{run} seed {seed}"))["gaussians"]
            .as_u64()
            .unwrap()
    };
    // One seed, not 0: several seeds paired by seed are bench_trade_match_adc_count_…'s
    // and the Slurm sweep's to show.
    let seed = 1;
    let adc = count("adc", seed);
    let half = (adc as f64 * 0.5).round() as u64;
    for exact in ["adc-exact", "adc-exact+lpm-local"] {
        let at1 = count(&format!("{exact}@1x-adc"), seed);
        let at_half = count(&format!("{exact}@0.5x-adc"), seed);
        assert!(at1 <= adc && at1 + 1 >= adc, "{exact}: {at1} for {adc}");
        assert!(
            at_half <= half && at_half + 1 >= half,
            "{exact}: {at_half} for {half}"
        );
    }
    assert!(count("adc@0.5x-adc", seed) <= half);
    // MCMC's rows say what it did towards each budget; the other
    // strategies' rows carry no MCMC totals.
    for run in ["mcmc@0.5x-adc", "mcmc@1x-adc"] {
        let row = runs
            .iter()
            .find(|r| r["run"] == run && r["iteration"] == 101)
            .unwrap();
        let mcmc = &row["mcmc"];
        assert!(mcmc["refinements"].as_u64().unwrap() > 0, "{run}: {row}");
        assert!(mcmc["relocated"].as_u64().is_some(), "{run}: {row}");
    }
    // (5 % a refinement: in 101 iterations it grows towards the budget, never past it.)
    assert!(count("mcmc@1x-adc", seed) <= adc);
    assert!(runs
        .iter()
        .filter(|r| r["mcmc"].is_object())
        .all(|r| r["run"].as_str().unwrap().starts_with("mcmc")));
    let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
    assert!(md.contains("LPM as a guide at one count"), "{md}");
    assert!(
        md.contains("| adc-exact+lpm-local@1x-adc | adc-exact@1x-adc | 101 |"),
        "{md}"
    );
    assert!(out.join("trade.png").is_file());
    // A grid cannot follow adc's count every iteration; a budget relative to adc must be
    // positive and named once.
    for (extra, says) in [
        (
            &["--budget", "0.5x-adc", "--match-adc-count"][..],
            "--match-adc-count",
        ),
        (&["--budget", "0x-adc"][..], "0.25x-adc"),
        (&["--budget", "0.5x-adc,0.5x-adc"][..], "twice"),
    ] {
        let mut c = door_trade("10", &dir.path().join("bad"));
        c.args(["--runs", "adc,mcmc"]).args(extra);
        let (ok, text) = output(&mut c);
        assert!(!ok && text.contains(says), "{extra:?}: {text}");
    }
}
