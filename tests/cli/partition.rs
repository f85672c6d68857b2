//! `partition` and `merge` without a cluster: the plan (its blocks as scenes `train` reads,
//! the same plan in a georeferenced frame, the automatic grid), the merge's crop against a
//! recount, and the readers' refusals (plan.json fuzzed, test_views.txt, missing and broken
//! blocks named).

use std::path::{Path, PathBuf};

use crate::cli_support::{lpmsplat, run, run_ok};
use lpmsplat::error::InputError;
use lpmsplat::partition::{self, merge, GridChoice, PartitionOptions, Plan, Targets};
use lpmsplat::scene::{colmap, LoadOptions, Scene};
use lpmsplat::splats::{ply::write_ply_with_comments, GaussianParams};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn opts(grid: GridChoice) -> PartitionOptions {
    PartitionOptions {
        grid,
        margin: 0.2,
        visibility: 0.25,
        budget: None,
        growth: 20.0,
        image_cache_mib: 2048.0,
        coarse: None,
    }
}

fn plan_of(root: &Path, grid: GridChoice) -> Plan {
    let scene = Scene::load_in_file_frame(root, &LoadOptions::default()).unwrap();
    let frame = scene.clone().into_training_frame().frame;
    partition::make_plan(&scene, frame, &opts(grid), vec![]).unwrap()
}

fn two_by_one() -> GridChoice {
    GridChoice::Fixed {
        columns: 2,
        rows: 1,
    }
}

/// A scene folder holding `model` (text) with the bundled door's images linked in.
fn scene_with(model: &colmap::ColmapModel, dir: &Path) -> PathBuf {
    let root = dir.join("scene");
    colmap::write_text(&root.join("sparse/0"), model).unwrap();
    std::os::unix::fs::symlink(data("lund_door_small").join("images"), root.join("images"))
        .unwrap();
    root
}

fn door_model() -> colmap::ColmapModel {
    colmap::read_model(&data("lund_door_small").join("sparse/0"), true).unwrap()
}

#[test]
fn blocks_are_scenes_that_hold_their_views_points_and_the_scenes_test_split() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("plan");
    run_ok(
        lpmsplat()
            .args(["partition"])
            .arg(data("lund_door_small"))
            .args(["--blocks", "2x1", "-o"])
            .arg(&out),
    );
    let plan = Plan::read(&out.join("plan.json")).unwrap();
    let whole = Scene::load(&data("lund_door_small"), &LoadOptions::default()).unwrap();
    let whole_test: Vec<&str> = whole
        .test
        .iter()
        .map(|&i| whole.views[i].name.as_str())
        .collect();
    let mut core_total = 0;
    for b in &plan.blocks {
        let scene = Scene::load(&out.join(&b.folder), &LoadOptions::default()).unwrap();
        let names = |ix: &[usize]| {
            let mut v: Vec<String> = ix.iter().map(|&i| scene.views[i].name.clone()).collect();
            v.sort();
            v
        };
        assert_eq!(names(&scene.train), b.train_views, "block {}", b.name);
        assert_eq!(names(&scene.test), b.test_views, "block {}", b.name);
        // Test views are the whole scene's, never one of its training views.
        assert!(b
            .test_views
            .iter()
            .all(|n| whole_test.contains(&n.as_str())));
        assert!(b
            .train_views
            .iter()
            .all(|n| !whole_test.contains(&n.as_str())));
        assert_eq!(scene.points.as_ref().unwrap().len(), b.region_points);
        assert!(b.core_points < b.region_points, "a margin adds points");
        core_total += b.core_points;
        // Images by reference.
        assert!(
            std::fs::symlink_metadata(out.join(&b.folder).join("images"))
                .unwrap()
                .file_type()
                .is_symlink()
        );
    }
    assert_eq!(
        core_total, plan.whole.points,
        "the cores share out every point"
    );

    // A second partition into the same folder is refused: it holds a plan (and maybe runs).
    let (ok, text) = run(lpmsplat()
        .args(["partition"])
        .arg(data("lund_door_small"))
        .args(["--blocks", "2x1", "-o"])
        .arg(&out));
    assert!(!ok && text.contains("holds a plan already"), "{text}");
}

