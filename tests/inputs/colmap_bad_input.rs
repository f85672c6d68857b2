//! Bad COLMAP input: every problem gives an error naming the file and the field; nothing panics.

use std::path::Path;

use crate::colmap_support::*;
use lpmsplat::error::InputError;
use lpmsplat::scene::colmap::ColmapModel;
use lpmsplat::scene::{CameraModel, ColmapForm, Scene};
use rand::Rng;

const FORMS: [(ColmapForm, &str); 2] = [(ColmapForm::Binary, "bin"), (ColmapForm::Text, "txt")];

fn good_model(seed: u64) -> ColmapModel {
    let mut r = rng(seed);
    let model = CameraModel::SimpleRadial {
        f: 60.0,
        cx: 32.0,
        cy: 24.0,
        k: -0.05,
    };
    synth_model(&mut r, &[(model, 64, 48)], 4, 6)
}

/// Loads `root` in `form` and returns the error's message; fails when loading succeeds or the
/// error is not an [`InputError`].
fn load_error(root: &Path, form: ColmapForm) -> String {
    let err = match Scene::load(root, &opts(form)) {
        Ok(_) => panic!("loading {} as {form:?} should fail", root.display()),
        Err(e) => e,
    };
    assert!(
        err.downcast_ref::<InputError>().is_some(),
        "not an InputError: {err:#}"
    );
    format!("{err:#}")
}

fn assert_mentions(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "error message lacks '{p}': {message}");
    }
}

/// Writes `model` as a scene, lets `spoil` damage it, and checks the error in both forms.
fn check_model_error(model: &ColmapModel, spoil: impl Fn(&Path), parts: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    write_scene(dir.path(), model);
    spoil(dir.path());
    for (form, ext) in FORMS {
        let msg = load_error(dir.path(), form);
        let parts: Vec<String> = parts.iter().map(|p| p.replace("{ext}", ext)).collect();
        let parts: Vec<&str> = parts.iter().map(String::as_str).collect();
        assert_mentions(&msg, &parts);
    }
}

fn no_spoil(_: &Path) {}

#[test]
fn missing_model_files() {
    for file in ["cameras", "images", "points3D"] {
        for (form, ext) in FORMS {
            let dir = tempfile::tempdir().unwrap();
            let sparse = write_scene(dir.path(), &good_model(1));
            let name = format!("{file}.{ext}");
            std::fs::remove_file(sparse.join(&name)).unwrap();
            // Removing cameras.bin makes Auto pick text; the explicit form must still complain.
            let msg = load_error(dir.path(), form);
            assert_mentions(&msg, &[&name, &format!("{file} file"), "missing"]);
        }
    }
}

