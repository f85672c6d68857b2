//! The `bench trade` harness: the accuracy / size / time trade-off of LPM, run side by side on
//! one device. The runs ([`TradeSettings::runs`], [`crate::bench::runs::RUNS`]: ADC, ADC + LPM
//! and its ablations, configured by [`run_config`]) train interleaved one iteration at a time,
//! so their times see the same load, and are evaluated ([`evaluate`]) at
//! [`TradeSettings::eval_at`] and at the end. [`run`] writes `trade.json`, `trade.md` (the
//! table, also printed), `trade.png` (PSNR against Gaussians and training time, and PSNR and
//! Gaussians against iterations) and `trade.html` (with one test view's renders)
//! ([`outputs`]); `bench merge` pools several such results. The command line (`bench trade`)
//! only turns its flags into [`TradeSettings`] and calls [`run`].

mod cell;
mod evaluate;
mod outputs;
pub mod run_config;
mod settings;

pub use run_config::runs_to_train;
pub use settings::TradeSettings;

use crate::bench::budget::{plan_cells, run_of, BenchBudget};
use crate::bench::report;
use crate::bench::runs::RUNS;
use crate::bench::summary::TradeRow;
use crate::error::prepare_output;
use crate::gpu::{GpuContext, GpuOptions};
use crate::initial::initial_model;
use crate::lpips::Lpips;
use crate::lpm::config::LpmConfig;
use crate::scene::image_source::{TrainImages, ViewImages};
use crate::scene::Scene;
use crate::splats::budget_draw::Draw;
use crate::train::trainer::TrainConfig;
use anyhow::Context;
use cell::Run;
use evaluate::{evaluate_run, TestSet};
use indicatif::{ProgressBar, ProgressStyle};
use outputs::{tables, write_outputs, RunFacts};
use run_config::calendar_config;
use std::time::Instant;

