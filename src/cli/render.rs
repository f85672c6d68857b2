//! `render`: PNGs of chosen cameras of a scene for a trained PLY.

use super::geometry_outputs;
use super::SceneArgs;
use anyhow::Context;
use clap::Args;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::models::BaseModel;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::scene::orbit::Orbit;
use lpmsplat::scene::{images, Image, Scene};
use lpmsplat::splats::{gpu::GpuSplats, GaussianParams};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Trained Gaussians (Inria-layout PLY).
    #[arg(long)]
    pub ply: PathBuf,
    /// The model the PLY was trained as: `mip-splatting` renders with its 2D Mip filter (the
    /// exported PLY already holds the 3D filter); 3dgs and pixel-gs render alike; 2dgs renders
    /// surfels; spacetime-lite and spacetime-full render each view at its time (the full model
    /// with the NAME.decoder.json beside its PLY). Default: the model the PLY's header
    /// records (`train` writes it), else 3dgs (another trainer's PLY); a --model that
    /// contradicts the header is an error.
    #[arg(long, value_parser = BaseModel::parse)]
    pub model: Option<BaseModel>,
    /// Output folder for the PNGs (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Which cameras: train, test or all.
    #[arg(long, default_value = "test", value_parser = ["train", "test", "all"])]
    pub cameras: String,
    /// Background colour as r,g,b in [0, 1] (default: the scene's, black for COLMAP scenes).
    #[arg(long, value_parser = lpmsplat::train::config::parse_rgb)]
    pub background: Option<[f32; 3]>,
    /// Instead of the scene's cameras, render N frames on a closed path around the scene (a
    /// turntable for 360° captures, a small ellipse for forward-facing ones; see
    /// `scene::orbit`) into OUT/orbit.gif, at the first training camera's size and focal length.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(2..=2000))]
    pub orbit: Option<u32>,
    /// 2dgs: also write each view's surface depth as OUT/<view>_depth.png (colour-mapped,
    /// near = bright) and OUT/<view>_depth.pfm (raw float32, camera z; 0 where nothing was
    /// drawn).
    #[arg(long)]
    pub depth: bool,
    /// 2dgs: also write each view's rendered normals as OUT/<view>_normal.png (world space,
    /// RGB = (n + 1)/2) and OUT/<view>_normal.pfm (raw float32 xyz).
    #[arg(long)]
    pub normals: bool,
    /// 2dgs: the surface depth of --depth: 0 the expected depth, 1 the median depth.
    #[arg(long, default_value_t = 0.0)]
    pub depth_ratio: f32,
    /// Video models: render every chosen camera once, at this time of the segment ([0, 1]; any
    /// time, not only a frame's), as OUT/<camera>_t<T>.png. Without it each view is rendered
    /// at its own frame's time.
    #[arg(long)]
    pub time: Option<f32>,
    /// Frames per second of the orbit GIF.
    #[arg(long, default_value_t = 25, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub fps: u32,
}

pub fn run(gpu: &GpuOptions, args: &RenderArgs) -> anyhow::Result<()> {
    let scene = crate::cli::model_segment::load_scene_for_model(&args.scene, &args.ply)?;
    let model = BaseModel::for_ply(args.model, &args.ply)?;
    let params = model.read_ply_for_scene(&args.ply, &scene)?;
    if let Some(t) = args.time {
        anyhow::ensure!(
            model.is_spacetime() && scene.view_times.is_some(),
            "--time renders a video model at one time; this is --model {} on a {} scene. Fix: \
             pass --model spacetime-lite (or spacetime-full) with the video scene it was trained on, or drop --time",
            model.name(),
            if scene.view_times.is_some() {
                "video"
            } else {
                "still"
            }
        );
        anyhow::ensure!(
            t.is_finite() && (0.0..=1.0).contains(&t),
            "--time {t}: a time of the segment lies in [0, 1] (frame k of n at k/n)"
        );
    }
    if let Some(frames) = args.orbit {
        return render_orbit(gpu, args, model, &scene, &params, frames as usize);
    }
    let mut indices: Vec<usize> = match args.cameras.as_str() {
        "train" => scene.train.clone(),
        "test" => scene.test.clone(),
        _ => (0..scene.views.len()).collect(),
    };
    if args.time.is_some() {
        // One view per camera: a video's cameras do not move, so the frames of a camera share
        // its pose.
        let mut seen: Vec<&lpmsplat::scene::Pose> = Vec::new();
        indices.retain(|&i| {
            let pose = &scene.views[i].pose;
            let new = !seen.contains(&pose);
            if new {
                seen.push(pose);
            }
            new
        });
    }
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
    let times = match args.time {
        Some(t) => Some(vec![t; indices.len()]),
        None => scene.times_of(&indices),
    };
    let mut renderer = model.view_renderer(&ctx, params.len(), &cams[0], times, Some(&args.ply))?;
    let bg = args.background.or(scene.background).unwrap_or([0.0; 3]);
    anyhow::ensure!(
        !(args.depth || args.normals) || model == BaseModel::Surfels2d,
        "--depth and --normals render 2DGS surfels' depth and normal maps; this PLY is read as \
         --model {}. Fix: pass --model 2dgs for a 2DGS model, or drop the flags",
        model.name()
    );
    for (k, &i) in indices.iter().enumerate() {
        let rgb = renderer.render(&splats, &cameras, k as u32, &cams[k], bg)?;
        if args.depth || args.normals {
            let maps = renderer
                .geometry(&cams[k])?
                .context("the surfel renderer gives geometry maps")?;
            let view = &scene.views[i];
            let written = geometry_outputs::write(
                &args.out,
                &view.stem,
                &maps,
                &view.camera,
                &view.pose,
                args.depth_ratio,
                args.depth,
                args.normals,
            )?;
            for p in written {
                println!("{}", p.display());
            }
        }
        let img = Image {
            width: cams[k].width(),
            height: cams[k].height(),
            rgb: rgb.iter().map(|v| v.clamp(0.0, 1.0)).collect(),
            alpha: None,
        };
        let path = match args.time {
            // A video view is named <camera>/<frame>: the camera at the chosen time.
            Some(t) => {
                let camera = scene.views[i].name.split('/').next().unwrap_or("view");
                args.out.join(format!("{camera}_t{t:.4}.png"))
            }
            None => args.out.join(format!("{}.png", scene.views[i].stem)),
        };
        images::save_png(&path, &img)?;
        println!("{}", path.display());
    }
    ctx.check_validation()?;
    Ok(())
}

