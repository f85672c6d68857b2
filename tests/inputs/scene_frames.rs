//! Any coordinate frame loads as the same scene: a COLMAP model rewritten in millimetres, in
//! kilometres, georeferenced far from the origin, or rotated, is held in one training frame
//! (`lpmsplat::scene::frame`), so every SfM point lies where it did in every camera, and models
//! written in the user's frame (less a recorded shift) read back into it.

use std::path::Path;

use lpmsplat::models::BaseModel;
use lpmsplat::scene::frame::{self, SceneFrame};
use lpmsplat::scene::{colmap, LoadOptions, Pose, Scene};
use lpmsplat::splats::{self, GaussianParams};

const SMALL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");

/// The frames of the tests: (name, scale, rotation, offset), `x' = scale · rotate(x) + offset`.
pub const FRAMES: [(&str, f64, [f64; 4], [f64; 3]); 5] = [
    ("as shipped", 1.0, [1.0, 0.0, 0.0, 0.0], [0.0; 3]),
    ("millimetres", 1000.0, [1.0, 0.0, 0.0, 0.0], [0.0; 3]),
    ("kilometres", 0.001, [1.0, 0.0, 0.0, 0.0], [0.0; 3]),
    (
        "georeferenced",
        1.0,
        [1.0, 0.0, 0.0, 0.0],
        [510_000.0, 4_000_000.0, 124.0],
    ),
    ("rotated", 1.0, [0.9, 0.3, -0.2, 0.25], [3.0, -2.0, 1.0]),
];

/// `SMALL` rewritten in a frame, in a temporary scene folder (images linked).
fn reframed(scale: f64, rotation: [f64; 4], offset: [f64; 3]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let src = Path::new(SMALL);
    let sparse = colmap::find_sparse_dir(src).unwrap();
    let model = colmap::read_model(&sparse, colmap::use_binary(&sparse, Default::default()))
        .unwrap()
        .reframed(scale, rotation, offset);
    colmap::write_text(&dir.path().join("sparse/0"), &model).unwrap();
    std::os::unix::fs::symlink(src.join("images"), dir.path().join("images")).unwrap();
    dir
}

/// Every SfM point in the camera space of every view (invariant under any change of world
/// frame once camera space is scaled with the world), and the training extent.
fn camera_space(scene: &Scene) -> (Vec<[f64; 3]>, f64) {
    let points = &scene.points.as_ref().unwrap().positions;
    let mut out = Vec::new();
    for v in &scene.views {
        out.extend(points.iter().map(|p| v.pose.transform(*p)));
    }
    (out, scene.extent)
}

#[test]
fn every_frame_loads_to_the_same_training_frame() {
    let base = Scene::load(Path::new(SMALL), &LoadOptions::default()).unwrap();
    let (want, want_extent) = camera_space(&base);
    // Unit extent over every view; the training views alone span a little less.
    assert!(
        (0.5..=1.0).contains(&want_extent),
        "unit extent: {want_extent}"
    );
    for (name, scale, rotation, offset) in FRAMES {
        let dir = reframed(scale, rotation, offset);
        let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
        let (got, extent) = camera_space(&scene);
        assert!(
            (extent - want_extent).abs() < 1e-9,
            "{name}: extent {extent}"
        );
        let worst = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max))
            .fold(0.0, f64::max);
        // Units of the extent: f64 at 4e6 keeps 1e-9 of a 7-unit scene.
        assert!(worst < 1e-8, "{name}: a point moved by {worst:e} extents");
        // The frame says where the user's world was.
        let f = scene.frame;
        assert!(
            (f.scale * scale - base.frame.scale).abs() < 1e-8 * base.frame.scale,
            "{name}: scale {}",
            f.scale
        );
        // Centred: the training cameras' centre is near the origin.
        assert!(
            scene.center.iter().all(|c| c.abs() < 1.0),
            "{name}: {:?}",
            scene.center
        );
    }
}

#[test]
fn poses_and_points_go_to_the_training_frame_and_back() {
    let f = SceneFrame {
        origin: [510_000.8, 4_000_000.02, 124.1],
        scale: 0.125,
    };
    let pose = Pose::from_qvec_tvec([0.3, -0.4, 0.5, 0.7], [-3.0e6, 2.0e5, 1.5e6]);
    let back = f.pose_to_user(&f.pose_to_train(&pose));
    for k in 0..3 {
        assert!((back.translation[k] - pose.translation[k]).abs() < 1e-6);
    }
    let p = [510_003.0, 3_999_998.5, 125.0];
    let q = f.to_user(f.to_train(p));
    assert!((0..3).all(|k| (q[k] - p[k]).abs() < 1e-8));
    // A point seen by the camera is seen at the same place scaled with the world.
    let a = pose.transform(p);
    let b = f.pose_to_train(&pose).transform(f.to_train(p));
    assert!((0..3).all(|k| (b[k] - f.scale * a[k]).abs() < 1e-6));
}

