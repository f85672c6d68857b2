//! Inputs that lie, and the layouts scenes are distributed in: a folder in the Mip-NeRF 360 /
//! LLFF layout (COLMAP model beside `poses_bounds.npy`) is a COLMAP scene and its `images_N/`
//! copies serve `-r N`; a truncated JPEG or PNG, a singular, reflected or sheared camera
//! matrix are refused naming the file and the field (a uniform scale in the matrix is divided
//! out); scores that are not numbers fail a run; a PLY's header says which model it holds.

use std::path::Path;

use lpmsplat::models::BaseModel;
use lpmsplat::scene::images::{check_complete, decode_image, load_view_image};
use lpmsplat::scene::{LoadOptions, Scene, SceneFormat};
use lpmsplat::train::trainer::ViewMetrics;

const DOOR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");

fn err(r: anyhow::Result<Scene>) -> String {
    format!("{:#}", r.expect_err("the load must fail"))
}

/// A copy of the door scene: its model, and its images linked one by one (so a test can spoil
/// one).
fn door_copy(dir: &Path) {
    let src = Path::new(DOOR);
    let sparse = dir.join("sparse");
    std::fs::create_dir_all(&sparse).unwrap();
    std::os::unix::fs::symlink(src.join("sparse/0"), sparse.join("0")).unwrap();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    for e in std::fs::read_dir(src.join("images")).unwrap().flatten() {
        std::os::unix::fs::symlink(e.path(), dir.join("images").join(e.file_name())).unwrap();
    }
}

#[test]
fn a_colmap_model_beside_poses_bounds_is_a_still_scene() {
    let dir = tempfile::tempdir().unwrap();
    door_copy(dir.path());
    // Any poses_bounds.npy: a COLMAP scene does not read it.
    std::fs::write(dir.path().join("poses_bounds.npy"), b"\x93NUMPY").unwrap();
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    assert!(matches!(scene.format, SceneFormat::Colmap { .. }));
    assert_eq!(scene.views.len(), 12);
    // With camera folders beside them, the same files are a Neural 3D Video scene.
    std::fs::create_dir(dir.path().join("cam00")).unwrap();
    let e = err(Scene::load(dir.path(), &LoadOptions::default()));
    assert!(e.contains("poses_bounds.npy"), "{e}");
}

/// Writes `images_N/` copies of the door's images at `size(w, h)`.
fn downscaled_copies(dir: &Path, n: u32, size: impl Fn(u32, u32) -> (u32, u32)) {
    let out = dir.join(format!("images_{n}"));
    std::fs::create_dir_all(&out).unwrap();
    for e in std::fs::read_dir(Path::new(DOOR).join("images"))
        .unwrap()
        .flatten()
    {
        let img = image::open(e.path()).unwrap();
        let (w, h) = size(img.width(), img.height());
        img.resize_exact(w, h, image::imageops::FilterType::Triangle)
            .to_rgb8()
            .save_with_format(out.join(e.file_name()), image::ImageFormat::Jpeg)
            .unwrap();
    }
}

#[test]
fn images_n_serve_minus_r_n() {
    let dir = tempfile::tempdir().unwrap();
    door_copy(dir.path());
    // Rounded up, as some tools do: within a pixel of 1/4.
    downscaled_copies(dir.path(), 4, |w, h| (w.div_ceil(4), h.div_ceil(4)));
    let r4 = LoadOptions {
        resolution_factor: Some(4),
        ..LoadOptions::default()
    };
    let scene = Scene::load(dir.path(), &r4).unwrap();
    let full = Scene::load(Path::new(DOOR), &r4).unwrap();
    for (v, f) in scene.views.iter().zip(&full.views) {
        assert!(
            v.image_path.starts_with(dir.path().join("images_4")),
            "{v:?}"
        );
        // The same training camera either way; the source camera follows its image.
        assert_eq!(v.camera, f.camera);
        assert_eq!(v.source_width, f.source_width.div_ceil(4));
    }
    // The pixels are the downscaled images' (close to downscaling the originals).
    let a = load_view_image(&scene.views[0]).unwrap();
    let b = load_view_image(&full.views[0]).unwrap();
    assert_eq!((a.width, a.height), (b.width, b.height));
    let mean_diff: f32 = a
        .rgb
        .iter()
        .zip(&b.rgb)
        .map(|(x, y)| (x - y).abs())
        .sum::<f32>()
        / a.rgb.len() as f32;
    assert!(mean_diff < 0.03, "{mean_diff}");
    // Other factors, and no factor, read images/.
    let r2 = LoadOptions {
        resolution_factor: Some(2),
        ..LoadOptions::default()
    };
    let s2 = Scene::load(dir.path(), &r2).unwrap();
    assert!(s2.views[0]
        .image_path
        .starts_with(dir.path().join("images")));
    assert!(!s2.views[0]
        .image_path
        .starts_with(dir.path().join("images_4")));
    // A copy at another size, or a missing one, is refused naming the file and the fix.
    let victim = dir.path().join("images_4/DSC_0002.JPG");
    image::RgbImage::new(100, 70)
        .save_with_format(&victim, image::ImageFormat::Jpeg)
        .unwrap();
    let e = err(Scene::load(dir.path(), &r4));
    assert!(
        e.contains("DSC_0002.JPG") && e.contains("100x70") && e.contains("Fix:"),
        "{e}"
    );
    std::fs::remove_file(&victim).unwrap();
    let e = err(Scene::load(dir.path(), &r4));
    assert!(e.contains("DSC_0002.JPG") && e.contains("images_4"), "{e}");
}