#[test]
fn truncated_binary_files_name_the_record() {
    let mut r = rng(2);
    for (file, kind) in [
        ("cameras.bin", "camera"),
        ("images.bin", "image"),
        ("points3D.bin", "point3D"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let sparse = write_scene(dir.path(), &good_model(2));
        let path = sparse.join(file);
        let bytes = std::fs::read(&path).unwrap();
        let mut cuts = vec![0, 3, 8, 12, bytes.len() - 1];
        cuts.extend((0..10).map(|_| r.gen_range(9..bytes.len() - 1)));
        for cut in cuts {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let msg = load_error(dir.path(), ColmapForm::Binary);
            assert_mentions(&msg, &[file, "truncated"]);
            if cut >= 8 {
                assert_mentions(&msg, &[&format!("{kind} record ")]);
            } else {
                assert_mentions(&msg, &[&format!("{kind} record count")]);
            }
            assert!(!msg.contains(" of 0 "), "a record of no records: {msg}");
        }
        // Extra bytes after the announced records are refused too.
        let mut longer = bytes.clone();
        longer.extend_from_slice(&[1, 2, 3]);
        std::fs::write(&path, &longer).unwrap();
        assert_mentions(
            &load_error(dir.path(), ColmapForm::Binary),
            &[file, "3 bytes follow"],
        );
    }
}

/// A record count the rest of the file cannot hold is named as the count, with its value.
#[test]
fn a_count_past_the_end_names_the_count() {
    for (file, kind) in [
        ("cameras.bin", "camera"),
        ("images.bin", "image"),
        ("points3D.bin", "point3D"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let sparse = write_scene(dir.path(), &good_model(4));
        let path = sparse.join(file);
        let mut bytes = std::fs::read(&path).unwrap();
        // More records than the file has bytes: refused before any record is read.
        let count = bytes.len() as u64 + 1;
        bytes[..8].copy_from_slice(&count.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let msg = load_error(dir.path(), ColmapForm::Binary);
        assert_mentions(
            &msg,
            &[file, &format!("{kind} record count = {count}"), "truncated"],
        );
        assert!(!msg.contains(" of 0 "), "{msg}");
    }
}

#[test]
fn truncated_image_names_its_record_number() {
    let model = good_model(3);
    let dir = tempfile::tempdir().unwrap();
    let sparse = write_scene(dir.path(), &model);
    let path = sparse.join("images.bin");
    let bytes = std::fs::read(&path).unwrap();
    // Cut inside the second image's name.
    let first = &model.images[0];
    let cut =
        8 + 4 + 56 + 4 + first.name.len() + 1 + 8 + 24 * first.points2d.len() + 4 + 56 + 4 + 2;
    std::fs::write(&path, &bytes[..cut]).unwrap();
    assert_mentions(
        &load_error(dir.path(), ColmapForm::Binary),
        &["images.bin", "image record 2 of 4 (name)"],
    );
}

/// Replaces `from` by `to` on data line `line` (1-based, counting comment lines) of a text file.
fn edit_line(path: &Path, line: usize, from: &str, to: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    assert!(lines[line - 1].contains(from), "{}", lines[line - 1]);
    lines[line - 1] = lines[line - 1].replacen(from, to, 1);
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn malformed_text_lines_name_the_line_and_column() {
    let model = good_model(4);
    let cases: Vec<(&str, usize, String, String, Vec<&str>)> = vec![
        (
            "cameras.txt",
            4,
            " 64 ".into(),
            " sixty-four ".into(),
            vec!["line 4", "WIDTH", "sixty-four"],
        ),
        (
            "cameras.txt",
            4,
            "SIMPLE_RADIAL".into(),
            "SIMPLE_RADIAL_X".into(),
            vec![
                "line 4",
                "camera 10 model",
                "SIMPLE_RADIAL_X",
                "PINHOLE, SIMPLE_RADIAL",
            ],
        ),
        (
            "cameras.txt",
            4,
            " -0.05".into(),
            "".into(),
            vec!["line 4", "PARAMS[3] of SIMPLE_RADIAL", "missing"],
        ),
        (
            "cameras.txt",
            4,
            " -0.05".into(),
            " -0.05 7".into(),
            vec!["line 4", "PARAMS", "takes 4 parameters"],
        ),
        (
            "images.txt",
            5,
            format!(" {}", model.images[0].name),
            "".into(),
            vec!["line 5", "NAME", "missing"],
        ),
        (
            "images.txt",
            5,
            format!("{} ", model.images[0].id),
            format!("{}x ", model.images[0].id),
            vec!["line 5", "IMAGE_ID"],
        ),
        (
            "images.txt",
            6,
            " -1".into(),
            " -1 7".into(),
            vec!["line 6", "POINTS2D of image", "multiple of 3"],
        ),
        (
            "images.txt",
            8,
            " -1".into(),
            " -1.5".into(),
            vec!["line 8", "POINT3D_ID", "-1.5"],
        ),
        (
            "points3D.txt",
            4,
            format!("{} ", model.points[0].id),
            format!("{} 1 2 3 ", model.points[0].id),
            vec!["line 4", "R G B"],
        ),
        (
            "points3D.txt",
            5,
            "".into(),
            " 77".into(),
            vec!["line 5", "TRACK of point3D", "multiple of 2"],
        ),
    ];
    for (file, line, from, to, parts) in cases {
        let dir = tempfile::tempdir().unwrap();
        let sparse = write_scene(dir.path(), &model);
        let path = sparse.join(file);
        if from.is_empty() {
            let text = std::fs::read_to_string(&path).unwrap();
            let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
            lines[line - 1].push_str(&to);
            std::fs::write(&path, lines.join("\n") + "\n").unwrap();
        } else {
            edit_line(&path, line, &from, &to);
        }
        let msg = load_error(dir.path(), ColmapForm::Text);
        let mut all = vec![file];
        all.extend(parts);
        assert_mentions(&msg, &all);
    }
}

#[test]
fn text_that_is_not_utf8() {
    let dir = tempfile::tempdir().unwrap();
    let sparse = write_scene(dir.path(), &good_model(5));
    std::fs::write(sparse.join("points3D.txt"), [b'1', b' ', 0xff, 0xfe, b'\n']).unwrap();
    assert_mentions(
        &load_error(dir.path(), ColmapForm::Text),
        &["points3D.txt", "byte 2", "UTF-8"],
    );
}

#[test]
fn image_with_unknown_camera() {
    let mut m = good_model(6);
    m.images[1].camera_id = 77;
    let id = m.images[1].id.to_string();
    check_model_error(
        &m,
        no_spoil,
        &[
            "images.{ext}",
            &format!("image {id}"),
            "camera_id",
            "camera 77 does not exist",
            "cameras.{ext}",
        ],
    );
}

#[test]
fn track_with_unknown_image_or_keypoint() {
    let mut m = good_model(7);
    let pid = m.points[2].id.to_string();
    m.points[2].track.push((4242, 0));
    check_model_error(
        &m,
        no_spoil,
        &[
            "points3D.{ext}",
            &format!("point3D {pid} track["),
            "image_id",
            "image 4242 does not exist",
        ],
    );

    let mut m = good_model(7);
    let (img, _) = m.points[2].track[0];
    m.points[2].track[0] = (img, 100_000);
    check_model_error(
        &m,
        no_spoil,
        &["points3D.{ext}", "point2D_idx", "100000 is out of range"],
    );
}

#[test]
fn keypoint_with_unknown_point() {
    let mut m = good_model(8);
    m.images[0].point3d_ids[0] = 999_999;
    check_model_error(
        &m,
        no_spoil,
        &[
            "images.{ext}",
            "points2D[0] point3D_id",
            "999999 is not a point",
        ],
    );
    let mut m = good_model(8);
    m.images[0].point3d_ids[0] = -7;
    check_model_error(
        &m,
        no_spoil,
        &["images.{ext}", "points2D[0] point3D_id", "-7"],
    );
}

#[test]
fn image_missing_on_disk() {
    let m = good_model(9);
    let name = m.images[2].name.clone();
    check_model_error(
        &m,
        |root| std::fs::remove_file(root.join("images").join(&name)).unwrap(),
        &[&name, "missing on disk", "images.{ext}"],
    );
}

#[test]
fn image_of_the_wrong_size_or_unreadable() {
    let m = good_model(10);
    let name = m.images[3].name.clone();
    check_model_error(
        &m,
        |root| write_png(&root.join("images").join(&name), 32, 24),
        &[
            &name,
            "width x height",
            "is 32x24 on disk",
            "says 64x48",
            "cameras.{ext}",
        ],
    );
    check_model_error(
        &m,
        |root| std::fs::write(root.join("images").join(&name), b"not a png").unwrap(),
        &[&name, "cannot read the image header"],
    );
}

#[test]
fn non_finite_poses_and_intrinsics() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut m = good_model(11);
        m.images[1].qvec[2] = bad;
        check_model_error(&m, no_spoil, &["images.{ext}", "qvec/tvec", "not finite"]);
        let mut m = good_model(11);
        m.images[0].tvec[0] = bad;
        check_model_error(&m, no_spoil, &["images.{ext}", "qvec/tvec"]);
        let mut m = good_model(11);
        m.cameras[0].params[3] = bad;
        check_model_error(
            &m,
            no_spoil,
            &[
                "cameras.{ext}",
                "camera 10 params[3]",
                "not a finite number",
            ],
        );
        let mut m = good_model(11);
        m.images[2].points2d[1][1] = bad;
        check_model_error(&m, no_spoil, &["images.{ext}", "points2D[1]", "not finite"]);
        let mut m = good_model(11);
        m.points[0].xyz[1] = bad;
        check_model_error(&m, no_spoil, &["points3D.{ext}", "xyz", "not finite"]);
    }
    let mut m = good_model(11);
    m.cameras[0].params[0] = -60.0;
    check_model_error(
        &m,
        no_spoil,
        &["cameras.{ext}", "camera 10 focal length", "positive"],
    );
    let mut m = good_model(11);
    m.images[0].qvec = [0.0; 4];
    check_model_error(&m, no_spoil, &["images.{ext}", "qvec", "all zeros"]);
}

#[test]
fn zero_sized_camera() {
    for (w, h) in [(0, 48), (64, 0)] {
        let mut m = good_model(12);
        m.cameras[0].width = w;
        m.cameras[0].height = h;
        check_model_error(
            &m,
            no_spoil,
            &[
                "cameras.{ext}",
                "camera 10 width/height",
                &format!("{w}x{h}"),
            ],
        );
    }
}

#[test]
fn empty_model() {
    let mut m = good_model(13);
    m.images.clear();
    m.points.clear();
    check_model_error(&m, no_spoil, &["images.{ext}", "images", "no images"]);
}

#[test]
fn unsupported_camera_models() {
    // OPENCV_FISHEYE is a COLMAP model we do not read: named, with the supported list.
    let mut m = good_model(14);
    m.cameras[0].model_id = 5;
    m.cameras[0].params = vec![60.0, 60.0, 32.0, 24.0, 0.1, 0.0, 0.0, 0.0];
    check_model_error(
        &m,
        no_spoil,
        &[
            "cameras.{ext}",
            "camera 10 model",
            "OPENCV_FISHEYE",
            "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV",
        ],
    );
    // An id COLMAP does not know either.
    let mut m = good_model(14);
    m.cameras[0].model_id = 99;
    check_model_error(
        &m,
        no_spoil,
        &[
            "cameras.{ext}",
            "camera 10 model",
            "99",
            "supported models: SIMPLE_PINHOLE",
        ],
    );
}

#[test]
fn duplicate_ids() {
    let mut m = good_model(15);
    m.images[1].id = m.images[0].id;
    check_model_error(
        &m,
        no_spoil,
        &[
            "images.{ext}",
            &format!("image {} id", m.images[0].id),
            "appears twice",
        ],
    );
    let mut m = good_model(15);
    m.cameras.push(m.cameras[0].clone());
    check_model_error(
        &m,
        no_spoil,
        &["cameras.{ext}", "camera 10 id", "appears twice"],
    );
    let mut m = good_model(15);
    let mut twin = m.points[0].clone();
    twin.track.clear();
    m.points.push(twin);
    check_model_error(&m, no_spoil, &["points3D.{ext}", "appears twice"]);
    let mut m = good_model(15);
    m.images[1].name = m.images[0].name.clone();
    check_model_error(
        &m,
        no_spoil,
        &["images.{ext}", "name", "is also the name of image"],
    );
}

/// Random damage to every file in both forms: loading may fail but must never panic.
#[test]
fn random_corruption_never_panics() {
    let model = good_model(16);
    let dir = tempfile::tempdir().unwrap();
    let sparse = write_scene(dir.path(), &model);
    let mut r = rng(17);
    let originals: Vec<(std::path::PathBuf, Vec<u8>)> = ["cameras", "images", "points3D"]
        .iter()
        .flat_map(|f| ["bin", "txt"].map(|e| sparse.join(format!("{f}.{e}"))))
        .map(|p| {
            let b = std::fs::read(&p).unwrap();
            (p, b)
        })
        .collect();
    let mut failures = 0;
    for round in 0..240 {
        let (path, bytes) = &originals[round % originals.len()];
        let mut damaged = bytes.clone();
        let text = path.extension().is_some_and(|e| e == "txt");
        for _ in 0..r.gen_range(1..4) {
            let at = r.gen_range(0..damaged.len());
            match r.gen_range(0..3) {
                0 => {
                    damaged[at] = if text {
                        b"0123456789 -.e\nxn#"[r.gen_range(0..18)]
                    } else {
                        r.gen()
                    }
                }
                1 => damaged.truncate(at),
                _ => {
                    damaged.remove(at);
                }
            }
            if damaged.is_empty() {
                break;
            }
        }
        std::fs::write(path, &damaged).unwrap();
        let form = if text {
            ColmapForm::Text
        } else {
            ColmapForm::Binary
        };
        if let Err(e) = Scene::load(dir.path(), &opts(form)) {
            let msg = format!("{e:#}");
            // Damage in one file can surface in another (a shortened keypoint list breaks the
            // tracks that point into it); the message must still name a file of the scene.
            let names = ["cameras.", "images.", "points3D.", "img_"];
            assert!(names.iter().any(|n| msg.contains(n)), "{msg}");
            assert!(msg.contains("Fix:"), "{msg}");
            failures += 1;
        }
        std::fs::write(path, bytes).unwrap();
    }
    assert!(
        failures > 100,
        "only {failures} of 240 damaged models were refused"
    );
}

/// A path inside a scene (its sparse/0, its images/, one of its files) names the scene's top
/// folder in the fix; a folder of scenes lists them; an empty folder says what a scene holds.
#[test]
fn a_path_that_is_not_a_scene_points_at_the_scene_nearby() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let door = data.join("lund_door_small");
    let top = door.canonicalize().unwrap();
    for inside in [
        door.join("sparse/0"),
        door.join("images"),
        door.join("README.md"),
    ] {
        let e = Scene::load(&inside, &Default::default()).unwrap_err();
        let ie = e.downcast_ref::<InputError>().expect("an InputError");
        assert_eq!(ie.file, inside);
        assert!(ie.fix.contains(&top.display().to_string()), "{e:#}");
    }
    let e = Scene::load(&data, &Default::default()).unwrap_err();
    let fix = &e.downcast_ref::<InputError>().unwrap().fix;
    for scene in ["lego_small", "lund_door_small", "n3v_tiny"] {
        assert!(fix.contains(scene), "{fix}");
    }
    assert!(!fix.contains("lpips"), "{fix}");
    let empty = tempfile::tempdir().unwrap();
    let e = Scene::load(empty.path(), &Default::default()).unwrap_err();
    let ie = e.downcast_ref::<InputError>().unwrap();
    assert!(
        ie.problem.contains("COLMAP") && ie.fix.contains("top folder"),
        "{e:#}"
    );
}
