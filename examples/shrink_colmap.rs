//! Writes a downscaled copy of a COLMAP scene (images, intrinsics and keypoints scaled).
//!
//! `cargo run --release --example shrink_colmap -- <src_scene> <dst_scene> <factor>`
//!
//! Keypoints without a 3D point are dropped to keep the copy small (tracks are re-indexed), the
//! images are written as JPEG (quality 90) under their original names, and the model is written
//! in both binary and text form. Distortion coefficients act on normalised coordinates, so they
//! stay as they are; keypoints scale as x·s because pixel centres sit at +0.5.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use lpmsplat::error::write_atomic;
use lpmsplat::scene::colmap::{self, models, ColmapCamera, ColmapModel};
use rayon::prelude::*;

/// Keypoint coordinates are rounded to 1/KEYPOINT_STEPS of a pixel, point positions to
/// 1/POSITION_STEPS of a scene unit and errors to 1/ERROR_STEPS of a pixel: far below SfM
/// accuracy, and it keeps the text form short.
const KEYPOINT_STEPS: f64 = 1e3;
const POSITION_STEPS: f64 = 1e6;
const ERROR_STEPS: f64 = 1e4;

/// `v` rounded to a multiple of `1 / steps`; dividing last gives the f64 nearest the decimal, so
/// it prints short.
fn round_to(v: f64, steps: f64) -> f64 {
    (v * steps).round() / steps
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [src, dst, factor] = args.as_slice() else {
        bail!("usage: shrink_colmap <src_scene> <dst_scene> <factor>");
    };
    let (src, dst) = (PathBuf::from(src), PathBuf::from(dst));
    let factor: f64 = factor
        .parse()
        .with_context(|| format!("factor '{factor}' is not a number"))?;
    if !(factor.is_finite() && factor >= 1.0) {
        bail!("factor must be a number >= 1, got {factor}");
    }
    let sparse = colmap::find_sparse_dir(&src).with_context(|| {
        format!(
            "{}: no sparse/0 or sparse folder with a COLMAP model",
            src.display()
        )
    })?;
    let binary = colmap::use_binary(&sparse, Default::default());
    let model = colmap::read_model(&sparse, binary)?;
    let small = shrink_model(&model, &sparse, factor)?;

    let out_sparse = dst.join("sparse").join("0");
    colmap::write_binary(&out_sparse, &small)?;
    colmap::write_text(&out_sparse, &small)?;

    let sizes: HashMap<u32, (u32, u32)> = small
        .cameras
        .iter()
        .map(|c| (c.id, (c.width as u32, c.height as u32)))
        .collect();
    std::fs::create_dir_all(dst.join("images"))?;
    small.images.par_iter().try_for_each(|im| {
        let (w, h) = sizes[&im.camera_id];
        shrink_image(
            &src.join("images").join(&im.name),
            &dst.join("images").join(&im.name),
            w,
            h,
        )
    })?;
    println!(
        "{}: {} cameras, {} images, {} points, {} keypoints",
        dst.display(),
        small.cameras.len(),
        small.images.len(),
        small.points.len(),
        small.images.iter().map(|i| i.points2d.len()).sum::<usize>()
    );
    Ok(())
}

fn shrink_model(model: &ColmapModel, sparse: &Path, factor: f64) -> anyhow::Result<ColmapModel> {
    let cameras_file = sparse.join("cameras");
    let mut scale = HashMap::new();
    let mut cameras = Vec::new();
    for c in &model.cameras {
        let cam = models::to_camera_model(c, &cameras_file)?;
        let w = ((c.width as f64 / factor).round() as u64).max(1);
        let h = ((c.height as f64 / factor).round() as u64).max(1);
        let (sx, sy) = (w as f64 / c.width as f64, h as f64 / c.height as f64);
        scale.insert(c.id, (sx, sy));
        cameras.push(ColmapCamera::from_model(c.id, &cam.scaled(sx, sy), w, h));
    }
    let mut new_index: HashMap<(u32, u32), u32> = HashMap::new();
    let mut images = Vec::new();
    for im in &model.images {
        let &(sx, sy) = scale
            .get(&im.camera_id)
            .with_context(|| format!("image {}: unknown camera", im.id))?;
        let mut small = im.clone();
        small.points2d.clear();
        small.point3d_ids.clear();
        for (k, (xy, &id)) in im.points2d.iter().zip(&im.point3d_ids).enumerate() {
            if id == -1 {
                continue;
            }
            new_index.insert((im.id, k as u32), small.points2d.len() as u32);
            small.points2d.push([
                round_to(xy[0] * sx, KEYPOINT_STEPS),
                round_to(xy[1] * sy, KEYPOINT_STEPS),
            ]);
            small.point3d_ids.push(id);
        }
        images.push(small);
    }
    let points = model
        .points
        .iter()
        .map(|p| {
            let mut p = p.clone();
            p.xyz = p.xyz.map(|v| round_to(v, POSITION_STEPS));
            p.error = round_to(p.error, ERROR_STEPS);
            p.track = p
                .track
                .iter()
                .filter_map(|&(img, k)| new_index.get(&(img, k)).map(|&n| (img, n)))
                .collect();
            p
        })
        .collect();
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

fn shrink_image(src: &Path, dst: &Path, w: u32, h: u32) -> anyhow::Result<()> {
    let img = image::open(src)
        .with_context(|| format!("{}: cannot read", src.display()))?
        .to_rgb8();
    let small = image::imageops::resize(&img, w, h, image::imageops::FilterType::Lanczos3);
    if let Some(dir) = dst.parent() {
        std::fs::create_dir_all(dir)?;
    }
    write_atomic(dst, |f| {
        let mut enc =
            image::codecs::jpeg::JpegEncoder::new_with_quality(std::io::BufWriter::new(f), 90);
        enc.encode_image(&small)
            .with_context(|| format!("{}: JPEG encoding failed", dst.display()))
    })
}