/// `--loss-masks`: every block's training views have a mask; a view two blocks share is
/// learned, cell by cell, by at least one of them (the regions cover the ground, so every
/// nearest point and every ray's far end is some block's); and `train` reads the file.
#[test]
fn loss_masks_share_out_every_cell_of_a_shared_view_and_train_reads_them() {
    use lpmsplat::scene::loss_masks;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("plan");
    let text = run_ok(
        lpmsplat()
            .args(["partition"])
            .arg(data("lund_door_small"))
            .args(["--blocks", "2x1", "--loss-masks", "-o"])
            .arg(&out),
    );
    assert!(text.contains("loss masks learn"), "{text}");
    let plan = Plan::read(&out.join("plan.json")).unwrap();
    let mut per_block = Vec::new();
    for b in &plan.blocks {
        let scene = Scene::load(&out.join(&b.folder), &LoadOptions::default()).unwrap();
        let (masks, share) = loss_masks::for_scene(&scene).unwrap().expect("masks");
        assert!(share > 0.0 && share < 1.0, "block {}: {share}", b.name);
        let by_name: std::collections::HashMap<String, Vec<bool>> = scene
            .views
            .iter()
            .enumerate()
            .filter_map(|(i, v)| masks.views[i].clone().map(|m| (v.name.clone(), m)))
            .collect();
        for n in &b.train_views {
            assert!(by_name.contains_key(n), "block {}: no mask for {n}", b.name);
        }
        per_block.push(by_name);
    }
    let mut shared = 0;
    for (name, a) in &per_block[0] {
        if let Some(b) = per_block[1].get(name) {
            shared += 1;
            assert!(
                a.iter().zip(b).all(|(x, y)| *x || *y),
                "{name}: a cell nobody learns"
            );
        }
    }
    assert!(shared > 0, "the two blocks share no view");
    let block = out.join(&plan.blocks[0].folder);
    let text = run_ok(
        lpmsplat()
            .arg("train")
            .arg(&block)
            .args(["--iterations", "3", "-o"])
            .arg(tmp.path().join("run")),
    );
    assert!(text.contains("loss masks (loss_masks.json)"), "{text}");
}

#[test]
fn the_plan_is_the_same_in_a_georeferenced_kilometre_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let near = plan_of(&data("lund_door_small"), two_by_one());
    // The same capture in kilometres, rotated, 4,000 km from the origin.
    let far_model = door_model().reframed(1e-3, [0.9, 0.1, -0.3, 0.2], [4.1e6, -2.3e6, 850.0]);
    let far = plan_of(&scene_with(&far_model, tmp.path()), two_by_one());
    let key = |p: &Plan| {
        let mut k: Vec<(Vec<String>, usize, usize)> = p
            .blocks
            .iter()
            .map(|b| (b.train_views.clone(), b.core_points, b.region_points))
            .collect();
        k.sort();
        k
    };
    assert_eq!(key(&near), key(&far));
    // The merged model's shift follows the frame: none near the origin, a round one far off.
    assert_eq!(near.frame().output_shift(), [0.0; 3]);
    assert!(far.frame().output_shift()[0].abs() > 1e6);
}

#[test]
fn the_automatic_grid_is_the_coarsest_that_fits_and_an_unfittable_target_says_why() {
    let fit = plan_of(
        &data("lund_door_small"),
        GridChoice::Fit(Targets {
            max_gaussians: Some(150_000),
            ..Targets::default()
        }),
    );
    assert!(fit.blocks.len() > 1);
    assert!(fit.blocks.iter().all(|b| b.expected_gaussians <= 150_000));
    // One block fewer would not fit: the whole scene expects more than the target.
    assert!(fit.whole.expected_gaussians > 150_000);

    // Every view sees the whole door: no grid brings a block under 5 views.
    let tmp = tempfile::tempdir().unwrap();
    let (ok, text) = run(lpmsplat()
        .args(["partition"])
        .arg(data("lund_door_small"))
        .args(["--max-views", "5", "-o"])
        .arg(tmp.path().join("p")));
    assert!(!ok && text.contains("no grid up to"), "{text}");
    assert!(!tmp.path().join("p/plan.json").exists());
    for (flags, says) in [
        (vec!["--blocks", "0x2"], "is not a grid"),
        (vec!["--blocks", "2x2", "--max-views", "9"], "not both"),
        (vec![], "needs --blocks"),
        (vec!["--blocks", "2x1", "--margin=-1"], "--margin"),
    ] {
        let (ok, text) = run(lpmsplat()
            .args(["partition"])
            .arg(data("lund_door_small"))
            .args(&flags)
            .arg("-o")
            .arg(tmp.path().join("q")));
        assert!(!ok && text.contains(says), "{flags:?}: {text}");
    }
}

