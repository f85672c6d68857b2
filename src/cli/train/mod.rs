//! `train`: fits Gaussians to a scene's training views on the GPU and writes the output folder:
//! `point_cloud.ply` (Inria layout), `renders/test/*.png`, `metrics.json`, `config.json`.
//! The flags are in `args`, what comes before the first iteration in `setup`, the record kept
//! while training in `progress`, and what a finished run writes in `outputs`.

mod args;
mod outputs;
mod progress;
mod setup;
pub(crate) mod strategy_args;

pub use args::TrainArgs;
use lpmsplat::initial::initial_model;

pub use strategy_args::StrategyName;

use super::lpips_scores;
use args::{check_flags, RecordAhead};
use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::scene::image_source::ViewImages;
use lpmsplat::scene::Scene;
use lpmsplat::splats::budget_draw::Draw;
use lpmsplat::splats::init::Look;
use lpmsplat::train::nan_check::NonFiniteCheck;
use lpmsplat::train::trainer::Trainer;
use outputs::Finished;
use progress::TrainingLog;
use setup::{resume_hint, save_after_oom};
use std::time::Instant;

/// `--budget-draw keep` (MCMC's default): the start is kept whole and the strategy's curve falls to the budget.
fn sa_keeps(args: &TrainArgs) -> bool {
    args.density_strategy.draw() == Draw::Keep
}