/// Runs the benchmark `settings` describes on the device `gpu` chooses: checks the settings,
/// loads the scene, trains every run × seed × budget cell, evaluating each at `eval_at` and at
/// the end, and writes the outputs into `settings.out` after every evaluation (progress on
/// stderr, the final table on stdout).
pub fn run(gpu: &GpuOptions, settings: &TradeSettings) -> anyhow::Result<()> {
    let selected = runs_to_train(settings.iterations, settings.seeds, &settings.runs)?;
    anyhow::ensure!(
        !settings.match_adc_count || selected.first().is_some_and(|&k| RUNS[k].name == "adc"),
        "bench trade --match-adc-count: the other runs follow adc's Gaussian count, but --runs \
         has no adc. Fix: add adc to --runs"
    );
    if let Some(r) = settings.lpm_threshold_ratio {
        // Refused before the scene loads or the output folder is made; the runs' whole LPM
        // settings are validated again once the calendar is known.
        LpmConfig {
            threshold_ratio: r,
            ..LpmConfig::default()
        }
        .validate()?;
    }
    let lpips = settings
        .lpips_weights
        .as_deref()
        .map(Lpips::load)
        .transpose()?;
    let scene = Scene::load(&settings.scene, &settings.load_options)?;
    anyhow::ensure!(
        !scene.test.is_empty(),
        "{}: bench trade needs test views to measure PSNR. Fix: use a scene with a test split",
        settings.scene.display()
    );
    prepare_output(&settings.out)?;
    let view_name = scene.views
        [scene.test[report::report_view(&scene, settings.report_view.as_deref())?]]
    .name
    .clone();
    let train_images = TrainImages::within_cache(&scene, settings.image_cache_mib)?;
    let test_images = ViewImages::new(&scene, &scene.test)?;
    let seeds: Vec<u64> = (0..settings.seeds as u64)
        .map(|i| settings.seed + i)
        .collect();
    // The model's own colour degree (SpacetimeGaussians lite: none), 3 otherwise.
    let sh_degree = {
        let mut c = TrainConfig::default();
        settings.model.configure(&mut c);
        c.sh_degree
    };
    let inits = seeds
        .iter()
        .map(|&seed| {
            initial_model(
                settings.model,
                &scene,
                None,
                settings.init,
                settings.init_points,
                seed,
                sh_degree,
            )
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let names: Vec<&str> = RUNS.iter().map(|r| r.name).collect();
    let cells = plan_cells(&names, &selected, seeds.len(), &settings.budget)?;
    let grid = cells.iter().any(|c| c.name.contains('@'));
    anyhow::ensure!(
        !(settings.match_adc_count && grid),
        "bench trade: --match-adc-count follows adc's count at every iteration, a grid of \
         budgets (--budget with several values, or one relative to adc) holds each run to its \
         own. Fix: drop one of them"
    );
    let ctx = GpuContext::new(gpu)?;
    let facts = RunFacts::new(&ctx.info.name, &scene, settings.lpm_block);
    let calendar = settings.calendar.unwrap_or(settings.iterations);
    anyhow::ensure!(
        calendar > 0,
        "bench trade: --calendar 0. Fix: pass the run length whose schedule to follow"
    );
    let mut eval_at: Vec<u32> = settings
        .eval_at
        .iter()
        .copied()
        .filter(|&i| i > 0 && i < settings.iterations)
        .chain([settings.iterations])
        .collect();
    eval_at.sort_unstable();
    eval_at.dedup();
    let base = calendar_config(settings, &scene, calendar)?;
    eprintln!(
        "bench trade: {} ({} train / {} test views), {} iterations per run on the calendar of \
         {calendar}: densify {}..{}, reset every {}, LPM error blocks of {}, on {}",
        settings.scene.display(),
        scene.train.len(),
        scene.test.len(),
        settings.iterations,
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
    let total = settings.iterations as u64 * cells.len() as u64;
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
            let seed = seeds[c.seed];
            let initial = inits[c.seed].len();
            let target = match c.budget {
                None => None,
                Some(b) => Some(
                    settings.budget[b]
                        .resolve(initial, adc_final[c.seed])
                        .with_context(|| {
                            format!("bench trade: adc's final count of seed {seed} is unknown")
                        })?,
                ),
            };
            if let Some(t) = target.filter(|&t| t < initial) {
                // A start above the budget is drawn down to it
                // (`splats::budget_draw::draw_down`), for every run at that budget and seed alike.
                if !drawn_told.contains(&(t, seed)) {
                    eprintln!(
                        "bench trade: budget {t} below the {initial} initial Gaussians of seed \
                         {seed}: the adc runs start from {t} of them, drawn at random (the same \
                         draw for each); the mcmc runs {} (mcmc-drawn's drawn at random, \
                         mcmc-spread's spread over the cloud, mcmc-keep's kept whole)",
                        match settings.mcmc_draw() {
                            Draw::Keep => format!("keep their start whole, falling to {t}"),
                            d => format!("are drawn ({})", d.name()),
                        }
                    );
                    drawn_told.push((t, seed));
                }
            }
            runs.push(Run::configure(
                c,
                seed,
                (initial, target),
                &base,
                calendar,
                grid,
                settings,
            )?);
        }
        // Interleaved: every run advances one iteration per round, so each run's summed step
        // time sees the same load. Sequential: one run to the end, evaluated and dropped, then
        // the next. --match-adc-count: adc's count after each iteration, one list per seed.
        // adc comes first in `runs` (table order), so within a round, or sequentially, it has
        // run the iteration that another run of its seed is about to.
        let mut adc_counts: Vec<Vec<usize>> = vec![Vec::new(); seeds.len()];
        let groups: Vec<Vec<usize>> = if settings.sequential {
            (0..runs.len()).map(|i| vec![i]).collect()
        } else {
            vec![(0..runs.len()).collect()]
        };
        for group in groups {
            for &i in &group {
                let r = &mut runs[i];
                r.start(&ctx, &scene, &train_images, &inits[r.init], settings)?;
            }
            for it in 1..=settings.iterations {
                for &i in &group {
                    let r = &mut runs[i];
                    let t = r.trainer.as_mut().expect("trainer built above");
                    let is_adc = RUNS[r.k].name == "adc";
                    if settings.match_adc_count && !is_adc {
                        let adc = adc_counts[r.init][it as usize - 1];
                        t.set_max_gaussians(Some(
                            settings.max_gaussians.map_or(adc, |cap| cap.min(adc)),
                        ));
                    }
                    if eval_at.contains(&it) {
                        t.snapshot_next_step();
                    }
                    let t0 = Instant::now();
                    // The next iteration is recorded while this one runs, unless an
                    // evaluation comes after this one or a snapshot before the next.
                    let prepare = it < settings.iterations
                        && !eval_at.contains(&it)
                        && !eval_at.contains(&(it + 1));
                    let report = t.step_ahead(prepare)?;
                    r.seconds += t0.elapsed().as_secs_f64();
                    // The count after this iteration, as `train`'s metrics.json averages it.
                    r.count_sum += report.gaussians as f64;
                    if settings.match_adc_count && is_adc {
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
                            evaluate_run(&ctx, &test, r, &mut t, it, settings)
                        })?;
                        if r.reference && it == settings.iterations {
                            adc_final[r.init] = Some(row.gaussians);
                        }
                        r.trainer = Some(t);
                        rows.push(row);
                    }
                    rows.sort_by_key(|r| row_order(r, &settings.budget, &seeds));
                    write_outputs(&rows, &facts, &view_name, settings)?;
                }
            }
            for &i in &group {
                runs[i].trainer = None;
            }
        }
    }
    bar.finish_and_clear();
    print!("{}", tables(&rows, &facts, settings));
    println!("wrote {}", settings.out.display());
    ctx.check_validation()?;
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