/// A block's run as `train` leaves it: a model in the user's frame and metrics.json.
fn fake_run(runs: &Path, name: &str, params: &GaussianParams, model: &str) {
    let dir = runs.join(name);
    std::fs::create_dir_all(&dir).unwrap();
    write_ply_with_comments(
        &dir.join("point_cloud.ply"),
        params,
        &[format!("lpmsplat model {model}")],
    )
    .unwrap();
    std::fs::write(dir.join("metrics.json"), r#"{"psnr": 20.0, "ssim": 0.5}"#).unwrap();
}

/// Gaussians spread over the SfM points' box (and beyond it), `n` of them.
fn spread(n: usize, seed: u64, lo: [f64; 3], hi: [f64; 3]) -> GaussianParams {
    let mut s = seed;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut p = GaussianParams::empty(1);
    for _ in 0..n {
        let x = [0, 1, 2].map(|k| (lo[k] + (hi[k] - lo[k]) * (1.4 * next() - 0.2)) as f32);
        p.positions.push(x);
        p.log_scales.push([-3.0; 3]);
        p.rotations.push([1.0, 0.0, 0.0, 0.0]);
        p.opacity_logits.push(0.5);
        p.sh_dc.push([0.2, 0.1, 0.0]);
        p.sh_rest.extend([0.01f32; 9]);
    }
    p
}

#[test]
fn merge_keeps_each_blocks_core_and_refuses_a_missing_or_broken_block_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = plan_of(&data("lund_door_small"), two_by_one());
    let scene =
        Scene::load_in_file_frame(&data("lund_door_small"), &LoadOptions::default()).unwrap();
    let pts = &scene.points.as_ref().unwrap().positions;
    let lo = [0, 1, 2].map(|k| pts.iter().map(|p| p[k]).fold(f64::MAX, f64::min));
    let hi = [0, 1, 2].map(|k| pts.iter().map(|p| p[k]).fold(f64::MIN, f64::max));
    let runs = tmp.path().join("runs");
    let models: Vec<GaussianParams> = (0..2).map(|k| spread(3000, k, lo, hi)).collect();
    for (b, m) in plan.blocks.iter().zip(&models) {
        fake_run(&runs, &b.name, m, "3dgs");
    }
    let merged = merge::merge(&plan, &runs).unwrap();
    // Recounted here: block k keeps its own Gaussians whose centre its core holds.
    let mut want = 0;
    for (b, m) in plan.blocks.iter().zip(&models) {
        let kept = m
            .positions
            .iter()
            .filter(|p| {
                b.core
                    .contains(plan.ground.coordinates(p.map(|x| x as f64)).0)
            })
            .count();
        assert!(kept > 300 && kept < 2700, "{kept}");
        let r = merged
            .report
            .blocks
            .iter()
            .find(|r| r.name == b.name)
            .unwrap();
        assert_eq!((r.gaussians, r.kept), (3000, kept));
        want += kept;
    }
    assert_eq!(merged.params.len(), want);
    merged.params.validate().unwrap();
    assert!(merged.params.positions.iter().all(|p| {
        plan.owner(plan.ground.coordinates(p.map(|x| x as f64)).0)
            .is_some()
    }));

    let refused = |what: &str| {
        let e = merge::merge(&plan, &runs)
            .err()
            .unwrap_or_else(|| panic!("{what}: merged"));
        format!("{e:#}")
    };
    let b1 = &plan.blocks[1].name;
    let metrics = runs.join(b1).join("metrics.json");
    std::fs::remove_file(&metrics).unwrap();
    let e = refused("missing metrics");
    assert!(
        e.contains(&format!("block {b1}")) && e.contains("has not finished"),
        "{e}"
    );
    std::fs::write(&metrics, "{\"psnr\": 2").unwrap();
    let e = refused("truncated metrics");
    assert!(
        e.contains(&format!("block {b1}")) && e.contains("not JSON"),
        "{e}"
    );
    std::fs::write(&metrics, "{}").unwrap();
    let ply = runs.join(b1).join("point_cloud.ply");
    let bytes = std::fs::read(&ply).unwrap();
    std::fs::write(&ply, &bytes[..bytes.len() / 2]).unwrap();
    let e = refused("truncated PLY");
    assert!(e.contains(b1), "{e}");
    fake_run(&runs, b1, &models[1], "2dgs");
    let e = refused("another model");
    assert!(e.contains("2dgs") && e.contains(b1), "{e}");
    // Through the CLI: the error names the block, and nothing is written.
    let (ok, text) = run(lpmsplat()
        .arg("merge")
        .arg(tmp.path().join("plan.json"))
        .arg("-o")
        .arg(tmp.path().join("merged")));
    assert!(!ok && text.contains("plan.json"), "{text}");
    assert!(!tmp.path().join("merged").exists());
}

