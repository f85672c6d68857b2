//! COLMAP scenes: binary and text forms agree, every camera model loads, keypoints and tracks
//! land where the cameras project the SfM points.

use std::path::Path;

use crate::colmap_support::*;
use lpmsplat::scene::colmap;
use lpmsplat::scene::{CameraModel, ColmapForm, LoadOptions, Scene, SceneFormat};

const SMALL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");

/// Largest distance between a keypoint and the projection of its SfM point through the view's
/// undistorted pinhole camera, and the median over all observations.
fn reprojection_errors(scene: &Scene) -> (f64, f64) {
    let points = scene.points.as_ref().unwrap();
    let mut errors = Vec::new();
    for (p, track) in points.positions.iter().zip(&points.tracks) {
        for &(v, k) in track {
            let view = &scene.views[v as usize];
            let uv = view.camera.project(view.pose.transform(*p));
            let kp = view.keypoints.as_ref().unwrap().xy[k as usize];
            errors.push(((uv[0] - kp[0]).powi(2) + (uv[1] - kp[1]).powi(2)).sqrt());
        }
    }
    assert!(!errors.is_empty());
    errors.sort_by(f64::total_cmp);
    (errors[errors.len() - 1], errors[errors.len() / 2])
}

/// Tracks and keypoint point3D ids say the same thing.
fn check_track_consistency(scene: &Scene) {
    let points = scene.points.as_ref().unwrap();
    let mut observations = 0;
    for (id, track) in points.ids.iter().zip(&points.tracks) {
        for &(v, k) in track {
            assert_eq!(
                scene.views[v as usize].keypoints.as_ref().unwrap().point3d[k as usize],
                *id as i64
            );
            observations += 1;
        }
    }
    let with_point: usize = scene
        .views
        .iter()
        .map(|v| {
            v.keypoints
                .as_ref()
                .unwrap()
                .point3d
                .iter()
                .filter(|&&i| i >= 0)
                .count()
        })
        .sum();
    assert_eq!(observations, with_point);
}

#[test]
fn lund_door_small_binary_and_text_give_identical_scenes() {
    let (bin, txt) = load_both(Path::new(SMALL), &LoadOptions::default());
    assert_eq!(bin, txt);
    assert_eq!(bin.views.len(), 12);
    assert_eq!(bin.points.as_ref().unwrap().len(), 11_384);
    assert_eq!(bin.test.len(), 2);
    assert_eq!(bin.train.len(), 10);
    assert!(bin.extent > 0.0 && bin.extent.is_finite());
    for (k, v) in bin.views.iter().enumerate() {
        assert_eq!(v.name, format!("DSC_{:04}.JPG", k + 1));
        assert_eq!(v.stem, format!("DSC_{:04}", k + 1));
        assert!(matches!(v.source_model, CameraModel::SimpleRadial { .. }));
        assert_eq!((v.source_width, v.source_height), (324, 484));
        assert_eq!((v.camera.width, v.camera.height), (324, 484));
        let (fx, fy, cx, cy) = v.source_model.pinhole_part();
        assert_eq!(
            (v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy),
            (fx, fy, cx, cy)
        );
    }
    check_track_consistency(&bin);
}