pub fn run(gpu: &GpuOptions, args: &TrainArgs) -> anyhow::Result<()> {
    check_flags(args)?;
    args.density_strategy.check(args.model)?;
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    let config = args.config(&scene)?;
    let lpm_config = args.lpm.config(&config.schedule, args.seed)?;
    let lpips = args.lpips.load()?;
    crate::cli::output_folder::prepare_output(&args.out)?;
    let checkpoint_path = args.out.join("checkpoint.bin");
    let t_load = Instant::now();
    let train_images = args.images.train_images(&scene)?;
    let test_images = ViewImages::new(&scene, &scene.test)?;
    let resumed = match &args.resume {
        Some(p) => Some(lpmsplat::train::checkpoint::Checkpoint::read(p)?),
        None => None,
    };
    if let (Some(ck), Some(p)) = (&resumed, &args.resume) {
        anyhow::ensure!(
            ck.iteration < config.iterations,
            "{}: iteration: the checkpoint is already at iteration {}, and --iterations is {}. \
             Fix: pass --iterations above {} to train further",
            p.display(),
            ck.iteration,
            config.iterations,
            ck.iteration
        );
    }
    let init = match &resumed {
        Some(ck) => ck.params(),
        None => initial_model(
            args.model,
            &scene,
            args.init_ply.as_deref(),
            args.init,
            args.init_points,
            args.seed,
            config.sh_degree,
        )?,
    };
    // The budget, resolved against the model as it starts (a resumed run's from its first
    // run's); a start above it is drawn down to it.
    let target = args.density_strategy.budget.map(|b| {
        resumed
            .as_ref()
            .and_then(|ck| strategy_args::budget_from_checkpoint(&ck.config_json, "target"))
            .unwrap_or_else(|| b.resolve(init.len()))
    });
    let init = match target {
        Some(t) if resumed.is_none() && t < init.len() && sa_keeps(args) => {
            eprintln!(
                "budget {t} below the {} initial Gaussians: starting from all of them; mcmc \
                 removes the least opaque along the densify window down to {t}",
                init.len()
            );
            init
        }
        Some(t) if resumed.is_none() && t < init.len() => {
            let sa = &args.density_strategy;
            let refit = sa.budget_refit_scales && args.init_ply.is_none();
            eprintln!(
                "budget {t} below the {} initial Gaussians: starting from {t} of them, drawn \
                 {}{}",
                init.len(),
                match sa.draw() {
                    Draw::Random => "at random",
                    Draw::Spread => "spread over the cloud",
                    Draw::Keep => "(kept)",
                },
                if refit { ", scales refitted" } else { "" }
            );
            lpmsplat::splats::budget_draw::draw_down(init, t, args.seed, sa.draw(), refit)
        }
        _ => init,
    };
    // After the draw, so that a refit works from the scales the points were given.
    let init = if resumed.is_none() && args.init_ply.is_none() && args.look() != Look::STANDARD {
        let mut init = init;
        args.look().apply(&mut init);
        init
    } else {
        init
    };
    let ctx = GpuContext::new(gpu)?;
    // From here on Ctrl-C is polled after each iteration (and saves a checkpoint).
    super::interrupt::install();
    eprintln!(
        "{}: {} training / {} test views at {}×{}, {} initial Gaussians, {} on {}",
        args.scene.scene.display(),
        scene.train.len(),
        scene.test.len(),
        scene.views[scene.train[0]].camera.width,
        scene.views[scene.train[0]].camera.height,
        init.len(),
        config.background.describe(),
        ctx.info.name
    );
    // The budget's curve starts from the initial count (a resumed run's from its first run's).
    let mut config = config;
    let initial = resumed
        .as_ref()
        .and_then(|ck| strategy_args::budget_from_checkpoint(&ck.config_json, "initial"))
        .unwrap_or(init.len());
    let strategy_args = &args.density_strategy;
    let curve = strategy_args.curve(initial, target, &config.schedule, config.iterations);
    match (strategy_args.strategy, curve) {
        (StrategyName::Adc, Some(c)) => {
            config.density.max_gaussians = Some(
                config
                    .density
                    .max_gaussians
                    .map_or(c.target, |m| m.min(c.target)),
            );
        }
        (StrategyName::AdcExact, c) => config.density.exact_budget = c,
        // MCMC keeps its own budget; the cap stops a guide's added points there too.
        (StrategyName::Mcmc, Some(c)) => {
            config.density.max_gaussians = Some(
                config
                    .density
                    .max_gaussians
                    .map_or(c.target, |m| m.min(c.target)),
            );
        }
        _ => {}
    }
    let trainer = match (&resumed, &args.resume) {
        (Some(ck), Some(p)) => {
            Trainer::restore(&ctx, &scene, train_images.clone(), config.clone(), ck, p)
                .inspect(|t| eprintln!("resuming {} at iteration {}", p.display(), t.iteration))
        }
        _ => Trainer::new(&ctx, &scene, train_images.clone(), &init, config.clone()),
    };
    let mut trainer = trainer.map_err(|e| match lpmsplat::gpu::out_of_memory(&e) {
        Some(oom) => anyhow::anyhow!(
            "setting up the training: {oom}. Fix: a device with more memory or a higher \
             --memory-limit, or less to hold: a coarser -r, fewer initial Gaussians \
             (--init-points), --image-cache MIB to stream the training images; or train the \
             scene as blocks that each fit (lpmsplat partition SCENE --memory MIB, \
             docs/partition.md)"
        ),
        None => e,
    })?;
    let resumed_at = resumed.as_ref().map(|ck| (ck.iteration, init.len()));
    drop(resumed);
    let mut nan_check = match args.nan_check {
        Some(_) => Some(NonFiniteCheck::new(&ctx)?),
        None => None,
    };
    let mcmc = match (strategy_args.strategy, curve) {
        (StrategyName::Mcmc, Some(c)) => Some(strategy_args.mcmc(c, args.seed)),
        _ => None,
    };
    let strategy = lpmsplat::strategies::assemble(
        &ctx,
        &scene,
        &train_images,
        &config,
        lpm_config.clone(),
        lpmsplat::strategies::Base::of(mcmc, strategy_args.blend(args.seed)),
        &args.out,
    )?;
    if let Some(s) = strategy {
        trainer.set_strategy(s);
    }
    let loss_masks = lpmsplat::scene::loss_masks::for_scene(&scene)?;
    if let Some((masks, share)) = &loss_masks {
        eprintln!(
            "loss masks ({}): the training views learn from {:.1} % of their pixels on average",
            lpmsplat::scene::loss_masks::LOSS_MASKS_FILE,
            100.0 * share
        );
        trainer.set_loss_masks(masks)?;
    }
    if let Some(p) = &args.resume {
        trainer.check_resumed_strategy(p)?;
    }
    let load_s = t_load.elapsed().as_secs_f64();
    let cache = trainer.image_cache_stats();
    eprintln!("training images: {}", cache.describe());
    // Recording a step while the one before runs needs slots for both steps' images.
    let per_step = config.batch_views.max(1) as usize;
    if args.record_ahead == RecordAhead::On && !cache.resident && cache.slots < 2 * per_step {
        let slot = cache.bytes as f64 / cache.slots.max(1) as f64;
        let need = (2 * per_step) as f64 * slot / (1u64 << 20) as f64;
        eprintln!(
            "note: the image cache's {} slots hold fewer than two steps' {} images, so each \
             iteration is recorded after the one before ends (slower on a GPU). Fix: \
             --image-cache {:.2} or more",
            cache.slots,
            2 * per_step,
            (need * 100.0).ceil() / 100.0
        );
    }
    let start_iteration = trainer.iteration;
    let mut log = TrainingLog::new(config.iterations, start_iteration);
    for _ in start_iteration..config.iterations {
        let next = trainer.iteration + 1;
        if next == config.iterations || (args.eval_every > 0 && next % args.eval_every == 0) {
            // Evaluate and export the model as it stands before this iteration's density
            // control, as the reference does.
            trainer.snapshot_next_step();
        }
        // Record the iteration after `next` while `next` runs, unless the host has work
        // between them (an evaluation or checkpoint after `next`, a snapshot before the one
        // after, the end).
        let snapshot_after = |k: u32| {
            k == config.iterations || (args.eval_every > 0 && k.is_multiple_of(args.eval_every))
        };
        let prepare = args.record_ahead == RecordAhead::On
            && next < config.iterations
            && !snapshot_after(next)
            && !snapshot_after(next + 1)
            && (args.checkpoint_every == 0 || !next.is_multiple_of(args.checkpoint_every));
        let r = match trainer.step_ahead(prepare) {
            Ok(r) => r,
            Err(e) => {
                log.abandon();
                return Err(match lpmsplat::gpu::out_of_memory(&e) {
                    Some(oom) => save_after_oom(&mut trainer, &scene, args, oom),
                    None => e,
                });
            }
        };
        log.record(&r);
        if let (Some(check), Some(every)) = (nan_check.as_mut(), args.nan_check) {
            if r.iteration % every == 0 || r.iteration == config.iterations {
                check.check(&trainer.state.params, r.iteration)?;
            }
        }
        if super::interrupt::requested() {
            log.abandon();
            // The next iteration may be recorded already: run it, and save after it.
            let r = match trainer.has_prepared() {
                true => trainer.step()?,
                false => r,
            };
            trainer.save_checkpoint(&scene, &checkpoint_path)?;
            crate::cli::model_segment::write_model_ply(
                &args.out.join("point_cloud.ply"),
                &trainer.export_model()?,
                lpmsplat::models::BaseModel::of(&trainer.config),
                &scene,
            )?;
            anyhow::bail!(
                "interrupted (Ctrl-C or SIGTERM) after iteration {}: wrote {} and {}. To continue: {}",
                r.iteration,
                checkpoint_path.display(),
                args.out.join("point_cloud.ply").display(),
                resume_hint(&checkpoint_path)
            );
        }
        if args.checkpoint_every > 0
            && r.iteration % args.checkpoint_every == 0
            && r.iteration < config.iterations
        {
            log.paused(|| trainer.save_checkpoint(&scene, &checkpoint_path))?;
        }
        if args.eval_every > 0
            && r.iteration % args.eval_every == 0
            && r.iteration < config.iterations
            && !scene.test.is_empty()
        {
            let gaussians = trainer.gaussians();
            log.evaluation(r.iteration, gaussians, || {
                let m = trainer.evaluate(&scene, &scene.test, &test_images, |_, m, r, gt| {
                    lpips_scores::score_view(lpips.as_ref(), m, r, gt)
                })?;
                let lp = lpips_scores::mean(&m);
                Ok((m, lp))
            })?;
        }
    }
    log.finish();
    let train_s = log.elapsed_s();
    let gaussians = outputs::export(&mut trainer, &scene, &args.out)?;
    let per_view = outputs::evaluate_and_render(
        &mut trainer,
        &scene,
        &test_images,
        lpips.as_ref(),
        &args.out,
    )?;
    if let Some(e) = lpmsplat::train::trainer::ViewMetrics::invalid(&per_view) {
        // No metrics.json, training.png or summary: nothing that reads as a finished run.
        return Err(e.context(format!(
            "training finished but its evaluation failed; {} holds the model",
            args.out.join("point_cloud.ply").display()
        )));
    }
    let finished = Finished {
        args,
        config: &config,
        scene: &scene,
        ctx: &ctx,
        trainer: &trainer,
        log: &log,
        lpm_config: lpm_config.as_ref(),
        per_view: &per_view,
        gaussians,
        train_s,
        load_s,
        start_iteration,
        resumed_at,
        init_gaussians: init.len(),
    };
    finished.write()?;
    finished.print_summary();
    println!("wrote {}", args.out.display());
    ctx.check_validation()?;
    Ok(())
}