#[test]
fn a_scene_far_from_the_origin_is_written_relative_to_a_round_shift() {
    let near = SceneFrame {
        origin: [3.0, -2.0, 1.0],
        scale: 0.125,
    };
    assert_eq!(near.output_shift(), [0.0; 3]);
    assert_eq!(frame::shift_comment(near.output_shift()), None);
    let far = SceneFrame {
        origin: [510_000.8, 4_000_000.02, 124.1],
        scale: 1.0 / 7.0,
    };
    let shift = far.output_shift();
    assert_eq!(shift, [510_000.0, 4_000_000.0, 120.0]);
    let comment = frame::shift_comment(shift).unwrap();
    let path = Path::new("model.ply");
    assert_eq!(
        frame::shift_from_comments(path, &["other".into(), comment]).unwrap(),
        shift
    );
    for bad in [
        "lpmsplat shift 1 2",
        "lpmsplat shift 1 2 nan",
        "lpmsplat shift a b c",
    ] {
        let e = frame::shift_from_comments(path, &[bad.to_string()]).unwrap_err();
        assert!(
            format!("{e:#}").contains("model.ply") && format!("{e:#}").contains("Fix:"),
            "{bad}: {e:#}"
        );
    }
    // A comment that only begins with the same word is someone else's.
    assert_eq!(
        frame::shift_from_comments(path, &["lpmsplat shifted".into()]).unwrap(),
        [0.0; 3]
    );
}

/// A small model with every field set.
fn model(n: usize, extra: bool) -> GaussianParams {
    let mut p = GaussianParams {
        sh_degree: 0,
        positions: (0..n)
            .map(|i| [0.1 * i as f32, -0.05 * i as f32, 0.3])
            .collect(),
        log_scales: (0..n)
            .map(|i| [-3.0, -3.5, -4.0 - i as f32 * 0.1])
            .collect(),
        rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
        opacity_logits: vec![0.5; n],
        sh_dc: vec![[0.1, 0.2, 0.3]; n],
        sh_rest: vec![],
        extra: vec![],
    };
    if extra {
        for (name, stride) in lpmsplat::render::spacetime::GROUPS {
            p.extra.push(splats::ExtraValues {
                group: splats::ExtraGroup::new(name, stride),
                values: (0..n * stride).map(|k| 0.01 * k as f32).collect(),
            });
        }
    }
    p
}

#[test]
fn models_are_read_back_into_the_training_frame_through_their_shift() {
    let dir = reframed(1.0, [1.0, 0.0, 0.0, 0.0], [510_000.0, 4_000_000.0, 124.0]);
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    let shift = scene.frame.output_shift();
    assert_ne!(shift, [0.0; 3], "a georeferenced scene is written shifted");
    for base in [
        BaseModel::Gaussians3d,
        BaseModel::Surfels2d,
        BaseModel::SpacetimeLite,
    ] {
        let mut trained = model(5, base.is_spacetime());
        if base == BaseModel::Surfels2d {
            for l in &mut trained.log_scales {
                l[2] = -20.0;
            }
        }
        // What the training writes: the user's frame less the shift.
        let mut stored = trained.clone();
        base.map_frame(&mut stored, scene.frame.train_to_stored(shift));
        // Stored positions are small numbers near the scene, not 4e6.
        assert!(stored.positions.iter().flatten().all(|v| v.abs() < 100.0));
        let ply = dir.path().join(format!("{}.ply", base.name()));
        splats::write_ply_with_comments(&ply, &stored, &[frame::shift_comment(shift).unwrap()])
            .unwrap();
        let back = base.read_ply_for_scene(&ply, &scene).unwrap();
        let close = |a: f32, b: f32, tol: f32| (a - b).abs() <= tol;
        for i in 0..5 {
            for k in 0..3 {
                // f32 at 100 user units, in extents of 7 units.
                assert!(
                    close(back.positions[i][k], trained.positions[i][k], 2e-6),
                    "{}: {:?} vs {:?}",
                    base.name(),
                    back.positions[i],
                    trained.positions[i]
                );
                assert!(close(back.log_scales[i][k], trained.log_scales[i][k], 1e-5));
            }
        }
        if base == BaseModel::Surfels2d {
            // A surfel's third log-scale is a marker, not a length: unchanged on the way.
            assert_eq!(stored.log_scales[3][2], trained.log_scales[3][2]);
        } else {
            let ln = (1.0 / scene.frame.scale).ln() as f32;
            assert!(close(
                stored.log_scales[3][2],
                trained.log_scales[3][2] + ln,
                1e-5
            ));
        }
        if base.is_spacetime() {
            // Motion (lengths per unit time) scales with the world; time groups do not.
            let (m0, m1) = (
                trained.extra_values("motion"),
                stored.extra_values("motion"),
            );
            let (m0, m1) = (m0.unwrap(), m1.unwrap());
            assert!(close(m1[7], m0[7] / scene.frame.scale as f32, 1e-5));
            assert_eq!(
                trained.extra_values("trbf_center"),
                stored.extra_values("trbf_center")
            );
            let got = back.extra_values("motion").unwrap();
            assert!(got.iter().zip(m0).all(|(a, b)| close(*a, *b, 1e-6)));
        }
    }
}

#[test]
fn a_camera_rig_without_spread_takes_the_points_spread() {
    let points = lpmsplat::scene::SfmPoints {
        positions: vec![[10.0, 0.0, 0.0], [-10.0, 0.0, 0.0], [0.0, 5.0, 0.0]],
        ..Default::default()
    };
    let f = SceneFrame::fit(&[[0.0; 3], [0.0; 3]], Some(&points));
    assert!((f.scale - 1.0 / 11.0).abs() < 1e-12, "{f:?}");
    // Neither: only recentred.
    let f = SceneFrame::fit(&[[4.0e6, 0.0, 0.0]], None);
    assert_eq!(f.scale, 1.0);
    assert_eq!(f.origin, [4.0e6, 0.0, 0.0]);
    // Non-finite cameras: the identity (the loaders refuse them first).
    assert!(SceneFrame::fit(&[[f64::NAN, 0.0, 0.0]], None).is_identity());
}
