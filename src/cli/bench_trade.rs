//! `bench trade SCENE`: the accuracy / size / time trade-off of LPM, run side by side on one
//! device: ADC only, ADC with the global threshold lowered to 1e-4, ADC + LPM, LPM without point
//! addition, LPM without opacity reset. Writes `trade.json`, `trade.md` (the table, also printed)
//! and `trade.png` (PSNR against Gaussian count, left, and against training time, right; one
//! colour per run, listed in the table).

use crate::cli::train::{background_from, build_lpm, initial_model, mean_metrics, prepare_output};
use crate::cli::SceneArgs;
use anyhow::Context;
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
    /// Iterations per run.
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u32,
    /// The run length whose calendar is followed: the reference's density / LPM calendar
    /// (densify 500..15000, resets every 3000, position learning-rate decay over 30000) is
    /// scaled by CALENDAR / 30000. Default: --iterations (a complete, compressed schedule);
    /// `--calendar 30000 --iterations 7000` is the reference schedule stopped at 7k.
    #[arg(long)]
    pub calendar: Option<u32>,
    /// Also evaluate every run at these iterations (comma separated); the final iteration is
    /// always evaluated. trade.json / trade.md / trade.png are rewritten after each, so an
    /// interrupted benchmark keeps the rows it reached.
    #[arg(long, value_delimiter = ',')]
    pub eval_at: Vec<u32>,
    /// Output folder for trade.json, trade.md and trade.png.
    #[arg(long, short = 'o', default_value = "bench_trade")]
    pub out: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Frames timed for the FPS of each result (1352×1014).
    #[arg(long, default_value_t = 20)]
    pub fps_frames: usize,
    /// The runs to compare, comma separated, in table order: adc, adc-threshold-1e-4, adc+lpm,
    /// lpm-no-add, lpm-no-reset (aliases: adc-1e-4, lpm). Default: all five.
    #[arg(long, value_delimiter = ',')]
    pub runs: Vec<String>,
    /// Run the variants one after another instead of interleaving their iterations. Interleaving
    /// (the default) keeps every run's time measured under the same machine load, so the time
    /// ratios hold on a noisy machine; sequential needs the memory of one run only.
    #[arg(long)]
    pub sequential: bool,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct TradeRow {
    pub run: String,
    pub iteration: u32,
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

pub const RUNS: [(&str, [u8; 3]); 5] = [
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
    let selected = selected_runs(&args.runs)?;
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
    let calendar = args.calendar.unwrap_or(args.iterations);
    anyhow::ensure!(
        calendar > 0,
        "bench trade: --calendar 0. Fix: pass the run length whose schedule to follow"
    );
    let mut eval_at: Vec<u32> = args
        .eval_at
        .iter()
        .copied()
        .filter(|&i| i > 0 && i < args.iterations)
        .chain([args.iterations])
        .collect();
    eval_at.sort_unstable();
    eval_at.dedup();
    let scale = |t: u32| ((t as u64 * calendar as u64) / 30_000) as u32;
    let mut base = TrainConfig {
        iterations: args.iterations,
        seed: args.seed,
        background: background_from(None, &scene)?,
        ..TrainConfig::default()
    };
    base.schedule.densify_from = scale(500);
    base.schedule.densify_until = scale(15_000);
    base.schedule.opacity_reset_interval = (scale(3000) / 100).max(1) * 100;
    base.lr.position_max_steps = calendar;
    eprintln!(
        "bench trade: {} ({} train / {} test views), {} iterations per run on the calendar of \
         {calendar}: densify {}..{}, reset every {}, on {}",
        args.scene.scene.display(),
        scene.train.len(),
        scene.test.len(),
        args.iterations,
        base.schedule.densify_from,
        base.schedule.densify_until,
        base.schedule.opacity_reset_interval,
        ctx.info.name
    );
    let mut runs = Vec::new();
    for &k in &selected {
        let name = RUNS[k].0;
        let mut cfg = base.clone();
        if name == "adc-threshold-1e-4" {
            cfg.density.grad_threshold = 1e-4;
        }
        let lpm = (k >= 2).then(|| LpmConfig {
            from: cfg.schedule.densify_from,
            until: cfg.schedule.densify_until,
            add_points: name != "lpm-no-add",
            reset: name != "lpm-no-reset",
            seed: args.seed,
            ..LpmConfig::default()
        });
        runs.push(Run {
            k,
            cfg,
            lpm,
            trainer: None,
            seconds: 0.0,
        });
    }
    let total = args.iterations as u64 * runs.len() as u64;
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} {msg} [{elapsed_precise} < {eta_precise}]",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let plain = !std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut last_line = Instant::now();
    let mut done = 0u64;
    let mut rows = Vec::new();
    // Interleaved: every run advances one iteration per round, so each run's summed step time
    // sees the same load. Sequential: one run to the end, evaluated and dropped, then the next.
    let groups: Vec<Vec<usize>> = if args.sequential {
        (0..runs.len()).map(|i| vec![i]).collect()
    } else {
        vec![(0..runs.len()).collect()]
    };
    for group in groups {
        for &i in &group {
            let r = &mut runs[i];
            let mut t = Trainer::new(&ctx, &scene, &train_images, &init, r.cfg.clone())?;
            if let Some(c) = r.lpm.clone() {
                t.lpm = Some(build_lpm(&ctx, &scene, &train_images, c, &args.out)?);
            }
            r.trainer = Some(t);
        }
        for it in 1..=args.iterations {
            for &i in &group {
                let r = &mut runs[i];
                let t = r.trainer.as_mut().expect("trainer built above");
                if eval_at.contains(&it) {
                    t.snapshot_next_step();
                }
                let t0 = Instant::now();
                t.step()?;
                r.seconds += t0.elapsed().as_secs_f64();
            }
            done += group.len() as u64;
            if done.is_multiple_of(20) || done == total {
                let msg = group
                    .iter()
                    .map(|&i| {
                        let r = &runs[i];
                        let t = r.trainer.as_ref().expect("trainer built above");
                        format!("{} {}", RUNS[r.k].0, t.state.count())
                    })
                    .collect::<Vec<_>>()
                    .join(" | ");
                bar.set_position(done);
                bar.set_message(format!("Gaussians: {msg}"));
                if plain && (last_line.elapsed().as_secs() >= 10 || done == total) {
                    eprintln!("[{done}/{total}] Gaussians: {msg}");
                    last_line = Instant::now();
                }
            }
            if eval_at.contains(&it) {
                for &i in &group {
                    let r = &mut runs[i];
                    let mut t = r.trainer.take().expect("trainer built above");
                    let row = bar.suspend(|| {
                        evaluate_run(&ctx, &scene, &test_images, r, &mut t, it, args)
                    })?;
                    r.trainer = Some(t);
                    rows.push(row);
                }
                rows.sort_by_key(|r| (r.iteration, RUNS.iter().position(|(n, _)| *n == r.run)));
                write_outputs(&rows, &ctx.info.name, args)?;
            }
        }
        for &i in &group {
            runs[i].trainer = None;
        }
    }
    bar.finish_and_clear();
    print!("{}", table(&rows, &ctx.info.name, args));
    println!("wrote {}", args.out.display());
    ctx.check_validation()?;
    Ok(())
}