#[test]
fn truncated_images_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    door_copy(dir.path());
    let victim = dir.path().join("images/DSC_0003.JPG");
    let bytes = std::fs::read(&victim).unwrap();
    std::fs::remove_file(&victim).unwrap();
    // A camera's trailer after the end of the image is fine.
    let mut trailer = bytes.clone();
    trailer.extend_from_slice(b"MAKERNOTE-TRAILER");
    std::fs::write(&victim, &trailer).unwrap();
    Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    // Cut anywhere in its scan data, it is refused at load (the header alone still reads).
    for cut in [bytes.len() / 3, bytes.len() / 2, bytes.len() - 2] {
        std::fs::write(&victim, &bytes[..cut]).unwrap();
        assert!(image::image_dimensions(&victim).is_ok());
        let e = err(Scene::load(dir.path(), &LoadOptions::default()));
        assert!(
            e.contains("DSC_0003.JPG") && e.contains("truncated") && e.contains("Fix:"),
            "{cut}: {e}"
        );
        assert!(decode_image(&victim).is_err());
    }
    // A PNG without its IEND chunk.
    let png = dir.path().join("x.png");
    image::RgbImage::from_fn(40, 30, |x, y| image::Rgb([x as u8, y as u8, 7]))
        .save(&png)
        .unwrap();
    let full = std::fs::read(&png).unwrap();
    check_complete(&png, &full).unwrap();
    for cut in [full.len() - 12, full.len() - 1, full.len() / 2] {
        let e = format!("{:#}", check_complete(&png, &full[..cut]).unwrap_err());
        assert!(e.contains("x.png") && e.contains("IEND"), "{cut}: {e}");
    }
}

/// A nerfstudio scene of three 8×6 frames whose second camera-to-world matrix is `m`.
fn nerfstudio_scene(dir: &Path, m: [[f64; 4]; 4]) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let good = |x: f64| {
        [
            [1.0, 0.0, 0.0, x],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    };
    let mut frames = Vec::new();
    for (k, mat) in [good(0.0), m, good(1.0)].iter().enumerate() {
        let name = format!("images/f{k}.png");
        image::RgbImage::from_pixel(8, 6, image::Rgb([10, 20, 30]))
            .save(dir.join(&name))
            .unwrap();
        frames.push(serde_json::json!({"file_path": name, "transform_matrix": mat}));
    }
    let j = serde_json::json!({
        "fl_x": 8.0, "fl_y": 8.0, "cx": 4.0, "cy": 3.0, "w": 8, "h": 6, "frames": frames
    });
    std::fs::write(dir.join("transforms.json"), j.to_string()).unwrap();
}

