//! Scoring a run: its test PSNR, SSIM and LPIPS, its size and LPM's and MCMC's telemetry so far
//! (a row of trade.json), its model's frame rate at 1352×1014, and at the end its PLY.

use super::cell::Run;
use super::TradeSettings;
use crate::bench::report;
use crate::bench::summary::TradeRow;
use crate::gpu::{GpuBuffer, GpuContext, Recorder};
use crate::lpips::{scores, Lpips};
use crate::lpm::strategy::LpmStrategy;
use crate::render::forward::{FrameSettings, Renderer};
use crate::render::layout::CameraGpu;
use crate::render::spacetime::TimedModel;
use crate::scene::image_source::ImageSource;
use crate::scene::Scene;
use crate::splats::gpu::GpuSplats;
use crate::train::trainer::{Trainer, ViewMetrics};
use std::time::Instant;

/// What every run is scored on: the scene's test views, their images, and LPIPS if loaded.
pub(super) struct TestSet<'a> {
    pub scene: &'a Scene,
    pub images: &'a dyn ImageSource,
    pub lpips: Option<&'a Lpips>,
}

/// Evaluates a run at iteration `iteration` on the test views and times its model at 1352×1014.
pub(super) fn evaluate_run(
    ctx: &std::sync::Arc<GpuContext>,
    test: &TestSet<'_>,
    r: &Run,
    t: &mut Trainer,
    iteration: u32,
    settings: &TradeSettings,
) -> anyhow::Result<TradeRow> {
    let (scene, test_images, lpips) = (test.scene, test.images, test.lpips);
    let (name, colour) = (r.name.as_str(), r.colour);
    // The report view's render and truth are saved at the final iteration of the first seed.
    let report = (iteration == settings.iterations && r.seed == settings.seed)
        .then(|| report::report_view(scene, settings.report_view.as_deref()))
        .transpose()?;
    let m = t.evaluate(scene, &scene.test, test_images, |k, m, render, truth| {
        scores::score_view(lpips, m, render, truth)?;
        if report == Some(k) {
            report::save_view_images(&settings.out, name, render, truth)?;
        }
        Ok(())
    })?;
    let lpips_mean = scores::mean(&m);
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
    let fps = fps_of(ctx, &model, decoder.as_deref(), scene, settings.fps_frames)?;
    if iteration == settings.iterations {
        // The final models, to view or `eval` later: `adc+lpm.ply` (`adc+lpm-seed1.ply` with
        // several seeds) and so on.
        let file = if settings.seeds > 1 {
            format!("{name}-seed{}.ply", r.seed)
        } else {
            format!("{name}.ply")
        };
        let ply = settings.out.join(file);
        let base = crate::models::BaseModel::of(&t.config);
        crate::models::output::write_model_ply(&ply, &model, base, scene)?;
        if let Some(w) = &decoder {
            let path = crate::splats::decoder_json::path_for(&ply);
            std::fs::write(&path, crate::splats::decoder_json::to_json(w)?)?;
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
        mcmc: crate::strategies::mcmc_of(t).map(|m| m.totals.to_json()),
        source: 0,
    };
    let name = if settings.seeds > 1 {
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
    model: &crate::splats::GaussianParams,
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
