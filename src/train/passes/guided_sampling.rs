//! SpacetimeGaussians' guided error sampling (the official train.py "ems", docs/algorithms/base-models.md §4.6):
//! the model's own localized point addition, which LPM runs beside.
//!
//! From iteration `from` the first SSIM of every training camera is recorded. Once every camera
//! has one, the `cameras` (2) with the lowest SSIM below `select_below` (0.91) are chosen — none
//! at all when fewer than two are below, as the official code does. Each chosen camera is
//! sampled once: when it is a step's last view more than `gap` iterations after the previous
//! sampling, and its SSIM there is below `sample_below` (0.88):
//!
//! 1. error `E = Σ_rgb |r/(mean r + 0.01) − g/(mean g + 0.01)|` (means over the image), error
//!    pixels above its `quantile` (0.6);
//! 2. 16×16 patches (the image padded with non-error pixels to whole patches plus one) holding
//!    more than 85 % error pixels; in them every pixel but those with both coordinates even is a
//!    seed; seeds within a tenth of the image of an edge are dropped (with a border of 0 pixels,
//!    an image under ten pixels, the official slicing drops them all, and so does this);
//! 3. per seed, two points on the pixel's ray at depths `D × (1 + jitter·(u − ½)) × r`,
//!    `r ∈ {0.7, 7.5}`, `u` uniform per point, where `D` is the view's depth: the largest median
//!    depth of the camera's render of the initial model at time 0 (the official code renders
//!    it before training and overwrites the per-pixel depths with it);
//! 4. each point: the ground truth's colour at the pixel, opacity 0.1, isotropic scale from the
//!    mean squared distance to its 3 nearest points among the new and existing ones (clamped to
//!    [e⁻¹⁰, e]), no motion or rotation speed, a temporal centre uniform in [0, 1), temporal
//!    log-scale 0.
//!
//! Differences from the official code, each deliberate: the rotation is the identity quaternion
//! (the official zero quaternion normalises to the identity in its rasterizer); `D` comes from
//! the engine's renderer (its median-depth pass) at a width of at most [`DEPTH_WIDTH`] pixels
//! (the largest median depth barely depends on resolution), and a camera whose initial render has no pixel with a
//! median depth (the official code would take the maximum of nothing) is not sampled; the
//! official N3DV world-z cull is not applied (it is scene-specific).

use std::sync::Arc;

use anyhow::Context;
use rand::{Rng, SeedableRng};

use super::spacetime_settings::GuidedSamplingSettings;
use crate::gpu::{GpuBuffer, GpuContext, Recorder};
use crate::render::forward::{FrameSettings, Renderer};
use crate::render::layout::CameraGpu;
use crate::render::spacetime::{TemporalBuffers, TimedModel};
use crate::scene::{PinholeCamera, Pose, View};
use crate::splats::gpu::GpuSplats;
use crate::splats::knn::mean_sq_dist_knn;
use crate::splats::GaussianParams;
use crate::train::density::append::{append_with_extras, NewGaussian};
use crate::train::strategy::{DensityContext, ModelRule, StepSeen, StrategyEvent};

/// The view depth is rendered at most this wide.
pub const DEPTH_WIDTH: u32 = 320;

/// Per pixel, `Σ_rgb |r/(mean r + 0.01) − g/(mean g + 0.01)|` (RGB interleaved inputs).
pub fn error_map(render: &[f32], truth: &[f32]) -> Vec<f64> {
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64;
    let (sr, sg) = (1.0 / (mean(render) + 0.01), 1.0 / (mean(truth) + 0.01));
    render
        .chunks(3)
        .zip(truth.chunks(3))
        .map(|(r, g)| {
            (0..3)
                .map(|c| (r[c] as f64 * sr - g[c] as f64 * sg).abs())
                .sum()
        })
        .collect()
}