#[test]
fn lund_door_small_keypoints_match_the_projected_points() {
    let scene = Scene::load(Path::new(SMALL), &LoadOptions::default()).unwrap();
    let (_, median) = reprojection_errors(&scene);
    // SfM errors of this model are a fraction of a pixel at full size, a quarter of that here.
    assert!(median < 0.2, "median reprojection error {median} px");

    // The same with the distorted keypoints (undistortion skipped) must be clearly worse, or the
    // check above would not be testing the undistortion.
    let mut raw = scene.clone();
    let model = colmap::read_model(&Path::new(SMALL).join("sparse/0"), true).unwrap();
    for v in &mut raw.views {
        let im = model
            .images
            .iter()
            .find(|i| Some(i.id) == v.colmap_image_id)
            .unwrap();
        v.keypoints.as_mut().unwrap().xy = im.points2d.clone();
    }
    let points = scene.points.as_ref().unwrap();
    let far = |s: &Scene| {
        // Mean error over observations far from the principal point, where distortion matters.
        let (mut sum, mut n) = (0.0, 0);
        for (p, track) in points.positions.iter().zip(&points.tracks) {
            for &(v, k) in track {
                let view = &s.views[v as usize];
                let kp = view.keypoints.as_ref().unwrap().xy[k as usize];
                if (kp[0] - view.camera.cx).hypot(kp[1] - view.camera.cy) < 200.0 {
                    continue;
                }
                let uv = view.camera.project(view.pose.transform(*p));
                sum += (uv[0] - kp[0]).hypot(uv[1] - kp[1]);
                n += 1;
            }
        }
        assert!(n > 100);
        sum / n as f64
    };
    let (undistorted, distorted) = (far(&scene), far(&raw));
    eprintln!("far-field error: {undistorted:.3} px undistorted, {distorted:.3} px raw; median {median:.3}");
    assert!(
        undistorted < 0.3 * distorted,
        "far-field error {undistorted} px undistorted vs {distorted} px raw"
    );
}

#[test]
fn lund_door_small_downscaled_by_factor() {
    let opts = LoadOptions {
        resolution_factor: Some(2),
        ..LoadOptions::default()
    };
    let (bin, txt) = load_both(Path::new(SMALL), &opts);
    assert_eq!(bin, txt);
    let v = &bin.views[0];
    assert_eq!((v.camera.width, v.camera.height), (162, 242));
    assert_eq!((v.source_width, v.source_height), (324, 484));
    let (max, median) = reprojection_errors(&bin);
    assert!(median < 0.25, "median {median} max {max}");
}

#[test]
fn shared_lund_door_when_present() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/lund_door");
    if !root.exists() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let (bin, txt) = load_both(&root, &LoadOptions::default());
    assert_eq!(bin, txt);
    assert_eq!(bin.views.len(), 12);
    assert_eq!(bin.points.as_ref().unwrap().len(), 11_384);
    assert!(bin
        .views
        .iter()
        .all(|v| matches!(v.source_model, CameraModel::SimpleRadial { .. })));
    assert_eq!(
        (bin.views[0].source_width, bin.views[0].source_height),
        (1296, 1936)
    );
    assert_eq!((bin.test.len(), bin.train.len()), (2, 10));
    assert!(bin.extent > 0.0 && bin.extent.is_finite());
    check_track_consistency(&bin);
    let (_, median) = reprojection_errors(&bin);
    eprintln!("lund_door: median reprojection error {median:.3} px");
    assert!(median < 0.5, "median reprojection error {median} px");
}

#[test]
fn every_camera_model_gives_identical_scenes_from_binary_and_text() {
    let mut rng = rng(1);
    let (w, h) = (64, 48);
    for model in all_models(&mut rng, w, h) {
        let dir = tempfile::tempdir().unwrap();
        let synth = synth_model(&mut rng, &[(model, w, h)], 6, 12);
        write_scene(dir.path(), &synth);
        assert_eq!(
            colmap::read_model(&dir.path().join("sparse/0"), true).unwrap(),
            synth
        );
        assert_eq!(
            colmap::read_model(&dir.path().join("sparse/0"), false).unwrap(),
            synth
        );
        let (bin, txt) = load_both(dir.path(), &LoadOptions::default());
        assert_eq!(bin, txt, "{}", model.name());
        assert_eq!(bin.views.len(), 6);
        assert!(
            bin.views.windows(2).all(|p| p[0].name < p[1].name),
            "views sorted by name"
        );
        assert!(bin.views.iter().all(|v| v.source_model == model));
        assert_eq!(
            bin.format,
            SceneFormat::Colmap {
                sparse_dir: dir.path().join("sparse/0"),
                binary: true
            }
        );
        check_track_consistency(&bin);
        let (max, _) = reprojection_errors(&bin);
        assert!(
            max < 1e-6,
            "{}: keypoints off their points by up to {max} px",
            model.name()
        );
    }
}