#[test]
fn camera_matrices_must_be_rotations() {
    let cases: [(&str, [[f64; 4]; 4], &str); 5] = [
        ("zeros", [[0.0; 4]; 4], "bottom row"),
        (
            "singular",
            [[0.0; 4], [0.0; 4], [0.0; 4], [0.0, 0.0, 0.0, 1.0]],
            "singular",
        ),
        (
            "collapsed axis",
            [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, 3.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            "singular",
        ),
        (
            "reflection",
            [
                [-1.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 3.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            "reflection",
        ),
        (
            "shear",
            [
                [1.0, 0.5, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 3.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
            "not a rotation",
        ),
    ];
    for (name, m, want) in cases {
        let dir = tempfile::tempdir().unwrap();
        nerfstudio_scene(dir.path(), m);
        let e = err(Scene::load(dir.path(), &LoadOptions::default()));
        assert!(
            e.contains("transforms.json")
                && e.contains("frames[1].transform_matrix")
                && e.contains(want)
                && e.contains("Fix:"),
            "{name}: {e}"
        );
    }
    // A rotation times a uniform scale: divided out, the camera as if it had none.
    let dir = tempfile::tempdir().unwrap();
    let s = 2.5;
    nerfstudio_scene(
        dir.path(),
        [
            [s, 0.0, 0.0, 0.5],
            [0.0, s, 0.0, 0.0],
            [0.0, 0.0, s, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    );
    let scene = Scene::load_in_file_frame(dir.path(), &LoadOptions::default()).unwrap();
    let v = scene.views.iter().find(|v| v.name.contains("f1")).unwrap();
    let r = v.pose.rotation;
    for i in 0..3 {
        for j in 0..3 {
            let want = match (i, j) {
                (0, 0) => 1.0,
                (1, 1) | (2, 2) => -1.0,
                _ => 0.0,
            };
            assert!((r[i][j] - want).abs() < 1e-12, "{r:?}");
        }
    }
    let c = v.pose.center();
    assert!(
        (c[0] - 0.5).abs() < 1e-12 && (c[2] - 3.0).abs() < 1e-12,
        "{c:?}"
    );
}

#[test]
fn scores_that_are_not_numbers_fail() {
    let ok = |view: &str, psnr: f64| ViewMetrics {
        view: view.into(),
        psnr,
        ssim: 0.9,
        lpips: None,
    };
    assert!(ViewMetrics::invalid(&[ok("a", 30.0), ok("b", f64::INFINITY)]).is_none());
    let e = ViewMetrics::invalid(&[ok("a", 30.0), ok("b", f64::NAN)]).unwrap();
    let e = format!("{e:#}");
    assert!(
        e.contains("1 of 2 views") && e.contains("b (PSNR NaN") && e.contains("Fix:"),
        "{e}"
    );
    let mut bad_ssim = ok("c", 20.0);
    bad_ssim.ssim = f64::NAN;
    assert!(ViewMetrics::invalid(&[bad_ssim]).is_some());
    let mut bad_lpips = ok("d", 20.0);
    bad_lpips.lpips = Some(f64::NAN);
    assert!(ViewMetrics::invalid(&[bad_lpips]).is_some());
    assert!(ViewMetrics::invalid(&[ok("e", f64::NEG_INFINITY)]).is_some());
}

#[test]
fn a_ply_says_which_model_it_holds() {
    let dir = tempfile::tempdir().unwrap();
    let params = lpmsplat::splats::GaussianParams {
        sh_degree: 0,
        positions: vec![[0.0, 0.0, 1.0]],
        log_scales: vec![[-2.0, -2.0, -20.0]],
        rotations: vec![[1.0, 0.0, 0.0, 0.0]],
        opacity_logits: vec![0.0],
        sh_dc: vec![[0.0; 3]],
        sh_rest: vec![],
        extra: vec![],
    };
    let write = |name: &str, comments: &[String]| {
        let p = dir.path().join(name);
        lpmsplat::splats::write_ply_with_comments(&p, &params, comments).unwrap();
        p
    };
    let mip = write("mip.ply", &[BaseModel::MipSplatting.ply_comment()]);
    let other = write("other.ply", &["made by another trainer".into()]);
    let unknown = write("unknown.ply", &["lpmsplat model 4dgs".into()]);
    assert_eq!(
        BaseModel::recorded_in(&mip).unwrap(),
        Some(BaseModel::MipSplatting)
    );
    // The header decides; --model may only agree.
    assert_eq!(
        BaseModel::for_ply(None, &mip).unwrap(),
        BaseModel::MipSplatting
    );
    assert_eq!(
        BaseModel::for_ply(Some(BaseModel::MipSplatting), &mip).unwrap(),
        BaseModel::MipSplatting
    );
    let e = format!(
        "{:#}",
        BaseModel::for_ply(Some(BaseModel::Gaussians3d), &mip).unwrap_err()
    );
    assert!(
        e.contains("mip.ply")
            && e.contains("mip-splatting")
            && e.contains("--model 3dgs")
            && e.contains("Fix:"),
        "{e}"
    );
    // Another trainer's file: 3DGS, or what --model says.
    assert_eq!(BaseModel::recorded_in(&other).unwrap(), None);
    assert_eq!(
        BaseModel::for_ply(None, &other).unwrap(),
        BaseModel::Gaussians3d
    );
    assert_eq!(
        BaseModel::for_ply(Some(BaseModel::Surfels2d), &other).unwrap(),
        BaseModel::Surfels2d
    );
    // A name this build does not know is an error, not a guess.
    let e = format!("{:#}", BaseModel::for_ply(None, &unknown).unwrap_err());
    assert!(e.contains("unknown.ply") && e.contains("4dgs"), "{e}");
}
