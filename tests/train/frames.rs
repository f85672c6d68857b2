//! Frame invariance end to end through the CLI: the same scene written in kilometres, far from
//! the origin (georeferenced, as UTM coordinates from a drone's GPS) and rotated trains to the
//! same test PSNR and Gaussian count as the scene as shipped, for 3DGS, 2DGS and a video model;
//! the models are written in the user's frame less the shift their header records, and `eval`
//! reads them back to the score the training reported. Before scenes were trained in a
//! normalised frame, the georeferenced door trained 12.8 dB worse and the kilometre one 3.5 dB.
//! Validation layer on.

use crate::cli_support;

use std::path::{Path, PathBuf};

use crate::cli_support::{lpmsplat, run_ok};
use lpmsplat::scene::colmap;
use lpmsplat::scene::video::npy;

const DOOR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");
const VIDEO: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/n3v_tiny");

/// The PSNR two runs of one frame may differ by, over the training views. Training is not
/// bit-reproducible on the GPU (float atomics add in any order), and a short run amplifies
/// that: three runs of one frame spread 0.9 dB on the door's two test views at `-r 2`, 400
/// iterations (2026-12-01), so the comparison is over its ten training views, which spread
/// less. The failures this guards against were 3.5 and 12.8 dB.
const PSNR_SPREAD_DB: f64 = 1.0;

/// A Gaussian count two runs of one frame may differ by (runs of one frame agree within 0.2 %).
const COUNT_SPREAD: f64 = 0.02;

const UTM: [f64; 3] = [510_000.0, 4_000_000.0, 124.0];

fn reframed_colmap(dir: &Path, scale: f64, rotation: [f64; 4], offset: [f64; 3]) -> PathBuf {
    let src = Path::new(DOOR);
    let sparse = colmap::find_sparse_dir(src).unwrap();
    let model = colmap::read_model(&sparse, colmap::use_binary(&sparse, Default::default()))
        .unwrap()
        .reframed(scale, rotation, offset);
    colmap::write_text(&dir.join("sparse/0"), &model).unwrap();
    std::os::unix::fs::symlink(src.join("images"), dir.join("images")).unwrap();
    dir.to_path_buf()
}

/// The video fixture with its world moved by `offset` (LLFF poses: the fourth column of each
/// camera's 3×5 block is its centre; rotations and bounds stay).
fn reframed_video(dir: &Path, offset: [f64; 3]) -> PathBuf {
    let src = Path::new(VIDEO);
    let poses = npy::read_array2(&src.join("poses_bounds.npy")).unwrap();
    let mut data = poses.data.clone();
    for r in 0..poses.rows {
        for k in 0..3 {
            data[r * poses.cols + k * 5 + 3] += offset[k];
        }
    }
    npy::write_array2(&dir.join("poses_bounds.npy"), poses.rows, poses.cols, &data).unwrap();
    for e in std::fs::read_dir(src).unwrap().flatten() {
        let name = e.file_name();
        if name.to_string_lossy().starts_with("cam") {
            std::os::unix::fs::symlink(e.path(), dir.join(&name)).unwrap();
        }
    }
    dir.to_path_buf()
}

#[derive(Clone)]
struct Run {
    /// The run's own final test PSNR.
    psnr: f64,
    /// `eval --split train` of its model.
    train_psnr: f64,
    gaussians: f64,
    ply: PathBuf,
}

fn train(scene: &Path, out: &Path, extra: &[&str]) -> Run {
    let mut c = lpmsplat();
    c.arg("train").arg(scene).arg("-o").arg(out).args(extra);
    run_ok(&mut c);
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    let ply = out.join("point_cloud.ply");
    let json = out.join("train_views.json");
    // The training's own -r (and --model, which the file's header must agree with).
    let mut keep = Vec::new();
    let mut it = extra.iter();
    while let Some(a) = it.next() {
        if matches!(*a, "-r" | "--model") {
            keep.push(*a);
            keep.extend(it.next().copied());
        }
    }
    let mut c = lpmsplat();
    c.arg("eval")
        .arg(scene)
        .arg("--ply")
        .arg(&ply)
        .args(["--split", "train", "--json"])
        .arg(&json)
        .args(&keep);
    run_ok(&mut c);
    let ev: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    Run {
        psnr: m["psnr"].as_f64().unwrap(),
        train_psnr: ev["psnr"].as_f64().unwrap(),
        gaussians: m["gaussians"].as_f64().unwrap(),
        ply,
    }
}

fn header(ply: &Path) -> String {
    let bytes = std::fs::read(ply).unwrap();
    let end = bytes.windows(10).position(|w| w == b"end_header").unwrap();
    String::from_utf8_lossy(&bytes[..end]).to_string()
}

/// Compares every frame's run with the one as shipped.
fn check(model: &str, base: &Run, runs: &[(&str, &Run)]) {
    for (name, r) in runs {
        let dpsnr = r.train_psnr - base.train_psnr;
        let dcount = r.gaussians / base.gaussians - 1.0;
        eprintln!(
            "{model} {name}: training views {:.3} dB ({dpsnr:+.3}), test views {:.3} dB \
             ({:+.3}), {} Gaussians ({:+.2} %)",
            r.train_psnr,
            r.psnr,
            r.psnr - base.psnr,
            r.gaussians,
            100.0 * dcount
        );
        assert!(
            dpsnr.abs() < PSNR_SPREAD_DB,
            "{model} {name}: PSNR {:.3} on the training views where the scene as shipped \
             gives {:.3}",
            r.train_psnr,
            base.train_psnr
        );
        assert!(
            dcount.abs() < COUNT_SPREAD,
            "{model} {name}: {} Gaussians where the scene as shipped gives {}",
            r.gaussians,
            base.gaussians
        );
    }
}

