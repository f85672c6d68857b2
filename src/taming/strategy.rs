//! The exact-budget ADC ranked by the blended score ([`super::score`]) instead of the gradient
//! statistic: at every densify step that grows, the strategy draws a few training views, renders
//! each twice with the model as it is (once for its error, once with the pixel importance
//! uploaded, summing each Gaussian's contributions), forms every Gaussian's score on the host
//! and hands it to ADC's own decision as its ranking (`ScoreInput::Replace`). Which Gaussians
//! are candidates (every one seen since the last step), how a candidate grows (clone or split
//! by its size) and the count each step ends at (the budget curve) are the exact-budget ADC's:
//! only the order in which the room is given out changes.
//!
//! Taming-3DGS draws its additions at random in proportion to the score, among the Gaussians
//! over the gradient threshold only, and so may end short of its budget; this ranking is
//! deterministic and fills the budget exactly.
//!
//! Cost: two frames a sampled view and one read-back of seven floats a Gaussian a view, on
//! densify steps only (every `--densify-interval` iterations); the model's statistics, opacities
//! and scales are read back once a step. The strategy keeps a renderer of its own (the
//! trainer's holds the iteration's frame for the backward).

use std::any::Any;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{ensure, Context};
use rand::SeedableRng;

use super::score::{self, ModelTerms, ScoreWeights, ViewTerms};
use crate::gpu::{BufferKind, GpuBuffer, GpuContext};
use crate::render::forward::{FrameSettings, Renderer};
use crate::render::layout::CameraGpu;
use crate::scene::image_source::TrainImages;
use crate::scene::Scene;
use crate::train::density::{DensifyArgs, DensifyOutcome, DensifyPhase, ScoreInput};
use crate::train::strategy::{
    DensityContext, DensityStrategy, Guide, IterationView, StrategyEvent,
};

/// The blended score's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlendConfig {
    /// Training views drawn a step (all of them when there are fewer).
    pub views: usize,
    pub weights: ScoreWeights,
    /// Keys the draw of views (with the iteration).
    pub seed: u64,
}

impl Default for BlendConfig {
    fn default() -> Self {
        BlendConfig {
            views: 10,
            weights: ScoreWeights::default(),
            seed: 0,
        }
    }
}

/// What one scored step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlendEvent {
    pub iteration: u32,
    pub views: usize,
    /// Gaussians with a positive score.
    pub scored: usize,
    /// Wall seconds the scoring took (renders, read-backs and host maths).
    pub seconds: f64,
}

