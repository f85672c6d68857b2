//! `bench trade SCENE`: the accuracy / size / time trade-off of LPM, run side by side on one
//! device: ADC only, ADC with the global threshold lowered to 1e-4, ADC + LPM, LPM without point
//! addition, LPM without opacity reset. Writes `trade.json`, `trade.md` (the table, also printed)
//! and `trade.png` (PSNR against Gaussian count, left, and against training time, right; one
//! colour per run, listed in the table).

use crate::cli::train::{background_from, build_lpm, initial_model, mean_metrics, prepare_output};
use crate::cli::SceneArgs;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::render::forward::{FrameSettings, Renderer};
use lpmsplat::render::layout::{CameraGpu, RenderConstants};
use lpmsplat::scene::{images, Scene};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::train::lpm_step::LpmConfig;
use lpmsplat::train::trainer::{TrainConfig, Trainer};
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct TradeArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Iterations per run. The density / LPM calendar (500..15000, resets every 3000 of 30000)
    /// is scaled to this length.
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u32,
    /// Output folder for trade.json, trade.md and trade.png.
    #[arg(long, short = 'o', default_value = "bench_trade")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Frames timed for the FPS of each result (1352×1014).
    #[arg(long, default_value_t = 20)]
    pub fps_frames: usize,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct TradeRow {
    pub run: String,
    pub colour: [u8; 3],
    pub psnr: f64,
    pub ssim: f64,
    pub lpips: String,
    pub gaussians: usize,
    pub train_seconds: f64,
    pub ms_per_iteration: f64,
    pub lpm_ms_per_iteration: f64,
    pub lpm_share: f64,
    pub fps_1352x1014: f64,
}

const RUNS: [(&str, [u8; 3]); 5] = [
    ("adc", [40, 40, 40]),
    ("adc-threshold-1e-4", [200, 120, 0]),
    ("adc+lpm", [220, 30, 30]),
    ("lpm-no-add", [30, 120, 220]),
    ("lpm-no-reset", [30, 170, 60]),
];

pub fn run(gpu: &GpuOptions, args: &TradeArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.iterations > 0,
        "bench trade: --iterations 0. Fix: pass at least 1"
    );
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    anyhow::ensure!(
        !scene.test.is_empty(),
        "{}: bench trade needs test views to measure PSNR. Fix: use a scene with a test split",
        args.scene.scene.display()
    );
    prepare_output(&args.out)?;
    let train_images = images::load_images(&scene, &scene.train)?;
    let test_images = images::load_images(&scene, &scene.test)?;
    let init = initial_model(&scene, None, 100_000, args.seed, 3)?;
    let ctx = GpuContext::new(gpu)?;
    let scale = |t: u32| ((t as u64 * args.iterations as u64) / 30_000) as u32;
    let mut base = TrainConfig {
        iterations: args.iterations,
        seed: args.seed,
        background: background_from(None, &scene)?,
        ..TrainConfig::default()
    };
    base.schedule.densify_from = scale(500);
    base.schedule.densify_until = scale(15_000);
    base.schedule.opacity_reset_interval = (scale(3000) / 100).max(1) * 100;
    base.lr.position_max_steps = args.iterations;
    eprintln!(
        "bench trade: {} ({} train / {} test views), {} iterations per run, densify {}..{}, \
         reset every {}, on {}",
        args.scene.scene.display(),
        scene.train.len(),
        scene.test.len(),
        args.iterations,
        base.schedule.densify_from,
        base.schedule.densify_until,
        base.schedule.opacity_reset_interval,
        ctx.info.name
    );
    let mut rows = Vec::new();
    for (k, (name, colour)) in RUNS.iter().enumerate() {
        let mut cfg = base.clone();
        if *name == "adc-threshold-1e-4" {
            cfg.density.grad_threshold = 1e-4;
        }
        let lpm = (k >= 2).then(|| LpmConfig {
            from: cfg.schedule.densify_from,
            until: cfg.schedule.densify_until,
            add_points: *name != "lpm-no-add",
            reset: *name != "lpm-no-reset",
            seed: args.seed,
            ..LpmConfig::default()
        });
        let mut t = Trainer::new(&ctx, &scene, &train_images, &init, cfg)?;
        if let Some(c) = lpm {
            t.lpm = Some(build_lpm(&ctx, &scene, &train_images, c, &args.out)?);
        }
        let bar = ProgressBar::new(args.iterations as u64);
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "[{}/{}] {name:<20} {{bar:30}} {{pos}}/{{len}} {{msg}} [{{elapsed_precise}} < {{eta_precise}}]",
                k + 1,
                RUNS.len()
            ))
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        let t0 = Instant::now();
        for _ in 0..args.iterations {
            let r = t.step()?;
            if r.iteration % 20 == 0 || r.iteration == args.iterations {
                bar.set_position(r.iteration as u64);
                bar.set_message(format!("L1 {:.4} | {} Gaussians", r.l1, r.gaussians));
            }
        }
        let train_s = t0.elapsed().as_secs_f64();
        bar.finish();
        let (m, _) = t.evaluate(&scene, &scene.test, &test_images)?;
        let (psnr, ssim) = mean_metrics(&m);
        let model = t.model()?;
        let lpm_s = t.lpm.as_ref().map_or(0.0, |l| l.totals.seconds);
        let fps = fps_of(&ctx, &model, &scene, args.fps_frames)?;
        let row = TradeRow {
            run: name.to_string(),
            colour: *colour,
            psnr,
            ssim,
            lpips: "n/a (no weights)".into(),
            gaussians: model.len(),
            train_seconds: train_s,
            ms_per_iteration: 1e3 * train_s / args.iterations as f64,
            lpm_ms_per_iteration: 1e3 * lpm_s / args.iterations as f64,
            lpm_share: lpm_s / train_s.max(1e-12),
            fps_1352x1014: fps,
        };
        eprintln!(
            "  {name}: PSNR {psnr:.3} dB, SSIM {ssim:.4}, {} Gaussians, {train_s:.1} s, {fps:.1} FPS",
            row.gaussians
        );
        rows.push(row);
    }
    let table = table(&rows, &ctx.info.name, args);
    print!("{table}");
    write_atomic(&args.out.join("trade.md"), |f| {
        Ok(f.write_all(table.as_bytes())?)
    })?;
    let json = serde_json::json!({
        "scene": args.scene.scene.display().to_string(),
        "resolution": args.scene.resolution,
        "iterations": args.iterations,
        "device": ctx.info.name,
        "runs": rows,
    });
    let text = serde_json::to_string_pretty(&json)?;
    write_atomic(&args.out.join("trade.json"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    let png = plot(&rows)?;
    write_atomic(&args.out.join("trade.png"), |f| Ok(f.write_all(&png)?))?;
    println!("wrote {}", args.out.display());
    ctx.check_validation()?;
    Ok(())
}

/// Median FPS of `model` rendered at 1352×1014 from the first test view's pose.
fn fps_of(
    ctx: &std::sync::Arc<GpuContext>,
    model: &lpmsplat::splats::GaussianParams,
    scene: &Scene,
    frames: usize,
) -> anyhow::Result<f64> {
    let v = &scene.views[scene.test[0]];
    let cam = CameraGpu::new(&v.camera.resized(1352, 1014), &v.pose);
    let splats = GpuSplats::upload(ctx, model, model.len().max(1))?;
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[cam])?;
    let settings = FrameSettings {
        sh_degree: model.sh_degree,
        background: [0.0; 3],
        constants: RenderConstants::default(),
    };
    let mut r = Renderer::for_camera(ctx, model.len().max(1), &cam)?;
    r.render_blocking(&splats, &cameras, 0, &cam, &settings)?;
    let mut ms = Vec::new();
    for _ in 0..frames.max(1) {
        let t0 = Instant::now();
        r.render_blocking(&splats, &cameras, 0, &cam, &settings)?;
        ms.push(t0.elapsed().as_secs_f64());
    }
    ms.sort_by(|a, b| a.total_cmp(b));
    Ok(1.0 / ms[ms.len() / 2])
}

