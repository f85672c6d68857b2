//! `bench`: measurements users quote. `bench fps` times the forward renderer at a chosen size
//! (1352×1014 by default) for a PLY or a generated scene: warm-up, many frames, median and
//! spread of the wall time, and per-stage GPU timestamps. Table on stdout, JSON on request.

use anyhow::Context;
use clap::{Args, Subcommand};
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder, StageTimes, TimestampPool};
use lpmsplat::models::BaseModel;
use lpmsplat::render::bands::FrameWork;
use lpmsplat::render::forward::{FrameSettings, Renderer};
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::render::spacetime::TimedModel;
use lpmsplat::render::synthetic;
use lpmsplat::scene::{LoadOptions, PinholeCamera, Pose, Scene};
use lpmsplat::splats::gpu::GpuSplats;
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

mod trade;
mod trade_args;
mod trade_merge;
mod trade_sweep;

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchKind,
}

#[derive(Subcommand, Debug)]
pub enum BenchKind {
    /// Rendering frames per second and per-stage GPU time.
    Fps(FpsArgs),
    /// ADC vs ADC+LPM (and ablations) side by side: PSNR, SSIM, size, time, FPS.
    Trade(Box<trade_args::TradeArgs>),
    /// Several `bench trade` results (more seeds, other machines, other settings) as one
    /// table, paired seed by seed with a baseline run; no device needed.
    Merge(trade_merge::MergeArgs),
}

#[derive(Args, Debug)]
pub struct FpsArgs {
    /// Gaussians from this PLY (the camera looks at its centroid from outside its bulk, or is
    /// --scene's first test view).
    #[arg(long, conflicts_with = "gaussians")]
    pub ply: Option<PathBuf>,
    /// With --ply: render from this scene's first test view (its field of view and pose, at
    /// --width × --height), as `bench trade` times its trained models, instead of the camera
    /// placed outside the model.
    #[arg(long, requires = "ply", value_name = "DIR")]
    pub scene: Option<PathBuf>,
    /// A generated scene of this many Gaussians; several counts may be given, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "100000")]
    pub gaussians: Vec<usize>,
    /// Frame width in pixels (1352×1014: the LPM paper's FPS resolution).
    #[arg(long, default_value_t = 1352)]
    pub width: u32,
    /// Frame height in pixels.
    #[arg(long, default_value_t = 1014)]
    pub height: u32,
    /// Frames timed (after the warm-up).
    #[arg(long, default_value_t = 50)]
    pub frames: usize,
    /// Frames rendered first and not timed (pipelines, caches and clocks settle).
    #[arg(long, default_value_t = 5)]
    pub warmup: usize,
    /// Write the results as JSON here as well.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Seed of the generated scene.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// SH degree of the generated scene (0–3).
    #[arg(long, default_value_t = 3)]
    pub sh_degree: u32,
    /// The model the PLY was trained as: `spacetime-lite` and `spacetime-full` read their
    /// temporal groups and time every frame with the temporal step (the model at --time)
    /// before the render; the full model also its features and its decoder (NAME.decoder.json
    /// beside the PLY) after it. Default: the model the PLY's header records, else 3dgs.
    #[arg(long, value_parser = BaseModel::parse)]
    pub model: Option<BaseModel>,
    /// Video models: the time rendered, in the segment's [0, 1).
    #[arg(long, default_value_t = 0.0)]
    pub time: f32,
}

