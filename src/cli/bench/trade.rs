//! `bench trade SCENE`: the accuracy / size / time trade-off of LPM, run side by side on one
//! device. The runs (`--runs`, [`super::trade_runs::RUNS`]: ADC, ADC + LPM and its ablations)
//! train interleaved one iteration at a time, so their times see the same load, and are
//! evaluated at `--eval-at` and at the end. Writes `trade.json`, `trade.md` (the table, also
//! printed), `trade.png` (PSNR against Gaussians and training time, and PSNR and Gaussians
//! against iterations) and `trade.html` (with one test view's renders); `bench merge` pools
//! several such results.

use super::trade_args::{settings_json, TradeArgs};
use super::trade_runs::{
    abs_grad_applies, calendar_config, fills_budget, run_draw, run_look, run_lpm_config,
    selected_runs, RUNS,
};
use crate::cli::lpips_scores;
use crate::cli::output_folder::prepare_output;
use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use lpmsplat::bench::budget::{plan_cells, run_of, BenchBudget};
use lpmsplat::bench::report;
use lpmsplat::bench::summary::{
    column_header, guide_table, paired_table, plot, summarize, table_rows, Summary, TradeRow,
};
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::initial::initial_model;
use lpmsplat::lpips::Lpips;
use lpmsplat::lpm::config::LpmConfig;
use lpmsplat::lpm::regions::RegionSettings;
use lpmsplat::lpm::strategy::LpmStrategy;
use lpmsplat::mcmc::McmcConfig;
use lpmsplat::render::forward::{FrameSettings, Renderer};
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::render::spacetime::TimedModel;
use lpmsplat::scene::image_source::{ImageSource, ViewImages};
use lpmsplat::scene::Scene;
use lpmsplat::splats::budget_draw::Draw;
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::init::Look;
use lpmsplat::taming::BlendConfig;
use lpmsplat::train::density::growth::{BudgetCurve, Growth};
use lpmsplat::train::trainer::{TrainConfig, Trainer, ViewMetrics};
use std::io::Write;
use std::time::Instant;

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
    if args.slurm.slurm {
        return super::trade_sweep::write(args, &args.slurm);
    }
    anyhow::ensure!(
        !args.match_adc_count || selected.first().is_some_and(|&k| RUNS[k].name == "adc"),
        "bench trade --match-adc-count: the other runs follow adc's Gaussian count, but --runs \
         has no adc. Fix: add adc to --runs"
    );
    if let Some(r) = args.lpm_threshold_ratio {
        // Refused before the scene loads or the output folder is made; the runs' whole LPM
        // settings are validated again once the calendar is known.
        LpmConfig {
            threshold_ratio: r,
            ..LpmConfig::default()
        }
        .validate()?;
    }
    let lpips = args.lpips.load()?;
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    anyhow::ensure!(
        !scene.test.is_empty(),
        "{}: bench trade needs test views to measure PSNR. Fix: use a scene with a test split",
        args.scene.scene.display()
    );
    prepare_output(&args.out)?;
    let view_name = scene.views
        [scene.test[report::report_view(&scene, args.report_view.as_deref())?]]
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
    let names: Vec<&str> = RUNS.iter().map(|r| r.name).collect();
    let cells = plan_cells(&names, &selected, seeds.len(), &args.budget)?;
    let grid = cells.iter().any(|c| c.name.contains('@'));
    anyhow::ensure!(
        !(args.match_adc_count && grid),
        "bench trade: --match-adc-count follows adc's count at every iteration, a grid of          budgets (--budget with several values, or one relative to adc) holds each run to its          own. Fix: drop one of them"
    );
    let ctx = GpuContext::new(gpu)?;
    let facts = RunFacts::new(&ctx.info.name, &scene, args.lpm_block);
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
         {calendar}: densify {}..{}, reset every {}, LPM error blocks of {}, on {}",
        args.scene.scene.display(),
        scene.train.len(),
        scene.test.len(),
        args.iterations,
        base.schedule.densify_from,
        base.schedule.densify_until,
        base.schedule.opacity_reset_interval,
        facts.blocks_px(),
        ctx.info.name
    );
    // Budgets relative to adc wait for the free adc runs (the references): two phases, each
    // interleaved in itself. Otherwise one.
    let (first, rest): (Vec<usize>, Vec<usize>) =
        (0..cells.len()).partition(|&i| cells[i].reference);
    let phases: Vec<Vec<usize>> = [first, rest]
        .into_iter()
        .filter(|p| !p.is_empty())
        .collect();
    let total = args.iterations as u64 * cells.len() as u64;
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
    // Each seed's free adc count at the end, once its reference has run.
    let mut adc_final: Vec<Option<usize>> = vec![None; seeds.len()];
    let mut drawn_told = Vec::new();
    for phase in phases {
        let mut runs = Vec::new();
        for &ci in &phase {
            let c = &cells[ci];
            let (name, seed) = (RUNS[c.k].name, seeds[c.seed]);
            let initial = inits[c.seed].len();
            let target = match c.budget {
                None => None,
                Some(b) => Some(
                    args.budget[b]
                        .resolve(initial, adc_final[c.seed])
                        .with_context(|| {
                            format!("bench trade: adc's final count of seed {seed} is unknown")
                        })?,
                ),
            };
            if let Some(t) = target.filter(|&t| t < initial) {
                // A start above the budget is drawn down to it (`splats::budget_draw::draw_down`), for every
                // run at that budget and seed alike.
                if !drawn_told.contains(&(t, seed)) {
                    eprintln!(
                        "bench trade: budget {t} below the {initial} initial Gaussians of seed \
                         {seed}: the adc runs start from {t} of them, drawn at random (the same \
                         draw for each); the mcmc runs {} (mcmc-drawn's drawn at random, \
                         mcmc-spread's spread over the cloud, mcmc-keep's kept whole)",
                        match args.mcmc_draw() {
                            Draw::Keep => format!("keep their start whole, falling to {t}"),
                            d => format!("are drawn ({})", d.name()),
                        }
                    );
                    drawn_told.push((t, seed));
                }
            }
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
            // A kept start (mcmc's by default) falls from the initial count to the budget.
            let draw = run_draw(name, args.mcmc_draw());
            let start = match draw.0 {
                Draw::Keep => initial,
                _ => target.map_or(initial, |t| t.min(initial)),
            };
            let mcmc = apply_budget(name, &mut cfg, args, (start, target), calendar)?;
            runs.push(Run {
                k: c.k,
                name: c.name.clone(),
                colour: cell_colour(RUNS[c.k].colour, c.budget, args.budget.len(), grid),
                seed,
                init: c.seed,
                target,
                reference: c.reference,
                cfg,
                lpm,
                mcmc,
                blend: name.starts_with("adc-exact-blend").then(|| BlendConfig {
                    seed,
                    ..BlendConfig::default()
                }),
                draw,
                look: run_look(name),
                trainer: None,
                seconds: 0.0,
                count_sum: 0.0,
                model_events: Vec::new(),
            });
        }
        // Interleaved: every run advances one iteration per round, so each run's summed step
        // time sees the same load. Sequential: one run to the end, evaluated and dropped, then
        // the next. --match-adc-count: adc's count after each iteration, one list per seed.
        // adc comes first in `runs` (table order), so within a round, or sequentially, it has
        // run the iteration that another run of its seed is about to.
        let mut adc_counts: Vec<Vec<usize>> = vec![Vec::new(); seeds.len()];
        let groups: Vec<Vec<usize>> = if args.sequential {
            (0..runs.len()).map(|i| vec![i]).collect()
        } else {
            vec![(0..runs.len()).collect()]
        };
        for group in groups {
            for &i in &group {
                let r = &mut runs[i];
                let init = match r.target {
                    Some(t) if t < inits[r.init].len() => {
                        std::borrow::Cow::Owned(lpmsplat::splats::budget_draw::draw_down(
                            inits[r.init].clone(),
                            t,
                            r.seed,
                            r.draw.0,
                            r.draw.1,
                        ))
                    }
                    _ => std::borrow::Cow::Borrowed(&inits[r.init]),
                };
                let init = if r.look != Look::STANDARD {
                    let mut own = init.into_owned();
                    r.look.apply(&mut own);
                    std::borrow::Cow::Owned(own)
                } else {
                    init
                };
                let mut t = Trainer::new(&ctx, &scene, train_images.clone(), &init, r.cfg.clone())?;
                let strategy = lpmsplat::strategies::assemble(
                    &ctx,
                    &scene,
                    &train_images,
                    &r.cfg,
                    r.lpm.clone(),
                    lpmsplat::strategies::Base::of(r.mcmc, r.blend),
                    &args.out,
                )?;
                if let Some(s) = strategy {
                    t.set_strategy(s);
                }
                r.trainer = Some(t);
            }
            for it in 1..=args.iterations {
                for &i in &group {
                    let r = &mut runs[i];
                    let t = r.trainer.as_mut().expect("trainer built above");
                    let is_adc = RUNS[r.k].name == "adc";
                    if args.match_adc_count && !is_adc {
                        let adc = adc_counts[r.init][it as usize - 1];
                        t.set_max_gaussians(Some(
                            args.max_gaussians.map_or(adc, |cap| cap.min(adc)),
                        ));
                    }
                    if eval_at.contains(&it) {
                        t.snapshot_next_step();
                    }
                    let t0 = Instant::now();
                    // The next iteration is recorded while this one runs, unless an
                    // evaluation comes after this one or a snapshot before the next.
                    let prepare = it < args.iterations
                        && !eval_at.contains(&it)
                        && !eval_at.contains(&(it + 1));
                    let report = t.step_ahead(prepare)?;
                    r.seconds += t0.elapsed().as_secs_f64();
                    // The count after this iteration, as `train`'s metrics.json averages it.
                    r.count_sum += report.gaussians as f64;
                    if args.match_adc_count && is_adc {
                        adc_counts[r.init].push(t.state.count());
                    }
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
                                format!("{}/{} {}", r.name, r.seed, t.state.count())
                            } else {
                                format!("{} {}", r.name, t.state.count())
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
                        if r.reference && it == args.iterations {
                            adc_final[r.init] = Some(row.gaussians);
                        }
                        r.trainer = Some(t);
                        rows.push(row);
                    }
                    rows.sort_by_key(|r| row_order(r, &args.budget, &seeds));
                    write_outputs(&rows, &facts, &view_name, args)?;
                }
            }
            for &i in &group {
                runs[i].trainer = None;
            }
        }
    }
    bar.finish_and_clear();
    print!("{}", tables(&rows, &facts, args));
    println!("wrote {}", args.out.display());
    ctx.check_validation()?;
    Ok(())
}

