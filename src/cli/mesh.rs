//! `mesh`: a triangle mesh of a trained 2DGS model (2DGS's bounded extraction): render every
//! chosen view's surface depth and diffuse colour (SH degree 0, as the official code), fuse them
//! into a TSDF, extract its zero level set, keep the large connected pieces, write a PLY.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::mesh::{extract::extract, ply::write_mesh_ply, tsdf::DepthView, tsdf::Tsdf};
use lpmsplat::models::BaseModel;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::scene::{images, Scene};
use lpmsplat::splats::gpu::GpuSplats;

use super::SceneArgs;

#[derive(Args, Debug)]
pub struct MeshArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// A trained 2DGS PLY (`train --model 2dgs`).
    #[arg(long)]
    pub ply: PathBuf,
    /// Output mesh (binary PLY with vertex colours).
    #[arg(long, short = 'o')]
    pub out: PathBuf,
    /// Views to fuse: train or all.
    #[arg(long, default_value = "train", value_parser = ["train", "all"])]
    pub cameras: String,
    /// The surface depth: 0 the expected depth, 1 the median depth (the official DTU and TnT
    /// scripts use 1).
    #[arg(long, default_value_t = 0.0)]
    pub depth_ratio: f32,
    /// Voxel side (world units). Default: the fused region's longest side / --mesh-res.
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Voxels along the fused region's longest side when --voxel is not given.
    #[arg(long, default_value_t = 256)]
    pub mesh_res: u32,
    /// TSDF truncation (world units). Default: 5 voxels (official).
    #[arg(long)]
    pub sdf_trunc: Option<f64>,
    /// Depths beyond this are not fused (world units). Default: no limit.
    #[arg(long)]
    pub depth_trunc: Option<f64>,
    /// Folder of object masks (PNG, white = object), named like the images (`<stem>.png`) or
    /// by the image's number (DTU's `mask/000.png` for `images/000000.jpg`); pixels outside a
    /// mask do not vote. Default: the scene's own `mask/` or `masks/` folder when it has one.
    #[arg(long, conflicts_with = "no_masks")]
    pub masks: Option<PathBuf>,
    /// Fuse every pixel, even when the scene has a mask folder.
    #[arg(long)]
    pub no_masks: bool,
    /// Drop connected pieces with fewer triangles (official 50).
    #[arg(long, default_value_t = 50)]
    pub min_triangles: usize,
    /// Keep at most this many of the largest pieces (official 50; DTU: 1).
    #[arg(long, default_value_t = 50)]
    pub max_pieces: usize,
    /// Also write a shaded picture of the mesh seen from the first fused view (PNG).
    #[arg(long)]
    pub preview: Option<PathBuf>,
}

/// Pixels with less accumulated alpha give no depth.
const MIN_ALPHA: f32 = 0.5;

