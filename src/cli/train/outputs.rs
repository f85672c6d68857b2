//! What a finished training run writes and prints: the exported model, the test renders and
//! their scores, training.png, metrics.json, config.json and the summary on stdout.

use super::args::TrainArgs;
use super::progress::TrainingLog;
use crate::cli::lpips_scores;
use crate::cli::train_plot::{write_training_plot, EvalPoint};
use anyhow::Context;
use clap::ValueEnum;
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuContext, StageTimes};
use lpmsplat::lpips::Lpips;
use lpmsplat::lpm::config::LpmConfig;
use lpmsplat::lpm::strategy::LpmStrategy;
use lpmsplat::mcmc::McmcStrategy;
use lpmsplat::scene::image_source::ViewImages;
use lpmsplat::scene::{images, Image, Scene};
use lpmsplat::splats::write_splat;
use lpmsplat::train::trainer::{TrainConfig, Trainer, ViewMetrics};
use std::io::Write;
use std::path::Path;

/// Writes the model into `out`: point_cloud.ply, the model's own files beside it, a .splat for
/// still models, and the checkpoint. Returns the model's Gaussian count.
pub fn export(trainer: &mut Trainer, scene: &Scene, out: &Path) -> anyhow::Result<usize> {
    let base = lpmsplat::models::BaseModel::of(&trainer.config);
    let (model, shift) =
        crate::cli::model_segment::in_output_frame(&trainer.export_model()?, base, scene);
    crate::cli::model_segment::write_stored_ply(
        &out.join("point_cloud.ply"),
        &model,
        shift,
        base,
        scene,
    )?;
    for (ext, contents) in trainer.export_files()? {
        let path = out.join("point_cloud.ply").with_extension(&ext);
        std::fs::write(&path, contents).with_context(|| format!("writing {}", path.display()))?;
    }
    // A .splat holds still Gaussians: a video model's would show it at no time at all.
    // It holds what the PLY holds: positions less the PLY's shift, when it has one.
    if model.extra.is_empty() {
        write_splat(&out.join("point_cloud.splat"), &model)?;
    }
    trainer.save_checkpoint(scene, &out.join("checkpoint.bin"))?;
    Ok(model.len())
}

/// The final evaluation: scores every test view and writes its render into
/// `out/renders/test` as it is scored.
pub fn evaluate_and_render(
    trainer: &mut Trainer,
    scene: &Scene,
    test_images: &ViewImages,
    lpips: Option<&Lpips>,
    out: &Path,
) -> anyhow::Result<Vec<ViewMetrics>> {
    let render_dir = out.join("renders").join("test");
    std::fs::create_dir_all(&render_dir)
        .with_context(|| format!("creating {}", render_dir.display()))?;
    trainer.evaluate(scene, &scene.test, test_images, |k, m, r, gt| {
        lpips_scores::score_view(lpips, m, r, gt)?;
        let img = Image {
            width: gt.width,
            height: gt.height,
            rgb: r.to_vec(),
            alpha: None,
        };
        let stem = &scene.views[scene.test[k]].stem;
        images::save_png(&render_dir.join(format!("{stem}.png")), &img)
    })
}

/// A finished run, as its outputs describe it.
pub struct Finished<'a> {
    pub args: &'a TrainArgs,
    pub config: &'a TrainConfig,
    pub scene: &'a Scene,
    pub ctx: &'a GpuContext,
    pub trainer: &'a Trainer,
    pub log: &'a TrainingLog,
    pub lpm_config: Option<&'a LpmConfig>,
    /// The final evaluation's per-view scores.
    pub per_view: &'a [ViewMetrics],
    pub gaussians: usize,
    /// Wall time of the iterations, intermediate evaluations and checkpoints included.
    pub train_s: f64,
    /// Loading the scene and setting up the trainer.
    pub load_s: f64,
    pub start_iteration: u32,
    /// A resumed run's checkpoint (iteration, Gaussians).
    pub resumed_at: Option<(u32, usize)>,
    /// A fresh run's initial Gaussians.
    pub init_gaussians: usize,
}