/// Writes trade.md, trade.json and trade.png for the rows so far (atomically).
fn write_outputs(rows: &[TradeRow], device: &str, args: &TradeArgs) -> anyhow::Result<()> {
    let table = table(rows, device, args);
    write_atomic(&args.out.join("trade.md"), |f| {
        Ok(f.write_all(table.as_bytes())?)
    })?;
    let json = serde_json::json!({
        "scene": args.scene.scene.display().to_string(),
        "resolution": args.scene.resolution,
        "iterations": args.iterations,
        "calendar": args.calendar.unwrap_or(args.iterations),
        "interleaved": !args.sequential,
        "device": device,
        "runs": rows,
    });
    let text = serde_json::to_string_pretty(&json)?;
    write_atomic(&args.out.join("trade.json"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    let png = plot(rows)?;
    write_atomic(&args.out.join("trade.png"), |f| Ok(f.write_all(&png)?))?;
    Ok(())
}

struct Run {
    k: usize,
    cfg: TrainConfig,
    lpm: Option<LpmConfig>,
    trainer: Option<Trainer>,
    seconds: f64,
}

/// Indices into [`RUNS`] for the `--runs` list (all when empty), in table order.
pub fn selected_runs(names: &[String]) -> anyhow::Result<Vec<usize>> {
    if names.is_empty() {
        return Ok((0..RUNS.len()).collect());
    }
    let mut out = Vec::new();
    for n in names {
        let canonical = match n.trim() {
            "adc-1e-4" => "adc-threshold-1e-4",
            "lpm" => "adc+lpm",
            other => other,
        };
        let k = RUNS
            .iter()
            .position(|(r, _)| *r == canonical)
            .with_context(|| {
                format!(
                    "bench trade --runs: unknown run {n:?}. Fix: choose from {}",
                    RUNS.iter().map(|r| r.0).collect::<Vec<_>>().join(", ")
                )
            })?;
        anyhow::ensure!(
            !out.contains(&k),
            "bench trade --runs: {n:?} is listed twice. Fix: name each run once"
        );
        out.push(k);
    }
    out.sort_unstable();
    Ok(out)
}

/// Evaluates a run at iteration `iteration` on the test views and times its model at 1352×1014.
fn evaluate_run(
    ctx: &std::sync::Arc<GpuContext>,
    scene: &Scene,
    test_images: &[images::Image],
    r: &Run,
    t: &mut Trainer,
    iteration: u32,
    args: &TradeArgs,
) -> anyhow::Result<TradeRow> {
    let (name, colour) = RUNS[r.k];
    let (m, _) = t.evaluate(scene, &scene.test, test_images)?;
    let (psnr, ssim) = mean_metrics(&m);
    let model = t.model()?;
    let lpm_s = t.lpm.as_ref().map_or(0.0, |l| l.totals.seconds);
    let fps = fps_of(ctx, &model, scene, args.fps_frames)?;
    let train_s = r.seconds;
    let row = TradeRow {
        run: name.to_string(),
        iteration,
        colour,
        psnr,
        ssim,
        lpips: "n/a (no weights)".into(),
        gaussians: model.len(),
        train_seconds: train_s,
        ms_per_iteration: 1e3 * train_s / iteration as f64,
        lpm_ms_per_iteration: 1e3 * lpm_s / iteration as f64,
        lpm_share: lpm_s / train_s.max(1e-12),
        fps_1352x1014: fps,
    };
    eprintln!(
        "  {name} @ {iteration}: PSNR {psnr:.3} dB, SSIM {ssim:.4}, {} Gaussians, {train_s:.1} s, {fps:.1} FPS",
        row.gaussians
    );
    Ok(row)
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
    let resolution = args
        .scene
        .resolution
        .map_or("full resolution".to_string(), |r| format!("-r {r}"));
    let mut s = format!(
        "bench trade: {} {resolution}, {} iterations on the calendar of {}, {device}\n\n{}\n\n\
         | run | iteration | colour | PSNR | ΔPSNR vs adc | SSIM | LPIPS | Gaussians | train s | time vs adc | ms/it | LPM ms/it (share) | FPS 1352×1014 |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        args.scene.scene.display(),
        args.iterations,
        args.calendar.unwrap_or(args.iterations),
        if args.sequential {
            "Runs were sequential: compare their times only on an otherwise idle machine."
        } else {
            "Runs were interleaved one iteration at a time, so their times saw the same machine load."
        }
    );
    for r in rows {
        let adc = rows
            .iter()
            .find(|a| a.run == "adc" && a.iteration == r.iteration);
        let (dpsnr, dtime) = match adc {
            Some(a) => (
                format!("{:+.3}", r.psnr - a.psnr),
                format!("{:.3}×", r.train_seconds / a.train_seconds.max(1e-12)),
            ),
            None => ("n/a".into(), "n/a".into()),
        };
        s += &format!(
            "| {} | {} | #{:02x}{:02x}{:02x} | {:.3} | {dpsnr} | {:.4} | {} | {} | {:.1} | {dtime} | {:.2} | {:.3} ({:.2} %) | {:.1} |\n",
            r.run,
            r.iteration,
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
/// each axis spanning its data with a 10 % margin; a 7-px square marker per evaluated row, and a
/// 1-px line joining a run's rows in iteration order (its trajectory).
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
        let point = |r: &TradeRow| {
            let x = if panel == 0 {
                r.gaussians as f64
            } else {
                r.train_seconds
            };
            let fx = (x - x0) / (x1 - x0);
            let fy = (r.psnr - ys.0) / (ys.1 - ys.0);
            (
                ox as f64 + m as f64 + fx * (pw - m - m / 2) as f64,
                (ph - m) as f64 - fy * (ph - m - m / 2) as f64,
            )
        };
        let mut put = |x: i64, y: i64, c: [u8; 3]| {
            if x >= 0 && y >= 0 && (x as u32) < 2 * pw && (y as u32) < ph {
                img.put_pixel(x as u32, y as u32, image::Rgb(c));
            }
        };
        let finite: Vec<&TradeRow> = rows.iter().filter(|r| r.psnr.is_finite()).collect();
        for (name, colour) in RUNS {
            let mut path: Vec<&TradeRow> =
                finite.iter().copied().filter(|r| r.run == name).collect();
            path.sort_by_key(|r| r.iteration);
            for w in path.windows(2) {
                let ((ax, ay), (bx, by)) = (point(w[0]), point(w[1]));
                let steps = (bx - ax).abs().max((by - ay).abs()).ceil().max(1.0) as i64;
                for s in 0..=steps {
                    let f = s as f64 / steps as f64;
                    put(
                        (ax + f * (bx - ax)) as i64,
                        (ay + f * (by - ay)) as i64,
                        colour,
                    );
                }
            }
            for r in path {
                let (px, py) = point(r);
                for dy in -3i64..=3 {
                    for dx in -3i64..=3 {
                        put(px as i64 + dx, py as i64 + dy, colour);
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
