//! `bench trade SCENE`: the accuracy / size / time trade-off of LPM, run side by side on one
//! device: ADC only, ADC with the global threshold lowered to 1e-4, ADC + LPM, LPM without point
//! addition, LPM without opacity reset. Writes `trade.json`, `trade.md` (the table, also printed)
//! and `trade.png` (PSNR against Gaussian count, left, and against training time, right; one
//! colour per run, listed in the table).

use super::trade_report;
use super::trade_summary::{
    column_header, paired_table, plot, summarize, table_rows, Summary, TradeRow,
};
use crate::cli::lpips_scores::{self, LpipsArgs};
use crate::cli::train::{background_from, build_lpm, initial_model, prepare_output};
use crate::cli::world_culls_arg::N3dvCulls;
use crate::cli::SceneArgs;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::lpips::Lpips;
use lpmsplat::lpm::config::{LpmConfig, PruneMode};
use lpmsplat::lpm::pairing::RegionKeypoints;
use lpmsplat::lpm::strategy::LpmStrategy;
use lpmsplat::lpm::{ConeRadius, NeighbourChoice, ZoneGeometry};
use lpmsplat::render::forward::{FrameSettings, Renderer};
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::render::spacetime::TimedModel;
use lpmsplat::scene::image_source::{ImageSource, ViewImages};
use lpmsplat::scene::Scene;
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::write_ply;

fn parse_prune(s: &str) -> anyhow::Result<PruneMode> {
    PruneMode::parse(s)
}
use lpmsplat::models::BaseModel;
use lpmsplat::train::trainer::{TrainConfig, Trainer, ViewMetrics};
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct TradeArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub images: crate::cli::image_cache_args::ImageCacheArgs,
    /// Iterations per run.
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u32,
    /// Base model of every run (3dgs, pixel-gs, mip-splatting, 2dgs; spacetime-lite or
    /// spacetime-full on a video scene): the table compares ADC and LPM on it.
    #[arg(long, default_value = "3dgs", value_parser = BaseModel::parse)]
    pub model: BaseModel,
    /// The run length whose calendar is followed: the reference's density / LPM calendar
    /// (densify 500..15000, resets every 3000, position learning-rate decay over 30000; 2dgs's
    /// normal and distortion regularisers from 7000 and 3000) is scaled by CALENDAR / 30000. Default: --iterations (a complete, compressed schedule);
    /// `--calendar 30000 --iterations 7000` is the reference schedule stopped at 7k.
    #[arg(long)]
    pub calendar: Option<u32>,
    /// Also evaluate every run at these iterations (comma separated); the final iteration is
    /// always evaluated. trade.json / trade.md / trade.png are rewritten after each, so an
    /// interrupted benchmark keeps the rows it reached.
    #[arg(long, value_delimiter = ',')]
    pub eval_at: Vec<u32>,
    /// Initial points when the scene has no point cloud (video scenes, transforms.json without
    /// points).
    #[arg(long, default_value_t = 100_000)]
    pub init_points: usize,
    /// Where they come from: auto (triangulate video scenes), random or triangulate (as
    /// `train --init`).
    #[arg(long, value_enum, default_value_t = crate::cli::train::InitSource::Auto)]
    pub init: crate::cli::train::InitSource,
    /// Output folder for trade.json, trade.md and trade.png.
    #[arg(long, short = 'o', default_value = "bench_trade")]
    pub out: PathBuf,
    /// The first seed; with --seeds K the runs use seeds SEED to SEED+K−1.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Train every variant with K seeds (initialisation where it is random, view order,
    /// split samples, LPM's neighbour picks) and report mean ± standard deviation, and the gain
    /// over ADC as the mean ± standard error of the per-seed differences (ADC and the variant
    /// share each seed). Run-to-run spread on scenes with few test views is several tenths of a
    /// dB, so a single seed cannot separate effects that small.
    #[arg(long, default_value_t = 1)]
    pub seeds: u32,
    /// Frames timed for the FPS of each result (1352×1014).
    #[arg(long, default_value_t = 20)]
    pub fps_frames: usize,
    /// The runs to compare, comma separated, in table order: adc, adc-threshold-1e-4, adc+lpm,
    /// lpm-no-add, lpm-no-reset, lpm-authors (the authors' rules), lpm-authors-adc (the same
    /// with ADC on steps without a zone), lpm-sphere (the paper's cone-intersection zone),
    /// adc-abs-grad (with the absolute-gradient test), lpm-additive (our rules with the additive
    /// pruning: exactly as many extra prunes as lowered-threshold densifications),
    /// lpm-overlap-neighbours (our rules with the neighbour views sharing the most tracks),
    /// lpm-error-blocks (our rules with only the matches on a region's own error blocks speaking
    /// for it), lpm-bounding-cone (our rules with the in-front cone to the zone's bounding
    /// sphere, the default before 2026-11-26), lpm-local-zones (our rules without the zones
    /// wider than the scene extent), lpm-slab (our rules with the zone cut to the view's cone
    /// through the region and the depths of its matches), lpm-loose-blocks (our rules with error
    /// blocks kept above 70 % error pixels, whatever --lpm-block-fraction says),
    /// lpm-local-resets (our rules with the zones wider than the scene kept but ignored by the
    /// opacity reset) (aliases: adc-1e-4, lpm). Default: the first five.
    #[arg(long, value_delimiter = ',')]
    pub runs: Vec<String>,
    /// Run the variants one after another instead of interleaving their iterations. Interleaving
    /// (the default) keeps every run's time measured under the same machine load, so the time
    /// ratios hold on a noisy machine; sequential needs the memory of one run only.
    #[arg(long)]
    pub sequential: bool,
    /// LPM runs: error-region block side in pixels (as `train --lpm-block`; 0 follows the
    /// image size).
    #[arg(long, default_value_t = 0)]
    pub lpm_block: u32,
    /// LPM runs: density-aware pruning (as `train --lpm-prune`; default: each rule set's own).
    #[arg(long, value_parser = parse_prune)]
    pub lpm_prune: Option<PruneMode>,
    /// LPM runs: fraction of error pixels that keeps a block (as `train --lpm-block-fraction`).
    #[arg(long, default_value_t = 0.85)]
    pub lpm_block_fraction: f32,
    /// Every run also densifies by the absolute-gradient test (as `train --densify-abs-grad`:
    /// Mip-Splatting's official densification).
    #[arg(long)]
    pub densify_abs_grad: bool,
    /// Every run trains under the same cap on the number of Gaussians (as `train
    /// --max-gaussians`): at the cap the runs compare at one count.
    #[arg(long, value_name = "N", value_parser = crate::cli::train::parse_max_gaussians)]
    pub max_gaussians: Option<usize>,
    /// spacetime-*: SpacetimeGaussians' Neural 3D Video culls (as `train --n3dv-culls`; their
    /// 1000-iteration rhythm scaled to the calendar).
    #[arg(long, value_enum, default_value_t = N3dvCulls::Auto)]
    pub n3dv_culls: N3dvCulls,
    /// The test view trade.html shows (name, file stem or index into the test views; default
    /// the first): the truth beside each run's final render and error map.
    #[arg(long)]
    pub report_view: Option<String>,
    #[command(flatten)]
    pub lpips: LpipsArgs,
}

