//! transforms.json scenes: the shipped lego_small copy, generated nerfstudio scenes, bad input,
//! and (when present) the full ../shared/data/lego.

use lpmsplat::scene::images::{decode_image, load_images, resize_area};
use lpmsplat::scene::split::axes_convergence_point;
use lpmsplat::scene::undistort::undistort_image;
use lpmsplat::scene::{CameraModel, LoadOptions, NerfTestSplit, Pose, Scene, SceneFormat};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

fn lego_small() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lego_small")
}

fn read(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Independent oracle for the OpenGL → OpenCV conversion: world point → pixel, straight from the
/// camera-to-world matrix of an OpenGL camera (x right, y up, looking down −z).
fn project_opengl(c2w: &Value, f: (f64, f64), c: (f64, f64), p: [f64; 3]) -> Option<[f64; 2]> {
    let m = |r: usize, k: usize| c2w[r][k].as_f64().unwrap();
    let d = [p[0] - m(0, 3), p[1] - m(1, 3), p[2] - m(2, 3)];
    // Camera-space coordinates: dot products with the columns (the camera axes in world space).
    let axis = |k: usize| (0..3).map(|r| m(r, k) * d[r]).sum::<f64>();
    let (x, y, z) = (axis(0), axis(1), axis(2));
    if z >= 0.0 {
        return None; // behind an OpenGL camera
    }
    let depth = -z;
    // Image y grows downwards while camera y points up.
    Some([f.0 * x / depth + c.0, -f.1 * y / depth + c.1])
}

fn err_text(r: anyhow::Result<Scene>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn lego_small_loads() {
    let root = lego_small();
    let scene = Scene::load_in_file_frame(&root, &LoadOptions::default()).unwrap();
    assert_eq!(scene.format, SceneFormat::NerfSynthetic);
    assert_eq!(scene.views.len(), 11);
    assert_eq!(scene.train.len(), 8);
    assert_eq!(scene.test.len(), 3);
    assert_eq!(scene.background, Some([1.0, 1.0, 1.0]));
    assert!(scene.has_alpha);
    assert!(scene.points.is_none());
    let names: Vec<&str> = scene.views.iter().map(|v| v.name.as_str()).collect();
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(names, sorted);
    assert!(scene.train_views().all(|v| v.name.starts_with("train/")));
    assert!(scene.test_views().all(|v| v.name.starts_with("val/")));
    assert!(names.contains(&"train/r_12") && names.contains(&"val/r_33"));

    let train_json = read(&root.join("transforms_train.json"));
    let val_json = read(&root.join("transforms_val.json"));
    let angle = train_json["camera_angle_x"].as_f64().unwrap();
    let focal = 0.5 * 100.0 / (0.5 * angle).tan();
    for v in &scene.views {
        assert_eq!((v.source_width, v.source_height), (100, 100));
        assert_eq!((v.camera.width, v.camera.height), (100, 100));
        assert!(
            (v.camera.fx - focal).abs() < 1e-9 && (v.camera.fy - focal).abs() < 1e-9,
            "{}",
            v.camera.fx
        );
        assert_eq!((v.camera.cx, v.camera.cy), (50.0, 50.0));
        assert_eq!(
            v.source_model,
            CameraModel::Pinhole {
                fx: focal,
                fy: focal,
                cx: 50.0,
                cy: 50.0
            }
        );
        assert_eq!(v.stem, v.name.rsplit('/').next().unwrap());
        assert!(v.image_path.is_file());
    }

    let mut rng = Pcg64::seed_from_u64(7);
    for (json, split) in [(&train_json, "train"), (&val_json, "val")] {
        for frame in json["frames"].as_array().unwrap() {
            let fp = frame["file_path"].as_str().unwrap();
            let name = format!("{split}/{}", fp.rsplit('/').next().unwrap());
            let v = scene.views.iter().find(|v| v.name == name).unwrap();
            let c2w = &frame["transform_matrix"];
            // Camera centre: the matrix's translation column, about 4.03 from the object (up to
            // the float32 rounding of the stored rotations, which are not exactly orthonormal).
            let c = v.pose.center();
            for k in 0..3 {
                assert!((c[k] - c2w[k][3].as_f64().unwrap()).abs() < 1e-5);
            }
            let r = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
            assert!((4.0..4.06).contains(&r), "{name}: radius {r}");
            // The object centre (world origin) projects near the image centre, in front.
            let o = v.pose.transform([0.0; 3]);
            assert!(o[2] > 3.9, "{name}: origin depth {}", o[2]);
            let uv = v.camera.project(o);
            assert!(
                (uv[0] - 50.0).abs() < 2.0 && (uv[1] - 50.0).abs() < 2.0,
                "{name}: {uv:?}"
            );
            // Up in the world (+z for Blender scenes) is up in the image: a sign error in the y
            // flip would still put the origin at the centre, this catches it.
            let above = v.camera.project(v.pose.transform([0.0, 0.0, 0.5]));
            assert!(above[1] < uv[1] - 1.0, "{name}: {above:?} vs {uv:?}");
            // Random points agree with the OpenGL oracle.
            for _ in 0..20 {
                let p = [
                    rng.gen_range(-1.5..1.5),
                    rng.gen_range(-1.5..1.5),
                    rng.gen_range(-1.5..1.5),
                ];
                let want = project_opengl(c2w, (focal, focal), (50.0, 50.0), p).unwrap();
                let got = v.camera.project(v.pose.transform(p));
                assert!(
                    (want[0] - got[0]).abs() < 1e-9 && (want[1] - got[1]).abs() < 1e-9,
                    "{want:?} {got:?}"
                );
            }
        }
    }

    // Extent: 1.1 × the largest distance of a training camera centre from their mean.
    let centers: Vec<[f64; 3]> = scene.train_views().map(|v| v.pose.center()).collect();
    let mean: Vec<f64> = (0..3)
        .map(|k| centers.iter().map(|c| c[k]).sum::<f64>() / 8.0)
        .collect();
    let max_d = centers
        .iter()
        .map(|c| (0..3).map(|k| (c[k] - mean[k]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    assert!((scene.extent - 1.1 * max_d).abs() < 1e-12);
    for (got, want) in scene.center.iter().zip(&mean) {
        assert!((got - want).abs() < 1e-12);
    }
}

#[test]
fn lego_small_options() {
    let root = lego_small();
    let half = Scene::load(
        &root,
        &LoadOptions {
            resolution_factor: Some(2),
            ..Default::default()
        },
    )
    .unwrap();
    let full = Scene::load(&root, &LoadOptions::default()).unwrap();
    for (h, f) in half.views.iter().zip(&full.views) {
        assert_eq!((h.camera.width, h.camera.height), (50, 50));
        assert!((h.camera.fx - f.camera.fx / 2.0).abs() < 1e-12);
        assert_eq!((h.camera.cx, h.camera.cy), (25.0, 25.0));
        assert_eq!(h.source_model, f.source_model);
    }
    let val = Scene::load(
        &root,
        &LoadOptions {
            nerf_test_split: NerfTestSplit::Val,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(val.test, full.test);
    let e = err_text(Scene::load(
        &root,
        &LoadOptions {
            nerf_test_split: NerfTestSplit::Test,
            ..Default::default()
        },
    ));
    assert!(e.contains("transforms_test.json"), "{e}");
    let all = Scene::load(
        &root,
        &LoadOptions {
            eval_split: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(all.train.len(), 11);
    assert!(all.test.is_empty());
}

#[test]
fn nerf_synthetic_with_test_file_prefers_it() {
    let dir = tempfile::tempdir().unwrap();
    copy_dir(&lego_small(), dir.path());
    // A test split made of two val frames, under a distinct folder name.
    let mut test = read(&dir.path().join("transforms_val.json"));
    let frames = test["frames"].as_array_mut().unwrap();
    frames.truncate(2);
    std::fs::create_dir_all(dir.path().join("test")).unwrap();
    for f in frames.iter_mut() {
        let fp = f["file_path"].as_str().unwrap().to_string();
        let new = fp.replace("val", "test");
        std::fs::copy(
            dir.path().join(format!("{fp}.png")),
            dir.path().join(format!("{new}.png")),
        )
        .unwrap();
        f["file_path"] = json!(new);
    }
    std::fs::write(dir.path().join("transforms_test.json"), test.to_string()).unwrap();
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views.len(), 13);
    assert_eq!(scene.test.len(), 2);
    assert!(scene.test_views().all(|v| v.name.starts_with("test/")));
    let val = Scene::load(
        dir.path(),
        &LoadOptions {
            nerf_test_split: NerfTestSplit::Val,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(val.test_views().all(|v| v.name.starts_with("val/")) && val.test.len() == 3);
}

fn copy_dir(src: &Path, dst: &Path) {
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            std::fs::create_dir_all(&to).unwrap();
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), to).unwrap();
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Generated nerfstudio scenes

const W: u32 = 40;
const H: u32 = 30;

fn random_c2w(rng: &mut Pcg64) -> Value {
    let q: Vec<f64> = (0..4).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    let r = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let c: Vec<f64> = (0..3).map(|_| rng.gen_range(-3.0..3.0)).collect();
    json!([
        [r[0][0], r[0][1], r[0][2], c[0]],
        [r[1][0], r[1][1], r[1][2], c[1]],
        [r[2][0], r[2][1], r[2][2], c[2]],
        [0.0, 0.0, 0.0, 1.0]
    ])
}

fn write_png(path: &Path, w: u32, h: u32, alpha: bool, rng: &mut Pcg64) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    if alpha {
        image::RgbaImage::from_fn(w, h, |_, _| image::Rgba(rng.gen()))
            .save(path)
            .unwrap();
    } else {
        image::RgbImage::from_fn(w, h, |_, _| image::Rgb(rng.gen()))
            .save(path)
            .unwrap();
    }
}

/// A nerfstudio scene of `n` frames with images/frame_XXXX.png; returns its transforms.json.
fn nerfstudio_scene(dir: &Path, n: usize, alpha: bool, seed: u64) -> Value {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut frames = Vec::new();
    for i in 0..n {
        let fp = format!("images/frame_{i:04}.png");
        write_png(&dir.join(&fp), W, H, alpha, &mut rng);
        frames.push(json!({ "file_path": fp, "transform_matrix": random_c2w(&mut rng) }));
    }
    json!({ "w": W, "h": H, "fl_x": 50.0, "cx": 20.5, "cy": 15.25, "frames": frames })
}

fn write_json(dir: &Path, name: &str, v: &Value) {
    std::fs::write(dir.join(name), serde_json::to_string_pretty(v).unwrap()).unwrap();
}

#[test]
fn nerfstudio_distortion_overrides_and_split() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = nerfstudio_scene(dir.path(), 6, false, 1);
    t["fl_y"] = json!(52.0);
    t["k1"] = json!(0.11);
    t["k2"] = json!(-0.025);
    t["p1"] = json!(0.0013);
    t["p2"] = json!(-0.0021);
    // Frame 2 has its own focal length and principal point x; frame 4 its own k1.
    t["frames"][2]["fl_x"] = json!(61.5);
    t["frames"][2]["cx"] = json!(19.0);
    t["frames"][4]["k1"] = json!(-0.05);
    t["train_filenames"] = json!([
        "images/frame_0000.png",
        "./images/frame_0002.png",
        "images/frame_0003.png",
        "images/frame_0005.png"
    ]);
    t["test_filenames"] = json!(["images/frame_0001.png", "images/frame_0004.png"]);
    write_json(dir.path(), "transforms.json", &t);

    let scene = Scene::load_in_file_frame(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.format, SceneFormat::Nerfstudio);
    assert_eq!(scene.background, None);
    assert!(!scene.has_alpha);
    assert_eq!(scene.views.len(), 6);
    let name = |k: usize| scene.views[k].name.clone();
    let train: Vec<String> = scene.train.iter().map(|&k| name(k)).collect();
    let test: Vec<String> = scene.test.iter().map(|&k| name(k)).collect();
    assert_eq!(
        train,
        [
            "images/frame_0000.png",
            "images/frame_0002.png",
            "images/frame_0003.png",
            "images/frame_0005.png"
        ]
    );
    assert_eq!(test, ["images/frame_0001.png", "images/frame_0004.png"]);

    for (i, v) in scene.views.iter().enumerate() {
        let frame = &t["frames"][i];
        assert_eq!(v.name, frame["file_path"].as_str().unwrap());
        assert_eq!(v.stem, format!("frame_{i:04}"));
        let (fx, cx) = if i == 2 { (61.5, 19.0) } else { (50.0, 20.5) };
        let k1 = if i == 4 { -0.05 } else { 0.11 };
        let want = CameraModel::OpenCv {
            fx,
            fy: 52.0,
            cx,
            cy: 15.25,
            k1,
            k2: -0.025,
            p1: 0.0013,
            p2: -0.0021,
        };
        assert_eq!(v.source_model, want, "frame {i}");
        assert_eq!(
            (v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy),
            (fx, 52.0, cx, 15.25)
        );
        assert_eq!(
            (
                v.camera.width,
                v.camera.height,
                v.source_width,
                v.source_height
            ),
            (W, H, W, H)
        );
        let mut rng = Pcg64::seed_from_u64(100 + i as u64);
        for _ in 0..20 {
            let p = [
                rng.gen_range(-5.0..5.0),
                rng.gen_range(-5.0..5.0),
                rng.gen_range(-5.0..5.0),
            ];
            let Some(want) = project_opengl(&frame["transform_matrix"], (fx, 52.0), (cx, 15.25), p)
            else {
                continue;
            };
            let cam = v.pose.transform(p);
            assert!(cam[2] > 0.0);
            let got = v.camera.project(cam);
            assert!(
                (want[0] - got[0]).abs() < 1e-6 && (want[1] - got[1]).abs() < 1e-6,
                "{want:?} {got:?}"
            );
        }
    }

    // Pixels go through undistortion with the view's own model, then the resize.
    let images = load_images(&scene, &[0, 2, 4]).unwrap();
    for (img, &k) in images.iter().zip(&[0usize, 2, 4]) {
        let v = &scene.views[k];
        assert!(matches!(v.source_model, CameraModel::OpenCv { .. }));
        let want = resize_area(
            &undistort_image(&v.source_model, &decode_image(&v.image_path).unwrap()),
            W,
            H,
        );
        assert_eq!(img, &want);
        assert!(img.alpha.is_none());
    }

    // -r 2: the pinhole part scales with the image.
    let half = Scene::load(
        dir.path(),
        &LoadOptions {
            resolution_factor: Some(2),
            ..Default::default()
        },
    )
    .unwrap();
    let c = half.views[2].camera;
    assert_eq!((c.width, c.height), (20, 15));
    assert!(
        (c.fx - 61.5 / 2.0).abs() < 1e-12
            && (c.cx - 9.5).abs() < 1e-12
            && (c.cy - 7.625).abs() < 1e-12
    );
    let imgs = load_images(&half, &[1]).unwrap();
    assert_eq!((imgs[0].width, imgs[0].height), (20, 15));
}

#[test]
fn nerfstudio_pinhole_angle_and_holdout() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = nerfstudio_scene(dir.path(), 10, true, 2);
    let top = t.as_object_mut().unwrap();
    top.remove("fl_x");
    top.remove("cx");
    top.remove("cy");
    top.insert("camera_angle_x".into(), json!(0.9));
    top.insert("k1".into(), json!(0.0));
    write_json(dir.path(), "transforms.json", &t);

    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert!(scene.has_alpha);
    let f = 0.5 * W as f64 / (0.45f64).tan();
    for v in &scene.views {
        assert_eq!(
            v.source_model,
            CameraModel::Pinhole {
                fx: f,
                fy: f,
                cx: 20.0,
                cy: 15.0
            }
        );
    }
    // No split lists: every 8th view by name is held out.
    let test: Vec<&str> = scene.test_views().map(|v| v.name.as_str()).collect();
    assert_eq!(test, ["images/frame_0000.png", "images/frame_0008.png"]);
    assert_eq!(scene.train.len(), 8);
    // Undistorted views are loaded as decoded, alpha kept.
    let imgs = load_images(&scene, &[3]).unwrap();
    assert_eq!(imgs[0], decode_image(&scene.views[3].image_path).unwrap());
    assert!(imgs[0].alpha.is_some());

    // Only test_filenames: the rest is train.
    t["test_filenames"] = json!(["images/frame_0003.png"]);
    write_json(dir.path(), "transforms.json", &t);
    let s = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(s.test.len(), 1);
    assert_eq!(s.views[s.test[0]].name, "images/frame_0003.png");
    assert_eq!(s.train.len(), 9);
}

// ---------------------------------------------------------------------------------------------
// Bad input: every error names the file and the field.

/// Writes a 3-frame nerfstudio scene, lets `edit` spoil it, loads it and returns the error.
fn broken(edit: impl FnOnce(&Path, &mut Value)) -> String {
    let dir = tempfile::tempdir().unwrap();
    let mut t = nerfstudio_scene(dir.path(), 3, false, 3);
    edit(dir.path(), &mut t);
    write_json(dir.path(), "transforms.json", &t);
    err_text(Scene::load(dir.path(), &LoadOptions::default()))
}

fn assert_names(e: &str, parts: &[&str]) {
    eprintln!("{e}");
    for p in parts {
        assert!(e.contains(p), "error should mention {p:?}: {e}");
    }
}

#[test]
fn bad_nerfstudio_inputs() {
    let e = broken(|_, t| {
        t.as_object_mut().unwrap().remove("frames");
    });
    assert_names(&e, &["transforms.json", "frames", "missing"]);
    assert_names(
        &broken(|_, t| t["frames"] = json!([])),
        &["transforms.json", "frames", "empty"],
    );
    assert_names(
        &broken(|_, t| t["frames"] = json!(3)),
        &["transforms.json", "frames"],
    );
    let e = broken(|_, t| {
        t.as_object_mut().unwrap().remove("fl_x");
    });
    assert_names(&e, &["transforms.json", "frames[0].fl_x", "missing"]);
    let e = broken(|_, t| {
        t["frames"][1].as_object_mut().unwrap().remove("file_path");
    });
    assert_names(&e, &["transforms.json", "frames[1].file_path", "missing"]);
    let e = broken(|_, t| {
        t["frames"][2]
            .as_object_mut()
            .unwrap()
            .remove("transform_matrix");
    });
    assert_names(
        &e,
        &["transforms.json", "frames[2].transform_matrix", "missing"],
    );
    let e = broken(|_, t| {
        t["frames"][1]["transform_matrix"]
            .as_array_mut()
            .unwrap()
            .pop();
    });
    assert_names(&e, &["transforms.json", "frames[1].transform_matrix", "4"]);
    let e = broken(|_, t| t["frames"][0]["transform_matrix"][2] = json!([1, 2, 3]));
    assert_names(
        &e,
        &["transforms.json", "frames[0].transform_matrix", "row 2"],
    );
    let e = broken(|_, t| t["frames"][0]["transform_matrix"][1][1] = json!("x"));
    assert_names(
        &e,
        &["transforms.json", "frames[0].transform_matrix", "[1][1]"],
    );
    let e = broken(|_, t| t["fl_x"] = json!("fifty"));
    assert_names(&e, &["transforms.json", "fl_x", "number"]);
    let e = broken(|_, t| t["fl_x"] = json!(-3.0));
    assert_names(&e, &["transforms.json", "fl_x", "positive"]);
    let e = broken(|dir, _| std::fs::remove_file(dir.join("images/frame_0001.png")).unwrap());
    assert_names(
        &e,
        &[
            "transforms.json",
            "frames[1].file_path",
            "frame_0001.png",
            "not found",
        ],
    );
    let e =
        broken(|dir, _| std::fs::write(dir.join("images/frame_0002.png"), b"not a png").unwrap());
    assert_names(
        &e,
        &["transforms.json", "frames[2].file_path", "frame_0002.png"],
    );
    let e = broken(|_, t| t["w"] = json!(41));
    assert_names(&e, &["transforms.json", "w", "frame_0000.png", "40x30"]);
    let e = broken(|_, t| t["frames"][1]["h"] = json!(31));
    assert_names(&e, &["transforms.json", "frames[1].h", "frame_0001.png"]);
    let e = broken(|_, t| t["w"] = json!(0));
    assert_names(&e, &["transforms.json", "w", "zero-area"]);
    let e = broken(|dir, _| {
        std::fs::write(dir.join("images/frame_0000.png"), zero_width_png()).unwrap()
    });
    assert_names(
        &e,
        &["transforms.json", "frames[0].file_path", "frame_0000.png"],
    );
    let e = broken(|_, t| t["camera_model"] = json!("OPENCV_FISHEYE"));
    assert_names(&e, &["transforms.json", "camera_model", "OPENCV_FISHEYE"]);
    let e = broken(|_, t| t["frames"][1]["k3"] = json!(0.1));
    assert_names(&e, &["transforms.json", "frames[1].k3"]);
    let e =
        broken(|_, t| t["train_filenames"] = json!(["images/frame_0000.png", "images/nope.png"]));
    assert_names(&e, &["transforms.json", "train_filenames[1]", "nope.png"]);
    let e = broken(|_, t| {
        t["train_filenames"] = json!(["images/frame_0000.png", "images/frame_0001.png"]);
        t["test_filenames"] = json!(["images/frame_0001.png"]);
    });
    assert_names(&e, &["transforms.json", "both"]);
    let e = broken(|_, t| t["frames"][2]["file_path"] = t["frames"][0]["file_path"].clone());
    assert_names(&e, &["transforms.json", "frames[2].file_path", "frames[0]"]);
}

#[test]
fn malformed_and_non_finite_json() {
    let dir = tempfile::tempdir().unwrap();
    let t = nerfstudio_scene(dir.path(), 2, false, 4);
    let good = serde_json::to_string_pretty(&t).unwrap();

    // A missing comma: the error gives the line and column.
    let bad = good.replacen("\"h\": 30,", "\"h\": 30", 1);
    std::fs::write(dir.path().join("transforms.json"), &bad).unwrap();
    let e = err_text(Scene::load(dir.path(), &LoadOptions::default()));
    let line = bad.lines().position(|l| l.contains("\"h\": 30")).unwrap() + 2;
    assert_names(
        &e,
        &["transforms.json", &format!("line {line}"), "malformed JSON"],
    );

    // NaN as Python's json module writes it: named as the matrix element.
    let m = &t["frames"][1]["transform_matrix"][0][2];
    let nan = good.replacen(&m.to_string(), "NaN", 1);
    assert_ne!(nan, good);
    std::fs::write(dir.path().join("transforms.json"), &nan).unwrap();
    let e = err_text(Scene::load(dir.path(), &LoadOptions::default()));
    assert_names(
        &e,
        &[
            "transforms.json",
            "frames[1].transform_matrix",
            "[0][2]",
            "NaN",
        ],
    );
    let inf = good.replacen("\"fl_x\": 50.0", "\"fl_x\": -Infinity", 1);
    assert_ne!(inf, good);
    std::fs::write(dir.path().join("transforms.json"), &inf).unwrap();
    let e = err_text(Scene::load(dir.path(), &LoadOptions::default()));
    assert_names(&e, &["transforms.json", "fl_x", "Infinity"]);
    // "NaN" inside a string stays a string (here: a file name that does not exist).
    let s = good.replacen("images/frame_0000.png", "images/NaN.png", 1);
    std::fs::write(dir.path().join("transforms.json"), &s).unwrap();
    let e = err_text(Scene::load(dir.path(), &LoadOptions::default()));
    assert_names(&e, &["frames[0].file_path", "images/NaN.png"]);
}

#[test]
fn bad_nerf_synthetic_inputs() {
    let case = |edit: &dyn Fn(&Path, &mut Value)| -> String {
        let dir = tempfile::tempdir().unwrap();
        copy_dir(&lego_small(), dir.path());
        let mut t = read(&dir.path().join("transforms_train.json"));
        edit(dir.path(), &mut t);
        write_json(dir.path(), "transforms_train.json", &t);
        err_text(Scene::load(dir.path(), &LoadOptions::default()))
    };
    let e = case(&|_, t| {
        t.as_object_mut().unwrap().remove("camera_angle_x");
    });
    assert_names(&e, &["transforms_train.json", "camera_angle_x", "missing"]);
    let e = case(&|_, t| t["camera_angle_x"] = json!(4.0));
    assert_names(&e, &["transforms_train.json", "camera_angle_x"]);
    let e = case(&|dir, _| std::fs::remove_file(dir.join("train/r_25.png")).unwrap());
    assert_names(
        &e,
        &["transforms_train.json", "frames[2].file_path", "r_25"],
    );
    let e = case(&|_, t| t["frames"][3]["transform_matrix"][3] = json!([0, 0, 1]));
    assert_names(&e, &["transforms_train.json", "frames[3].transform_matrix"]);
    let e = case(&|_, t| t["frames"] = json!([]));
    assert_names(&e, &["transforms_train.json", "frames", "empty"]);

    // Malformed val file.
    let dir = tempfile::tempdir().unwrap();
    copy_dir(&lego_small(), dir.path());
    std::fs::write(
        dir.path().join("transforms_val.json"),
        "{\n  \"camera_angle_x\": 0.69,\n  \"frames\": [,]\n}",
    )
    .unwrap();
    let e = err_text(Scene::load(dir.path(), &LoadOptions::default()));
    assert_names(&e, &["transforms_val.json", "line 3", "column"]);
}

/// A PNG whose header declares a 0×4 image (valid chunk CRCs, so only the size is wrong).
fn zero_width_png() -> Vec<u8> {
    fn crc32(data: &[u8]) -> u32 {
        let mut c = 0xffff_ffffu32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend((data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend(data);
        out.extend(&body);
        out.extend(crc32(&body).to_be_bytes());
    }
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(0u32.to_be_bytes());
    ihdr.extend(4u32.to_be_bytes());
    ihdr.extend([8, 2, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(
        &mut png,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    chunk(&mut png, b"IEND", &[]);
    png
}

// ---------------------------------------------------------------------------------------------
// The full scene, when ../shared/data is there.

#[test]
fn full_lego_when_present() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/lego");
    if !root.join("transforms_train.json").exists() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let scene = Scene::load(&root, &LoadOptions::default()).unwrap();
    assert_eq!(scene.train.len(), 100);
    assert_eq!(scene.test.len(), 100);
    assert!(scene.test_views().all(|v| v.name.starts_with("val/")));
    assert!(scene
        .views
        .iter()
        .all(|v| (v.camera.width, v.camera.height) == (800, 800)));
    let angle = read(&root.join("transforms_train.json"))["camera_angle_x"]
        .as_f64()
        .unwrap();
    let f = 400.0 / (0.5 * angle).tan();
    assert!(scene.views.iter().all(|v| (v.camera.fx - f).abs() < 1e-9));

    let r4 = Scene::load(
        &root,
        &LoadOptions {
            resolution_factor: Some(4),
            ..Default::default()
        },
    )
    .unwrap();
    assert!(r4
        .views
        .iter()
        .all(|v| (v.camera.width, v.camera.height) == (200, 200)));
    assert!(r4
        .views
        .iter()
        .all(|v| (v.camera.fx - f / 4.0).abs() < 1e-9 && v.camera.cx == 100.0));
    let imgs = load_images(&r4, &[r4.train[0]]).unwrap();
    assert_eq!((imgs[0].width, imgs[0].height), (200, 200));
    assert!(imgs[0].alpha.is_some());
}

/// A world-to-camera pose at `eye` looking at `target` (engine axes: x right, y down, z forward).
fn look_at(eye: [f64; 3], target: [f64; 3], up: [f64; 3]) -> Pose {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let norm = |a: [f64; 3]| {
        let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        a.map(|v| v / n)
    };
    let z = norm(sub(target, eye));
    let x = norm(cross(z, up));
    let y = cross(z, x);
    let rotation = [x, y, z];
    let t = [0, 1, 2].map(|r| -(0..3).map(|k| rotation[r][k] * eye[k]).sum::<f64>());
    Pose {
        rotation,
        translation: t,
    }
}

#[test]
fn random_init_box_surrounds_what_the_cameras_look_at() {
    let scene = Scene::load_in_file_frame(&lego_small(), &LoadOptions::default()).unwrap();
    // NeRF-synthetic: the reference's box, although the cameras' mean is far above the object.
    assert_eq!(scene.random_init_box(), ([0.0; 3], 1.3));
    // Trained recentred and scaled, the box is the same box of the dataset's frame.
    let trained = Scene::load(&lego_small(), &LoadOptions::default()).unwrap();
    let (c, half) = trained.random_init_box();
    let user = trained.frame.to_user(c);
    assert!(user.iter().all(|v| v.abs() < 1e-9), "{user:?}");
    assert!((half / trained.frame.scale - 1.3).abs() < 1e-9, "{half}");
    assert!(scene.center[2] > 1.5, "{:?}", scene.center);
    // The lego cameras look at the origin, so their axes converge there.
    let p = axes_convergence_point(&scene.views, &scene.train).unwrap();
    assert!(p.iter().all(|v| v.abs() < 1e-3), "{p:?}");

    // Another format: cameras on a hemisphere (all above the target, as in the lego capture)
    // looking at `target`, slightly off, so the least-squares point is still near it.
    let target = [3.0, -2.0, 5.0];
    let mut rng = Pcg64::seed_from_u64(9);
    let mut s = scene.clone();
    s.format = SceneFormat::Nerfstudio;
    for v in s.views.iter_mut() {
        let az: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
        let el: f64 = rng.gen_range(0.2..1.4);
        let eye = [
            target[0] + 4.0 * el.cos() * az.cos(),
            target[1] + 4.0 * el.cos() * az.sin(),
            target[2] + 4.0 * el.sin(),
        ];
        let aim = target.map(|t| t + rng.gen_range(-0.05..0.05));
        v.pose = look_at(eye, aim, [0.0, 0.0, 1.0]);
    }
    let (center, extent) = lpmsplat::scene::split::camera_extent(&s.views, &s.train);
    s.center = center;
    s.extent = extent;
    assert!(
        center[2] - target[2] > 1.5,
        "the cameras' mean is above the target"
    );
    let (c, half) = s.random_init_box();
    let dist = (0..3)
        .map(|k| (c[k] - target[k]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(dist < 0.1, "box centre {c:?} should be near {target:?}");
    assert!((half - extent / 1.1 * 0.5).abs() < 1e-12);

    // Forward-facing cameras (parallel axes): no convergence point, so the cameras' mean.
    for (i, v) in s.views.iter_mut().enumerate() {
        let eye = [i as f64 * 0.3, 0.1 * (i % 3) as f64, 0.0];
        v.pose = look_at(eye, [eye[0], eye[1], 10.0], [0.0, -1.0, 0.0]);
    }
    assert!(axes_convergence_point(&s.views, &s.train).is_none());
    let (center, extent) = lpmsplat::scene::split::camera_extent(&s.views, &s.train);
    s.center = center;
    s.extent = extent;
    assert_eq!(s.random_init_box().0, center);
}