impl StrategyEvent for BlendEvent {
    fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "iteration": self.iteration, "views": self.views, "scored": self.scored,
            "seconds": self.seconds,
        })
    }
    fn describe(&self) -> String {
        format!(
            "blended score: {} views, {} Gaussians scored, {:.2} s",
            self.views, self.scored, self.seconds
        )
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

pub struct BlendedScore {
    ctx: Arc<GpuContext>,
    config: BlendConfig,
    images: TrainImages,
    /// The training views' cameras, in the order of `images`.
    cameras: Vec<CameraGpu>,
    camera_buffer: GpuBuffer<CameraGpu>,
    renderer: Option<Renderer>,
    score: Option<GpuBuffer<f32>>,
    last: Option<BlendEvent>,
    /// Scored steps so far, and the wall seconds they took.
    pub steps: usize,
    pub seconds: f64,
}

impl BlendedScore {
    pub fn new(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        images: TrainImages,
        config: BlendConfig,
    ) -> anyhow::Result<Self> {
        ensure!(
            config.views > 0,
            "the blended score needs at least one view a step (--budget-score-views)"
        );
        ensure!(
            !scene.train.is_empty(),
            "the blended score needs training views"
        );
        let cameras: Vec<CameraGpu> = scene
            .train
            .iter()
            .map(|&i| CameraGpu::new(&scene.views[i].camera, &scene.views[i].pose))
            .collect();
        Ok(BlendedScore {
            ctx: ctx.clone(),
            config,
            images,
            camera_buffer: GpuBuffer::from_slice(ctx, "score cameras", &cameras)?,
            cameras,
            renderer: None,
            score: None,
            last: None,
            steps: 0,
            seconds: 0.0,
        })
    }

    /// Every Gaussian's blended score over `views` (positions in the training set).
    fn scores(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        views: &[usize],
    ) -> anyhow::Result<Vec<f32>> {
        let n = t.state.count();
        let stats = t.density.stats();
        let grad = stats.grad_accum.read_range(0, n)?;
        let denom = stats.denom.read_range(0, n)?;
        let logits = t.state.params.opacity_logits.read_range(0, n)?;
        let log_scales = t.state.params.log_scales.read_range(0, 3 * n)?;
        let model = ModelTerms {
            gradient: grad
                .iter()
                .zip(&denom)
                .map(|(&g, &d)| if d > 0.0 { g / d } else { 0.0 })
                .collect(),
            opacity: logits.iter().map(|&x| 1.0 / (1.0 + (-x).exp())).collect(),
            scale: log_scales
                .chunks_exact(3)
                .map(|s| (s[0] + s[1] + s[2]).exp())
                .collect(),
        };
        let w = self.config.weights;
        let model_part = score::model_part(&model, &w);
        let mut total = vec![0.0f64; n];
        let settings = FrameSettings::plain(t.state.params.sh_degree, at.background);
        for &k in views {
            let cam = self.cameras[k];
            let renderer = match self.renderer.as_mut() {
                Some(r) => r,
                None => self
                    .renderer
                    .insert(Renderer::for_camera(&self.ctx, n.max(1), &cam)?.with_contributions()?),
            };
            let cap = renderer.capacity();
            renderer.ensure_capacity(crate::render::forward::Capacity {
                gaussians: cap.gaussians.max(n),
                ..cap
            })?;
            renderer.fit_camera(&cam)?;
            let (width, height) = (cam.width() as usize, cam.height() as usize);
            let truth = self
                .images
                .source
                .load(k)
                .with_context(|| format!("the blended score's view {k}"))?;
            ensure!(
                (truth.width as usize, truth.height as usize) == (width, height),
                "the blended score: training image {k} is {}×{}, its camera {width}×{height}",
                truth.width,
                truth.height
            );
            let truth_rgb: Vec<f32> = match &truth.alpha {
                None => truth.rgb.clone(),
                Some(a) => truth
                    .rgb
                    .chunks_exact(3)
                    .zip(a)
                    .flat_map(|(c, &a)| {
                        let bg = at.background;
                        [0, 1, 2].map(|i| c[i] * a + bg[i] * (1.0 - a))
                    })
                    .collect(),
            };
            // Once for the view's error, once with its pixel importance uploaded.
            let draw = |r: &mut Renderer| {
                r.render_blocking(
                    &t.state.params,
                    &self.camera_buffer,
                    k as u32,
                    &cam,
                    &settings,
                )
            };
            draw(renderer)?;
            let image = renderer.read_image()?;
            let l1 = crate::metrics::l1(&image, &truth_rgb)?;
            let ssim = crate::metrics::ssim(&image, &truth_rgb, width, height)?;
            let edges = score::edge_map(&truth_rgb, width, height);
            let importance = score::pixel_importance(&image, &truth_rgb, &edges, &w);
            renderer
                .pixel_weights_buffer()
                .expect("allocated by the first frame")
                .upload(&importance)?;
            draw(renderer)?;
            let sums = renderer.read_contributions(n)?;
            let bounds = renderer.frame.projected.bounds.read_range(0, n)?;
            let view = ViewTerms {
                loss: 0.8 * l1 + 0.2 * (1.0 - ssim),
                depth: bounds.iter().map(|b| b.depth).collect(),
                radius: bounds.iter().map(|b| b.radius).collect(),
                importance: sums.weight,
                pixels: sums.pixels,
                blend: sums.blend,
                distance: sums.distance,
            };
            score::add_view(&mut total, &model_part, &view, &w);
        }
        Ok(total.iter().map(|&s| s as f32).collect())
    }

    /// A density step ranked by the blended score (times `guide`'s weights when given); a step
    /// that cannot grow, or a run without an exact budget, is ADC's own.
    fn scored_step(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
        guide: Option<&Guide>,
    ) -> anyhow::Result<DensifyOutcome> {
        let n = t.state.count();
        let grows = args.phase != DensifyPhase::PruneOnly;
        if !grows || t.density.config.exact_budget.is_none() || n == 0 {
            return t.density.step(t.rec, t.state, args, None);
        }
        let start = Instant::now();
        // The statistics and the model the views are drawn with: the iteration's work first.
        t.rec.submit_and_wait()?;
        t.rec.begin()?;
        let count = self.cameras.len();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(
            self.config.seed ^ (u64::from(args.iteration) << 20) ^ 0x7A31_0000,
        );
        let mut views =
            rand::seq::index::sample(&mut rng, count, self.config.views.min(count)).into_vec();
        views.sort_unstable();
        let mut scores = self.scores(t, at, &views)?;
        if let Some(g) = guide {
            let weight = g.weight.read_range(0, n)?;
            for (s, w) in scores.iter_mut().zip(weight) {
                *s *= w;
            }
        }
        let scored = scores.iter().filter(|&&s| s > 0.0).count();
        let need = t.state.capacity().max(n);
        if self.score.as_ref().is_none_or(|b| b.len() < need) {
            self.score = None;
            self.score = Some(GpuBuffer::new(
                &self.ctx,
                "blended score",
                need,
                BufferKind::DeviceLocal,
            )?);
        }
        let buf = self.score.as_ref().expect("allocated above");
        buf.upload(&scores)?;
        t.density
            .record_decide(t.rec, t.state, args, None, Some(ScoreInput::Replace(buf)))?;
        let out = t.density.apply(t.rec, t.state, args)?;
        let seconds = start.elapsed().as_secs_f64();
        self.steps += 1;
        self.seconds += seconds;
        self.last = Some(BlendEvent {
            iteration: args.iteration,
            views: views.len(),
            scored,
            seconds,
        });
        Ok(out)
    }
}

impl DensityStrategy for BlendedScore {
    fn name(&self) -> &'static str {
        "adc-exact-blend"
    }

    fn densify(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        self.scored_step(t, at, args, None)
    }

    fn takes_guide(&self) -> bool {
        true
    }

    /// Each score times the guide's weight (LPM's zones): where the room goes, not how much.
    fn densify_guided(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
        guide: &Guide,
    ) -> anyhow::Result<DensifyOutcome> {
        self.scored_step(t, at, args, Some(guide))
    }

    fn after_density(
        &mut self,
        _t: &mut DensityContext,
        _at: &IterationView,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        Ok(self
            .last
            .take()
            .map(|e| Arc::new(e) as Arc<dyn StrategyEvent>))
    }

    fn settings_json(&self) -> serde_json::Value {
        self.settings()
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

impl BlendedScore {
    /// The settings that decide results, and (`totals`) what the scoring cost so far.
    pub fn totals_json(&self) -> serde_json::Value {
        serde_json::json!({
            "settings": self.settings()["blended_score"],
            "steps": self.steps,
            "seconds": self.seconds,
        })
    }

    fn settings(&self) -> serde_json::Value {
        let w = &self.config.weights;
        serde_json::json!({ "blended_score": {
            "views": self.config.views, "seed": self.config.seed,
            "weights": {
                "view": w.view, "error_map": w.error_map, "edge_map": w.edge_map,
                "gradient": w.gradient, "opacity": w.opacity, "depth": w.depth,
                "radius": w.radius, "scale": w.scale, "importance": w.importance,
                "pixels": w.pixels, "blend": w.blend, "distance": w.distance,
            },
        }})
    }
}