/// What the tables say about the setting besides the arguments: the device and the LPM error
/// blocks' side in pixels over the training views (the automatic size follows each image's).
pub struct RunFacts {
    pub device: String,
    pub lpm_blocks: (u32, u32),
}

impl RunFacts {
    pub fn new(device: &str, scene: &Scene, lpm_block: u32) -> RunFacts {
        let settings = RegionSettings {
            block: lpm_block,
            ..RegionSettings::default()
        };
        let sides = scene.train.iter().map(|&v| {
            let c = &scene.views[v].camera;
            settings.resolved(c.width, c.height).block
        });
        let lpm_blocks = match sides.fold((u32::MAX, 0), |(lo, hi), b| (lo.min(b), hi.max(b))) {
            (lo, hi) if lo > hi => (lpm_block, lpm_block), // no training view
            range => range,
        };
        RunFacts {
            device: device.to_string(),
            lpm_blocks,
        }
    }

    /// "12 px", or "10–12 px" where the training images differ in size.
    fn blocks_px(&self) -> String {
        match self.lpm_blocks {
            (lo, hi) if lo == hi => format!("{lo} px"),
            (lo, hi) => format!("{lo}–{hi} px"),
        }
    }
}

/// The table: what was run, how to read it, and the rows ([`table_rows`]).
pub fn table(rows: &[Summary], facts: &RunFacts, args: &TradeArgs) -> String {
    let device = &facts.device;
    let resolution = args
        .scene
        .resolution
        .map_or("full resolution".to_string(), |r| format!("-r {r}"));
    let several = rows.iter().any(|r| r.seeds > 1);
    let s = format!(
        "bench trade: {} {resolution}, base model {}, {} iterations on the calendar of {}, {device}; LPM \
         error blocks of {} kept above {} error pixels{}\n\n{} \
         trade.png plots test PSNR against Gaussians and training seconds (top), and PSNR and \
         Gaussians against iterations (bottom), one named line per run through its evaluated \
         iterations; trade.html shows the plot, this table and the runs' renders. LPIPS is \
         AlexNet v0.1 (n/a without --lpips-weights).{}{}\n\n",
        args.scene.scene.display(),
        args.model.name(),
        args.iterations,
        args.calendar.unwrap_or(args.iterations),
        if args.lpm_block == 0 {
            format!(
                "the image's size ({} here: 16 px at 1 MP, scaled with the diagonal, at least 4)",
                facts.blocks_px()
            )
        } else {
            format!("{} px", args.lpm_block)
        },
        args.lpm_block_fraction,
        args.lpm_threshold_ratio
            .map_or(String::new(), |r| format!(", gradient threshold × {r} inside zones")),
        if args.sequential {
            "Runs were sequential: compare their times only on an otherwise idle machine."
        } else {
            "Runs were interleaved one iteration at a time, so their times saw the same machine load."
        },
        budget_sentence(args),
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

/// What the table header says of the Gaussian budget, if the runs had one.
fn budget_sentence(args: &TradeArgs) -> String {
    let follow = "Every run but adc trained under a budget of adc's count at the same seed and \
                  iteration";
    let grid = if args.budget.len() > 1
        || args
            .budget
            .iter()
            .any(|b| matches!(b, BenchBudget::TimesAdc(_)))
    {
        format!(
            " Every run trained at each budget ({}; RUN@BUDGET), x-adc of the final count of a \
             free adc of the same seed, trained first (the rows named adc): adc-exact* and mcmc \
             fill the budget exactly, the others are capped at it.",
            args.budget
                .iter()
                .map(BenchBudget::label)
                .collect::<Vec<_>>()
                .join(", ")
        )
    } else {
        String::new()
    };
    let cap = match (args.match_adc_count, args.max_gaussians) {
        (true, None) => format!(" {follow} (--match-adc-count)."),
        (true, Some(n)) => format!(" {follow}, at most {n} Gaussians (--match-adc-count)."),
        (false, Some(n)) => format!(" Every run trained under a budget of at most {n} Gaussians."),
        (false, None) => String::new(),
    };
    cap + &grid
}

/// [`table`] of the rows' summary, and with several seeds each run's per-seed differences from
/// ADC ([`paired_table`]).
fn tables(rows: &[TradeRow], facts: &RunFacts, args: &TradeArgs) -> String {
    let mut s = table(&summarize(rows), facts, args);
    if args.seeds > 1 && rows.iter().any(|r| r.run == "adc") {
        s += "\n";
        s += &paired_table(rows, "adc");
    }
    if let Some(g) = guide_table(rows) {
        s += "\n";
        s += &g;
    }
    s
}

/// Writes trade.md, trade.json and trade.png for the rows so far (atomically).
fn write_outputs(
    rows: &[TradeRow],
    facts: &RunFacts,
    view_name: &str,
    args: &TradeArgs,
) -> anyhow::Result<()> {
    let summary = summarize(rows);
    let table = tables(rows, facts, args);
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
        "device": facts.device,
        "seeds": args.seeds,
        "lpm_block": args.lpm_block,
        // The block sides the LPM runs used over the training views: [smallest, largest].
        "lpm_block_px": [facts.lpm_blocks.0, facts.lpm_blocks.1],
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
    let page = report::Page {
        title: &title,
        baseline: "adc",
        view: Some(view_name),
        sources: &[],
    };
    report::write_html(&args.out, &page, rows, &summary, &table)?;
    Ok(())
}

/// Where a row sorts: by iteration, the runs table's order, the budgets' order, the seed.
fn row_order(r: &TradeRow, budgets: &[BenchBudget], seeds: &[u64]) -> (u32, usize, usize, usize) {
    let run = RUNS
        .iter()
        .position(|n| n.name == run_of(&r.run))
        .unwrap_or(RUNS.len());
    let budget = budgets
        .iter()
        .position(|b| r.run.ends_with(&format!("@{}", b.label())))
        .map_or(0, |i| i + 1);
    let seed = seeds.iter().position(|&s| s == r.seed).unwrap_or(0);
    (r.iteration, run, budget, seed)
}

/// A cell's colour: its run's, lightened along the budgets in a grid so that one run's cells
/// stay one hue and can still be told apart in the curves.
fn cell_colour(colour: [u8; 3], budget: Option<usize>, budgets: usize, grid: bool) -> [u8; 3] {
    match budget {
        Some(b) if grid && budgets > 1 => {
            let f = 0.55 * b as f64 / (budgets - 1) as f64;
            colour.map(|c| (c as f64 + (255.0 - c as f64) * f).round() as u8)
        }
        _ => colour,
    }
}

struct Run {
    k: usize,
    /// The name its rows carry (`mcmc@0.5x-adc` in a grid) and its colour in the plots.
    name: String,
    colour: [u8; 3],
    seed: u64,
    /// Index of the run's initial model (one per seed).
    init: usize,
    /// Its budget's count (the initial model is drawn down to it where above).
    target: Option<usize>,
    /// A free adc run that budgets relative to adc's count wait for.
    reference: bool,
    cfg: TrainConfig,
    lpm: Option<LpmConfig>,
    /// MCMC's settings, for the mcmc run.
    mcmc: Option<McmcConfig>,
    /// The blended score's settings, for the adc-exact-blend runs.
    blend: Option<BlendConfig>,
    /// How a start above its budget is drawn down to it, and whether the scales are refitted.
    draw: (Draw, bool),
    /// How its start from points looks (opacity, scale factor).
    look: Look,
    trainer: Option<Trainer>,
    seconds: f64,
    /// The Gaussian counts after each iteration so far, summed (for the mean model size).
    count_sum: f64,
    /// The base model's own rules' events so far.
    model_events: Vec<serde_json::Value>,
}

/// The budget of run `name` on `cfg` (its initial model of `initial` Gaussians, the budget
/// `target` resolved before the start was drawn down to it, its calendar):
/// a cap for ADC and its LPM runs, the exact budget for adc-exact* (adc's count under
/// --match-adc-count when no --budget is given), and MCMC's settings for mcmc (returned).
fn apply_budget(
    name: &str,
    cfg: &mut TrainConfig,
    args: &TradeArgs,
    (initial, target): (usize, Option<usize>),
    calendar: u32,
) -> anyhow::Result<Option<McmcConfig>> {
    anyhow::ensure!(
        !fills_budget(name)
            || !args.budget.is_empty()
            || (args.match_adc_count && !name.starts_with("mcmc")),
        "bench trade: run {name} fills a Gaussian budget. Fix: pass --budget N (e.g. adc's final \
         count), or --match-adc-count for the adc-exact runs"
    );
    let mcmc = name.starts_with("mcmc");
    if mcmc {
        lpmsplat::mcmc::config::apply_schedule(&mut cfg.schedule, calendar, None);
    }
    if name.ends_with("lpm-lowered") {
        cfg.density.rank_lowered = true;
    }
    let window = (
        cfg.schedule.densify_from,
        cfg.schedule
            .densify_until
            .min(args.iterations.saturating_add(1)),
        cfg.schedule.interval,
    );
    let curve = |default: Growth| {
        target.map(|target| BudgetCurve {
            target,
            growth: args.budget_growth.unwrap_or(default),
            initial,
            window,
        })
    };
    if mcmc {
        let c = curve(Growth::Mcmc).expect("checked above");
        // The cap stops a guide's added points at the budget too.
        cfg.density.max_gaussians = Some(c.target);
        return Ok(Some(McmcConfig {
            seed: cfg.seed,
            ..McmcConfig::with_budget(c)
        }));
    }
    if name.starts_with("adc-exact") {
        // Without a budget the cap (adc's count, moved every iteration) decides each step.
        cfg.density.exact_budget = Some(curve(Growth::Taming).unwrap_or(BudgetCurve {
            target: usize::MAX / 4,
            growth: Growth::Linear,
            initial,
            window,
        }));
    } else if let Some(c) = curve(Growth::Taming) {
        cfg.density.max_gaussians = Some(
            cfg.density
                .max_gaussians
                .map_or(c.target, |m| m.min(c.target)),
        );
    }
    Ok(None)
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
    let (name, colour) = (r.name.as_str(), r.colour);
    // The report view's render and truth are saved at the final iteration of the first seed.
    let report = (iteration == args.iterations && r.seed == args.seed)
        .then(|| report::report_view(scene, args.report_view.as_deref()))
        .transpose()?;
    let m = t.evaluate(scene, &scene.test, test_images, |k, m, render, truth| {
        lpips_scores::score_view(lpips, m, render, truth)?;
        if report == Some(k) {
            report::save_view_images(&args.out, name, render, truth)?;
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
        let base = lpmsplat::models::BaseModel::of(&t.config);
        crate::cli::model_segment::write_model_ply(&ply, &model, base, scene)?;
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
        mean_gaussians: r.count_sum / iteration as f64,
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
        mcmc: lpmsplat::strategies::mcmc_of(t).map(|m| m.totals.to_json()),
        source: 0,
    };
    let name = if args.seeds > 1 {
        format!("{name} (seed {})", r.seed)
    } else {
        name.to_string()
    };
    eprintln!(
        "  {name} @ {iteration}: PSNR {psnr:.3} dB, SSIM {ssim:.4}, {} Gaussians ({:.0} on average \
         over the run), {train_s:.1} s, {fps:.1} FPS",
        row.gaussians, row.mean_gaussians
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