#[test]
fn plan_reader_fuzzed_refuses_with_the_file_named_and_never_panics() {
    let tmp = tempfile::tempdir().unwrap();
    let plan = plan_of(&data("lund_door_small"), two_by_one());
    let good = serde_json::to_string_pretty(&plan).unwrap();
    let path = tmp.path().join("plan.json");
    std::fs::write(&path, &good).unwrap();
    assert_eq!(Plan::read(&path).unwrap(), plan);

    let check = |text: &str, must_fail: bool, what: &str| {
        std::fs::write(&path, text).unwrap();
        match Plan::read(&path) {
            Ok(_) => assert!(!must_fail, "{what}: accepted"),
            Err(e) => {
                let i = e
                    .downcast_ref::<InputError>()
                    .unwrap_or_else(|| panic!("{what}: not an input error: {e:#}"));
                assert_eq!(i.file, path, "{what}");
            }
        }
    };
    let mut j: serde_json::Value = serde_json::from_str(&good).unwrap();
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let edits: Vec<(&str, Edit)> = vec![
        ("version", Box::new(|j| j["version"] = 2.into())),
        ("format", Box::new(|j| j["format"] = "x".into())),
        (
            "no blocks",
            Box::new(|j| j["blocks"] = serde_json::json!([])),
        ),
        ("grid", Box::new(|j| j["columns"] = 3.into())),
        (
            "up folder",
            Box::new(|j| j["blocks"][0]["folder"] = "../elsewhere".into()),
        ),
        (
            "absolute folder",
            Box::new(|j| j["blocks"][0]["folder"] = "/tmp/x".into()),
        ),
        (
            "same name",
            Box::new(|j| j["blocks"][1]["name"] = j["blocks"][0]["name"].clone()),
        ),
        (
            "overlap",
            Box::new(|j| j["blocks"][1]["core"] = j["blocks"][0]["core"].clone()),
        ),
        (
            "gap",
            Box::new(|j| j["blocks"][1]["core"]["u"]["lo"] = 1e9.into()),
        ),
        ("scale", Box::new(|j| j["frame_scale"] = 0.into())),
        (
            "no views",
            Box::new(|j| j["blocks"][0]["train_views"] = serde_json::json!([])),
        ),
        ("string", Box::new(|j| j["margin"] = "wide".into())),
    ];
    for (what, edit) in &edits {
        let mut k = j.clone();
        edit(&mut k);
        check(&k.to_string(), true, what);
    }
    j["blocks"][0]["memory_mib"] = 1.0.into();
    check(&j.to_string(), false, "a changed estimate");
    // Truncations and byte flips: refused with the file named, or read; never a panic.
    let bytes = good.as_bytes();
    for cut in (0..bytes.len()).step_by(bytes.len() / 60 + 1) {
        check(&String::from_utf8_lossy(&bytes[..cut]), true, "truncated");
    }
    let mut s = 1u64;
    for _ in 0..300 {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut b = bytes.to_vec();
        let at = (s >> 33) as usize % b.len();
        b[at] = (s >> 17) as u8;
        check(&String::from_utf8_lossy(&b), false, "flipped");
    }
    std::fs::remove_file(&path).unwrap();
    check_missing(&path);
}

fn check_missing(path: &Path) {
    let e = Plan::read(path).unwrap_err();
    assert!(format!("{e:#}").contains("plan.json"), "{e:#}");
}

#[test]
fn test_views_txt_sets_the_split_and_a_bad_line_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let root = scene_with(&door_model(), tmp.path());
    let names: Vec<String> = door_model().images.iter().map(|i| i.name.clone()).collect();
    let list = root.join("test_views.txt");
    std::fs::write(
        &list,
        format!("# the held-out views\n\n{}\n  {}  \n", names[3], names[5]),
    )
    .unwrap();
    let scene = Scene::load(&root, &LoadOptions::default()).unwrap();
    let mut test: Vec<&str> = scene
        .test
        .iter()
        .map(|&i| scene.views[i].name.as_str())
        .collect();
    test.sort();
    let mut want = vec![names[3].as_str(), names[5].as_str()];
    want.sort();
    assert_eq!(test, want);
    assert_eq!(scene.train.len(), names.len() - 2);
    let no_eval = Scene::load(
        &root,
        &LoadOptions {
            eval_split: false,
            ..LoadOptions::default()
        },
    )
    .unwrap();
    assert!(no_eval.test.is_empty());
    for (text, line, says) in [
        (
            format!("{}\nnot_a_view.jpg\n", names[0]),
            "line 2",
            "is not a view",
        ),
        (
            format!("{}\n{}\n", names[1], names[1]),
            "line 2",
            "listed twice",
        ),
    ] {
        std::fs::write(&list, text).unwrap();
        let e = Scene::load(&root, &LoadOptions::default()).unwrap_err();
        let i = e.downcast_ref::<InputError>().unwrap();
        assert_eq!(i.file, list);
        assert!(i.field == line && i.problem.contains(says), "{i:?}");
    }
    std::fs::write(&list, [0xff, 0xfe, b'\n']).unwrap();
    let e = Scene::load(&root, &LoadOptions::default()).unwrap_err();
    assert!(e.downcast_ref::<InputError>().is_some(), "{e:#}");
}

