//! `eval`: PSNR, SSIM and (with `--lpips-weights`) LPIPS of a trained PLY on a scene's test
//! views, per image and mean, as a table on stdout and optionally JSON; side-by-side PNGs
//! (render | ground truth) on request.
//!
//! Without LPIPS weights (which this project cannot ship) the JSON says so (`"lpips": null`
//! and a note) rather than reporting a stand-in.

use super::lpips_scores::{self, LpipsArgs};
use super::SceneArgs;
use anyhow::Context;
use clap::Args;
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::models::BaseModel;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::scene::image_source::{load_range, ViewImages};
use lpmsplat::scene::{images, Image};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::train::trainer::{Background, ViewMetrics};
use std::io::Write;
use std::path::PathBuf;

/// Evaluates a trained PLY on the test split (or, with `--split train`, on the training views).
/// Reports PSNR, SSIM (11×11 Gaussian window, σ 1.5) and, given `--lpips-weights`, LPIPS
/// (AlexNet, v0.1) per image and their mean.
#[derive(Args, Debug)]
pub struct EvalArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Trained Gaussians (Inria-layout PLY, e.g. OUT/point_cloud.ply from `train`).
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
    /// Background: black, white, or r,g,b in [0, 1]. Default: the scene's (white for
    /// NeRF-synthetic), black otherwise. Ground truth with alpha is composited on it.
    #[arg(long)]
    pub background: Option<String>,
    /// Also write the results as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write `<view>.png` side-by-side images (render | ground truth) into this folder.
    #[arg(long)]
    pub side_by_side: Option<PathBuf>,
    /// The views to score: the held-out `test` views, or the `train` views the model was fitted
    /// to. Scoring both tells overfitting (train rising while test falls) from a failure to fit.
    #[arg(long, value_enum, default_value_t = EvalSplit::Test)]
    pub split: EvalSplit,
    #[command(flatten)]
    pub lpips: LpipsArgs,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum EvalSplit {
    Test,
    Train,
}

impl EvalSplit {
    fn name(self) -> &'static str {
        match self {
            EvalSplit::Test => "test",
            EvalSplit::Train => "train",
        }
    }
}

/// One held-out camera of a video scene: the means over its frames.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CameraMeans {
    pub camera: String,
    pub frames: usize,
    pub psnr: f64,
    pub ssim: f64,
}

/// The per-camera means of a video scene's views, in order of first appearance. A video view
/// is named `CAMERA/FRAME` (Panoptic `cam15/000010`, Neural 3D Video `cam00/0003`): with a
/// few held-out cameras, one camera's floaters can move the mean by a dB (Panoptic's camera
/// 15 once scored 6 dB beside three at 20), which the overall mean alone hides.
pub fn per_camera(per_view: &[ViewMetrics]) -> Vec<CameraMeans> {
    let mut out: Vec<CameraMeans> = Vec::new();
    for m in per_view {
        let camera = m.view.rsplit_once('/').map_or(m.view.as_str(), |(c, _)| c);
        let k = match out.iter().position(|c| c.camera == camera) {
            Some(k) => k,
            None => {
                out.push(CameraMeans {
                    camera: camera.to_string(),
                    frames: 0,
                    psnr: 0.0,
                    ssim: 0.0,
                });
                out.len() - 1
            }
        };
        out[k].frames += 1;
        out[k].psnr += m.psnr;
        out[k].ssim += m.ssim;
    }
    for c in &mut out {
        c.psnr /= c.frames as f64;
        c.ssim /= c.frames as f64;
    }
    out
}

fn side_by_side(render: &[f32], gt: &Image) -> Image {
    let (w, h) = (gt.width as usize, gt.height as usize);
    let mut rgb = Vec::with_capacity(2 * w * h * 3);
    for y in 0..h {
        rgb.extend_from_slice(&render[y * w * 3..(y + 1) * w * 3]);
        rgb.extend_from_slice(&gt.rgb[y * w * 3..(y + 1) * w * 3]);
    }
    Image {
        width: 2 * gt.width,
        height: gt.height,
        rgb,
        alpha: None,
    }
}