pub fn run(gpu: &GpuOptions, args: &MeshArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.mesh_res >= 8 && (0.0..=1.0).contains(&args.depth_ratio),
        "--mesh-res {} must be ≥ 8 and --depth-ratio {} in [0, 1]",
        args.mesh_res,
        args.depth_ratio
    );
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    if let Some(m) = BaseModel::recorded_in(&args.ply)
        .ok()
        .flatten()
        .filter(|m| *m != BaseModel::Surfels2d)
    {
        return lpmsplat::error::bad_input(
            &args.ply,
            format!("header comment '{}'", m.ply_comment()),
            format!(
                "the file holds a {} model; meshes are extracted from 2DGS surfels",
                m.name()
            ),
            "train the scene with --model 2dgs and mesh that model",
        );
    }
    let params = BaseModel::Surfels2d
        .read_ply_for_scene(&args.ply, &scene)?
        .with_sh_degree(0)?;
    // The lengths the user gives are in the scene's own units; the fusion runs in the
    // training frame (`lpmsplat::scene::frame`).
    let to_train = |l: f64| scene.frame.length_to_train(l);
    lpmsplat::splats::require_nonempty(&args.ply, &params)?;
    let views: Vec<usize> = match args.cameras.as_str() {
        "train" if !scene.train.is_empty() => scene.train.clone(),
        _ => (0..scene.views.len()).collect(),
    };
    let ctx = GpuContext::new(gpu)?;
    let splats = GpuSplats::upload(&ctx, &params, params.len())?;
    let cams: Vec<CameraGpu> = views
        .iter()
        .map(|&i| CameraGpu::new(&scene.views[i].camera, &scene.views[i].pose))
        .collect();
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &cams)?;
    let mut renderer =
        BaseModel::Surfels2d.view_renderer(&ctx, params.len(), &cams[0], None, None)?;
    let depth_trunc = args.depth_trunc.map(to_train).unwrap_or(f64::INFINITY);
    let masks = mask_folder(args);
    if let (Some(dir), None) = (&masks, &args.masks) {
        println!(
            "using the scene's object masks in {} (--no-masks fuses every pixel)",
            dir.display()
        );
    }
    // Render every view once: surface depth, colour and mask.
    let mut frames = Vec::new();
    for (k, &v) in views.iter().enumerate() {
        let rgb = renderer.render(&splats, &cameras, k as u32, &cams[k], [0.0; 3])?;
        let maps = renderer
            .geometry(&cams[k])?
            .context("the surfel renderer gives geometry maps")?;
        let mut depth = maps.surface_depth(args.depth_ratio);
        for (d, &a) in depth.iter_mut().zip(&maps.alpha) {
            if a < MIN_ALPHA || !d.is_finite() || *d as f64 > depth_trunc {
                *d = 0.0;
            }
        }
        let mask = match &masks {
            Some(dir) => Some(load_mask(dir, &scene, v)?),
            None => None,
        };
        frames.push((v, depth, rgb, mask));
    }
    // The fused region: robust bounds (1st–99th percentile per axis) of the back-projected
    // depths, so a few far background pixels do not blow up the volume.
    let mut points: Vec<[f64; 3]> = Vec::new();
    for (v, depth, _, mask) in &frames {
        let view = &scene.views[*v];
        let cam = &view.camera;
        for (pix, &d) in depth.iter().enumerate() {
            if d <= 0.0 || mask.as_ref().is_some_and(|m| !m[pix]) {
                continue;
            }
            let (x, y) = (
                (pix % cam.width as usize) as f64,
                (pix / cam.width as usize) as f64,
            );
            let d = d as f64;
            let c = [
                (x + 0.5 - cam.cx) / cam.fx * d,
                (y + 0.5 - cam.cy) / cam.fy * d,
                d,
            ];
            points.push(view.pose.inverse_transform(c));
        }
    }
    anyhow::ensure!(
        points.len() >= 8,
        "{}: the model covers no pixel of the chosen views (with --masks and --depth-trunc as \
         given); nothing to fuse",
        args.ply.display()
    );
    let (mut lo, mut hi) = ([0.0; 3], [0.0; 3]);
    for a in 0..3 {
        let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
        v.sort_by(f64::total_cmp);
        lo[a] = v[v.len() / 100];
        hi[a] = v[v.len() - 1 - v.len() / 100];
    }
    let longest = (0..3)
        .map(|a| hi[a] - lo[a])
        .fold(0.0f64, f64::max)
        .max(1e-9);
    let voxel = args
        .voxel
        .map(to_train)
        .unwrap_or(longest / args.mesh_res as f64);
    let sdf_trunc = args.sdf_trunc.map(to_train).unwrap_or(5.0 * voxel);
    for a in 0..3 {
        lo[a] -= sdf_trunc;
        hi[a] += sdf_trunc;
    }
    let mut tsdf = Tsdf::new(lo, hi, voxel, sdf_trunc)?;
    for (v, depth, rgb, mask) in &frames {
        let view = &scene.views[*v];
        tsdf.integrate(
            &DepthView {
                camera: &view.camera,
                pose: &view.pose,
                depth,
                rgb,
                mask: mask.as_deref(),
            },
            depth_trunc,
        );
    }
    let mesh = extract(&tsdf).keep_large_pieces(args.min_triangles, args.max_pieces);
    // Written in the user's frame, less the shift of a far-off scene (recorded in the header).
    let shift = scene.frame.output_shift();
    let (k, b) = scene.frame.train_to_stored(shift);
    let mut stored = mesh.clone();
    for p in &mut stored.vertices {
        *p = [0, 1, 2].map(|a| (p[a] as f64 * k + b[a]) as f32);
    }
    let comments: Vec<String> = lpmsplat::scene::frame::shift_comment(shift)
        .into_iter()
        .collect();
    write_mesh_ply(&args.out, &stored, &comments)?;
    if let Some(path) = &args.preview {
        let view = &scene.views[views[0]];
        let img = lpmsplat::mesh::preview::render_preview(&mesh, &view.camera, &view.pose);
        images::save_png(path, &img)?;
        println!("{}: the mesh seen from {}", path.display(), view.name);
    }
    println!(
        "{}: {} vertices, {} triangles ({} views, voxel {:.5}, {}×{}×{} voxels, sdf \
         truncation {:.5}, in the scene's units)",
        args.out.display(),
        mesh.vertices.len(),
        mesh.triangles.len(),
        frames.len(),
        voxel / scene.frame.scale,
        tsdf.dims[0],
        tsdf.dims[1],
        tsdf.dims[2],
        sdf_trunc / scene.frame.scale
    );
    ctx.check_validation()?;
    Ok(())
}