/// The seed pixels `(x, y)` of a `width × height` render against its truth (steps 1–2 above),
/// in row-major order.
pub fn error_seeds(
    render: &[f32],
    truth: &[f32],
    width: u32,
    height: u32,
    s: &GuidedSamplingSettings,
) -> Vec<[u32; 2]> {
    let (w, h) = (width as usize, height as usize);
    let e = error_map(render, truth);
    if e.is_empty() {
        return Vec::new();
    }
    let mut sorted = e.clone();
    sorted.sort_by(f64::total_cmp);
    let threshold = sorted[((e.len() as f64 * s.quantile) as usize).min(e.len() - 1)];
    let p = s.patch.max(1) as usize;
    // Patches cover the image padded to (⌊side / p⌋ + 1) · p: padding counts as no error.
    let (px, py) = (w / p + 1, h / p + 1);
    let mut counts = vec![0usize; px * py];
    for y in 0..h {
        for x in 0..w {
            if e[y * w + x] > threshold {
                counts[(y / p) * px + x / p] += 1;
            }
        }
    }
    let need = (p * p) as f64 * s.patch_fraction;
    let (bx, by) = (
        (w as f64 * s.border) as usize,
        (h as f64 * s.border) as usize,
    );
    let mut out = Vec::new();
    if bx == 0 || by == 0 {
        return out;
    }
    for y in by..h - by.min(h) {
        for x in bx..w - bx.min(w) {
            // Both coordinates even within the patch: not a seed.
            if counts[(y / p) * px + x / p] as f64 > need
                && !((x % p).is_multiple_of(2) && (y % p).is_multiple_of(2))
            {
                out.push([x as u32, y as u32]);
            }
        }
    }
    out
}

/// Points on the rays through the centres of pixels `seeds` of `camera` at `pose`, at
/// view-space depth `depth × (1 + jitter·(u − ½)) × r` for each `r` of `ratios` (one `u` per
/// point from `rng`): all seeds at the first ratio, then all at the second, as the official
/// code orders them.
pub fn ray_points(
    camera: &PinholeCamera,
    pose: &Pose,
    seeds: &[[u32; 2]],
    depth: f64,
    ratios: &[f64],
    jitter: f64,
    rng: &mut impl Rng,
) -> Vec<[f64; 3]> {
    let mut out = Vec::with_capacity(seeds.len() * ratios.len());
    for &r in ratios {
        for &[x, y] in seeds {
            let u: f64 = rng.gen();
            let z = depth * (1.0 + jitter * (u - 0.5)) * r;
            let p = [
                (x as f64 + 0.5 - camera.cx) / camera.fx * z,
                (y as f64 + 0.5 - camera.cy) / camera.fy * z,
                z,
            ];
            out.push(pose.inverse_transform(p));
        }
    }
    out
}

/// The largest median depth of each of `views` (camera, pose) looking at `model` (a video
/// model at time `t`; a still model as it is), drawn by the engine's renderer at a width of at
/// most [`DEPTH_WIDTH`] with the default rasterizer constants (`render::forward`'s median-depth
/// pass); `None` for a view where no pixel's transmittance falls below ½.
pub fn view_depths(
    ctx: &Arc<GpuContext>,
    model: &GaussianParams,
    t: f64,
    views: &[(PinholeCamera, Pose)],
) -> anyhow::Result<Vec<Option<f64>>> {
    if views.is_empty() {
        return Ok(Vec::new());
    }
    let cams: Vec<CameraGpu> = views
        .iter()
        .map(|(camera, pose)| {
            let cam = if camera.width > DEPTH_WIDTH {
                let h = ((camera.height as f64 * DEPTH_WIDTH as f64 / camera.width as f64).round()
                    as u32)
                    .max(1);
                camera.resized(DEPTH_WIDTH, h)
            } else {
                *camera
            };
            CameraGpu::new(&cam, pose)
        })
        .collect();
    let n = model.len();
    let splats = GpuSplats::upload(ctx, model, n.max(1))?;
    // A video model is drawn as the still model it is at `t` (the temporal step).
    let timed = match TemporalBuffers::of(&splats) {
        Ok(_) => {
            let timed = TimedModel::new(ctx, &splats, None)?;
            let mut rec = Recorder::new(ctx)?;
            rec.begin()?;
            timed.record(&mut rec, &splats, t as f32)?;
            rec.submit_and_wait()?;
            Some(timed)
        }
        Err(_) => None,
    };
    let still = timed.as_ref().map_or(&splats, |m| &m.instant);
    let cameras = GpuBuffer::from_slice(ctx, "depth cameras", &cams)?;
    let mut renderer = Renderer::for_camera(ctx, n.max(1), &cams[0])?.with_median_depth()?;
    let settings = FrameSettings::plain(still.sh_degree, [0.0; 3]);
    let mut out = Vec::with_capacity(cams.len());
    for (i, cam) in cams.iter().enumerate() {
        renderer.fit_camera(cam)?;
        renderer.render_blocking(still, &cameras, i as u32, cam, &settings)?;
        let depth = renderer.read_median_depth()?;
        out.push(
            depth
                .iter()
                .filter(|&&d| d > 0.0)
                .fold(None, |m: Option<f32>, &d| Some(m.map_or(d, |m| m.max(d))))
                .map(f64::from),
        );
    }
    Ok(out)
}

