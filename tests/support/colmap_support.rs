//! Synthetic COLMAP scenes for the colmap tests: random poses, points seen by the cameras,
//! keypoints from projecting the points through the (distorted) camera, small PNG images.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use lpmsplat::scene::colmap::{self, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use lpmsplat::scene::{CameraModel, ColmapForm, LoadOptions, Pose, Scene};
use rand::Rng;
use rand_pcg::Pcg64;

pub fn rng(seed: u64) -> Pcg64 {
    Pcg64::new(
        0xcafe_f00d_d15e_a5e5 ^ seed as u128,
        0xa02b_dbf7_bb3c_0a7a_c28f_a64a_5d32_2a5d,
    )
}

/// One camera of each supported model, with realistic random parameters for a `w` × `h` image.
pub fn all_models(rng: &mut Pcg64, w: u32, h: u32) -> Vec<CameraModel> {
    let f = rng.gen_range(0.8..1.4) * w as f64;
    let fy = f * rng.gen_range(0.95..1.05);
    let cx = w as f64 * rng.gen_range(0.45..0.55);
    let cy = h as f64 * rng.gen_range(0.45..0.55);
    vec![
        CameraModel::SimplePinhole { f, cx, cy },
        CameraModel::Pinhole { fx: f, fy, cx, cy },
        CameraModel::SimpleRadial {
            f,
            cx,
            cy,
            k: rng.gen_range(-0.08..0.08),
        },
        CameraModel::Radial {
            f,
            cx,
            cy,
            k1: rng.gen_range(-0.08..0.08),
            k2: rng.gen_range(-0.02..0.02),
        },
        CameraModel::OpenCv {
            fx: f,
            fy,
            cx,
            cy,
            k1: rng.gen_range(-0.08..0.08),
            k2: rng.gen_range(-0.02..0.02),
            p1: rng.gen_range(-0.005..0.005),
            p2: rng.gen_range(-0.005..0.005),
        },
    ]
}

/// Source pixel of camera-space point `p` through `model` (distortion, then K).
pub fn project_distorted(model: &CameraModel, p: [f64; 3]) -> [f64; 2] {
    let (fx, fy, cx, cy) = model.pinhole_part();
    let (x, y) = model.distort_normalized(p[0] / p[2], p[1] / p[2]);
    [fx * x + cx, fy * y + cy]
}

fn random_unit_quaternion(rng: &mut Pcg64) -> [f64; 4] {
    loop {
        let q: [f64; 4] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if n > 0.1 && n < 1.0 {
            return q.map(|v| v / n);
        }
    }
}