#[test]
fn mixed_cameras_downscaled_keypoints_follow_the_resize() {
    let mut rng = rng(2);
    let models = all_models(&mut rng, 80, 60);
    let cams: Vec<(CameraModel, u32, u32)> = models.iter().map(|m| (*m, 80, 60)).collect();
    let synth = synth_model(&mut rng, &cams, 10, 8);
    let dir = tempfile::tempdir().unwrap();
    write_scene(dir.path(), &synth);
    for opts in [
        LoadOptions {
            resolution_factor: Some(4),
            ..LoadOptions::default()
        },
        LoadOptions {
            max_width: 50,
            ..LoadOptions::default()
        },
        LoadOptions {
            eval_split: false,
            ..LoadOptions::default()
        },
    ] {
        let (bin, txt) = load_both(dir.path(), &opts);
        assert_eq!(bin, txt);
        let (max, _) = reprojection_errors(&bin);
        assert!(max < 1e-6, "{opts:?}: max error {max} px");
        let (tw, th) = lpmsplat::scene::target_size(80, 60, &opts);
        assert!(bin
            .views
            .iter()
            .all(|v| (v.camera.width, v.camera.height) == (tw, th)));
        assert_eq!(bin.train.len() + bin.test.len(), 10);
        assert_eq!(bin.test.is_empty(), !opts.eval_split);
    }
}

#[test]
fn auto_form_prefers_binary_and_falls_back_to_text() {
    let mut rng = rng(3);
    let model = all_models(&mut rng, 40, 30)[2];
    let synth = synth_model(&mut rng, &[(model, 40, 30)], 3, 5);
    let dir = tempfile::tempdir().unwrap();
    let sparse = write_scene(dir.path(), &synth);
    let auto = Scene::load(dir.path(), &opts(ColmapForm::Auto)).unwrap();
    assert!(matches!(
        auto.format,
        SceneFormat::Colmap { binary: true, .. }
    ));
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        std::fs::remove_file(sparse.join(f)).unwrap();
    }
    let auto = Scene::load(dir.path(), &opts(ColmapForm::Auto)).unwrap();
    assert!(matches!(
        auto.format,
        SceneFormat::Colmap { binary: false, .. }
    ));
}

/// The shipped copy is the shared scene scaled by 1/4: same poses and points, keypoints and
/// intrinsics divided by 4 (up to the rounding documented in its README).
#[test]
fn lund_door_small_is_the_shared_scene_scaled_down() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/lund_door");
    if !root.exists() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let full = Scene::load(&root, &LoadOptions::default()).unwrap();
    let small = Scene::load(Path::new(SMALL), &LoadOptions::default()).unwrap();
    assert_eq!(full.views.len(), small.views.len());
    for (a, b) in full.views.iter().zip(&small.views) {
        assert_eq!((a.name.as_str(), a.pose), (b.name.as_str(), b.pose));
        assert_eq!(a.source_model.scaled(0.25, 0.25), b.source_model);
        let (ka, kb) = (a.keypoints.as_ref().unwrap(), b.keypoints.as_ref().unwrap());
        let kept: Vec<usize> = (0..ka.xy.len()).filter(|&k| ka.point3d[k] != -1).collect();
        assert_eq!(kept.len(), kb.xy.len());
        for (&k, (xy, id)) in kept.iter().zip(kb.xy.iter().zip(&kb.point3d)) {
            assert_eq!(ka.point3d[k], *id);
            assert!(
                (ka.xy[k][0] / 4.0 - xy[0]).abs() < 1e-3
                    && (ka.xy[k][1] / 4.0 - xy[1]).abs() < 1e-3
            );
        }
    }
    let (pa, pb) = (
        full.points.as_ref().unwrap(),
        small.points.as_ref().unwrap(),
    );
    assert_eq!((&pa.ids, &pa.colors), (&pb.ids, &pb.colors));
    for (a, b) in pa.positions.iter().zip(&pb.positions) {
        assert!((0..3).all(|i| (a[i] - b[i]).abs() <= 5e-7));
    }
}