/// The mask folder to use: `--masks`, else (unless `--no-masks`) the scene's `mask/` (DTU's
/// name) or `masks/` folder when it has one, so that a scene shipped with its object masks is
/// meshed with them as its users expect.
fn mask_folder(args: &MeshArgs) -> Option<PathBuf> {
    if args.no_masks {
        return None;
    }
    if let Some(dir) = &args.masks {
        return Some(dir.clone());
    }
    ["mask", "masks"]
        .iter()
        .map(|name| args.scene.scene.join(name))
        .find(|dir| dir.is_dir())
}

/// The mask of view `v`: `<stem>.png`, else the PNG whose name is the same number as the
/// image's stem (DTU). Resized to the view's size when the scene was downscaled.
fn load_mask(dir: &Path, scene: &Scene, v: usize) -> anyhow::Result<Vec<bool>> {
    let view = &scene.views[v];
    let by_stem = dir.join(format!("{}.png", view.stem));
    let path = if by_stem.is_file() {
        by_stem
    } else {
        let number: Option<u64> = view.stem.trim_start_matches('0').parse().ok().or((view
            .stem
            .chars()
            .all(|c| c == '0')
            && !view.stem.is_empty())
        .then_some(0));
        let found = number.and_then(|n| {
            std::fs::read_dir(dir)
                .ok()?
                .filter_map(|e| e.ok())
                .find_map(|e| {
                    let p = e.path();
                    let s = p.file_stem()?.to_str()?;
                    (p.extension()? == "png" && s.parse::<u64>().ok()? == n).then_some(p)
                })
        });
        found.with_context(|| {
            format!(
                "{}: no mask for view {} (looked for {}.png or a PNG named by its number). \
                 Fix: name the masks like the images, or pass --no-masks to fuse every pixel",
                dir.display(),
                view.stem,
                view.stem
            )
        })?
    };
    let img = images::decode_image(&path)?;
    let cam = &view.camera;
    let img = if (img.width, img.height) != (cam.width, cam.height) {
        images::resize_area(&img, cam.width, cam.height)
    } else {
        img
    };
    Ok(img
        .rgb
        .chunks_exact(3)
        .map(|p| (p[0] + p[1] + p[2]) / 3.0 > 0.5)
        .collect())
}