/// A model with `n_images` images of `cameras` (assigned round-robin), `points_per_image`
/// points created in front of each camera and observed by every camera that sees them, and a
/// few keypoints without a 3D point. Ids are deliberately not in name order.
pub fn synth_model(
    rng: &mut Pcg64,
    cameras: &[(CameraModel, u32, u32)],
    n_images: usize,
    points_per_image: usize,
) -> ColmapModel {
    let cams: Vec<ColmapCamera> = cameras
        .iter()
        .enumerate()
        .map(|(k, (m, w, h))| ColmapCamera::from_model(10 + 3 * k as u32, m, *w as u64, *h as u64))
        .collect();
    let mut images: Vec<ColmapImage> = (0..n_images)
        .map(|k| {
            let qvec = random_unit_quaternion(rng);
            let tvec = std::array::from_fn(|_| rng.gen_range(-2.0..2.0));
            ColmapImage {
                id: 100 + 7 * (n_images - k) as u32,
                qvec,
                tvec,
                camera_id: cams[k % cams.len()].id,
                name: format!("img_{k:03}.png"),
                points2d: Vec::new(),
                point3d_ids: Vec::new(),
            }
        })
        .collect();
    let poses: Vec<Pose> = images
        .iter()
        .map(|im| Pose::from_qvec_tvec(im.qvec, im.tvec))
        .collect();
    let model_of = |im: &ColmapImage| {
        let k = cams.iter().position(|c| c.id == im.camera_id).unwrap();
        cameras[k]
    };
    let mut points = Vec::new();
    for k in 0..n_images {
        let (m, w, h) = model_of(&images[k]);
        let (fx, fy, cx, cy) = m.pinhole_part();
        for _ in 0..points_per_image {
            // A point in front of camera k, inside its (pinhole) view.
            let u = rng.gen_range(0.1..0.9) * w as f64;
            let v = rng.gen_range(0.1..0.9) * h as f64;
            let z = rng.gen_range(1.0..6.0);
            let pc = [(u - cx) / fx * z, (v - cy) / fy * z, z];
            let xyz = camera_to_world(&poses[k], pc);
            let id = 1000 + 13 * points.len() as u64;
            let mut track = Vec::new();
            for (j, im) in images.iter_mut().enumerate() {
                let p = poses[j].transform(xyz);
                let (mj, wj, hj) = model_of(im);
                // Keep to the lens's field of view: far outside it a barrel distortion folds back
                // and would put the point inside the image, where no real camera sees it.
                if p[2] <= 0.1 || (p[0] / p[2]).hypot(p[1] / p[2]) > 1.0 {
                    continue;
                }
                let px = project_distorted(&mj, p);
                if !(px[0] >= 0.0 && px[1] >= 0.0 && px[0] < wj as f64 && px[1] < hj as f64) {
                    continue;
                }
                track.push((im.id, im.points2d.len() as u32));
                im.points2d.push(px);
                im.point3d_ids.push(id as i64);
            }
            let rgb = std::array::from_fn(|_| rng.gen());
            points.push(ColmapPoint {
                id,
                xyz,
                rgb,
                error: rng.gen_range(0.1..2.0),
                track,
            });
        }
    }
    for im in &mut images {
        let (_, w, h) = model_of(im);
        for _ in 0..5 {
            let at = rng.gen_range(0..=im.points2d.len());
            im.points2d.insert(
                at,
                [rng.gen_range(0.0..w as f64), rng.gen_range(0.0..h as f64)],
            );
            im.point3d_ids.insert(at, -1);
            // Inserting shifts later keypoints: move their track references along.
            for p in &mut points {
                for t in &mut p.track {
                    if t.0 == im.id && t.1 as usize >= at {
                        t.1 += 1;
                    }
                }
            }
        }
    }
    ColmapModel {
        cameras: cams,
        images,
        points,
    }
}

pub fn camera_to_world(pose: &Pose, pc: [f64; 3]) -> [f64; 3] {
    let r = &pose.rotation;
    let d = [
        pc[0] - pose.translation[0],
        pc[1] - pose.translation[1],
        pc[2] - pose.translation[2],
    ];
    [
        r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2],
        r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2],
        r[0][2] * d[0] + r[1][2] * d[1] + r[2][2] * d[2],
    ]
}

/// Writes `model` in both forms under `root/sparse/0` and a PNG of the right size per image.
pub fn write_scene(root: &Path, model: &ColmapModel) -> PathBuf {
    let sparse = root.join("sparse").join("0");
    colmap::write_binary(&sparse, model).unwrap();
    colmap::write_text(&sparse, model).unwrap();
    std::fs::create_dir_all(root.join("images")).unwrap();
    for im in &model.images {
        let Some(cam) = model
            .cameras
            .iter()
            .find(|c| c.id == im.camera_id && c.width > 0 && c.height > 0)
        else {
            continue;
        };
        write_png(
            &root.join("images").join(&im.name),
            cam.width as u32,
            cam.height as u32,
        );
    }
    sparse
}

pub fn write_png(path: &Path, w: u32, h: u32) {
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7) as u8, (y * 5) as u8, 90]))
        .save(path)
        .unwrap();
}

pub fn opts(form: ColmapForm) -> LoadOptions {
    LoadOptions {
        colmap_form: form,
        ..LoadOptions::default()
    }
}

/// Loads `root` in both forms, returning (binary, text) with the format field made equal.
pub fn load_both(root: &Path, base: &LoadOptions) -> (Scene, Scene) {
    let bin = Scene::load(
        root,
        &LoadOptions {
            colmap_form: ColmapForm::Binary,
            ..base.clone()
        },
    )
    .unwrap();
    let mut txt = Scene::load(
        root,
        &LoadOptions {
            colmap_form: ColmapForm::Text,
            ..base.clone()
        },
    )
    .unwrap();
    match (&bin.format, &txt.format) {
        (
            lpmsplat::scene::SceneFormat::Colmap {
                binary: true,
                sparse_dir: a,
            },
            lpmsplat::scene::SceneFormat::Colmap {
                binary: false,
                sparse_dir: b,
            },
        ) => assert_eq!(a, b),
        other => panic!("unexpected formats {other:?}"),
    }
    txt.format = bin.format.clone();
    (bin, txt)
}