/// What the sampler did at one step (the CLI prints it; `metrics.json` keeps them).
#[derive(Debug, Clone)]
pub enum GuidedEvent {
    /// Every camera's first SSIM is in: the chosen cameras (camera index, SSIM).
    Selected {
        iteration: u32,
        /// Training camera index, the name of its first view, its SSIM.
        chosen: Vec<(usize, String, f32)>,
    },
    /// A chosen camera came up: its view, SSIM, and the points added (0 when the SSIM was at
    /// or above the gate, or the camera has no depth).
    Sampled {
        iteration: u32,
        camera: usize,
        view: usize,
        view_name: String,
        ssim: f32,
        seeds: usize,
        added: usize,
        depth: Option<f64>,
    },
}

impl StrategyEvent for GuidedEvent {
    fn to_json(&self) -> serde_json::Value {
        match self {
            GuidedEvent::Selected { iteration, chosen } => serde_json::json!({
                "rule": "guided_sampling", "iteration": iteration, "selected": chosen,
            }),
            GuidedEvent::Sampled {
                iteration,
                camera,
                view,
                view_name,
                ssim,
                seeds,
                added,
                depth,
            } => serde_json::json!({
                "rule": "guided_sampling", "iteration": iteration, "camera": camera,
                "view": view, "view_name": view_name, "ssim": ssim, "seeds": seeds,
                "added": added, "depth": depth,
            }),
        }
    }
    fn describe(&self) -> String {
        self.to_string()
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl std::fmt::Display for GuidedEvent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GuidedEvent::Selected { iteration, chosen } if chosen.is_empty() => write!(
                f,
                "[{iteration}] guided sampling: fewer than two cameras below the SSIM gate, none \
                 chosen"
            ),
            GuidedEvent::Selected { iteration, chosen } => {
                let list: Vec<String> = chosen
                    .iter()
                    .map(|(_, name, s)| format!("{name}'s camera (SSIM {s:.3})"))
                    .collect();
                write!(
                    f,
                    "[{iteration}] guided sampling: chose {}",
                    list.join(", ")
                )
            }
            GuidedEvent::Sampled {
                iteration,
                view_name,
                ssim,
                seeds,
                added,
                depth,
                ..
            } => match depth {
                Some(d) => write!(
                    f,
                    "[{iteration}] guided sampling: {view_name} at SSIM {ssim:.3}: {seeds} seed \
                     pixels, {added} Gaussians added (view depth {d:.3})"
                ),
                None => write!(
                    f,
                    "[{iteration}] guided sampling: {view_name}: its camera's initial render has \
                     no median depth, nothing added"
                ),
            },
        }
    }
}

/// The sampler's state between steps (checkpointed).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
struct State {
    /// Per training camera: the view depth (computed from the initial model), the first SSIM
    /// seen from `from` on.
    depth: Vec<Option<f64>>,
    first_ssim: Vec<Option<f32>>,
    /// The chosen cameras not sampled yet (`None` until every camera has an SSIM).
    chosen: Option<Vec<usize>>,
    last: u32,
}

pub struct GuidedSampler {
    settings: GuidedSamplingSettings,
    seed: u64,
    /// Scene view → training camera (views of one camera share a pose and intrinsics).
    camera_of_view: Vec<Option<usize>>,
    /// Each camera's earliest training view.
    first_view: Vec<usize>,
    views: Vec<View>,
    state: State,
}