/// Each block of `plan` (in `out`) reads as a scene whose training and test views are exactly
/// the block's, all of them views of `whole`; the transforms files are the block's own, the
/// rest of the scene folder is linked.
fn assert_transforms_blocks(out: &Path, plan: &Plan, whole: &Scene, json_files: &[&str]) {
    let names = |s: &Scene, ix: &[usize]| {
        let mut v: Vec<String> = ix.iter().map(|&i| s.views[i].name.clone()).collect();
        v.sort();
        v
    };
    let whole_train = names(whole, &whole.train);
    let whole_test = names(whole, &whole.test);
    let mut covered = std::collections::HashSet::new();
    for b in &plan.blocks {
        let dir = out.join(&b.folder);
        let scene = Scene::load(&dir, &LoadOptions::default()).unwrap();
        assert_eq!(
            names(&scene, &scene.train),
            b.train_views,
            "block {}",
            b.name
        );
        assert_eq!(names(&scene, &scene.test), b.test_views, "block {}", b.name);
        assert!(b.train_views.iter().all(|n| whole_train.contains(n)));
        assert!(b.test_views.iter().all(|n| whole_test.contains(n)));
        assert!(!b.train_views.is_empty() && b.expected_gaussians > 0);
        covered.extend(b.train_views.iter().cloned());
        for f in json_files {
            let meta = std::fs::symlink_metadata(dir.join(f));
            assert!(
                meta.as_ref().is_ok_and(|m| m.file_type().is_file()),
                "{}: {f} is the block's own file",
                b.name
            );
        }
    }
    assert_eq!(
        covered.len(),
        whole_train.len(),
        "every training view trains a block"
    );
}

/// A transforms scene (NeRF-synthetic: the bundled lego; nerfstudio: a street of cameras made
/// here) partitions like a COLMAP one: each block is its transforms file(s) cut to its frames
/// (the scene's conventions and view names kept, the split lists rewritten), the image
/// folders linked, and `train` reads it unchanged. Without SfM points the budget is shared by
/// training views, and a plan without --budget is refused, naming it.
#[test]
fn transforms_scenes_partition_into_blocks_train_reads() {
    let tmp = tempfile::tempdir().unwrap();
    let lego = data("lego_small");
    let (ok, text) = run(lpmsplat()
        .arg("partition")
        .arg(&lego)
        .args(["--blocks", "2x1", "-o"])
        .arg(tmp.path().join("refused")));
    assert!(!ok && text.contains("--budget"), "{text}");
    assert!(!tmp.path().join("refused/plan.json").exists());

    let out = tmp.path().join("lego");
    run_ok(
        lpmsplat()
            .arg("partition")
            .arg(&lego)
            .args(["--blocks", "2x1", "--budget", "20k", "-o"])
            .arg(&out),
    );
    let plan = Plan::read(&out.join("plan.json")).unwrap();
    let whole = Scene::load(&lego, &LoadOptions::default()).unwrap();
    assert_transforms_blocks(&out, &plan, &whole, &["transforms_train.json"]);
    let train_views: usize = plan.blocks.iter().map(|b| b.train_views.len()).sum();
    for b in &plan.blocks {
        let share = 20_000.0 * b.train_views.len() as f64 / whole.train.len() as f64;
        assert_eq!(b.expected_gaussians, share.ceil() as u64);
        assert!(std::fs::symlink_metadata(out.join(&b.folder).join("train"))
            .unwrap()
            .file_type()
            .is_symlink());
    }
    assert!(train_views >= whole.train.len());
    // train takes a block as it is.
    let block = out.join(&plan.blocks[0].folder);
    run_ok(
        lpmsplat()
            .arg("train")
            .arg(&block)
            .args(["--iterations", "5", "--init-points", "500", "-o"])
            .arg(tmp.path().join("run")),
    );
    assert!(tmp.path().join("run/point_cloud.ply").exists());

    // nerfstudio: sixteen cameras along a street (x), looking down, every fourth a test view,
    // one frame with its own distortion; an unread point cloud and a val list dropped.
    let street = tmp.path().join("street");
    std::fs::create_dir_all(street.join("images")).unwrap();
    let mut frames = Vec::new();
    let mut test = Vec::new();
    for i in 0..16 {
        let fp = format!("images/f{i:02}.png");
        image::RgbImage::from_fn(40, 30, |x, y| {
            image::Rgb([(x * 6) as u8, (y * 8) as u8, i * 9])
        })
        .save(street.join(&fp))
        .unwrap();
        let mut f = serde_json::json!({
            "file_path": fp,
            "transform_matrix": [
                [1.0, 0.0, 0.0, i as f64],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 3.0],
                [0.0, 0.0, 0.0, 1.0]
            ],
        });
        if i == 5 {
            f["k1"] = serde_json::json!(0.01);
        }
        if i % 4 == 2 {
            test.push(fp.clone());
        }
        frames.push(f);
    }
    let json = serde_json::json!({
        "w": 40, "h": 30, "fl_x": 40.0, "fl_y": 40.0, "cx": 20.0, "cy": 15.0,
        "frames": frames, "test_filenames": test, "val_filenames": [],
        "ply_file_path": "sparse_pc.ply",
    });
    std::fs::write(
        street.join("transforms.json"),
        serde_json::to_string_pretty(&json).unwrap(),
    )
    .unwrap();
    let out = tmp.path().join("street_plan");
    run_ok(
        lpmsplat()
            .arg("partition")
            .arg(&street)
            .args(["--blocks", "2x1", "--budget", "8k", "-o"])
            .arg(&out),
    );
    let plan = Plan::read(&out.join("plan.json")).unwrap();
    let whole = Scene::load(&street, &LoadOptions::default()).unwrap();
    assert_eq!(whole.test.len(), 4);
    assert_transforms_blocks(&out, &plan, &whole, &["transforms.json"]);
    for b in &plan.blocks {
        let j: serde_json::Value = serde_json::from_slice(
            &std::fs::read(out.join(&b.folder).join("transforms.json")).unwrap(),
        )
        .unwrap();
        assert!(j.get("val_filenames").is_none() && j.get("ply_file_path").is_none());
        assert_eq!(j["fl_x"], 40.0, "the shared intrinsics kept");
        let frames = j["frames"].as_array().unwrap();
        assert_eq!(
            frames.len(),
            b.train_views.len() + b.test_views.len(),
            "{}",
            b.name
        );
        if let Some(f) = frames.iter().find(|f| f["file_path"] == "images/f05.png") {
            assert_eq!(f["k1"], 0.01, "a frame's own fields kept");
        }
    }
    // The two blocks split the street: neither holds every training view.
    assert!(plan
        .blocks
        .iter()
        .all(|b| b.train_views.len() < whole.train.len()));
}