#[derive(Serialize, Debug)]
pub struct FpsResult {
    pub source: String,
    pub gaussians: usize,
    pub width: u32,
    pub height: u32,
    /// Where the camera is: `test view NAME` (--scene), `outside the model` (a PLY alone) or
    /// `generated` (the generated scene's fixed camera).
    pub camera: String,
    pub frames: usize,
    /// Gaussians that pair with a tile in the last frame (the rest are culled).
    pub visible: u64,
    pub intersections: u64,
    /// Bands of tile rows a frame is drawn in: 1, or more when its intersections pass what
    /// one storage binding holds (`lpmsplat::render::bands`).
    pub bands: usize,
    pub fps_median: f64,
    pub frame_ms_median: f64,
    pub frame_ms_p10: f64,
    pub frame_ms_p90: f64,
    pub frame_ms_min: f64,
    pub frame_ms_max: f64,
    /// Frames rendered back to back, two in flight (each recorded while the one before runs,
    /// as a viewer with a swapchain does): frames over the wall time of the run. The frame
    /// times above are one frame at a time (record, submit, wait), so they include the host's
    /// recording and the wait's latency between frames.
    pub fps_pipelined: f64,
    pub frame_ms_pipelined: f64,
    /// Median GPU time per stage, ms.
    pub stages_ms: Vec<(String, f64)>,
    pub gpu_memory_mib: f64,
    pub device: String,
}

pub fn run(gpu: &GpuOptions, args: &BenchArgs) -> anyhow::Result<()> {
    match &args.what {
        BenchKind::Fps(a) => fps(gpu, a),
        BenchKind::Trade(a) => trade::run(gpu, a),
        BenchKind::Merge(a) => trade_merge::run(a),
    }
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

fn fps(gpu: &GpuOptions, args: &FpsArgs) -> anyhow::Result<()> {
    let model = match &args.ply {
        Some(p) => BaseModel::for_ply(args.model, p)?,
        None => args.model.unwrap_or_default(),
    };
    anyhow::ensure!(
        args.width > 0 && args.height > 0,
        "bench fps: --width {} --height {} is an empty image. Fix: give both at least 1",
        args.width,
        args.height
    );
    anyhow::ensure!(
        args.frames > 0,
        "bench fps: --frames 0. Fix: time at least 1 frame"
    );
    let ctx = GpuContext::new(gpu)?;
    let mut results = Vec::new();
    let sources: Vec<(String, lpmsplat::splats::GaussianParams)> = match &args.ply {
        Some(path) => vec![(path.display().to_string(), model.read_ply(path)?)],
        None => args
            .gaussians
            .iter()
            .map(|&n| -> anyhow::Result<_> {
                Ok((
                    format!("generated({n})"),
                    synthetic::random_scene(n, args.seed).with_sh_degree(args.sh_degree)?,
                ))
            })
            .collect::<anyhow::Result<_>>()?,
    };
    for (source, params) in sources {
        let r = fps_one(&ctx, model, &source, &params, args)?;
        print_result(&r);
        results.push(r);
    }
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&results)?;
        write_atomic(path, |f| Ok(f.write_all(text.as_bytes())?))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    ctx.check_validation()?;
    Ok(())
}

/// The first test view of the scene at `dir` (the training CLI's default loading), its camera
/// resized to `width × height`.
fn test_view_camera(
    dir: &std::path::Path,
    ply: Option<&std::path::Path>,
    width: u32,
    height: u32,
) -> anyhow::Result<(PinholeCamera, Pose, String)> {
    let scene = Scene::load(dir, &LoadOptions::default())
        .with_context(|| format!("bench fps --scene {}", dir.display()))?;
    let Some(&first) = scene.test.first() else {
        anyhow::bail!(
            "bench fps --scene {}: the scene has no test views. Fix: leave out --scene to place \
             the camera outside the model",
            dir.display()
        );
    };
    let v = &scene.views[first];
    // The model is drawn as its file stores it: the view's pose in the file's frame (the
    // scene's own, less the shift the file records).
    let shift = match ply {
        Some(p) => {
            lpmsplat::scene::frame::shift_from_comments(p, &lpmsplat::splats::ply_comments(p)?)?
        }
        None => [0.0; 3],
    };
    Ok((
        v.camera.resized(width, height),
        scene.frame.of_stored(shift).pose_to_user(&v.pose),
        format!("test view {}", v.name),
    ))
}