fn table(rows: &[TradeRow], device: &str, args: &TradeArgs) -> String {
    let mut s = format!(
        "bench trade: {} -r {:?}, {} iterations, {device}\n\n\
         | run | colour | PSNR | SSIM | LPIPS | Gaussians | train s | ms/it | LPM ms/it (share) | FPS 1352×1014 |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
        args.scene.scene.display(),
        args.scene.resolution,
        args.iterations
    );
    for r in rows {
        s += &format!(
            "| {} | #{:02x}{:02x}{:02x} | {:.3} | {:.4} | {} | {} | {:.1} | {:.2} | {:.3} ({:.2} %) | {:.1} |\n",
            r.run,
            r.colour[0],
            r.colour[1],
            r.colour[2],
            r.psnr,
            r.ssim,
            r.lpips,
            r.gaussians,
            r.train_seconds,
            r.ms_per_iteration,
            r.lpm_ms_per_iteration,
            100.0 * r.lpm_share,
            r.fps_1352x1014
        );
    }
    s
}

/// Two panels side by side: PSNR (y) against Gaussian count and against training time (x),
/// each axis spanning its data with a 10 % margin; a 7-px square marker per run.
fn plot(rows: &[TradeRow]) -> anyhow::Result<Vec<u8>> {
    let (pw, ph, m) = (400u32, 300u32, 30u32);
    let mut img = image::RgbImage::from_pixel(2 * pw, ph, image::Rgb([255, 255, 255]));
    let span = |v: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
        let pad = ((hi - lo) * 0.1).max(1e-9);
        (lo - pad, hi + pad)
    };
    let ys = span(&mut rows.iter().map(|r| r.psnr).filter(|v| v.is_finite()));
    let xs = [
        span(&mut rows.iter().map(|r| r.gaussians as f64)),
        span(&mut rows.iter().map(|r| r.train_seconds)),
    ];
    for (panel, &(x0, x1)) in xs.iter().enumerate() {
        let ox = panel as u32 * pw;
        let axis = image::Rgb([0, 0, 0]);
        for x in ox + m..ox + pw - m / 2 {
            img.put_pixel(x, ph - m, axis);
        }
        for y in m / 2..ph - m {
            img.put_pixel(ox + m, y, axis);
        }
        for r in rows {
            let x = if panel == 0 {
                r.gaussians as f64
            } else {
                r.train_seconds
            };
            if !r.psnr.is_finite() {
                continue;
            }
            let fx = (x - x0) / (x1 - x0);
            let fy = (r.psnr - ys.0) / (ys.1 - ys.0);
            let px = ox as f64 + m as f64 + fx * (pw - m - m / 2) as f64;
            let py = (ph - m) as f64 - fy * (ph - m - m / 2) as f64;
            for dy in -3i64..=3 {
                for dx in -3i64..=3 {
                    let (x, y) = (px as i64 + dx, py as i64 + dy);
                    if x >= 0 && y >= 0 && (x as u32) < 2 * pw && (y as u32) < ph {
                        img.put_pixel(x as u32, y as u32, image::Rgb(r.colour));
                    }
                }
            }
        }
    }
    let mut out = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}
