//! What leaves the trainer: renders of the model, its scores on test views, the model itself
//! (for viewers: Mip-Splatting's 3D filter folded in) and, for tests, its gradients.

use super::{snapshot_or, Trainer};
use crate::scene::image_source::{load_range, ImageSource};
use crate::scene::{Image, Scene};
use crate::splats::GaussianParams;
use crate::train::passes::FrameArgs;

/// Per-view evaluation result.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ViewMetrics {
    pub view: String,
    pub psnr: f64,
    pub ssim: f64,
    /// Filled in by callers that have LPIPS weights (the trainer has none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f64>,
}

impl ViewMetrics {
    /// An error naming every view of `metrics` whose score is not a number (NaN, or a PSNR
    /// of −∞; +∞ is an exact render): a run whose scores cannot be trusted must not end as
    /// if it had succeeded. `None` when every score is valid.
    pub fn invalid(metrics: &[ViewMetrics]) -> Option<anyhow::Error> {
        let bad: Vec<String> = metrics
            .iter()
            .filter(|m| {
                m.psnr.is_nan()
                    || m.psnr == f64::NEG_INFINITY
                    || !m.ssim.is_finite()
                    || m.lpips.is_some_and(|l| !l.is_finite())
            })
            .map(|m| format!("{} (PSNR {}, SSIM {})", m.view, m.psnr, m.ssim))
            .collect();
        (!bad.is_empty()).then(|| {
            anyhow::anyhow!(
                "the evaluation gave scores that are not numbers for {} of {} views: {}. The \
                 renders or the images of those views hold NaN (a camera whose pose or \
                 intrinsics are degenerate, or a model that diverged). Fix: check those views \
                 with `lpmsplat info SCENE` and the model with `lpmsplat info --ply`; rerun \
                 with --nan-check to find the iteration a NaN appears",
                bad.len(),
                metrics.len(),
                bad[..bad.len().min(8)].join(", ")
            )
        })
    }

    /// PSNR and SSIM of a clamped render against its composited truth (RGB interleaved).
    pub fn of(view: &str, render: &[f32], truth: &Image) -> anyhow::Result<ViewMetrics> {
        let (w, h) = (truth.width as usize, truth.height as usize);
        Ok(ViewMetrics {
            view: view.to_string(),
            psnr: crate::metrics::psnr(render, &truth.rgb)?,
            ssim: crate::metrics::ssim(render, &truth.rgb, w, h)?,
            lpips: None,
        })
    }

    /// The mean PSNR and SSIM over `views` (NaN for none).
    pub fn means(views: &[ViewMetrics]) -> (f64, f64) {
        if views.is_empty() {
            return (f64::NAN, f64::NAN);
        }
        let n = views.len() as f64;
        (
            views.iter().map(|v| v.psnr).sum::<f64>() / n,
            views.iter().map(|v| v.ssim).sum::<f64>() / n,
        )
    }
}

/// Test images decoded at once by [`Trainer::evaluate`] (in parallel, then dropped).
const EVAL_CHUNK: usize = 8;

impl Trainer {
    /// The last step's gradients (the batch mean when batched), downloaded: for tests and
    /// debugging.
    pub fn gradients(&self) -> anyhow::Result<GaussianParams> {
        self.grads.download()
    }

    pub fn model(&self) -> anyhow::Result<GaussianParams> {
        self.eval_params().download()
    }

    /// The model to export for viewers: Mip-Splatting's 3D filter folded into scales and
    /// opacity (as the official `create_fused_ply.py`; the 2D filter cannot be folded, so
    /// render it with `--model mip-splatting`); other models as [`Trainer::model`].
    pub fn export_model(&mut self) -> anyhow::Result<GaussianParams> {
        self.assert_nothing_prepared("export_model");
        let model = self.model()?;
        let params = snapshot_or(
            &self.snapshot,
            self.snapshot_iteration,
            self.iteration,
            &self.state.params,
        );
        self.passes
            .export(params, &self.cameras, self.iteration, model)
    }

    /// Renders view `view` of the scene with the current model (RGB interleaved).
    pub fn render_view(&mut self, view: usize, background: [f32; 3]) -> anyhow::Result<Vec<f32>> {
        self.assert_nothing_prepared("render_view");
        let cam = self.cameras_host[view];
        // Field by field (not `eval_params`): the passes are borrowed mutably below.
        let params = snapshot_or(
            &self.snapshot,
            self.snapshot_iteration,
            self.iteration,
            &self.state.params,
        );
        self.passes.render_view(&FrameArgs {
            params,
            cameras: &self.cameras,
            view: view as u32,
            camera: &cam,
            sh_degree: self.config.sh_degree,
            background,
            iteration: self.iteration,
        })
    }

    /// PSNR and SSIM of every view in `views` against `images` (image `k` is that of
    /// `views[k]`, composited on the evaluation background). `each` sees every view's metrics,
    /// clamped render and composited truth as they are made (LPIPS, saving renders): images are
    /// decoded a few at a time and nothing is kept, so a video's thousands of test frames take
    /// the memory of a handful.
    pub fn evaluate(
        &mut self,
        scene: &Scene,
        views: &[usize],
        images: &dyn ImageSource,
        mut each: impl FnMut(usize, &mut ViewMetrics, &[f32], &Image) -> anyhow::Result<()>,
    ) -> anyhow::Result<Vec<ViewMetrics>> {
        self.assert_nothing_prepared("evaluate");
        anyhow::ensure!(
            images.count() == views.len(),
            "evaluate: {} images for {} views",
            images.count(),
            views.len()
        );
        let bg = self.config.background.eval_colour();
        let mut out = Vec::with_capacity(views.len());
        for start in (0..views.len()).step_by(EVAL_CHUNK) {
            let end = (start + EVAL_CHUNK).min(views.len());
            let truths = load_range(images, start..end)?;
            for (k, truth) in (start..end).zip(truths) {
                let v = views[k];
                let render: Vec<f32> = self
                    .render_view(v, bg)?
                    .iter()
                    .map(|x| x.clamp(0.0, 1.0))
                    .collect();
                let gt = crate::scene::images::composite_on_background(&truth, bg);
                let mut m = ViewMetrics::of(&scene.views[v].name, &render, &gt)?;
                each(k, &mut m, &render, &gt)?;
                out.push(m);
            }
        }
        Ok(out)
    }
}