pub const RUNS: [(&str, [u8; 3]); 17] = [
    ("adc", [40, 40, 40]),
    ("adc-threshold-1e-4", [200, 120, 0]),
    ("adc+lpm", [220, 30, 30]),
    ("lpm-no-add", [30, 120, 220]),
    ("lpm-no-reset", [30, 170, 60]),
    // `train --lpm-rules authors`: the authors' code's rules exactly.
    ("lpm-authors", [150, 60, 200]),
    // The authors' rules with ADC kept on steps without a zone (`--lpm-skip-adc false`).
    ("lpm-authors-adc", [200, 110, 230]),
    // Our rules with the paper's cone-intersection sphere instead of the triangulated zone.
    ("lpm-sphere", [120, 90, 40]),
    // ADC with the absolute-gradient test as well (`train --densify-abs-grad`).
    ("adc-abs-grad", [90, 90, 90]),
    // Our rules with the additive pruning (`train --lpm --lpm-prune additive`), beside the
    // default authors' pruning in one interleaved run.
    ("lpm-additive", [240, 150, 150]),
    // Our rules with the neighbour views sharing the most tracks
    // (`train --lpm --lpm-neighbours overlap`).
    ("lpm-overlap-neighbours", [60, 200, 200]),
    // Our rules with only the matches on a region's own error blocks speaking for it
    // (`train --lpm --lpm-region-keypoints error-blocks`).
    ("lpm-error-blocks", [230, 190, 40]),
    // Our rules with the in-front cone to the zone's bounding sphere
    // (`train --lpm --lpm-cone bounding`; the default until the region cone measured better).
    ("lpm-bounding-cone", [40, 60, 160]),
    // Our rules without the zones wider than the scene
    // (`train --lpm --lpm-max-zone-radius 1`).
    ("lpm-local-zones", [160, 200, 60]),
    // Our rules with the zone cut to the region's cone and the matches' depths
    // (`train --lpm --lpm-zone slab`).
    ("lpm-slab", [200, 80, 200]),
    // Our rules with error blocks kept above 70 % error pixels instead of the paper's 85 %
    // (`train --lpm --lpm-block-fraction 0.7`), beside the default in one interleaved run.
    ("lpm-loose-blocks", [250, 120, 40]),
    // Our rules with zones wider than the scene kept but ignored by the opacity reset
    // (`train --lpm --lpm-reset-max-zone-radius 1`).
    ("lpm-local-resets", [120, 40, 120]),
];