pub fn run(gpu: &GpuOptions, args: &EvalArgs) -> anyhow::Result<()> {
    let scene = crate::cli::model_segment::load_scene_for_model(&args.scene, &args.ply)?;
    let bg = match lpmsplat::train::config::Background::choose(
        args.background.as_deref(),
        scene.background,
    )? {
        Background::Fixed(c) => c,
        Background::Random => anyhow::bail!(
            "--background random: evaluation needs a fixed colour. Fix: pass black, white or r,g,b"
        ),
    };
    let views: &[usize] = match args.split {
        EvalSplit::Test => &scene.test,
        EvalSplit::Train => &scene.train,
    };
    anyhow::ensure!(
        !views.is_empty(),
        "{}: the scene has no {} views to evaluate on. Fix: use a scene with a test split \
         (COLMAP scenes hold out every 8th image; NeRF-synthetic needs transforms_test.json or \
         transforms_val.json), or pass --split train",
        args.scene.scene.display(),
        args.split.name()
    );
    let lpips = args.lpips.load()?;
    let model = BaseModel::for_ply(args.model, &args.ply)?;
    let params = model.read_ply_for_scene(&args.ply, &scene)?;
    lpmsplat::splats::require_nonempty(&args.ply, &params)?;
    if let Some(dir) = &args.side_by_side {
        std::fs::create_dir_all(dir).with_context(|| {
            format!(
                "{}: cannot create the --side-by-side folder. Fix: choose a writable path",
                dir.display()
            )
        })?;
    }
    let truths = ViewImages::new(&scene, views)?;
    let ctx = GpuContext::new(gpu)?;
    let splats = GpuSplats::upload(&ctx, &params, params.len())?;
    let cams: Vec<CameraGpu> = views
        .iter()
        .map(|&i| CameraGpu::new(&scene.views[i].camera, &scene.views[i].pose))
        .collect();
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &cams)?;
    let biggest = (0..cams.len())
        .max_by_key(|&k| cams[k].width() as u64 * cams[k].height() as u64)
        .unwrap_or(0);
    let mut renderer = model.view_renderer(
        &ctx,
        params.len(),
        &cams[biggest],
        scene.times_of(views),
        Some(&args.ply),
    )?;
    let mut per_view = Vec::new();
    // A few images decoded at a time, nothing kept: a video's test frames take the memory of a
    // handful.
    for start in (0..views.len()).step_by(8) {
        let end = (start + 8).min(views.len());
        let chunk = load_range(&truths, start..end)?;
        for (k, truth) in (start..end).zip(chunk) {
            let v = views[k];
            let render: Vec<f32> = renderer
                .render(&splats, &cameras, k as u32, &cams[k], bg)?
                .iter()
                .map(|x| x.clamp(0.0, 1.0))
                .collect();
            let gt = images::composite_on_background(&truth, bg);
            let mut m = ViewMetrics::of(&scene.views[v].name, &render, &gt)?;
            lpips_scores::score_view(lpips.as_ref(), &mut m, &render, &gt)?;
            if let Some(dir) = &args.side_by_side {
                let path = dir.join(format!("{}.png", scene.views[v].stem));
                images::save_png(&path, &side_by_side(&render, &gt))?;
            }
            per_view.push(m);
        }
    }
    if let Some(e) = ViewMetrics::invalid(&per_view) {
        return Err(e.context(format!("eval of {}", args.ply.display())));
    }
    let lpips_mean = lpips_scores::mean(&per_view);
    let (psnr, ssim) = ViewMetrics::means(&per_view);
    let name_w = per_view
        .iter()
        .map(|m| m.view.len())
        .max()
        .unwrap_or(4)
        .max(4);
    let lp = |v: Option<f64>| v.map_or("–".to_string(), |d| format!("{d:.4}"));
    println!(
        "{:<name_w$}  {:>9}  {:>7}  {:>7}",
        "view", "PSNR (dB)", "SSIM", "LPIPS"
    );
    for m in &per_view {
        println!(
            "{:<name_w$}  {:>9.3}  {:>7.4}  {:>7}",
            m.view,
            m.psnr,
            m.ssim,
            lp(m.lpips)
        );
    }
    println!(
        "{:<name_w$}  {:>9.3}  {:>7.4}  {:>7}",
        "mean",
        psnr,
        ssim,
        lp(lpips_mean)
    );
    // Video scenes: each held-out camera's mean over its frames.
    let cameras = scene.view_times.as_ref().map(|_| per_camera(&per_view));
    if let Some(cameras) = &cameras {
        for c in cameras {
            println!(
                "{:<name_w$}  {:>9.3}  {:>7.4}  ({} frames)",
                c.camera, c.psnr, c.ssim, c.frames
            );
        }
    }
    if lpips_mean.is_none() {
        println!("({})", lpips_scores::NOT_COMPUTED);
    }
    if let Some(path) = &args.json {
        let json = serde_json::json!({
            "scene": args.scene.scene.display().to_string(),
            "ply": args.ply.display().to_string(),
            "gaussians": params.len(),
            "background": bg,
            "split": args.split.name(),
            "views": per_view.len(),
            "psnr": psnr,
            "ssim": ssim,
            "lpips": lpips_mean,
            "lpips_note": if lpips_mean.is_none() { Some(lpips_scores::NOT_COMPUTED) } else { None },
            "per_view": per_view,
            "per_camera": cameras,
        });
        let text = serde_json::to_string_pretty(&json)?;
        write_atomic(path, |f| Ok(f.write_all(text.as_bytes())?)).with_context(|| {
            format!(
                "{}: cannot write --json. Fix: choose a writable path",
                path.display()
            )
        })?;
    }
    ctx.check_validation()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(name: &str, psnr: f64, ssim: f64) -> ViewMetrics {
        ViewMetrics {
            view: name.to_string(),
            psnr,
            ssim,
            lpips: None,
        }
    }

    #[test]
    fn per_camera_means_group_a_videos_frames_by_camera() {
        let views = [
            view("cam15/000000", 6.0, 0.2),
            view("cam00/000000", 22.0, 0.7),
            view("cam15/000001", 8.0, 0.4),
            view("cam00/000001", 20.0, 0.9),
            view("cam00/000002", 21.0, 0.8),
        ];
        let c = per_camera(&views);
        assert_eq!(c.len(), 2);
        assert_eq!((c[0].camera.as_str(), c[0].frames), ("cam15", 2));
        assert!((c[0].psnr - 7.0).abs() < 1e-12 && (c[0].ssim - 0.3).abs() < 1e-12);
        assert_eq!((c[1].camera.as_str(), c[1].frames), ("cam00", 3));
        assert!((c[1].psnr - 21.0).abs() < 1e-12 && (c[1].ssim - 0.8).abs() < 1e-12);
        // A name without a camera part is its own group.
        assert_eq!(per_camera(&[view("r_0", 30.0, 0.9)])[0].camera, "r_0");
        assert!(per_camera(&[]).is_empty());
    }
}
