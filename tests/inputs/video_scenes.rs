//! Multi-view video scenes: the Neural 3D Video and Panoptic layouts, the segment of frames,
//! poses against cameras built by hand, and the errors for broken input.

use std::path::Path;

use lpmsplat::scene::images::{load_view_image, save_png};
use lpmsplat::scene::video::{npy, FrameRange, Segment, VideoLayout, VideoScene};
use lpmsplat::scene::{Image, LoadOptions};

fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() <= tol)
}

/// An OpenCV camera-to-world rotation looking from `centre` at the origin (columns x right,
/// y down, z forward).
fn look_at_origin(centre: [f64; 3]) -> [[f64; 3]; 3] {
    let n = |v: [f64; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / l)
    };
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let z = n(centre.map(|c| -c));
    let x = n(cross(z, [0.0, 0.0, -1.0]));
    let y = cross(z, x);
    [x, y, z]
}

fn write_frame(path: &Path, w: u32, h: u32, shade: f32) {
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.set_pixel(x, y, [shade, x as f32 / w as f32, y as f32 / h as f32]);
        }
    }
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    save_png(path, &img).unwrap();
}

const CENTRES: [[f64; 3]; 3] = [[4.0, 0.0, 1.0], [0.0, 4.0, 1.5], [-3.0, -3.0, 0.5]];

/// A Neural 3D Video scene: 3 cameras around the origin, 6 frames of `w`×`h` (the videos
/// declared at 2× that size when `downscaled`, as frames extracted at half size).
fn n3v_fixture(dir: &Path, frames: usize, w: u32, h: u32, downscaled: bool) {
    let (vw, vh) = if downscaled { (2 * w, 2 * h) } else { (w, h) };
    let focal = 0.8 * vw as f64;
    let mut rows = Vec::new();
    for (i, c) in CENTRES.iter().enumerate() {
        let [x, y, z] = look_at_origin(*c);
        // LLFF columns: [down, right, back, centre, hwf] = [y, x, −z, c, (h, w, f)].
        for r in 0..3 {
            rows.extend([y[r], x[r], -z[r], c[r], [vh as f64, vw as f64, focal][r]]);
        }
        rows.extend([0.5, 20.0]);
        for f in 0..frames {
            write_frame(
                &dir.join(format!("cam{i:02}/{f}.png")),
                w,
                h,
                f as f32 / frames as f32,
            );
        }
    }
    npy::write_array2(&dir.join("poses_bounds.npy"), CENTRES.len(), 17, &rows).unwrap();
}

#[test]
fn npy_round_trip_and_refusals() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.npy");
    let data: Vec<f64> = (0..34).map(|i| i as f64 * 0.25 - 3.0).collect();
    npy::write_array2(&p, 2, 17, &data).unwrap();
    let a = npy::read_array2(&p).unwrap();
    assert_eq!((a.rows, a.cols), (2, 17));
    assert_eq!(a.data, data);
    assert_eq!(a.row(1)[0], data[17]);
    let bytes = std::fs::read(&p).unwrap();
    let e = npy::parse_array2(&p, &bytes[..bytes.len() - 8])
        .unwrap_err()
        .to_string();
    assert!(e.contains("data") && e.contains("shape (2, 17)"), "{e}");
    let mut big_endian = bytes.clone();
    let at = big_endian.windows(3).position(|w| w == b"<f8").unwrap();
    big_endian[at] = b'>';
    let e = npy::parse_array2(&p, &big_endian).unwrap_err().to_string();
    assert!(e.contains("descr") && e.contains(">f8"), "{e}");
    let e = npy::parse_array2(&p, b"not numpy at all")
        .unwrap_err()
        .to_string();
    assert!(e.contains("a.npy") && e.contains("magic"), "{e}");
}

#[test]
fn frame_ranges_parse() {
    assert_eq!(
        "10..60".parse::<FrameRange>().unwrap(),
        FrameRange {
            start: 10,
            count: Some(50)
        }
    );
    assert_eq!(
        "5..".parse::<FrameRange>().unwrap(),
        FrameRange {
            start: 5,
            count: None
        }
    );
    assert!("7..7".parse::<FrameRange>().unwrap_err().contains("empty"));
    assert!("a..3".parse::<FrameRange>().is_err());
    assert!("12".parse::<FrameRange>().is_err());
}