/// `eval` of a trained model on its scene scores what the training's final evaluation did:
/// the model went out to the user's frame (less its shift) and came back.
fn eval_matches(scene: &Path, run: &Run, extra: &[&str]) {
    let json = run.ply.with_extension("eval.json");
    let mut c = lpmsplat();
    c.arg("eval")
        .arg(scene)
        .arg("--ply")
        .arg(&run.ply)
        .args(extra)
        .arg("--json")
        .arg(&json);
    let text = run_ok(&mut c);
    let ev: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let psnr = ev["psnr"].as_f64().unwrap();
    assert!(
        (psnr - run.psnr).abs() < 0.02,
        "eval {psnr} vs training {}:\n{text}",
        run.psnr
    );
}

/// The short door run of the still models' tests: `-r 8`, 200 iterations, densifying from 100
/// every 50.
fn door_run(model: &str) -> [&str; 10] {
    [
        "--model",
        model,
        "-r",
        "8",
        "--iterations",
        "200",
        "--densify-from",
        "100",
        "--densify-interval",
        "50",
    ]
}

#[test]
fn gaussians_3d_train_alike_in_every_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let args = door_run("3dgs");
    let base = train(Path::new(DOOR), &tmp.path().join("base"), &args);
    let frames: [(&str, f64, [f64; 4], [f64; 3]); 3] = [
        ("kilometres", 0.001, [1.0, 0.0, 0.0, 0.0], [0.0; 3]),
        ("georeferenced", 1.0, [1.0, 0.0, 0.0, 0.0], UTM),
        ("rotated", 1.0, [0.9, 0.3, -0.2, 0.25], [3.0, -2.0, 1.0]),
    ];
    let mut runs = Vec::new();
    for (name, scale, rotation, offset) in frames {
        let dir = tmp.path().join(name.replace(' ', "_"));
        std::fs::create_dir_all(&dir).unwrap();
        let scene = reframed_colmap(&dir, scale, rotation, offset);
        runs.push((
            name,
            train(&scene, &tmp.path().join(format!("out_{name}")), &args),
        ));
    }
    let named: Vec<(&str, &Run)> = runs.iter().map(|(n, r)| (*n, r)).collect();
    check("3dgs", &base, &named);
    // The model says which model it is; a scene near the origin is written as it is.
    let h = header(&base.ply);
    assert!(h.contains("comment lpmsplat model 3dgs"), "{h}");
    assert!(!h.contains("lpmsplat shift"), "{h}");
    // The georeferenced one is written relative to a round shift near the scene, and reads
    // back through it.
    let geo = runs[1].1.clone();
    let h = header(&geo.ply);
    assert!(
        h.contains("comment lpmsplat shift 510000.0 4000000.0 120.0"),
        "{h}"
    );
    let params = lpmsplat::splats::read_ply(&geo.ply).unwrap();
    let base_params = lpmsplat::splats::read_ply(&base.ply).unwrap();
    assert!(!base_params.is_empty());
    assert!(
        params.positions.iter().flatten().all(|v| v.abs() < 1e3),
        "stored positions are relative to the shift"
    );
    eval_matches(&tmp.path().join("georeferenced"), &geo, &["-r", "8"]);
    // The kilometre model is in kilometres: its positions lie within the scene's 7 m.
    let km = lpmsplat::splats::read_ply(&runs[0].1.ply).unwrap();
    let mut xs: Vec<f32> = km.positions.iter().map(|p| p[0]).collect();
    xs.sort_by(f32::total_cmp);
    let spread = xs[xs.len() * 9 / 10] - xs[xs.len() / 10];
    assert!(spread > 1e-4 && spread < 0.02, "km spread {spread}");
}

#[test]
fn surfels_train_alike_far_from_the_origin() {
    let tmp = tempfile::tempdir().unwrap();
    let args = door_run("2dgs");
    let base = train(Path::new(DOOR), &tmp.path().join("base"), &args);
    let dir = tmp.path().join("geo");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = reframed_colmap(&dir, 1.0, [1.0, 0.0, 0.0, 0.0], UTM);
    let geo = train(&scene, &tmp.path().join("out_geo"), &args);
    check("2dgs", &base, &[("georeferenced", &geo)]);
    assert!(header(&base.ply).contains("comment lpmsplat model 2dgs"));
    // Without --model, eval reads the file as the 2DGS model its header records; a --model
    // that contradicts it is refused, naming both.
    eval_matches(&scene, &geo, &["-r", "8"]);
    let mut c = lpmsplat();
    c.arg("eval")
        .arg(&scene)
        .args(["-r", "8", "--model", "3dgs", "--ply"])
        .arg(&geo.ply);
    let (ok, text) = cli_support::run(&mut c);
    assert!(
        !ok && text.contains("2dgs") && text.contains("--model 3dgs") && text.contains("Fix:"),
        "{text}"
    );
}

#[test]
fn a_video_model_trains_alike_far_from_the_origin() {
    let tmp = tempfile::tempdir().unwrap();
    let args = [
        "--model",
        "spacetime-lite",
        "--iterations",
        "200",
        "--init-points",
        "2000",
    ];
    let base = train(Path::new(VIDEO), &tmp.path().join("base"), &args);
    let dir = tmp.path().join("geo");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = reframed_video(&dir, UTM);
    let geo = train(&scene, &tmp.path().join("out_geo"), &args);
    let h = header(&geo.ply);
    assert!(
        h.contains("comment lpmsplat model spacetime-lite") && h.contains("lpmsplat shift"),
        "{h}"
    );
    eval_matches(&scene, &geo, &[]);
    check("spacetime-lite", &base, &[("georeferenced", &geo)]);
}