pub fn run(gpu: &GpuOptions, args: &TradeArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.iterations > 0,
        "bench trade: --iterations 0. Fix: pass at least 1"
    );
    anyhow::ensure!(
        args.seeds > 0,
        "bench trade: --seeds 0. Fix: pass at least 1"
    );
    let selected = selected_runs(&args.runs)?;
    let lpips = args.lpips.load()?;
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    anyhow::ensure!(
        !scene.test.is_empty(),
        "{}: bench trade needs test views to measure PSNR. Fix: use a scene with a test split",
        args.scene.scene.display()
    );
    prepare_output(&args.out)?;
    let view_name = scene.views
        [scene.test[trade_report::report_view(&scene, args.report_view.as_deref())?]]
    .name
    .clone();
    let train_images = args.images.train_images(&scene)?;
    let test_images = ViewImages::new(&scene, &scene.test)?;
    let seeds: Vec<u64> = (0..args.seeds as u64).map(|i| args.seed + i).collect();
    // The model's own colour degree (SpacetimeGaussians lite: none), 3 otherwise.
    let sh_degree = {
        let mut c = TrainConfig::default();
        args.model.configure(&mut c);
        c.sh_degree
    };
    let inits = seeds
        .iter()
        .map(|&seed| {
            initial_model(
                args.model,
                &scene,
                None,
                args.init,
                args.init_points,
                seed,
                sh_degree,
            )
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
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
    let base = calendar_config(args, &scene, calendar)?;
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
        for (si, &seed) in seeds.iter().enumerate() {
            let name = RUNS[k].0;
            let mut cfg = base.clone();
            cfg.seed = seed;
            if name == "adc-threshold-1e-4" {
                cfg.density.grad_threshold = 1e-4;
            }
            if name == "adc-abs-grad" {
                abs_grad_applies(args.model)?;
                cfg.density.abs_grad = true;
            }
            let lpm = run_lpm_config(name, &cfg, args);
            if let Some(c) = &lpm {
                c.validate()?;
            }
            runs.push(Run {
                k,
                seed,
                init: si,
                cfg,
                lpm,
                trainer: None,
                seconds: 0.0,
                model_events: Vec::new(),
            });
        }
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
            let init = &inits[r.init];
            let mut t = Trainer::new(&ctx, &scene, train_images.clone(), init, r.cfg.clone())?;
            if let Some(c) = r.lpm.clone() {
                t.set_strategy(Box::new(build_lpm(
                    &ctx,
                    &scene,
                    &train_images,
                    c,
                    &args.out,
                )?));
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
                // The next iteration is recorded while this one runs, unless an evaluation
                // comes after this one or a snapshot before the next.
                let prepare =
                    it < args.iterations && !eval_at.contains(&it) && !eval_at.contains(&(it + 1));
                let report = t.step_ahead(prepare)?;
                r.seconds += t0.elapsed().as_secs_f64();
                r.model_events
                    .extend(report.model_events.iter().map(|e| e.to_json()));
            }
            done += group.len() as u64;
            if done.is_multiple_of(20) || done == total {
                let msg = group
                    .iter()
                    .map(|&i| {
                        let r = &runs[i];
                        let t = r.trainer.as_ref().expect("trainer built above");
                        if seeds.len() > 1 {
                            format!("{}/{} {}", RUNS[r.k].0, r.seed, t.state.count())
                        } else {
                            format!("{} {}", RUNS[r.k].0, t.state.count())
                        }
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
                        let test = TestSet {
                            scene: &scene,
                            images: &test_images,
                            lpips: lpips.as_ref(),
                        };
                        evaluate_run(&ctx, &test, r, &mut t, it, args)
                    })?;
                    r.trainer = Some(t);
                    rows.push(row);
                }
                rows.sort_by_key(|r| {
                    (
                        r.iteration,
                        RUNS.iter().position(|(n, _)| *n == r.run),
                        r.seed,
                    )
                });
                write_outputs(&rows, &ctx.info.name, &view_name, args)?;
            }
        }
        for &i in &group {
            runs[i].trainer = None;
        }
    }
    bar.finish_and_clear();
    print!("{}", tables(&rows, &ctx.info.name, args));
    println!("wrote {}", args.out.display());
    ctx.check_validation()?;
    Ok(())
}