fn fps_one(
    ctx: &std::sync::Arc<GpuContext>,
    base: BaseModel,
    source: &str,
    params: &lpmsplat::splats::GaussianParams,
    args: &FpsArgs,
) -> anyhow::Result<FpsResult> {
    let (camera, pose, placed) = match (&args.scene, &args.ply) {
        (Some(dir), ply) => test_view_camera(dir, ply.as_deref(), args.width, args.height)?,
        (None, Some(_)) => {
            let (c, p) = synthetic::camera_for_model(params, args.width, args.height);
            (c, p, "outside the model".to_string())
        }
        (None, None) => {
            let (c, p) = synthetic::bench_camera(args.width, args.height);
            (c, p, "generated".to_string())
        }
    };
    let cam = CameraGpu::new(&camera, &pose);
    let model = GpuSplats::upload(ctx, params, params.len().max(1))?;
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[cam])?;
    // A video model: every frame first writes the model at --time as still Gaussians (what a
    // player does per displayed time), so the temporal step is part of the frame time.
    // The full model also writes its features at --time, and its decoder makes the RGB.
    let decoder = match (&base, &args.ply) {
        (BaseModel::SpacetimeFull, Some(p)) => Some(lpmsplat::splats::decoder_json::read_for(p)?),
        (BaseModel::SpacetimeFull, None) => anyhow::bail!(
            "bench fps --model spacetime-full times a trained model: pass --ply with its \
             .decoder.json beside it"
        ),
        _ => None,
    };
    let temporal = if base.is_spacetime() {
        Some(TimedModel::new(ctx, &model, decoder.as_deref())?)
    } else {
        None
    };
    if let Some(timed) = &temporal {
        let mut rec = Recorder::new(ctx)?;
        rec.begin()?;
        timed.record(&mut rec, &model, args.time)?;
        rec.submit_and_wait()?;
    }
    let still = temporal;
    let splats = still.as_ref().map_or(&model, |t| &t.instant);
    let settings = match &still {
        Some(t) => t.settings([0.0; 3]),
        None => FrameSettings::plain(splats.sh_degree, [0.0; 3]),
    };
    let mut renderer = Renderer::for_camera(ctx, params.len(), &cam)?;
    // First frame sizes the intersection buffers.
    renderer.render_blocking(splats, &cameras, 0, &cam, &settings)?;
    let intersections = renderer.last_intersections()?;
    let visible = renderer.last_visible()?;
    // A frame drawn in bands of tile rows times three stages a band.
    let bands = renderer.last_frame_bands() as u32;
    let mut pool = TimestampPool::new(ctx, 16 + 3 * bands)?;
    let planned = FrameWork::Bands(renderer.bands_for(&cam));
    let mut rec = Recorder::new(ctx)?;
    let mut wall = Vec::new();
    let mut stages: Vec<StageTimes> = Vec::new();
    for k in 0..args.warmup + args.frames {
        rec.begin()?;
        rec.start_timestamps(&mut pool);
        let t0 = Instant::now();
        if let Some(t) = &still {
            t.record(&mut rec, &model, args.time)?;
        }
        renderer.record_work(
            &mut rec,
            splats,
            &cameras,
            0,
            &cam,
            &settings,
            &planned,
            Some(&mut pool),
        )?;
        rec.submit_and_wait()?;
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if k >= args.warmup {
            wall.push(ms);
            stages.push(pool.read()?);
        }
    }
    let pipelined_ms = time_pipelined(ctx, args, &mut renderer, &still, &model, &cameras, &cam)?;
    wall.sort_by(|a, b| a.total_cmp(b));
    let median = percentile(&wall, 0.5);
    let stage_names: Vec<String> = stages
        .first()
        .map(|s| s.stages.iter().map(|x| x.0.clone()).collect())
        .unwrap_or_default();
    let stages_ms = stage_names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let mut v: Vec<f64> = stages.iter().map(|s| s.stages[i].1).collect();
            v.sort_by(|a, b| a.total_cmp(b));
            (name.clone(), percentile(&v, 0.5))
        })
        .collect();
    Ok(FpsResult {
        source: source.to_string(),
        gaussians: params.len(),
        width: args.width,
        height: args.height,
        camera: placed,
        frames: args.frames,
        visible,
        intersections,
        bands: bands as usize,
        fps_median: 1e3 / median,
        frame_ms_median: median,
        frame_ms_p10: percentile(&wall, 0.1),
        frame_ms_p90: percentile(&wall, 0.9),
        frame_ms_min: wall[0],
        frame_ms_max: wall[wall.len() - 1],
        fps_pipelined: 1e3 / pipelined_ms,
        frame_ms_pipelined: pipelined_ms,
        stages_ms,
        gpu_memory_mib: ctx.memory_in_use().1 as f64 / (1u64 << 20) as f64,
        device: ctx.info.name.clone(),
    })
}