impl Finished<'_> {
    /// Iterations this run trained (a resumed run's, not the checkpoint's).
    fn trained(&self) -> u32 {
        (self.config.iterations - self.start_iteration).max(1)
    }

    /// The training's own time: without intermediate evaluations and checkpoints.
    fn unpaused_s(&self) -> f64 {
        self.train_s - self.log.paused_s
    }

    fn psnr_ssim(&self) -> (f64, f64) {
        ViewMetrics::means(self.per_view)
    }

    /// training.png: test PSNR, Gaussians and loss against iterations and training time.
    pub fn write_plot(&self) -> anyhow::Result<()> {
        let mut points = self.log.eval_points.clone();
        if !self.per_view.is_empty() {
            points.push(EvalPoint {
                iteration: self.config.iterations,
                seconds: self.unpaused_s(),
                psnr: self.psnr_ssim().0,
                gaussians: self.gaussians,
            });
        }
        let run_name = format!(
            "{}{}",
            self.args.model.name(),
            if self.lpm_config.is_some() {
                " + LPM"
            } else {
                ""
            }
        );
        write_training_plot(
            &self.args.out.join("training.png"),
            &run_name,
            &self.log.samples,
            &points,
        )
    }

    pub fn metrics_json(&self) -> serde_json::Value {
        let (config, log, trainer, ctx) = (self.config, self.log, self.trainer, self.ctx);
        let (psnr, ssim) = self.psnr_ssim();
        let trained = self.trained() as f64;
        serde_json::json!({
            "scene": self.args.scene.scene.display().to_string(),
            "iterations": config.iterations,
            "gaussians": self.gaussians,
            // The count after each iteration, averaged over this run's iterations (a resumed
            // run's from `resumed_from`): what the model size cost over the run.
            "mean_gaussians": log.mean_gaussians(),
            "test_views": self.scene.test.len(),
            "psnr": psnr,
            "ssim": ssim,
            "lpips": lpips_scores::mean(self.per_view),
            "per_view": self.per_view,
            "evaluations": log.evals,
            "history": log.samples,
            "train_seconds": self.train_s,
            "iterations_per_second": trained / self.train_s,
            // Of train_seconds, the intermediate evaluations (--eval-every) and checkpoints
            // (--checkpoint-every): the training's own rate is without them.
            "paused_seconds": log.paused_s,
            "iterations_per_second_unpaused": trained / self.unpaused_s().max(1e-9),
            "resumed_from": self.start_iteration,
            "setup_seconds": self.load_s,
            "dropped_frames": trainer.dropped_frames,
            // Iterations submitted, how many were recorded while the previous one ran
            // (--record-ahead), and the host's recording time.
            "recording": trainer.recording,
            "image_cache": trainer.image_cache_stats(),
            "model_events": log.model_events,
            "device": ctx.info.name,
            "gpu_memory_mib": ctx.memory_in_use().1 as f64 / (1u64 << 20) as f64,
            "device_buffers_peak_mib": ctx.memory.peak() as f64 / (1u64 << 20) as f64,
            // The rasterizers' pixels per invocation when --raster-pixels set them (null: the
            // device's default).
            "raster_pixels": config.raster_pixels,
            // The loss kernels' layout when --loss-layout set it (null: the default, segments).
            "loss_layout": config.loss_layout.map(|l| l.name()),
            // The radix sorts' digit width when --sort-digits set it (null: the default, 4).
            "sort_digits": ctx.sort_digit_bits,
            "max_gaussians": config.density.max_gaussians.map(|cap| serde_json::json!({
                "cap": cap, "dropped_additions": log.budget.0, "steps_at_cap": log.budget.1,
            })),
            "stages": if config.timestamps { stage_shares(&log.stages) } else { serde_json::Value::Null },
            "lpm": trainer.strategy_as::<LpmStrategy>().map(|l| {
                let mut j = l.totals.to_json(self.train_s, config.iterations);
                j["per_step"] = l.steps.iter().map(|r| r.to_json()).collect();
                j
            }),
            "mcmc": lpmsplat::strategies::mcmc_of(trainer).map(|m| {
                let mut j = m.totals.to_json();
                j["settings"] = m.config.to_json();
                j
            }),
            "exact_budget": config.density.exact_budget.map(|b| b.to_json()),
            "blended_score": lpmsplat::strategies::blended_of(trainer).map(|b| b.totals_json()),
        })
    }

    /// Every setting the run used, and where it started from.
    pub fn config_json(&self) -> serde_json::Value {
        let args = self.args;
        let mut cfg = self.config.to_json();
        cfg["scene"] = serde_json::json!(args.scene.scene.display().to_string());
        cfg["resolution"] = serde_json::json!(args.scene.resolution);
        cfg["strategy"] = serde_json::json!(args
            .density_strategy
            .strategy
            .to_possible_value()
            .map(|v| v.get_name().to_string()));
        match (self.resumed_at, &args.resume) {
            // The checkpoint's model is not the run's initialisation: say where the run resumed.
            (Some((iteration, gaussians)), Some(p)) => {
                cfg["resumed_from"] = serde_json::json!({
                    "checkpoint": p.display().to_string(),
                    "iteration": iteration,
                    "gaussians": gaussians,
                });
            }
            _ => {
                cfg["init_points"] = serde_json::json!(self.init_gaussians);
                let sa = &args.density_strategy;
                if sa.budget.is_some() {
                    cfg["budget_draw"] = serde_json::json!({
                        "draw": sa.draw().name(),
                        "refit_scales": sa.budget_refit_scales && args.init_ply.is_none(),
                    });
                }
                cfg["init"] = serde_json::json!(format!("{:?}", args.init).to_lowercase());
                if args.init_ply.is_none() {
                    let look = args.look();
                    cfg["init_look"] =
                        serde_json::json!({"opacity": look.opacity, "scale": look.scale});
                }
            }
        }
        cfg["lpm"] = self
            .lpm_config
            .map_or(serde_json::Value::Null, |c| c.to_json());
        cfg
    }

    /// training.png, metrics.json and config.json.
    pub fn write(&self) -> anyhow::Result<()> {
        self.write_plot()?;
        for (name, json) in [
            ("metrics.json", self.metrics_json()),
            ("config.json", self.config_json()),
        ] {
            let text = serde_json::to_string_pretty(&json)?;
            write_atomic(&self.args.out.join(name), |f| {
                Ok(f.write_all(text.as_bytes())?)
            })?;
        }
        Ok(())
    }

    /// The summary on stdout: time, rate, count and scores; with --timestamps the stages'
    /// shares and the host's recording; the budget's drops; LPM's totals.
    pub fn print_summary(&self) {
        let (config, trainer) = (self.config, self.trainer);
        let trained = self.trained() as f64;
        let (psnr, ssim) = self.psnr_ssim();
        let paused_s = self.log.paused_s;
        // Intermediate evaluations and checkpoints are in the wall time; say what they took.
        let unpaused = if paused_s > 0.0 {
            format!(
                "; {:.1} s and {:.2} it/s without {:.1} s of intermediate evaluations and checkpoints",
                self.unpaused_s(),
                trained / self.unpaused_s().max(1e-9),
                paused_s
            )
        } else {
            String::new()
        };
        println!(
            "trained {} iterations in {:.1} s ({:.2} it/s{unpaused}): {} Gaussians ({:.0} on average over the run), test PSNR {:.3} dB, SSIM {:.4}{}",
            config.iterations,
            self.train_s,
            trained / self.train_s,
            self.gaussians,
            self.log.mean_gaussians(),
            psnr,
            ssim,
            lpips_scores::mean(self.per_view).map_or(String::new(), |d| format!(", LPIPS {d:.4}"))
        );
        if self.gaussians == 0 {
            // Density control may prune every Gaussian (an opacity floor above what training
            // reaches, a scene box that excludes the model); the empty PLY is still written, and
            // eval, render, mesh and export refuse it, so say why here.
            eprintln!(
                "warning: the model ended with no Gaussians: density control pruned them all \
                 (Gaussians fainter than --min-opacity {} are pruned at every density step). \
                 Fix: a lower --min-opacity, or check the scene's scale and the learning rates",
                config.density.min_opacity
            );
        }
        if config.timestamps {
            let stages = &self.log.stages;
            let total = stages.total_ms().max(1e-12);
            for (n, ms) in &stages.stages {
                println!(
                    "  {n:<20} {:>6.1}%  ({:.2} ms/it)",
                    100.0 * ms / total,
                    ms / trained
                );
            }
            println!(
                "  the stages sum to {:.2} ms/it of {:.2} ms/it wall (the rest: host work, \
                 submission, waits, evaluation and checkpoints)",
                total / trained,
                1e3 * self.train_s / trained
            );
            let r = trainer.recording;
            println!(
                "  host recording {:.3} ms/it; {} of {} iterations recorded while the one before ran \
                 (--record-ahead {}); {} prepared ones dropped and recorded again",
                1e3 * r.seconds / r.iterations.max(1) as f64,
                r.ahead,
                r.iterations,
                self.args.record_ahead.name(),
                r.dropped
            );
        }
        let mcmc = trainer.strategy_as::<McmcStrategy>().or_else(|| {
            let lpm = trainer.strategy_as::<LpmStrategy>()?;
            lpm.inner().as_any().downcast_ref::<McmcStrategy>()
        });
        match (mcmc, config.density.max_gaussians) {
            (Some(m), _) => println!(
                "  MCMC to {} Gaussians ({} growth): {} refinements, {} dead Gaussians relocated \
                 ({} onto LPM's surface samples), {} added, {} of the least opaque removed",
                m.config.budget.target,
                m.config.budget.growth.name(),
                m.totals.refinements,
                m.totals.relocated + m.totals.seeded,
                m.totals.seeded,
                m.totals.added,
                m.totals.removed
            ),
            (None, Some(cap)) => println!(
                "  Gaussian budget {cap}{}: {} clones and splits dropped on {} density steps",
                match config.density.exact_budget {
                    Some(b) => format!(" (exact, {} growth)", b.growth.name()),
                    None => String::new(),
                },
                self.log.budget.0,
                self.log.budget.1
            ),
            (None, None) => {
                if let Some(b) = config.density.exact_budget {
                    println!(
                        "  exact budget {} ({} growth): {} candidates dropped on {} density steps",
                        b.target,
                        b.growth.name(),
                        self.log.budget.0,
                        self.log.budget.1
                    );
                }
            }
        }
        if let Some(l) = trainer.strategy_as::<LpmStrategy>() {
            let t = &l.totals;
            println!(
                "  LPM: {} steps ({} with zones), {} error regions, {} paired, {} zones{}, {} \
                 densified by the lowered threshold, {} extra prunes, {} opacity resets, {} added; \
                 {:.2} s = {:.2} % of training ({:.3} ms/it); zone radius mean {:.3} / largest {:.3} \
                 scene extents",
                t.steps,
                t.steps_with_zones,
                t.regions,
                t.paired,
                t.zones,
                if t.wide > 0 {
                    format!(" (and {} wider than the largest radius, dropped)", t.wide)
                } else {
                    String::new()
                },
                t.lowered,
                t.pruned,
                t.reset,
                t.added,
                t.seconds,
                100.0 * t.seconds / self.train_s.max(1e-12),
                1e3 * t.seconds / config.iterations as f64,
                t.radius_mean,
                t.radius_max
            );
        }
    }
}

fn stage_shares(t: &StageTimes) -> serde_json::Value {
    let total = t.total_ms().max(1e-12);
    serde_json::Value::Array(
        t.stages
            .iter()
            .map(|(n, ms)| serde_json::json!({"stage": n, "ms_total": ms, "share": ms / total}))
            .collect(),
    )
}
