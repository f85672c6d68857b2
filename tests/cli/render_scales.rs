//! Rendering a model at a scale other than the one it was trained at (issue 16: what users
//! come to Mip-Splatting for). The same small real scene is trained at `-r 4` as 3DGS and as
//! Mip-Splatting, then `eval` and `render` run at `-r 8` (zoom out ×2) and `-r 2` (zoom in ×2):
//! the renders have the asked size, and away from the training scale Mip-Splatting's filters
//! beat 3DGS's fixed dilation by a margin no run-to-run noise reaches (on this scene at 300
//! iterations: about +8 dB at ×½ and +2 dB at ×2, measured on lavapipe 2026-11-29, while the
//! two are within 0.5 dB at the training scale). Validation layer on.

use std::path::{Path, PathBuf};

use crate::cli_support::{lpmsplat, run_ok};

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lund_door_small")
}

/// Test-view PSNR of `ply` rendered as `model` at `-r r`.
fn eval_at(dir: &Path, ply: &Path, model: &str, r: u32) -> f64 {
    let json = dir.join(format!("eval-{model}-{r}.json"));
    run_ok(
        lpmsplat()
            .arg("eval")
            .arg(scene())
            .arg("--ply")
            .arg(ply)
            .args(["--model", model, "-r", &r.to_string(), "--json"])
            .arg(&json),
    );
    let e: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    e["psnr"].as_f64().unwrap()
}

#[test]
fn mip_splatting_holds_up_away_from_the_training_scale_where_3dgs_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let mut psnr = std::collections::BTreeMap::new();
    for model in ["3dgs", "mip-splatting"] {
        let out = dir.path().join(model);
        run_ok(
            lpmsplat()
                .arg("train")
                .arg(scene())
                .args(["-r", "4", "--iterations", "300", "--model", model, "-o"])
                .arg(&out),
        );
        let ply = out.join("point_cloud.ply");
        for r in [8, 4, 2] {
            psnr.insert((model, r), eval_at(dir.path(), &ply, model, r));
        }
        // render draws the test views at the asked scale: the source's 324×484 divided by r.
        for (r, size) in [(8, (41, 61)), (2, (162, 242))] {
            let renders = dir.path().join(format!("render-{model}-{r}"));
            run_ok(
                lpmsplat()
                    .arg("render")
                    .arg(scene())
                    .arg("--ply")
                    .arg(&ply)
                    .args(["--model", model, "-r", &r.to_string(), "--out"])
                    .arg(&renders),
            );
            let pngs: Vec<PathBuf> = std::fs::read_dir(&renders)
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|e| e == "png"))
                .collect();
            assert_eq!(pngs.len(), 2, "the two test views: {pngs:?}");
            for p in &pngs {
                assert_eq!(image::image_dimensions(p).unwrap(), size, "{}", p.display());
            }
        }
    }
    eprintln!("test-view PSNR (dB) by model and -r: {psnr:?}");
    let gain = |r| psnr[&("mip-splatting", r)] - psnr[&("3dgs", r)];
    assert!(
        gain(8) > 3.0,
        "zoomed out ×2: Mip-Splatting {:+.3} dB over 3DGS",
        gain(8)
    );
    assert!(
        gain(2) > 0.8,
        "zoomed in ×2: Mip-Splatting {:+.3} dB over 3DGS",
        gain(2)
    );
    assert!(
        gain(4).abs() < 1.5,
        "at the training scale the two are close: {:+.3} dB",
        gain(4)
    );
    for ((model, r), p) in &psnr {
        assert!(*p > 18.0, "{model} at -r {r}: {p} dB");
    }
}