impl GuidedSampler {
    /// The sampler of a video scene's training views (`times`: every view's time), with the
    /// view depths of `initial` at the earliest time of each camera.
    pub fn new(
        ctx: &Arc<GpuContext>,
        settings: GuidedSamplingSettings,
        seed: u64,
        views: &[View],
        train: &[usize],
        times: &[f64],
        initial: &GaussianParams,
    ) -> anyhow::Result<Self> {
        let mut camera_of_view = vec![None; views.len()];
        let mut first_view: Vec<usize> = Vec::new();
        for &v in train {
            let same =
                |&u: &usize| views[u].pose == views[v].pose && views[u].camera == views[v].camera;
            let c = match first_view.iter().position(same) {
                Some(c) => c,
                None => {
                    first_view.push(v);
                    first_view.len() - 1
                }
            };
            camera_of_view[v] = Some(c);
            if times[v] < times[first_view[c]] {
                first_view[c] = v;
            }
        }
        let t0 = first_view
            .iter()
            .map(|&v| times[v])
            .fold(f64::INFINITY, f64::min);
        let t0 = if t0.is_finite() { t0 } else { 0.0 };
        anyhow::ensure!(
            crate::render::spacetime::GROUPS
                .iter()
                .all(|&(g, _)| initial.extra_values(g).is_some()),
            "guided sampling: the initial model has no temporal groups"
        );
        let cameras: Vec<(PinholeCamera, Pose)> = first_view
            .iter()
            .map(|&v| (views[v].camera, views[v].pose))
            .collect();
        let depth = view_depths(ctx, initial, t0, &cameras)?;
        let cameras = first_view.len();
        Ok(Self {
            settings,
            seed,
            camera_of_view,
            first_view,
            views: views.to_vec(),
            state: State {
                depth,
                first_ssim: vec![None; cameras],
                chosen: None,
                last: 0,
            },
        })
    }

    /// Training cameras, and each one's view depth.
    pub fn depths(&self) -> &[Option<f64>] {
        &self.state.depth
    }

    /// Chooses the cameras once every one has a first SSIM.
    fn choose(&mut self, iteration: u32) -> Option<GuidedEvent> {
        let ssim: Option<Vec<f32>> = self.state.first_ssim.iter().copied().collect();
        let ssim = ssim?;
        let mut below: Vec<(usize, f32)> = ssim
            .iter()
            .copied()
            .enumerate()
            .filter(|&(_, s)| s < self.settings.select_below)
            .collect();
        below.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        let chosen: Vec<(usize, String, f32)> = if below.len() < self.settings.cameras.max(1) {
            Vec::new()
        } else {
            below.truncate(self.settings.cameras);
            below
                .into_iter()
                .map(|(c, s)| (c, self.views[self.first_view[c]].name.clone(), s))
                .collect()
        };
        self.state.chosen = Some(chosen.iter().map(|c| c.0).collect());
        Some(GuidedEvent::Selected { iteration, chosen })
    }

    /// Adds the points of one sampling (the rec is idle; begun and submitted here).
    fn sample(
        &mut self,
        t: &mut DensityContext,
        view: usize,
        depth: f64,
        background: [f32; 3],
        iteration: u32,
    ) -> anyhow::Result<(usize, usize)> {
        let (w, h) = (t.width, t.height);
        let n_px = (w * h) as usize;
        let render = t.render.read_range(0, 3 * n_px)?;
        let words = t.truth.read_range(t.truth_offset_px as usize, n_px)?;
        // The truth as the loss sees it: composited on the step's background.
        let mut truth = Vec::with_capacity(3 * n_px);
        for &px in &words {
            let a = ((px >> 24) & 255) as f32 / 255.0;
            for (c, bg) in background.iter().enumerate() {
                let v = ((px >> (8 * c)) & 255) as f32 / 255.0;
                truth.push(v * a + bg * (1.0 - a));
            }
        }
        let seeds = error_seeds(&render, &truth, w, h, &self.settings);
        if seeds.is_empty() {
            return Ok((0, 0));
        }
        let v = &self.views[view];
        let mut rng = rand_pcg::Pcg64::seed_from_u64(
            self.seed
                ^ 0x656d_735f_7361_6d70
                ^ (iteration as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
        );
        let points = ray_points(
            &v.camera,
            &v.pose,
            &seeds,
            depth,
            &self.settings.depth_ratios,
            self.settings.jitter,
            &mut rng,
        );
        // Scales from the 3 nearest among the new and the existing points.
        let n = t.state.count();
        let existing = t.state.params.positions.read_range(0, 3 * n)?;
        let mut all: Vec<[f64; 3]> = points.clone();
        all.extend(
            existing
                .chunks(3)
                .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]),
        );
        let d2 = mean_sq_dist_knn(&all, 3);
        let centre = v.pose.center().map(|c| c as f32);
        let rows: Vec<NewGaussian> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let [x, y] = seeds[i % seeds.len()];
                let k = 3 * (y * w + x) as usize;
                let log_scale = (d2[i].max(1e-7).sqrt().ln()).clamp(-10.0, 1.0);
                NewGaussian {
                    position: p.map(|c| c as f32),
                    scale: log_scale.exp() as f32,
                    color: [truth[k], truth[k + 1], truth[k + 2]],
                    opacity: self.settings.opacity,
                    camera_center: centre,
                }
            })
            .collect();
        // Extra groups: the model's new row, with a temporal centre uniform in [0, 1).
        let m = rows.len();
        let mut extras: Vec<Vec<f32>> = t
            .new_extras
            .iter()
            .map(|row| row.iter().copied().cycle().take(row.len() * m).collect())
            .collect();
        let centre_group = t
            .state
            .params
            .extra_groups
            .iter()
            .position(|g| g.name == "trbf_center")
            .context("guided sampling: the model has no temporal centre")?;
        for c in extras[centre_group].iter_mut() {
            *c = rng.gen::<f32>();
        }
        t.rec.begin()?;
        // Under a Gaussian budget only the rows that fit are added.
        let added = append_with_extras(t, &rows, Some(&extras))?;
        t.rec.submit_and_wait()?;
        Ok((seeds.len(), added))
    }
}