/// The table: what was run, how to read it, and the rows ([`table_rows`]).
pub fn table(rows: &[Summary], device: &str, args: &TradeArgs) -> String {
    let resolution = args
        .scene
        .resolution
        .map_or("full resolution".to_string(), |r| format!("-r {r}"));
    let several = rows.iter().any(|r| r.seeds > 1);
    let s = format!(
        "bench trade: {} {resolution}, base model {}, {} iterations on the calendar of {}, {device}; LPM \
         error blocks of {} kept above {} error pixels\n\n{} \
         trade.png plots test PSNR against Gaussians and training seconds (top), and PSNR and \
         Gaussians against iterations (bottom), one named line per run through its evaluated \
         iterations; trade.html shows the plot, this table and the runs' renders. LPIPS is \
         AlexNet v0.1 (n/a without --lpips-weights).{}\n\n",
        args.scene.scene.display(),
        args.model.name(),
        args.iterations,
        args.calendar.unwrap_or(args.iterations),
        if args.lpm_block == 0 {
            "the image's size (16 px at 1 MP, scaled with the diagonal, at least 4)".to_string()
        } else {
            format!("{} px", args.lpm_block)
        },
        args.lpm_block_fraction,
        if args.sequential {
            "Runs were sequential: compare their times only on an otherwise idle machine."
        } else {
            "Runs were interleaved one iteration at a time, so their times saw the same machine load."
        },
        if several {
            format!(
                " Each row is the mean over {} seeds ({}..{}): PSNR and SSIM ± their standard \
                 deviation, ΔPSNR ± the standard error of the per-seed differences from ADC, \
                 the rest means; the plot shows the means.",
                args.seeds,
                args.seed,
                args.seed + args.seeds as u64 - 1
            )
        } else {
            String::new()
        }
    );
    s + &column_header("adc") + &table_rows(rows)
}

/// What changes the runs beyond the scene, model, resolution and calendar (trade.json's
/// `settings`): `bench merge` pools only runs whose files agree here, and names the others by
/// the difference. Settings whose name starts with `lpm_` change only the LPM runs.
pub fn settings_json(args: &TradeArgs) -> serde_json::Value {
    serde_json::json!({
        "lpm_block": args.lpm_block,
        "lpm_block_fraction": args.lpm_block_fraction,
        "lpm_prune": args.lpm_prune.as_ref().map(PruneMode::name),
        "densify_abs_grad": args.densify_abs_grad,
        "max_gaussians": args.max_gaussians,
        "init": format!("{:?}", args.init).to_lowercase(),
        "init_points": args.init_points,
        "n3dv_culls": format!("{:?}", args.n3dv_culls).to_lowercase(),
        "test_split": args.scene.test_split,
        "frames": args.scene.frames.map(|f| serde_json::json!({"start": f.start, "count": f.count})),
    })
}

/// [`table`] of the rows' summary, and with several seeds each run's per-seed differences from
/// ADC ([`paired_table`]).
fn tables(rows: &[TradeRow], device: &str, args: &TradeArgs) -> String {
    let mut s = table(&summarize(rows), device, args);
    if args.seeds > 1 && rows.iter().any(|r| r.run == "adc") {
        s += "\n";
        s += &paired_table(rows, "adc");
    }
    s
}