/// `partition --coarse`: the plan records the coarse model and counts each block's start from
/// it in the block's estimate; by default a block starts from all of it, with
/// `--coarse-backdrop S` from the Gaussians in its region and the top share S of the others
/// by opacity × area; a block task starts from its `coarse.ply` when fresh and not when it
/// resumes (`train` refuses `--init-ply` beside `--resume`); a real block run starts with its
/// Gaussians; and the flags that would contradict it are refused by name.
#[test]
fn a_coarse_model_is_every_fresh_blocks_start_and_counted_in_the_plan() {
    let tmp = tempfile::tempdir().unwrap();
    let scene =
        Scene::load_in_file_frame(&data("lund_door_small"), &LoadOptions::default()).unwrap();
    let pts = &scene.points.as_ref().unwrap().positions;
    let lo = [0, 1, 2].map(|k| pts.iter().map(|p| p[k]).fold(f64::MAX, f64::min));
    let hi = [0, 1, 2].map(|k| pts.iter().map(|p| p[k]).fold(f64::MIN, f64::max));
    let coarse = tmp.path().join("coarse.ply");
    // Opacities of eleven levels: the backdrop's ranking has something to rank.
    let mut coarse_model = spread(700, 3, lo, hi);
    for (i, o) in coarse_model.opacity_logits.iter_mut().enumerate() {
        *o = ((i * 37) % 11) as f32 - 5.0;
    }
    write_ply_with_comments(&coarse, &coarse_model, &["lpmsplat model 3dgs".to_string()]).unwrap();
    let out = tmp.path().join("plan");
    let partition = |out: &Path, more: &[&str]| {
        let mut c = lpmsplat();
        c.args(["partition"])
            .arg(data("lund_door_small"))
            .args([
                "-r",
                "4",
                "--blocks",
                "2x1",
                "--slurm",
                "--slurm-gres",
                "none",
            ])
            .args(more)
            .arg("-o")
            .arg(out)
            .args(["--", "--iterations", "5"]);
        c
    };
    let coarse_flag = ["--coarse", coarse.to_str().unwrap()];
    let text = run_ok(&mut partition(&out, &coarse_flag));
    assert!(text.contains("700 Gaussians"), "{text}");
    let plan = Plan::read(&out.join("plan.json")).unwrap();
    let c = plan
        .coarse
        .as_ref()
        .expect("the plan records the coarse model");
    assert_eq!(c.gaussians, 700);
    assert!(c.ply.is_absolute() && c.ply.ends_with("coarse.ply"));
    // The same plan without it: every block's estimate is 700 Gaussians lower, and its memory.
    run_ok(&mut partition(&tmp.path().join("bare"), &[]));
    let bare = Plan::read(&tmp.path().join("bare/plan.json")).unwrap();
    assert!(bare.coarse.is_none());
    for (b, o) in plan.blocks.iter().zip(&bare.blocks) {
        assert_eq!(
            b.expected_gaussians,
            o.expected_gaussians + 700,
            "{}",
            b.name
        );
        assert!(b.memory_mib > o.memory_mib, "{}", b.name);
        assert_eq!(b.start_gaussians, Some(700), "{}", b.name);
        let start = lpmsplat::splats::read_ply(&out.join(&b.folder).join("coarse.ply")).unwrap();
        assert_eq!(start.positions, coarse_model.positions, "{}", b.name);
    }

    // A quarter of the backdrop: each block's start is its region's Gaussians and the most
    // important quarter (rounded up) of the others, as counted in the plan and written.
    let quarter = tmp.path().join("quarter");
    run_ok(&mut partition(
        &quarter,
        &[coarse_flag[0], coarse_flag[1], "--coarse-backdrop", "0.25"],
    ));
    let qplan = Plan::read(&quarter.join("plan.json")).unwrap();
    assert_eq!(qplan.coarse.as_ref().unwrap().backdrop, 0.25);
    let importance = |i: usize| {
        let o = 1.0 / (1.0 + (-(coarse_model.opacity_logits[i] as f64)).exp());
        let s = coarse_model.log_scales[i].map(|l| (l as f64).exp());
        o * (s[0] * s[1] + s[0] * s[2] + s[1] * s[2])
    };
    for (b, o) in qplan.blocks.iter().zip(&bare.blocks) {
        let in_region = |i: usize| {
            let p = coarse_model.positions[i].map(|v| v as f64);
            b.region.contains(qplan.ground.coordinates(p).0)
        };
        let (inside, outside): (Vec<usize>, Vec<usize>) = (0..700).partition(|&i| in_region(i));
        let start =
            lpmsplat::splats::read_ply(&quarter.join(&b.folder).join("coarse.ply")).unwrap();
        let kept: Vec<usize> = (0..700)
            .filter(|&i| start.positions.contains(&coarse_model.positions[i]))
            .collect();
        let kept_outside: Vec<usize> = outside
            .iter()
            .copied()
            .filter(|i| kept.contains(i))
            .collect();
        assert!(!inside.is_empty() && !outside.is_empty(), "{}", b.name);
        assert!(inside.iter().all(|i| kept.contains(i)), "{}", b.name);
        assert_eq!(kept_outside.len(), outside.len().div_ceil(4), "{}", b.name);
        let dropped_best = outside
            .iter()
            .filter(|i| !kept.contains(i))
            .map(|&i| importance(i))
            .fold(0.0, f64::max);
        assert!(
            kept_outside.iter().all(|&i| importance(i) >= dropped_best),
            "{}: the backdrop keeps the most important",
            b.name
        );
        assert_eq!(start.len(), kept.len());
        assert_eq!(b.start_gaussians, Some(kept.len() as u64));
        assert_eq!(
            b.expected_gaussians,
            o.expected_gaussians + kept.len() as u64
        );
    }

    // A stand-in binary prints the arguments a task passes: --init-ply on a fresh start,
    // --resume and no --init-ply once the block's folder holds a checkpoint.
    let echo = tmp.path().join("echo-args.sh");
    std::fs::write(&echo, "#!/bin/sh\nprintf '%s\\n' \"$@\"\n").unwrap();
    let task = out.join("slurm/task.sh");
    let args_of_task = || {
        run_ok(
            std::process::Command::new("bash")
                .arg(&task)
                .arg("0")
                .env_remove("SLURM_ARRAY_TASK_ID")
                .env("LPMSPLAT", &echo),
        )
    };
    std::fs::set_permissions(&echo, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let run0 = out.join("runs").join(&plan.blocks[0].name);
    let fresh = args_of_task();
    let start0 = out.join(&plan.blocks[0].folder).join("coarse.ply");
    assert!(
        fresh.contains(&format!("--init-ply\n{}\n", start0.display()))
            && !fresh.contains("--resume"),
        "{fresh}"
    );
    std::fs::remove_file(run0.join("metrics.json")).ok();
    std::fs::write(run0.join("checkpoint.bin"), b"stand-in").unwrap();
    let resumed = args_of_task();
    assert!(
        resumed.contains("--resume") && !resumed.contains("--init-ply"),
        "{resumed}"
    );
    std::fs::remove_dir_all(&run0).unwrap();

    // A real block run from the printed command's start: it begins with the coarse model.
    let text = run_ok(
        lpmsplat()
            .arg("train")
            .arg(out.join(&plan.blocks[0].folder))
            .arg("-o")
            .arg(&run0)
            .args(&plan.train_args)
            .arg("--init-ply")
            .arg(&start0),
    );
    assert!(text.contains("700 initial Gaussians"), "{text}");

    // Refused, each naming the fix: the start given to train directly, a budget beside it,
    // a missing file.
    let (ok, text) = run(lpmsplat()
        .args(["partition"])
        .arg(data("lund_door_small"))
        .args(["--blocks", "2x1", "-o"])
        .arg(tmp.path().join("p2"))
        .args(["--", "--init-ply"])
        .arg(&coarse));
    assert!(!ok && text.contains("--coarse PLY"), "{text}");
    let (ok, text) = run(&mut partition(
        &tmp.path().join("p3"),
        &[coarse_flag[0], coarse_flag[1], "--budget", "20k"],
    ));
    assert!(!ok && text.contains("--coarse with --budget"), "{text}");
    let (ok, text) = run(lpmsplat()
        .args(["partition"])
        .arg(data("lund_door_small"))
        .args(["--blocks", "2x1", "--coarse"])
        .arg(tmp.path().join("nothing.ply"))
        .arg("-o")
        .arg(tmp.path().join("p4")));
    assert!(!ok && text.contains("nothing.ply"), "{text}");
    let (ok, text) = run(&mut partition(
        &tmp.path().join("p5"),
        &[coarse_flag[0], coarse_flag[1], "--coarse-backdrop", "1.5"],
    ));
    assert!(!ok && text.contains("--coarse-backdrop 1.5"), "{text}");
}

/// `partition --grow-within-region`: every block's folder holds its region as a growth region
/// (`region.json`) that holds exactly the points the plan puts in the block's region, every
/// block task passes it (`--grow-within`), and a block run densifying with it grows less than
/// without it and records it in config.json.
#[test]
fn blocks_can_grow_within_their_region_only() {
    use lpmsplat::train::density::region::GrowthRegion;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("plan");
    run_ok(
        lpmsplat()
            .args(["partition"])
            .arg(data("lund_door_small"))
            .args([
                "-r",
                "4",
                "--blocks",
                "2x1",
                "--grow-within-region",
                "--slurm",
            ])
            .args(["--slurm-gres", "none", "-o"])
            .arg(&out)
            .args(["--", "--iterations", "5"]),
    );
    let plan = Plan::read(&out.join("plan.json")).unwrap();
    assert!(plan.grow_within_region);
    let scene =
        Scene::load_in_file_frame(&data("lund_door_small"), &LoadOptions::default()).unwrap();
    let pts = &scene.points.as_ref().unwrap().positions;
    for b in &plan.blocks {
        let region = GrowthRegion::read(&out.join(&b.folder).join("region.json")).unwrap();
        let (mut inside, mut outside) = (0, 0);
        for &p in pts {
            let g = plan.ground.coordinates(p).0;
            // The cuts lie on points: one on a bound is in or out by the last bit of the
            // arithmetic, which a moving Gaussian never notices.
            let on_bound = [(g[0], b.region.u), (g[1], b.region.v)]
                .iter()
                .any(|(x, i)| [i.lo, i.hi].iter().flatten().any(|c| (x - c).abs() < 1e-9));
            if on_bound {
                continue;
            }
            let planned = b.region.contains(g);
            assert_eq!(region.contains(p), planned, "{}: {p:?}", b.name);
            if planned {
                inside += 1
            } else {
                outside += 1
            }
        }
        assert!(inside > 0 && outside > 0, "{}", b.name);
    }
    let task = std::fs::read_to_string(out.join("slurm/task.sh")).unwrap();
    for b in &plan.blocks {
        let region = out.join(&b.folder).join("region.json");
        assert!(
            task.contains(&format!("--grow-within {}", region.display())),
            "{task}"
        );
    }
    // A block run that densifies, with its region and without.
    let b = &plan.blocks[0];
    let train = |name: &str, extra: &[&str]| -> serde_json::Value {
        let run = tmp.path().join(name);
        run_ok(
            lpmsplat()
                .arg("train")
                .arg(out.join(&b.folder))
                .args(["-r", "4", "--iterations", "60", "--densify-from", "10"])
                .args([
                    "--densify-interval",
                    "10",
                    "--densify-grad-threshold",
                    "1e-6",
                ])
                .args(["--seed", "1", "-o"])
                .arg(&run)
                .args(extra),
        );
        let read = |f: &str| -> serde_json::Value {
            serde_json::from_slice(&std::fs::read(run.join(f)).unwrap()).unwrap()
        };
        let mut m = read("metrics.json");
        m["config"] = read("config.json");
        m
    };
    let region = out.join(&b.folder).join("region.json");
    let held = train("held", &["--grow-within", region.to_str().unwrap()]);
    let free = train("free", &[]);
    let count = |m: &serde_json::Value| m["gaussians"].as_u64().unwrap();
    assert!(
        count(&held) < count(&free),
        "{} vs {}",
        count(&held),
        count(&free)
    );
    assert!(held["config"]["density"]["grow_within"]["bands"].is_array());
    assert!(free["config"]["density"].get("grow_within").is_none());
    // MCMC does not grow by clones and splits: refused.
    let (ok, text) = run(lpmsplat()
        .arg("train")
        .arg(out.join(&b.folder))
        .args(["--strategy", "mcmc", "--budget", "2x", "--grow-within"])
        .arg(&region)
        .arg("-o")
        .arg(tmp.path().join("mcmc")));
    assert!(
        !ok && text.contains("--grow-within with --strategy mcmc"),
        "{text}"
    );
}