#[test]
fn neural_3d_video_layout_gives_the_cameras_it_was_built_from() {
    let dir = tempfile::tempdir().unwrap();
    n3v_fixture(dir.path(), 6, 40, 30, false);
    assert_eq!(
        VideoScene::detect(dir.path()),
        Some(VideoLayout::NeuralVideo)
    );
    let s = VideoScene::load(dir.path(), &LoadOptions::default(), FrameRange::default()).unwrap();
    assert_eq!(s.cameras.len(), 3);
    assert_eq!((s.first_frame, s.frames), (0, 6));
    assert_eq!(s.test, vec![0], "cam00 is the test camera");
    assert_eq!(s.train, vec![1, 2]);
    for (c, centre) in s.cameras.iter().zip(CENTRES) {
        assert!(
            close(c.pose.center(), centre, 1e-12),
            "{:?}",
            c.pose.center()
        );
        let axis = c.pose.optical_axis();
        let toward_origin = centre.map(|v| -v / centre.iter().map(|x| x * x).sum::<f64>().sqrt());
        assert!(close(axis, toward_origin, 1e-12), "{axis:?}");
        // The origin projects to the image centre.
        let p = c.camera.project(c.pose.transform([0.0; 3]));
        assert!(
            (p[0] - 20.0).abs() < 1e-9 && (p[1] - 15.0).abs() < 1e-9,
            "{p:?}"
        );
        assert!((c.camera.fx - 32.0).abs() < 1e-12);
        assert_eq!(c.frames.len(), 6);
    }
    assert_eq!(s.time(0), 0.0);
    assert_eq!(s.time(3), 0.5);
    // Frames come in time order and load at the training size.
    let v = s.view(1, 4);
    assert!(v.image_path.ends_with("cam01/4.png"), "{:?}", v.image_path);
    assert_eq!(v.name, "cam01/000004");
    let img = load_view_image(&v).unwrap();
    assert!((img.pixel(0, 0)[0] - 4.0 / 6.0).abs() < 0.003);
    // -r 2 halves the camera; a segment picks frames.
    let opts = LoadOptions {
        resolution_factor: Some(2),
        ..LoadOptions::default()
    };
    let s2 = VideoScene::load(dir.path(), &opts, "2..5".parse().unwrap()).unwrap();
    assert_eq!((s2.first_frame, s2.frames), (2, 3));
    assert_eq!(
        (s2.cameras[0].camera.width, s2.cameras[0].camera.height),
        (20, 15)
    );
    assert!(s2.cameras[0].frames[0].ends_with("cam00/2.png"));
    assert_eq!(s2.view(0, 0).name, "cam00/000002");
    let frame = s2.frame_scene(1);
    assert_eq!(frame.views.len(), 3);
    assert!(frame.views[2].image_path.ends_with("cam02/3.png"));
}

#[test]
fn neural_3d_video_frames_extracted_downscaled_scale_the_focal_length() {
    let dir = tempfile::tempdir().unwrap();
    n3v_fixture(dir.path(), 2, 40, 30, true);
    let s = VideoScene::load(dir.path(), &LoadOptions::default(), FrameRange::default()).unwrap();
    let c = &s.cameras[1];
    assert_eq!((c.source_width, c.source_height), (40, 30));
    assert!((c.camera.fx - 32.0).abs() < 1e-12, "{}", c.camera.fx);
}