/// Renders `frames` views along the scene's orbit into OUT/orbit.gif.
fn render_orbit(
    gpu: &GpuOptions,
    args: &RenderArgs,
    model: BaseModel,
    scene: &Scene,
    params: &GaussianParams,
    frames: usize,
) -> anyhow::Result<()> {
    lpmsplat::splats::require_nonempty(&args.ply, params)?;
    let fitted: Vec<usize> = if scene.train.is_empty() {
        (0..scene.views.len()).collect()
    } else {
        scene.train.clone()
    };
    let poses: Vec<_> = fitted.iter().map(|&i| scene.views[i].pose).collect();
    // Forward-facing captures look at the model's median depth along the mean optical axis.
    let orbit = Orbit::fit(&poses, |centre, axis| {
        let mut depths: Vec<f64> = params
            .positions
            .iter()
            .map(|p| (glam::DVec3::from_array(p.map(f64::from)) - centre).dot(axis))
            .filter(|d| *d > 0.0)
            .collect();
        if depths.is_empty() {
            return 1.0;
        }
        let mid = depths.len() / 2;
        *depths.select_nth_unstable_by(mid, f64::total_cmp).1
    });
    let camera = scene.views[fitted[0]].camera;
    let cams: Vec<CameraGpu> = orbit
        .poses(frames)
        .iter()
        .map(|pose| CameraGpu::new(&camera, pose))
        .collect();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating output folder {}", args.out.display()))?;
    let ctx = GpuContext::new(gpu)?;
    let splats = GpuSplats::upload(&ctx, params, params.len())?;
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &cams)?;
    // An orbit of a video model runs through its segment, one time per frame (or stays at
    // --time: bullet time).
    let times = (0..cams.len())
        .map(|k| args.time.unwrap_or(k as f32 / cams.len() as f32))
        .collect();
    let mut renderer =
        model.view_renderer(&ctx, params.len(), &cams[0], Some(times), Some(&args.ply))?;
    let bg = args.background.or(scene.background).unwrap_or([0.0; 3]);
    let path = args.out.join("orbit.gif");
    let mut gif = OrbitGif::new(camera.width, camera.height, args.fps);
    for (k, cam) in cams.iter().enumerate() {
        gif.push(&renderer.render(&splats, &cameras, k as u32, cam, bg)?)?;
    }
    ctx.check_validation()?;
    gif.write(&path)?;
    println!(
        "{} ({frames} frames, {}×{}, {:?} orbit around [{:.3}, {:.3}, {:.3}])",
        path.display(),
        camera.width,
        camera.height,
        orbit.kind,
        orbit.target[0],
        orbit.target[1],
        orbit.target[2]
    );
    Ok(())
}

/// An animated GIF built in memory (frames quantised to 256 colours each with NeuQuant) and
/// written atomically at the end, so an interrupted render leaves no half file.
struct OrbitGif {
    width: u16,
    height: u16,
    delay_cs: u16,
    frames: Vec<gif::Frame<'static>>,
}

impl OrbitGif {
    fn new(width: u32, height: u32, fps: u32) -> OrbitGif {
        OrbitGif {
            width: width.min(u16::MAX as u32) as u16,
            height: height.min(u16::MAX as u32) as u16,
            delay_cs: (100 / fps.max(1)).max(1) as u16,
            frames: Vec::new(),
        }
    }

    fn push(&mut self, rgb: &[f32]) -> anyhow::Result<()> {
        anyhow::ensure!(
            rgb.len() == self.width as usize * self.height as usize * 3,
            "a GIF frame must be {}×{} (at most 65535 px a side)",
            self.width,
            self.height
        );
        let bytes: Vec<u8> = rgb
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        // Speed 10 of 1..=30: NeuQuant's usual quality / time balance.
        let mut frame = gif::Frame::from_rgb_speed(self.width, self.height, &bytes, 10);
        frame.delay = self.delay_cs;
        self.frames.push(frame);
        Ok(())
    }

    fn write(self, path: &std::path::Path) -> anyhow::Result<()> {
        lpmsplat::error::write_atomic(path, |file| {
            let mut enc =
                gif::Encoder::new(std::io::BufWriter::new(file), self.width, self.height, &[])?;
            enc.set_repeat(gif::Repeat::Infinite)?;
            for frame in &self.frames {
                enc.write_frame(frame)?;
            }
            Ok(())
        })
        .with_context(|| format!("{}: writing the GIF failed", path.display()))
    }
}