impl ModelRule for GuidedSampler {
    fn name(&self) -> &'static str {
        "guided_sampling"
    }

    /// Sampling (GPU work) happens only on a step whose last view's camera is among the
    /// chosen ones and due; choosing them is host-only but done once, counted as work. This
    /// mirrors the `due` test of `after_step`, asked with the state that step will see.
    fn quiet_after(&self, iteration: u32, views: &[usize]) -> bool {
        let s = self.settings;
        if iteration < s.from {
            return true;
        }
        let Some(chosen) = self.state.chosen.as_ref() else {
            return false;
        };
        let camera = views
            .last()
            .and_then(|&v| self.camera_of_view.get(v).copied().flatten());
        let due = iteration > s.from
            && iteration - self.state.last > s.gap
            && camera.is_some_and(|c| chosen.contains(&c));
        !due
    }

    fn after_step(
        &mut self,
        t: &mut DensityContext,
        step: &StepSeen,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        let s = self.settings;
        let it = step.iteration;
        if it < s.from {
            return Ok(None);
        }
        let mut event = None;
        if self.state.chosen.is_none() {
            for (&v, &ssim) in step.views.iter().zip(step.view_ssim) {
                if let Some(c) = self.camera_of_view.get(v).copied().flatten() {
                    self.state.first_ssim[c].get_or_insert(ssim);
                }
            }
            event = self.choose(it);
        }
        let (Some(&view), Some(&ssim)) = (step.views.last(), step.view_ssim.last()) else {
            return Ok(event.map(|e| Arc::new(e) as Arc<dyn StrategyEvent>));
        };
        let Some(camera) = self.camera_of_view.get(view).copied().flatten() else {
            return Ok(event.map(|e| Arc::new(e) as Arc<dyn StrategyEvent>));
        };
        let due = it > s.from
            && it - self.state.last > s.gap
            && self
                .state
                .chosen
                .as_ref()
                .is_some_and(|c| c.contains(&camera));
        if due {
            if let Some(c) = self.state.chosen.as_mut() {
                c.retain(|&x| x != camera);
            }
            self.state.last = it;
            let depth = self.state.depth[camera];
            let (seeds, added) = match depth {
                Some(d) if ssim < s.sample_below => self.sample(t, view, d, step.background, it)?,
                _ => (0, 0),
            };
            event = Some(GuidedEvent::Sampled {
                iteration: it,
                camera,
                view,
                view_name: self.views[view].name.clone(),
                ssim,
                seeds,
                added,
                depth,
            });
        }
        Ok(event.map(|e| Arc::new(e) as Arc<dyn StrategyEvent>))
    }

    fn state_json(&self) -> serde_json::Value {
        serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null)
    }

    fn restore_state(&mut self, state: &serde_json::Value) -> anyhow::Result<()> {
        let s: State = serde_json::from_value(state.clone())
            .context("the checkpoint's guided sampling state is malformed")?;
        anyhow::ensure!(
            s.depth.len() == self.state.depth.len() && s.first_ssim.len() == s.depth.len(),
            "the checkpoint's guided sampling state has {} cameras, the scene {}",
            s.depth.len(),
            self.state.depth.len()
        );
        self.state = s;
        Ok(())
    }
}