#[test]
fn a_models_segment_gives_any_part_of_it_its_training_times() {
    let dir = tempfile::tempdir().unwrap();
    n3v_fixture(dir.path(), 6, 40, 30, false);
    // The PLY comment round-trips; other comments are not a segment; a broken one is refused.
    let trained = Segment {
        start: 1,
        frames: 4,
    };
    assert_eq!(trained.comment(), "lpmsplat video segment 1..5");
    let ply = dir.path().join("m.ply");
    let found = Segment::from_comments(&ply, &["made by hand".into(), trained.comment()]);
    assert_eq!(found.unwrap(), Some(trained));
    assert_eq!(Segment::from_comments(&ply, &["x".into()]).unwrap(), None);
    let e = Segment::from_comments(&ply, &["lpmsplat video segment 5..2".into()]).unwrap_err();
    let e = format!("{e:#}");
    assert!(e.contains("m.ply") && e.contains("START..END"), "{e}");
    // Frames 2..4 of a model trained on 1..5: times (2 − 1) / 4 and (3 − 1) / 4, not 0 and 1/2.
    let opts = LoadOptions {
        time_base: Some(trained),
        ..LoadOptions::default()
    };
    let part = VideoScene::load(dir.path(), &opts, "2..4".parse().unwrap()).unwrap();
    assert_eq!((part.time(0), part.time(1)), (0.25, 0.5));
    let scene = part.to_scene();
    assert_eq!(scene.time_base, Some(trained));
    let times = scene.view_times.unwrap();
    assert_eq!(
        &times[..2],
        &[0.25, 0.5],
        "camera-major: cam00's two frames first"
    );
    // The whole trained segment loads with the times training gave it.
    let whole = VideoScene::load(dir.path(), &opts, trained.range()).unwrap();
    assert_eq!(
        (0..4).map(|k| whole.time(k)).collect::<Vec<_>>(),
        vec![0.0, 0.25, 0.5, 0.75]
    );
    // Without a time base the loaded segment is its own.
    let own = VideoScene::load(dir.path(), &LoadOptions::default(), "2..4".parse().unwrap())
        .unwrap()
        .to_scene();
    assert_eq!(own.view_times.unwrap()[..2], [0.0, 0.5]);
    assert_eq!(
        own.time_base,
        Some(Segment {
            start: 2,
            frames: 2
        })
    );
    // Frames outside the trained segment have no time in it: refused, naming the fix.
    for outside in ["0..3", "4..6"] {
        let e = VideoScene::load(dir.path(), &opts, outside.parse().unwrap()).unwrap_err();
        let e = format!("{e:#}");
        assert!(
            e.contains("outside the segment 1..5") && e.contains("--frames within 1..5"),
            "{e}"
        );
    }
}

#[test]
fn neural_3d_video_refusals_name_the_file_and_the_fix() {
    let dir = tempfile::tempdir().unwrap();
    n3v_fixture(dir.path(), 4, 16, 12, false);
    let load = |r: &str| {
        VideoScene::load(dir.path(), &LoadOptions::default(), r.parse().unwrap())
            .unwrap_err()
            .to_string()
    };
    let e = load("2..9");
    assert!(e.contains("frames") && e.contains("4 frames"), "{e}");
    let e = load("4..");
    assert!(e.contains("starts at frame 4"), "{e}");
    // A camera missing a frame shortens every camera's segment; a missing folder is named.
    std::fs::remove_file(dir.path().join("cam02/3.png")).unwrap();
    let s = VideoScene::load(dir.path(), &LoadOptions::default(), FrameRange::default()).unwrap();
    assert_eq!(s.frames, 3);
    std::fs::rename(dir.path().join("cam02"), dir.path().join("other")).unwrap();
    let e = load("0..");
    assert!(
        e.contains("poses_bounds.npy") && e.contains("3 cameras but 2"),
        "{e}"
    );
    std::fs::create_dir(dir.path().join("cam02")).unwrap();
    let e = load("0..");
    assert!(e.contains("cam02") && e.contains("ffmpeg"), "{e}");
    // A frame of another size.
    std::fs::rename(
        dir.path().join("other/0.png"),
        dir.path().join("cam02/0.png"),
    )
    .unwrap();
    write_frame(&dir.path().join("cam02/0.png"), 17, 12, 0.0);
    let e = load("0..");
    assert!(e.contains("0.png") && e.contains("17x12"), "{e}");
    // A camera matrix that is no rotation (a registration that failed wrote zeros; a scaled
    // one), named by its row.
    write_frame(&dir.path().join("cam02/0.png"), 16, 12, 0.0);
    let npy = dir.path().join("poses_bounds.npy");
    let poses = npy::read_array2(&npy).unwrap();
    for (spoil, want) in [(0.0, "not a rotation"), (2.0, "not a rotation")] {
        let mut data = poses.data.clone();
        for r in 0..3 {
            for c in 0..3 {
                data[poses.cols + r * 5 + c] *= spoil;
            }
        }
        npy::write_array2(&npy, poses.rows, poses.cols, &data).unwrap();
        let e = load("0..");
        assert!(
            e.contains("poses_bounds.npy") && e.contains("row 1") && e.contains(want),
            "{spoil}: {e}"
        );
    }
    // A reflection: one axis flipped.
    let mut data = poses.data.clone();
    for r in 0..3 {
        data[poses.cols + r * 5] *= -1.0;
    }
    npy::write_array2(&npy, poses.rows, poses.cols, &data).unwrap();
    assert!(load("0..").contains("reflection"));
}

