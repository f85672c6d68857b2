//! `render`: PNGs of chosen cameras of a scene for a trained PLY.

use super::SceneArgs;
use anyhow::Context;
use clap::Args;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::models::BaseModel;
use lpmsplat::render::forward::{FrameSettings, Renderer};
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::scene::{images, Image, Scene};
use lpmsplat::splats::{gpu::GpuSplats, read_ply};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Trained Gaussians (Inria-layout PLY).
    #[arg(long)]
    pub ply: PathBuf,
    /// The model the PLY was trained as: `mip-splatting` renders with its 2D Mip filter (the
    /// exported PLY already holds the 3D filter); 3dgs and pixel-gs render alike.
    #[arg(long, default_value = "3dgs", value_parser = BaseModel::parse)]
    pub model: BaseModel,
    /// Output folder for the PNGs (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Which cameras: train, test or all.
    #[arg(long, default_value = "test", value_parser = ["train", "test", "all"])]
    pub cameras: String,
    /// Background colour as r,g,b in [0, 1] (default: the scene's, black for COLMAP scenes).
    #[arg(long, value_parser = parse_rgb)]
    pub background: Option<[f32; 3]>,
}

pub fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("'{s}': {e}; give three numbers like 1,1,1"))?;
    match v[..] {
        [r, g, b] if v.iter().all(|x| (0.0..=1.0).contains(x)) => Ok([r, g, b]),
        _ => Err(format!("'{s}': give three numbers in [0, 1] like 0,0,0")),
    }
}

pub fn run(gpu: &GpuOptions, args: &RenderArgs) -> anyhow::Result<()> {
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    let params = read_ply(&args.ply)?;
    let indices: Vec<usize> = match args.cameras.as_str() {
        "train" => scene.train.clone(),
        "test" => scene.test.clone(),
        _ => (0..scene.views.len()).collect(),
    };
    anyhow::ensure!(
        !indices.is_empty(),
        "{}: the scene has no {} cameras. Fix: pass --cameras all",
        args.scene.scene.display(),
        args.cameras
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating output folder {}", args.out.display()))?;
    let ctx = GpuContext::new(gpu)?;
    let splats = GpuSplats::upload(&ctx, &params, params.len().max(1))?;
    let cams: Vec<CameraGpu> = indices
        .iter()
        .map(|&i| CameraGpu::new(&scene.views[i].camera, &scene.views[i].pose))
        .collect();
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &cams)?;
    let mut renderer = Renderer::for_camera(&ctx, params.len(), &cams[0])?;
    let bg = args.background.or(scene.background).unwrap_or([0.0; 3]);
    let settings = FrameSettings {
        sh_degree: params.sh_degree,
        background: bg,
        constants: args.model.render_constants(),
        filter3d: None,
    };
    for (k, &i) in indices.iter().enumerate() {
        renderer.render_blocking(&splats, &cameras, k as u32, &cams[k], &settings)?;
        let rgb = renderer.read_image()?;
        let img = Image {
            width: cams[k].width(),
            height: cams[k].height(),
            rgb: rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect(),
            alpha: None,
        };
        let path = args.out.join(format!("{}.png", scene.views[i].stem));
        images::save_png(&path, &img)?;
        println!("{}", path.display());
    }
    ctx.check_validation()?;
    Ok(())
}
