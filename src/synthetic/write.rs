//! A generated district written as a capture: the survey's images rendered from the truth by
//! our own renderer, a COLMAP text model whose points are a sample of the truth's centres with
//! the views that see them (occlusion included), and the truth itself as a PLY.

use super::city::{City, CitySpec};
use crate::gpu::{GpuBuffer, GpuContext};
use crate::models::BaseModel;
use crate::render::layout::CameraGpu;
use crate::scene::camera::unit_quaternion_of_rotation;
use crate::scene::colmap::{self, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use crate::scene::{images, CameraModel, Image};
use crate::splats::{gpu::GpuSplats, model::sh_dc_to_rgb, ply::write_ply_with_comments};
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;

/// What `city.json` records beside the scene.
#[derive(Debug, Clone, Serialize)]
pub struct CityReport {
    pub lots: [usize; 2],
    pub gaussians: usize,
    pub views: usize,
    pub test_views: usize,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    pub buildings: usize,
    pub sfm_points: usize,
    /// Mean views a point's track holds.
    pub mean_track: f64,
    pub ground_min: [f64; 2],
    pub ground_max: [f64; 2],
    pub render_seconds: f64,
}

/// Cells of the coarse depth buffer that decides which points a view sees, in pixels.
const OCCLUSION_CELL: u32 = 8;
/// A point is seen when it lies within this share of the nearest depth in its cell.
const OCCLUSION_SLACK: f64 = 0.02;

/// Writes `city` as a COLMAP scene into `out` (which must not exist, or be empty): images/,
/// sparse/0/ (text), truth.ply and city.json. `points` SfM points are sampled from the truth.
pub fn write_city(
    ctx: &Arc<GpuContext>,
    city: &City,
    spec: &CitySpec,
    out: &Path,
    points: usize,
) -> anyhow::Result<CityReport> {
    if out.exists() {
        let empty = std::fs::read_dir(out)?.next().is_none();
        anyhow::ensure!(
            empty,
            "{}: the folder exists and is not empty; nothing in it is overwritten. Fix: choose \
             another output folder, or remove it to generate again",
            out.display()
        );
    }
    let image_dir = out.join("images");
    std::fs::create_dir_all(&image_dir)?;
    let names: Vec<String> = (0..city.views.len())
        .map(|k| format!("view_{k:05}.png"))
        .collect();
    let start = std::time::Instant::now();
    render_views(ctx, city, &image_dir, &names)?;
    let render_seconds = start.elapsed().as_secs_f64();

    let camera = &city.views[0].0;
    let cameras = vec![ColmapCamera::from_model(
        1,
        &CameraModel::Pinhole {
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
        },
        camera.width as u64,
        camera.height as u64,
    )];
    let mut model = ColmapModel {
        cameras,
        images: city
            .views
            .iter()
            .zip(&names)
            .enumerate()
            .map(|(k, ((_, pose), name))| ColmapImage {
                id: k as u32 + 1,
                qvec: unit_quaternion_of_rotation(pose.rotation),
                tvec: pose.translation,
                camera_id: 1,
                name: name.clone(),
                points2d: Vec::new(),
                point3d_ids: Vec::new(),
            })
            .collect(),
        points: Vec::new(),
    };
    add_points(&mut model, city, points);
    let tracked = model.points.len();
    let mean_track =
        model.points.iter().map(|p| p.track.len()).sum::<usize>() as f64 / tracked.max(1) as f64;
    colmap::write_text(&out.join("sparse").join("0"), &model)?;
    write_ply_with_comments(
        &out.join("truth.ply"),
        &city.params,
        &[BaseModel::Gaussians3d.ply_comment()],
    )?;
    let report = CityReport {
        lots: [spec.lots.0, spec.lots.1],
        gaussians: city.params.len(),
        views: city.views.len(),
        test_views: city.views.len().div_ceil(8),
        width: spec.width,
        height: spec.height,
        seed: spec.seed,
        buildings: city.buildings.len(),
        sfm_points: tracked,
        mean_track,
        ground_min: city.ground_min,
        ground_max: city.ground_max,
        render_seconds,
    };
    std::fs::write(
        out.join("city.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    Ok(report)
}

/// Renders every view of the survey from the truth into `dir` (black where nothing is).
fn render_views(
    ctx: &Arc<GpuContext>,
    city: &City,
    dir: &Path,
    names: &[String],
) -> anyhow::Result<()> {
    let splats = GpuSplats::upload(ctx, &city.params, city.params.len())?;
    let cams: Vec<CameraGpu> = city
        .views
        .iter()
        .map(|(c, p)| CameraGpu::new(c, p))
        .collect();
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &cams)?;
    let mut renderer =
        BaseModel::Gaussians3d.view_renderer(ctx, city.params.len(), &cams[0], None, None)?;
    for (k, name) in names.iter().enumerate() {
        let rgb = renderer.render(&splats, &cameras, k as u32, &cams[k], [0.0; 3])?;
        let img = Image {
            width: cams[k].width(),
            height: cams[k].height(),
            rgb: rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect(),
            alpha: None,
        };
        images::save_png(&dir.join(name), &img)?;
        if (k + 1) % 20 == 0 || k + 1 == names.len() {
            eprintln!("rendered {} of {} views", k + 1, names.len());
        }
    }
    ctx.check_validation()
}

/// SfM points: every n-th Gaussian of the truth (about `count` of them), each observed by the
/// views in whose image it falls in front of the camera and not behind nearer points (a coarse
/// depth buffer of the candidates themselves). Points no view sees are left out, as a
/// reconstruction would never have them; keypoints are the exact projections.
fn add_points(model: &mut ColmapModel, city: &City, count: usize) {
    let stride = (city.params.len() / count.max(1)).max(1);
    let candidates: Vec<usize> = (0..city.params.len()).step_by(stride).collect();
    let mut tracks: Vec<Vec<(u32, u32)>> = vec![Vec::new(); candidates.len()];
    for (v, (cam, pose)) in city.views.iter().enumerate() {
        let (cw, ch) = (
            cam.width.div_ceil(OCCLUSION_CELL) as usize,
            cam.height.div_ceil(OCCLUSION_CELL) as usize,
        );
        let mut nearest = vec![f64::INFINITY; cw * ch];
        let projected: Vec<Option<(f64, f64, f64, usize)>> = candidates
            .iter()
            .map(|&g| {
                let p = city.params.positions[g].map(|x| x as f64);
                let c = pose.transform(p);
                if c[2] <= 1e-9 {
                    return None;
                }
                let u = cam.fx * c[0] / c[2] + cam.cx;
                let w = cam.fy * c[1] / c[2] + cam.cy;
                if u < 0.0 || w < 0.0 || u >= cam.width as f64 || w >= cam.height as f64 {
                    return None;
                }
                let cell = (w as usize / OCCLUSION_CELL as usize) * cw
                    + u as usize / OCCLUSION_CELL as usize;
                Some((u, w, c[2], cell))
            })
            .collect();
        for &(_, _, z, cell) in projected.iter().flatten() {
            nearest[cell] = nearest[cell].min(z);
        }
        let image = &mut model.images[v];
        for (i, p) in projected.iter().enumerate() {
            if let Some((u, w, z, cell)) = *p {
                if z <= nearest[cell] * (1.0 + OCCLUSION_SLACK) {
                    tracks[i].push((image.id, image.points2d.len() as u32));
                    image.points2d.push([u, w]);
                    image.point3d_ids.push(-1);
                }
            }
        }
    }
    for (i, track) in tracks.into_iter().enumerate() {
        if track.len() < 2 {
            // One view does not triangulate a point; unlink its keypoint.
            continue;
        }
        let id = model.points.len() as u64 + 1;
        let g = candidates[i];
        for &(image, key) in &track {
            model.images[image as usize - 1].point3d_ids[key as usize] = id as i64;
        }
        model.points.push(ColmapPoint {
            id,
            xyz: city.params.positions[g].map(|x| x as f64),
            rgb: city.params.sh_dc[g]
                .map(|d| (sh_dc_to_rgb(d).clamp(0.0, 1.0) * 255.0).round() as u8),
            error: 0.5,
            track,
        });
    }
}