/// A Panoptic scene: cameras 1, 3 (train) and 2 (test), `frames` frames.
fn panoptic_fixture(dir: &Path, frames: usize, moving: bool) {
    let cam = |id: usize, f: usize| {
        let c = CENTRES[id - 1];
        let r = look_at_origin(c);
        // w2c = [Rᵀ | −Rᵀ c] with R the camera-to-world rotation (columns x, y, z).
        let t: Vec<f64> = (0..3)
            .map(|i| -(0..3).map(|k| r[i][k] * c[k]).sum::<f64>())
            .collect();
        let shift = if moving && f == 1 && id == 3 {
            0.01
        } else {
            0.0
        };
        let w2c: Vec<Vec<f64>> = (0..3)
            .map(|i| vec![r[i][0], r[i][1], r[i][2], t[i] + shift])
            .chain([vec![0.0, 0.0, 0.0, 1.0]])
            .collect();
        let k = vec![
            vec![30.0, 0.0, 16.0],
            vec![0.0, 31.0, 12.0],
            vec![0.0, 0.0, 1.0],
        ];
        (k, w2c, format!("{id}/{f:06}.jpg"))
    };
    let meta = |ids: &[usize]| {
        let per = |g: &dyn Fn(usize, usize) -> serde_json::Value| -> Vec<Vec<serde_json::Value>> {
            (0..frames)
                .map(|f| ids.iter().map(|&i| g(i, f)).collect())
                .collect()
        };
        serde_json::json!({
            "w": 32, "h": 24,
            "k": per(&|i, f| serde_json::json!(cam(i, f).0)),
            "w2c": per(&|i, f| serde_json::json!(cam(i, f).1)),
            "fn": per(&|i, f| serde_json::json!(cam(i, f).2)),
            "cam_id": per(&|i, _| serde_json::json!(i)),
        })
    };
    std::fs::write(dir.join("train_meta.json"), meta(&[1, 3]).to_string()).unwrap();
    std::fs::write(dir.join("test_meta.json"), meta(&[2]).to_string()).unwrap();
    for id in 1..=3 {
        for f in 0..frames {
            write_frame(
                &dir.join(format!("ims/{id}/{f:06}.jpg")),
                32,
                24,
                0.1 * f as f32,
            );
            if id != 2 {
                write_frame(&dir.join(format!("seg/{id}/{f:06}.png")), 32, 24, 1.0);
            }
        }
    }
}

#[test]
fn panoptic_layout_reads_cameras_split_and_masks() {
    let dir = tempfile::tempdir().unwrap();
    panoptic_fixture(dir.path(), 3, false);
    assert_eq!(VideoScene::detect(dir.path()), Some(VideoLayout::Panoptic));
    let s = VideoScene::load(dir.path(), &LoadOptions::default(), FrameRange::default()).unwrap();
    let names: Vec<_> = s.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["cam01", "cam02", "cam03"]);
    assert_eq!((s.train.clone(), s.test.clone()), (vec![0, 2], vec![1]));
    assert_eq!(s.frames, 3);
    for (c, centre) in s.cameras.iter().zip(CENTRES) {
        assert!(
            close(c.pose.center(), centre, 1e-12),
            "{:?}",
            c.pose.center()
        );
        assert_eq!(
            (c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy),
            (30.0, 31.0, 16.0, 12.0)
        );
    }
    assert!(s.cameras[0].masks.as_ref().unwrap()[2].ends_with("seg/1/000002.png"));
    assert!(s.cameras[1].masks.is_none(), "the test camera has no masks");
    assert!(s.cameras[2].frames[1].ends_with("ims/3/000001.jpg"));
    let img = load_view_image(&s.view(2, 2)).unwrap();
    assert_eq!((img.width, img.height), (32, 24));
}