/// Writes trade.md, trade.json and trade.png for the rows so far (atomically).
fn write_outputs(
    rows: &[TradeRow],
    device: &str,
    view_name: &str,
    args: &TradeArgs,
) -> anyhow::Result<()> {
    let summary = summarize(rows);
    let table = tables(rows, device, args);
    write_atomic(&args.out.join("trade.md"), |f| {
        Ok(f.write_all(table.as_bytes())?)
    })?;
    let json = serde_json::json!({
        "scene": args.scene.scene.display().to_string(),
        "model": args.model.name(),
        "resolution": args.scene.resolution,
        "iterations": args.iterations,
        "calendar": args.calendar.unwrap_or(args.iterations),
        "interleaved": !args.sequential,
        "device": device,
        "seeds": args.seeds,
        "lpm_block": args.lpm_block,
        "lpm_block_fraction": args.lpm_block_fraction,
        "settings": settings_json(args),
        "summary": summary,
        "runs": rows,
    });
    let text = serde_json::to_string_pretty(&json)?;
    write_atomic(&args.out.join("trade.json"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    let png = plot(&summary.iter().map(Summary::as_row).collect::<Vec<_>>())?;
    write_atomic(&args.out.join("trade.png"), |f| Ok(f.write_all(&png)?))?;
    let title = format!(
        "bench trade: {}, {}, {} iterations",
        args.scene.scene.display(),
        args.model.name(),
        args.iterations
    );
    trade_report::write_html(&args.out, &title, view_name, rows, &summary, &table)?;
    Ok(())
}

struct Run {
    k: usize,
    seed: u64,
    /// Index of the run's initial model (one per seed).
    init: usize,
    cfg: TrainConfig,
    lpm: Option<LpmConfig>,
    trainer: Option<Trainer>,
    seconds: f64,
    /// The base model's own rules' events so far.
    model_events: Vec<serde_json::Value>,
}

/// The configuration every run starts from: the base model's defaults with every iteration
/// its official code names on a 30k calendar (densification, opacity resets, the position
/// learning rate's decay, the models' own rules' starts) scaled to `calendar` iterations.
fn calendar_config(args: &TradeArgs, scene: &Scene, calendar: u32) -> anyhow::Result<TrainConfig> {
    let scale = |t: u32| ((t as u64 * calendar as u64) / 30_000) as u32;
    let mut base = TrainConfig {
        iterations: args.iterations,
        seed: args.seed,
        background: background_from(None, scene)?,
        ..TrainConfig::default()
    };
    base.schedule.densify_from = scale(500);
    base.schedule.densify_until = scale(args.model.default_densify_until());
    base.schedule.opacity_reset_interval = (scale(3000) / 100).max(1) * 100;
    base.lr.position_max_steps = calendar;
    base.density.min_opacity = args.model.default_min_opacity();
    args.model.configure(&mut base);
    if args.densify_abs_grad {
        abs_grad_applies(args.model)?;
        base.density.abs_grad = true;
    }
    base.density.max_gaussians = args.max_gaussians;
    if let Some(g) = base.spacetime.as_mut().and_then(|s| s.guided.as_mut()) {
        // SpacetimeGaussians' guided sampling on the same calendar (official 1600 and 100).
        g.from = scale(g.from);
        g.gap = scale(g.gap);
    }
    if let Some(f) = base
        .spacetime
        .as_mut()
        .and_then(|s| s.omega_freeze.as_mut())
    {
        // The angular-velocity split on the same calendar (official 8001 of 30k).
        f.from = scale(f.from);
    }
    // The Neural 3D Video culls on the same calendar (official: every 1000 of 30k).
    crate::cli::world_culls_arg::apply(
        args.n3dv_culls,
        &scene.root,
        args.model,
        &mut base,
        scale(1000),
    )?;
    if let Some(t) = base.surfels.as_mut() {
        // 2DGS's regularisers start on the same calendar (official 7000 and 3000 of 30k).
        t.normal_from = scale(t.normal_from);
        t.distortion_from = scale(t.distortion_from);
    }
    Ok(base)
}

/// The absolute-gradient test needs the mean-gradient statistic of a Gaussian model.
fn abs_grad_applies(model: BaseModel) -> anyhow::Result<()> {
    anyhow::ensure!(
        matches!(
            model,
            BaseModel::Gaussians3d
                | BaseModel::MipSplatting
                | BaseModel::SpacetimeLite
                | BaseModel::SpacetimeFull
        ),
        "bench trade: the absolute-gradient test (--densify-abs-grad, run adc-abs-grad) with \
         --model {}: it applies to 3dgs, mip-splatting and the spacetime models. Fix: drop it",
        model.name()
    );
    Ok(())
}

/// The block rule of `lpm-loose-blocks`: ahead of the paper's 0.85 at one Gaussian count on
/// Truck `-r 4` over eleven seeds (docs/lpm-results.md), not yet measured at full size.
const LOOSE_BLOCK_FRACTION: f32 = 0.7;

/// LPM's configuration for run `name` (None for the runs without LPM), on `cfg`'s calendar
/// and seed, with the benchmark's LPM overrides.
fn run_lpm_config(name: &str, cfg: &TrainConfig, args: &TradeArgs) -> Option<LpmConfig> {
    if !name.contains("lpm") {
        return None;
    }
    let mut c = if name.starts_with("lpm-authors") {
        LpmConfig::authors()
    } else {
        LpmConfig::default()
    };
    if name == "lpm-authors-adc" {
        c.skip_adc_without_zone = false;
    }
    c.from = cfg.schedule.densify_from;
    c.until = cfg.schedule.densify_until;
    c.add_points &= name != "lpm-no-add";
    c.reset = name != "lpm-no-reset";
    c.seed = cfg.seed;
    if name == "lpm-sphere" {
        c.zones.geometry = ZoneGeometry::Sphere;
    }
    if name == "lpm-additive" {
        c.prune = PruneMode::Additive;
    }
    if name == "lpm-overlap-neighbours" {
        c.matching.neighbours.choice = NeighbourChoice::Overlap;
    }
    if name == "lpm-error-blocks" {
        c.region_keypoints = RegionKeypoints::ErrorBlocks;
    }
    if name == "lpm-bounding-cone" {
        c.cone = ConeRadius::Bounding;
    }
    if name == "lpm-local-zones" {
        c.max_zone_radius = Some(1.0);
    }
    if name == "lpm-slab" {
        c.zones.geometry = ZoneGeometry::Slab;
    }
    if name == "lpm-local-resets" {
        c.reset_max_zone_radius = Some(1.0);
    }
    if let Some(p) = args.lpm_prune {
        c.prune = p;
    }
    c.regions.block = args.lpm_block;
    c.regions.keep_fraction = if name == "lpm-loose-blocks" {
        LOOSE_BLOCK_FRACTION
    } else {
        args.lpm_block_fraction
    };
    Some(c)
}

/// Indices into [`RUNS`] for the `--runs` list (all when empty), in table order.
pub fn selected_runs(names: &[String]) -> anyhow::Result<Vec<usize>> {
    if names.is_empty() {
        return Ok((0..5).collect());
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

/// What every run is scored on: the scene's test views, their images, and LPIPS if loaded.
struct TestSet<'a> {
    scene: &'a Scene,
    images: &'a dyn ImageSource,
    lpips: Option<&'a Lpips>,
}

/// Evaluates a run at iteration `iteration` on the test views and times its model at 1352×1014.
fn evaluate_run(
    ctx: &std::sync::Arc<GpuContext>,
    test: &TestSet<'_>,
    r: &Run,
    t: &mut Trainer,
    iteration: u32,
    args: &TradeArgs,
) -> anyhow::Result<TradeRow> {
    let (scene, test_images, lpips) = (test.scene, test.images, test.lpips);
    let (name, colour) = RUNS[r.k];
    // The report view's render and truth are saved at the final iteration of the first seed.
    let report = (iteration == args.iterations && r.seed == args.seed)
        .then(|| trade_report::report_view(scene, args.report_view.as_deref()))
        .transpose()?;
    let m = t.evaluate(scene, &scene.test, test_images, |k, m, render, truth| {
        lpips_scores::score_view(lpips, m, render, truth)?;
        if report == Some(k) {
            trade_report::save_view_images(&args.out, name, render, truth)?;
        }
        Ok(())
    })?;
    let lpips_mean = lpips_scores::mean(&m);
    let (psnr, ssim) = ViewMetrics::means(&m);
    let view_psnr = report.map(|k| m[k].psnr);
    let model = t.export_model()?;
    let lpm = t.strategy_as::<LpmStrategy>();
    let lpm_totals = lpm.map(|l| l.totals).unwrap_or_default();
    let lpm_steps: Vec<serde_json::Value> = lpm
        .map(|l| l.steps.iter().map(|s| s.to_json()).collect())
        .unwrap_or_default();
    let lpm_s = lpm_totals.seconds;
    // The full SpacetimeGaussians model's decoder weights, for its FPS and beside its PLY.
    let decoder: Option<Vec<f32>> = t
        .model_state()?
        .and_then(|s| serde_json::from_value(s["decoder_weights"].clone()).ok());
    let fps = fps_of(ctx, &model, decoder.as_deref(), scene, args.fps_frames)?;
    if iteration == args.iterations {
        // The final models, to view or `eval` later: `adc+lpm.ply` (`adc+lpm-seed1.ply` with
        // several seeds) and so on.
        let file = if args.seeds > 1 {
            format!("{name}-seed{}.ply", r.seed)
        } else {
            format!("{name}.ply")
        };
        let ply = args.out.join(file);
        write_ply(&ply, &model)?;
        if let Some(w) = &decoder {
            let path = lpmsplat::splats::decoder_json::path_for(&ply);
            std::fs::write(&path, lpmsplat::splats::decoder_json::to_json(w)?)?;
        }
    }
    let train_s = r.seconds;
    let row = TradeRow {
        run: name.to_string(),
        seed: r.seed,
        iteration,
        colour,
        psnr,
        ssim,
        lpips: lpips_mean,
        gaussians: model.len(),
        train_seconds: train_s,
        ms_per_iteration: 1e3 * train_s / iteration as f64,
        lpm_ms_per_iteration: 1e3 * lpm_s / iteration as f64,
        lpm_share: lpm_s / train_s.max(1e-12),
        lpm_zones: lpm_totals.zones as f64,
        lpm_lowered: lpm_totals.lowered as f64,
        lpm_added: lpm_totals.added as f64,
        lpm_reset: lpm_totals.reset as f64,
        lpm_pruned: lpm_totals.pruned as f64,
        lpm_radius: lpm_totals.radius_mean,
        fps_1352x1014: fps,
        view_psnr,
        model_events: r.model_events.clone(),
        lpm_steps,
        source: 0,
    };
    let name = if args.seeds > 1 {
        format!("{name} (seed {})", r.seed)
    } else {
        name.to_string()
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
    decoder: Option<&[f32]>,
    scene: &Scene,
    frames: usize,
) -> anyhow::Result<f64> {
    let v = &scene.views[scene.test[0]];
    let cam = CameraGpu::new(&v.camera.resized(1352, 1014), &v.pose);
    let model_gpu = GpuSplats::upload(ctx, model, model.len().max(1))?;
    // A video model: each frame is the temporal step at the view's time, then the render (and
    // the full model's decoder).
    let timed = match scene.times_of(&scene.test[..1]) {
        Some(t) if !model.extra.is_empty() => {
            let timed = TimedModel::new(ctx, &model_gpu, decoder)?;
            Some((timed, t[0]))
        }
        _ => None,
    };
    let splats = timed.as_ref().map_or(&model_gpu, |t| &t.0.instant);
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[cam])?;
    let settings = match &timed {
        Some((t, _)) => t.settings([0.0; 3]),
        None => FrameSettings::plain(splats.sh_degree, [0.0; 3]),
    };
    let mut r = Renderer::for_camera(ctx, model.len().max(1), &cam)?;
    let frame = |r: &mut Renderer| -> anyhow::Result<()> {
        if let Some((timed, t)) = &timed {
            let mut rec = Recorder::new(ctx)?;
            rec.begin()?;
            timed.record(&mut rec, &model_gpu, *t)?;
            rec.submit_and_wait()?;
        }
        r.render_blocking(splats, &cameras, 0, &cam, &settings)?;
        Ok(())
    };
    frame(&mut r)?;
    let mut ms = Vec::new();
    for _ in 0..frames.max(1) {
        let t0 = Instant::now();
        frame(&mut r)?;
        ms.push(t0.elapsed().as_secs_f64());
    }
    ms.sort_by(|a, b| a.total_cmp(b));
    Ok(1.0 / ms[ms.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_calendar_scales_the_official_schedule() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            trade: TradeArgs,
        }
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");
        let scene = Scene::load(std::path::Path::new(root), &Default::default()).unwrap();
        // The shortened calendar the LPM tables use: 3,000 iterations on a 3,000 calendar is
        // train's --densify-from 50 --densify-until 1500 --opacity-reset-interval 300
        // --lr-position-max-steps 3000.
        let args = Cli::parse_from([
            "bench",
            "scene",
            "--iterations",
            "3000",
            "--max-gaussians",
            "9",
        ]);
        let c = calendar_config(&args.trade, &scene, 3000).unwrap();
        let s = &c.schedule;
        assert_eq!(
            (s.densify_from, s.densify_until, s.opacity_reset_interval),
            (50, 1500, 300)
        );
        assert_eq!((c.iterations, c.lr.position_max_steps), (3000, 3000));
        assert_eq!(c.density.max_gaussians, Some(9));
        // The full calendar is the official schedule itself; the reset interval stays a
        // multiple of 100 and at least 100 on a short one.
        let c = calendar_config(&args.trade, &scene, 30_000).unwrap();
        let s = &c.schedule;
        assert_eq!(
            (s.densify_from, s.densify_until, s.opacity_reset_interval),
            (500, 15_000, 3000)
        );
        let c = calendar_config(&args.trade, &scene, 1000).unwrap();
        assert_eq!(c.schedule.opacity_reset_interval, 100);
    }

    #[test]
    fn each_lpm_run_gets_its_rules_and_the_benchmark_overrides() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            trade: TradeArgs,
        }
        let args = Cli::parse_from(["bench", "scene", "--lpm-block", "6", "--lpm-prune", "off"]);
        let cfg = TrainConfig {
            seed: 7,
            ..TrainConfig::default()
        };
        assert!(run_lpm_config("adc", &cfg, &args.trade).is_none());
        let ours = run_lpm_config("adc+lpm", &cfg, &args.trade).unwrap();
        let authors = run_lpm_config("lpm-authors", &cfg, &args.trade).unwrap();
        let authors_adc = run_lpm_config("lpm-authors-adc", &cfg, &args.trade).unwrap();
        assert!(!ours.skip_adc_without_zone && ours.add_points);
        assert!(authors.skip_adc_without_zone && !authors.add_points);
        // The same rules as lpm-authors but for ADC on steps without a zone.
        assert!(!authors_adc.skip_adc_without_zone);
        let mut same = authors_adc.clone();
        same.skip_adc_without_zone = true;
        assert_eq!(same, authors);
        for c in [&ours, &authors, &authors_adc] {
            assert_eq!((c.seed, c.regions.block, c.prune), (7, 6, PruneMode::Off));
            assert_eq!(
                (c.from, c.until),
                (cfg.schedule.densify_from, cfg.schedule.densify_until)
            );
        }
        let no_add = run_lpm_config("lpm-no-add", &cfg, &args.trade).unwrap();
        assert!(!no_add.add_points && no_add.reset);
        let no_reset = run_lpm_config("lpm-no-reset", &cfg, &args.trade).unwrap();
        assert!(no_reset.add_points && !no_reset.reset);
        let sphere = run_lpm_config("lpm-sphere", &cfg, &args.trade).unwrap();
        assert_eq!(sphere.zones.geometry, ZoneGeometry::Sphere);
        let plain = Cli::parse_from(["bench", "scene"]);
        let additive = run_lpm_config("lpm-additive", &cfg, &plain.trade).unwrap();
        let default = run_lpm_config("adc+lpm", &cfg, &plain.trade).unwrap();
        assert_eq!(additive.prune, PruneMode::Additive);
        assert_ne!(default.prune, PruneMode::Additive);
        let mut same = additive.clone();
        same.prune = default.prune;
        assert_eq!(same, default, "only the pruning differs");
        assert_eq!(ours.zones.geometry, ZoneGeometry::Triangulated);
        // lpm-slab: our rules but for the zone's shape.
        let slab = run_lpm_config("lpm-slab", &cfg, &plain.trade).unwrap();
        assert_eq!(slab.zones.geometry, ZoneGeometry::Slab);
        let mut same = slab.clone();
        same.zones.geometry = ZoneGeometry::Triangulated;
        assert_eq!(same, default, "only the zone geometry differs");
        // lpm-loose-blocks: our rules but for the block fraction, whatever the flag says.
        let loose = run_lpm_config("lpm-loose-blocks", &cfg, &plain.trade).unwrap();
        assert_eq!(loose.regions.keep_fraction, 0.7);
        let mut same = loose.clone();
        same.regions.keep_fraction = default.regions.keep_fraction;
        assert_eq!(same, default, "only the block fraction differs");
        let flagged = Cli::parse_from(["bench", "scene", "--lpm-block-fraction", "0.6"]);
        let loose = run_lpm_config("lpm-loose-blocks", &cfg, &flagged.trade).unwrap();
        let ours = run_lpm_config("adc+lpm", &cfg, &flagged.trade).unwrap();
        assert_eq!(
            (loose.regions.keep_fraction, ours.regions.keep_fraction),
            (0.7, 0.6)
        );
        // lpm-local-resets: our rules but for the reset's largest zone.
        let local = run_lpm_config("lpm-local-resets", &cfg, &plain.trade).unwrap();
        assert_eq!(local.reset_max_zone_radius, Some(1.0));
        let mut same = local.clone();
        same.reset_max_zone_radius = None;
        assert_eq!(same, default, "only the reset's largest zone differs");
    }

    #[test]
    fn runs_are_selected_by_name_or_alias_in_table_order() {
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(selected_runs(&[]).unwrap(), vec![0, 1, 2, 3, 4]);
        assert_eq!(
            selected_runs(&names(&["lpm", "adc-1e-4", "adc"])).unwrap(),
            vec![0, 1, 2]
        );
        assert!(selected_runs(&names(&["adc", "lpm", "adc+lpm"])).is_err());
    }
}