/// Renders `args.frames` frames (after `args.warmup`) back to back with two recorders, each
/// frame recorded while the previous one runs (its command buffer starts with a barrier
/// against everything before it, as the frames share the renderer's buffers); the mean wall
/// time a frame, ms.
fn time_pipelined(
    ctx: &std::sync::Arc<GpuContext>,
    args: &FpsArgs,
    renderer: &mut Renderer,
    still: &Option<TimedModel>,
    model: &GpuSplats,
    cameras: &GpuBuffer<CameraGpu>,
    cam: &CameraGpu,
) -> anyhow::Result<f64> {
    let splats = still.as_ref().map_or(model, |t| &t.instant);
    let settings = match still {
        Some(t) => t.settings([0.0; 3]),
        None => FrameSettings::plain(splats.sh_degree, [0.0; 3]),
    };
    let planned = FrameWork::Bands(renderer.bands_for(cam));
    let mut recs = [Recorder::new(ctx)?, Recorder::new(ctx)?];
    let mut t0 = Instant::now();
    for k in 0..args.warmup + args.frames {
        if k == args.warmup {
            for r in &mut recs {
                r.wait()?;
            }
            t0 = Instant::now();
        }
        // Waits for frame k - 2 (if it still runs): two frames in flight at most.
        let rec = &mut recs[k % 2];
        rec.begin()?;
        rec.barrier();
        if let Some(t) = still {
            t.record(rec, model, args.time)?;
        }
        renderer.record_work(rec, splats, cameras, 0, cam, &settings, &planned, None)?;
        rec.submit()?;
    }
    for r in &mut recs {
        r.wait()?;
    }
    Ok(1e3 * t0.elapsed().as_secs_f64() / args.frames.max(1) as f64)
}

fn print_result(r: &FpsResult) {
    println!(
        "{} — {} Gaussians at {}×{} on {}, camera: {} ({} visible, {} intersections)",
        r.source, r.gaussians, r.width, r.height, r.device, r.camera, r.visible, r.intersections
    );
    if r.bands > 1 {
        println!(
            "  drawn in {} bands of tile rows: the intersections pass what one storage binding \
             holds on this device",
            r.bands
        );
    }
    println!(
        "  {:.2} FPS (median frame {:.2} ms; p10 {:.2}, p90 {:.2}, min {:.2}, max {:.2}; {} frames)",
        r.fps_median,
        r.frame_ms_median,
        r.frame_ms_p10,
        r.frame_ms_p90,
        r.frame_ms_min,
        r.frame_ms_max,
        r.frames
    );
    println!(
        "  {:.2} FPS back to back (two frames in flight, each recorded while the one before \
         runs: {:.2} ms a frame)",
        r.fps_pipelined, r.frame_ms_pipelined
    );
    let total: f64 = r.stages_ms.iter().map(|s| s.1).sum();
    println!("  {:<12} {:>10} {:>7}", "stage", "GPU ms", "share");
    for (name, ms) in &r.stages_ms {
        println!(
            "  {:<12} {:>10.3} {:>6.1}%",
            name,
            ms,
            100.0 * ms / total.max(1e-12)
        );
    }
    println!("  GPU memory held: {:.1} MiB", r.gpu_memory_mib);
}