#[test]
fn panoptic_moving_cameras_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    panoptic_fixture(dir.path(), 2, true);
    let e = VideoScene::load(dir.path(), &LoadOptions::default(), FrameRange::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("train_meta.json") && e.contains("w2c[1][1]") && e.contains("camera 3"),
        "{e}"
    );
}

#[test]
fn shared_panoptic_basketball_when_present() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/panoptic_basketball");
    if !root.exists() {
        eprintln!("skipping: {} is absent", root.display());
        return;
    }
    let s = VideoScene::load(&root, &LoadOptions::default(), FrameRange::default()).unwrap();
    assert_eq!(s.cameras.len(), 31);
    assert_eq!(s.frames, 50);
    let test: Vec<_> = s.test.iter().map(|&i| s.cameras[i].name.as_str()).collect();
    assert_eq!(test, ["cam00", "cam10", "cam15", "cam30"]);
    assert!(s.train.iter().all(|&i| s.cameras[i].masks.is_some()));
    // The cameras surround the court and look at one region: every optical axis passes within
    // a fraction of the extent of the point nearest to all of them.
    let frame = s.frame_scene(0);
    let p = lpmsplat::scene::split::axes_convergence_point(&frame.views, &s.train).unwrap();
    for v in &frame.views {
        let c = v.pose.center();
        let d = v.pose.optical_axis();
        let w = [0, 1, 2].map(|k| p[k] - c[k]);
        let along: f64 = (0..3).map(|k| w[k] * d[k]).sum();
        assert!(along > 0.0, "{} looks away from the court", v.name);
        let off = ((0..3).map(|k| (w[k] - along * d[k]).powi(2)).sum::<f64>()).sqrt();
        assert!(
            off < 0.5 * s.extent,
            "{}: axis misses by {off} (extent {})",
            v.name,
            s.extent
        );
    }
    let img = load_view_image(&s.view(s.test[0], 49)).unwrap();
    assert_eq!((img.width, img.height), (640, 360));
}

/// LPM in time pairs a view with other cameras' views of the same instant: a zone is
/// triangulated from two views of one time. Without the times the same cameras' other frames
/// compete (and the nearest-centre fallback would pick the same camera at another frame, with
/// no baseline at all).
#[test]
fn lpm_neighbours_of_a_video_view_share_its_time() {
    use lpmsplat::lpm::neighbours::{
        select_neighbours, select_neighbours_at_times, NeighbourSettings,
    };
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    let scene = lpmsplat::scene::Scene::load(&dir, &LoadOptions::default()).unwrap();
    let times = scene.view_times.clone().unwrap();
    let s = NeighbourSettings::default();
    let n = select_neighbours_at_times(&scene.views, &scene.train, Some(&times), None, &s);
    for &v in &scene.train {
        assert!(!n.of[v].is_empty(), "view {v} has no neighbour");
        for &o in &n.of[v] {
            assert_eq!(
                times[o], times[v],
                "view {v} paired with {o} of another time"
            );
            let (a, b) = (scene.views[v].pose.center(), scene.views[o].pose.center());
            let d: f64 = (0..3).map(|k| a[k] - b[k]).map(|x| x * x).sum();
            assert!(d > 1e-6, "view {v} paired with its own camera ({o})");
        }
    }
    let plain = select_neighbours(&scene.views, &scene.train, None, &s);
    assert!(
        scene
            .train
            .iter()
            .any(|&v| plain.of[v].iter().any(|&o| times[o] != times[v])),
        "without times, some neighbour is of another time (the case the filter exists for)"
    );
}
