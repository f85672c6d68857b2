//! SpacetimeGaussians (lite) as a base model: the Gaussians carry four extra groups (cubic
//! motion, angular velocity, temporal centre and log-scale, docs/algorithms/base-models.md §4.2); each frame
//! the temporal step (`render::spacetime`) writes the model at the view's time as still 3D
//! Gaussians, which the 3DGS passes draw and differentiate unchanged, and the still Gaussians'
//! gradients go back through the temporal step to the model's.
//!
//! New Gaussians: clones and split children get a temporal centre uniform over the segment
//! (the official rule; `glsl/spacetime/random_centres.comp`, [`ChildTime`]), LPM's added points
//! the time of the frame whose error asked for them; the rest of the official density schedule
//! (six clone/split rounds, then pruning only) is not followed: ADC's schedule runs.
//!
//! Colour: the official lite model uses its three features as RGB directly; here they are the
//! SH DC coefficients at degree 0 (colour `0.5 + C₀·f`, clamped at 0 like every 3DGS colour), the
//! same model up to an affine change of variable except that a colour cannot go negative.
//!
//! The full model ([`FullModel`], docs/algorithms/base-models.md §4.3): two more groups, the specular feature
//! `f_spec` and the time feature `f_t`; each frame the Gaussians' 6 feature channels
//! `[f_spec, Δ·f_t]` are blended beside the raw DC coefficients (the base colour, no SH
//! encoding, no clamp) over a black background, and the per-pixel decoder
//! (`render::decoder`) turns the 9 channels and the pixel's ray into RGB; the decoder's 90
//! weights are the model's own parameters with their own Adam state.

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::gaussians::GaussianPasses;
use super::spacetime_settings::ChildTime;
use super::spacetime_settings::FullModelRates;
use super::{FrameArgs, GradArgs, ModelPasses};
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder, TimestampPool};
use crate::render::backward::FeatureGrads;
use crate::render::decoder::{Decoder, DecoderFrame, FeatureGroups, TimeFeatures};
use crate::render::forward::Capacity;
use crate::render::forward::FeatureChannels;
use crate::render::layout::{CameraGpu, ProjectedBoundsGpu};
use crate::render::spacetime::{At, InstantBuffers, TemporalBuffers, TemporalStep};
use crate::settings::spacetime::PRESENT_MIN_WEIGHT;
use crate::splats::decoder_json::{self as decoder, FEATURE_CHANNELS};
use crate::splats::gpu::{grown_capacity, GpuSplats};
use crate::splats::GaussianParams;
use crate::train::adam::Adam;
use crate::train::adam::SplatState;
use crate::train::config::TrainConfig;
use crate::train::density::rng::{fold_seed, rng_uniform};
use crate::train::density::DensityControl;
use crate::train::strategy::{FramePositions, Primitive};

pub use crate::render::spacetime::{extra_groups, GROUPS};

/// The full model's feature groups, after the temporal ones (PLY names `f_spec_0..2`,
/// `f_t_0..2`; the official PLY stores `f_spec` as `f_dc_3..5`).
pub const FULL_GROUPS: [(&str, usize); 2] = [("f_spec", 3), ("f_t", 3)];

/// The extra groups of the lite (`full` false) or the full model, in their order.
pub fn extra_groups_of(full: bool) -> Vec<crate::splats::ExtraGroup> {
    let mut groups = extra_groups();
    if full {
        groups.extend(
            FULL_GROUPS
                .iter()
                .map(|&(n, s)| crate::splats::ExtraGroup::new(n, s)),
        );
    }
    groups
}

/// The full model's own state: the decoder and its weights with their Adam moments, and the
/// per-Gaussian feature channels of the current frame with their gradients.
pub struct FullModel {
    features: TimeFeatures,
    decoder: Decoder,
    weights: GpuBuffer<f32>,
    weight_grads: GpuBuffer<f32>,
    m: GpuBuffer<f32>,
    v: GpuBuffer<f32>,
    adam: Adam,
    rates: FullModelRates,
    /// `[f_spec, Δ·f_t]` per Gaussian at the current frame's time, and their gradients.
    instant_features: GpuBuffer<f32>,
    feature_grads: GpuBuffer<f32>,
}

/// The official decoder's initial weights: PyTorch's default 1×1-convolution initialisation,
/// uniform in ±1/√fan_in (fan_in 12 for `W₁`, 6 for `W₂`), seeded.
pub fn initial_decoder_weights(seed: u64) -> Vec<f32> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0xDEC0);
    let w1 = 1.0 / (decoder::INPUTS as f32).sqrt();
    let w2 = 1.0 / (decoder::HIDDEN as f32).sqrt();
    (0..decoder::WEIGHTS)
        .map(|k| {
            let b = if k < decoder::HIDDEN * decoder::INPUTS {
                w1
            } else {
                w2
            };
            rng.gen_range(-b..b)
        })
        .collect()
}

impl FullModel {
    fn new(
        ctx: &Arc<GpuContext>,
        rates: FullModelRates,
        seed: u64,
        capacity: usize,
    ) -> Result<Self> {
        let dl = BufferKind::DeviceLocal;
        let zeros = vec![0.0f32; decoder::WEIGHTS];
        Ok(Self {
            features: TimeFeatures::new(ctx)?,
            decoder: Decoder::new(ctx)?,
            weights: GpuBuffer::from_slice(ctx, "decoder weights", &initial_decoder_weights(seed))?,
            weight_grads: GpuBuffer::from_slice(ctx, "decoder weight grads", &zeros)?,
            m: GpuBuffer::from_slice(ctx, "decoder m", &zeros)?,
            v: GpuBuffer::from_slice(ctx, "decoder v", &zeros)?,
            adam: Adam::new(ctx)?,
            rates,
            instant_features: GpuBuffer::new(
                ctx,
                "instant features",
                FEATURE_CHANNELS * capacity.max(1),
                dl,
            )?,
            feature_grads: GpuBuffer::new(
                ctx,
                "feature grads",
                FEATURE_CHANNELS * capacity.max(1),
                dl,
            )?,
        })
    }

    fn reserve(&mut self, ctx: &Arc<GpuContext>, capacity: usize) -> Result<()> {
        if self.instant_features.len() < FEATURE_CHANNELS * capacity {
            let cap = FEATURE_CHANNELS * grown_capacity(capacity);
            let dl = BufferKind::DeviceLocal;
            self.instant_features = GpuBuffer::new(ctx, "instant features", cap, dl)?;
            self.feature_grads = GpuBuffer::new(ctx, "feature grads", cap, dl)?;
        }
        Ok(())
    }

    fn channels(&self) -> FeatureChannels<'_> {
        FeatureChannels {
            values: &self.instant_features,
            channels: FEATURE_CHANNELS as u32,
            // Training keeps the base and feature images for the backward (decode.comp).
            decoded_by: None,
        }
    }
}

fn feature_groups(s: &GpuSplats) -> Result<FeatureGroups<'_>> {
    let group = |name: &str| {
        s.extra_group(name).ok_or_else(|| {
            anyhow::anyhow!("SpacetimeGaussians (full): the model has no '{name}' group")
        })
    };
    Ok(FeatureGroups {
        f_spec: group("f_spec")?,
        f_t: group("f_t")?,
        t_center: group("trbf_center")?,
    })
}
pub use super::spacetime_settings::SpacetimeTraining;

pub struct SpacetimePasses {
    ctx: Arc<GpuContext>,
    inner: GaussianPasses,
    step: TemporalStep,
    rates: SpacetimeTraining,
    /// The time of every view (indices into the camera buffer).
    view_times: Vec<f32>,
    /// The model at the current frame's time, and its gradients.
    instant: GpuSplats,
    instant_grads: GpuSplats,
    /// The time of the last recorded frame (new Gaussians are centred there).
    time: f32,
    /// The full model's decoder and features (`None`: lite).
    full: Option<FullModel>,
    /// The angular-velocity / rotation split (`None`: off).
    omega_freeze: Option<super::omega_freeze::OmegaFreezer>,
    /// Draws clones' and split children's temporal centres ([`ChildTime::Random`]).
    random_centres: Option<ComputePipeline>,
    seed: u32,
    rec: Recorder,
}

const WG: u32 = 256;

/// Keeps the child-time draws apart from the split's position draws of the same step.
const CHILD_TIME_SALT: u32 = 0x5354_4354;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CentresPush {
    first: u32,
    end: u32,
    seed: u32,
    step: u32,
}

/// The temporal centre `glsl/spacetime/random_centres.comp` gives new row `row` at density step
/// `step` of a run with `seed` (the kernel's numbers, for tests).
pub fn random_child_centre(seed: u64, step: u32, row: u32) -> f32 {
    rng_uniform(fold_seed(seed) ^ CHILD_TIME_SALT, step, row, 0) as f32
}

fn temporal(s: &GpuSplats) -> Result<TemporalBuffers<'_>> {
    TemporalBuffers::of(s)
}

fn instant(s: &GpuSplats) -> InstantBuffers<'_> {
    InstantBuffers::of(s)
}

impl SpacetimePasses {
    pub fn new(
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        cameras: &[CameraGpu],
        train_views: &[usize],
        view_times: &[f64],
        capacity: usize,
        frame: Capacity,
    ) -> Result<Self> {
        ensure!(
            view_times.len() == cameras.len() && view_times.iter().all(|t| t.is_finite()),
            "SpacetimeGaussians: {} view times for {} views (a video scene gives every view a \
             finite time)",
            view_times.len(),
            cameras.len()
        );
        let Some(&rates) = config.model_settings::<SpacetimeTraining>() else {
            anyhow::bail!("SpacetimeGaussians' passes need the config's temporal rates");
        };
        ensure!(
            config.sh_degree == 0,
            "SpacetimeGaussians has no SH: degree 0, not {}",
            config.sh_degree
        );
        let mut inner = GaussianPasses::new(ctx, config, cameras, train_views, capacity, frame)?;
        let full = match rates.full {
            Some(r) => {
                inner = inner.with_features(FEATURE_CHANNELS as u32)?;
                let mut full = FullModel::new(ctx, r, config.seed, capacity)?;
                full.decoder.reserve(frame.pixels)?;
                Some(full)
            }
            None => None,
        };
        Ok(Self {
            ctx: ctx.clone(),
            inner,
            full,
            omega_freeze: rates
                .omega_freeze
                .map(|f| super::omega_freeze::OmegaFreezer::new(ctx, f))
                .transpose()?,
            step: TemporalStep::new(ctx)?,
            rates,
            view_times: view_times.iter().map(|&t| t as f32).collect(),
            instant: GpuSplats::zeroed(ctx, "instant ", 0, 0, capacity.max(1))?,
            instant_grads: GpuSplats::zeroed(ctx, "instant grad ", 0, 0, capacity.max(1))?,
            time: 0.0,
            random_centres: match rates.child_time {
                ChildTime::Random => Some(ComputePipeline::new(
                    ctx,
                    "spacetime/random_centres",
                    crate::shaders::SPACETIME_RANDOM_CENTRES,
                    1,
                    std::mem::size_of::<CentresPush>() as u32,
                    WG,
                    &[],
                )?),
                ChildTime::Parent => None,
            },
            seed: fold_seed(config.seed) ^ CHILD_TIME_SALT,
            rec: Recorder::new(ctx)?,
        })
    }

    fn time_of(&self, view: u32) -> Result<f32> {
        self.view_times.get(view as usize).copied().ok_or_else(|| {
            anyhow::anyhow!(
                "SpacetimeGaussians: view {view} has no time ({} views)",
                self.view_times.len()
            )
        })
    }

    /// Records the still Gaussians of `f.params` at the view's time into `instant`.
    fn record_instant(&mut self, rec: &mut Recorder, f: &FrameArgs) -> Result<()> {
        let count = f.params.count;
        ensure!(
            self.instant.capacity >= count,
            "SpacetimeGaussians: {count} Gaussians, room for {} (reserve first)",
            self.instant.capacity
        );
        self.time = self.time_of(f.view)?;
        self.instant.count = count;
        rec.barrier();
        self.step.record_forward(
            rec,
            &temporal(f.params)?,
            &instant(&self.instant),
            At {
                count,
                t: self.time,
            },
        )?;
        // Scales and colour do not change with time.
        rec.copy(&f.params.log_scales, &self.instant.log_scales, 3 * count);
        rec.copy(&f.params.sh_dc, &self.instant.sh_dc, 3 * count);
        if let Some(full) = &self.full {
            full.features.record_forward(
                rec,
                &feature_groups(f.params)?,
                &full.instant_features,
                count,
                self.time,
            )?;
        }
        rec.barrier();
        Ok(())
    }

    /// The frame the full model's decoder reads: the base and feature images of the last
    /// render of `f`'s view.
    fn decoder_frame<'a>(
        &'a self,
        full: &'a FullModel,
        f: &FrameArgs<'a>,
    ) -> Result<DecoderFrame<'a>> {
        Ok(DecoderFrame {
            cameras: f.cameras,
            camera_index: f.view,
            camera: f.camera,
            base: self.inner.image(),
            features: self
                .inner
                .feature_image()
                .ok_or_else(|| anyhow::anyhow!("SpacetimeGaussians (full): no feature image"))?,
            weights: &full.weights,
        })
    }
}

/// The full model blends its features over black (the official zero background in all nine
/// channels): the decoder gives empty pixels their colour.
fn full_frame<'a>(instant: &'a GpuSplats, f: &FrameArgs<'a>, full: bool) -> FrameArgs<'a> {
    let mut g = at_instant(instant, f);
    if full {
        g.background = [0.0; 3];
    }
    g
}

/// `f` with the still Gaussians `instant` as its model.
fn at_instant<'a>(instant: &'a GpuSplats, f: &FrameArgs<'a>) -> FrameArgs<'a> {
    FrameArgs {
        params: instant,
        cameras: f.cameras,
        view: f.view,
        camera: f.camera,
        sh_degree: 0,
        background: f.background,
        iteration: f.iteration,
    }
}

impl ModelPasses for SpacetimePasses {
    fn primitive(&self) -> Primitive {
        Primitive::Gaussian
    }

    fn reserve(&mut self, capacity: usize) -> Result<()> {
        if let Some(full) = self.full.as_mut() {
            full.reserve(&self.ctx, capacity)?;
        }
        if self.instant.capacity < capacity {
            let cap = grown_capacity(capacity);
            self.instant = GpuSplats::zeroed(&self.ctx, "instant ", 0, 0, cap)?;
            self.instant_grads = GpuSplats::zeroed(&self.ctx, "instant grad ", 0, 0, cap)?;
        }
        self.inner.reserve(capacity)
    }

    fn record_prepare(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        config: &TrainConfig,
    ) -> Result<()> {
        self.inner.record_prepare(rec, f, config)
    }

    fn record_forward(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        self.record_instant(rec, f)?;
        let g = full_frame(&self.instant, f, self.full.is_some());
        let Some(full) = &self.full else {
            return self.inner.record_forward(rec, &g, timestamps);
        };
        self.inner
            .record_forward_with(rec, &g, Some(full.channels()), timestamps)?;
        rec.barrier();
        full.decoder
            .record_forward(rec, &self.decoder_frame(full, f)?)?;
        rec.barrier();
        Ok(())
    }

    fn image(&self) -> &GpuBuffer<f32> {
        match &self.full {
            Some(full) => full.decoder.image(),
            None => self.inner.image(),
        }
    }

    fn projected_bounds(&self) -> &GpuBuffer<ProjectedBoundsGpu> {
        self.inner.projected_bounds()
    }

    fn pixel_count(&self) -> Option<&GpuBuffer<u32>> {
        self.inner.pixel_count()
    }

    fn abs_grad(&self) -> Option<&GpuBuffer<f32>> {
        self.inner.abs_grad()
    }

    fn record_backward(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        g: &GradArgs,
        config: &TrainConfig,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        let count = g.count;
        self.instant_grads.count = count;
        if let Some(full) = self.full.take() {
            // RGB → base and feature images (and the weights' gradient, summed over the batch),
            // then the rasterizer backward with the feature channels.
            let recorded = (|| -> Result<()> {
                full.decoder.record_backward(
                    rec,
                    &self.decoder_frame(&full, &g.frame)?,
                    g.dl_dimage,
                    &full.weight_grads,
                    g.view_in_step > 0,
                    1.0 / g.views_in_step.max(1) as f32,
                )?;
                rec.barrier();
                let args = GradArgs {
                    frame: full_frame(&self.instant, &g.frame, true),
                    dl_dimage: full.decoder.dl_dbase(),
                    grads: &self.instant_grads,
                    view_grad_norm: g.view_grad_norm,
                    count,
                    view_in_step: g.view_in_step,
                    views_in_step: g.views_in_step,
                };
                self.inner.record_backward_with(
                    ctx,
                    rec,
                    &args,
                    Some(FeatureGrads {
                        values: &full.instant_features,
                        dl_dimage: full.decoder.dl_dfeatures(),
                        grads: &full.feature_grads,
                        channels: FEATURE_CHANNELS as u32,
                    }),
                    timestamps,
                )?;
                rec.barrier();
                full.features.record_backward(
                    rec,
                    &feature_groups(g.frame.params)?,
                    &full.feature_grads,
                    &feature_groups(g.grads)?,
                    count,
                    self.time,
                )
            })();
            self.full = Some(full);
            recorded?;
        } else {
            let args = GradArgs {
                frame: at_instant(&self.instant, &g.frame),
                dl_dimage: g.dl_dimage,
                grads: &self.instant_grads,
                view_grad_norm: g.view_grad_norm,
                count,
                view_in_step: g.view_in_step,
                views_in_step: g.views_in_step,
            };
            self.inner
                .record_backward(ctx, rec, &args, config, timestamps)?;
        }
        rec.barrier();
        self.step.record_backward(
            rec,
            &temporal(g.frame.params)?,
            &instant(&self.instant_grads),
            &temporal(g.grads)?,
            At {
                count,
                t: self.time,
            },
            false,
        )?;
        rec.copy(
            &self.instant_grads.log_scales,
            &g.grads.log_scales,
            3 * count,
        );
        rec.copy(&self.instant_grads.sh_dc, &g.grads.sh_dc, 3 * count);
        rec.barrier();
        Ok(())
    }

    fn frame_need(&self) -> Result<Option<usize>> {
        self.inner.frame_need()
    }

    fn intersection_capacity(&self) -> usize {
        self.inner.intersection_capacity()
    }

    fn reserve_intersections(&mut self, n: usize) -> Result<()> {
        self.inner.reserve_intersections(n)
    }

    fn model_changed(&mut self) {
        self.inner.model_changed()
    }

    /// ADC's reset lowers the base opacity σ(o), which caps the opacity at every time.
    fn record_opacity_reset(
        &mut self,
        rec: &mut Recorder,
        density: &DensityControl,
        state: &SplatState,
        cameras: &GpuBuffer<CameraGpu>,
    ) -> Result<()> {
        self.inner
            .record_opacity_reset(rec, density, state, cameras)
    }

    fn render_view(&mut self, f: &FrameArgs) -> Result<Vec<f32>> {
        self.reserve(f.params.count)?;
        let mut rec = std::mem::replace(&mut self.rec, Recorder::new(&self.ctx)?);
        rec.begin()?;
        let recorded = self.record_instant(&mut rec, f);
        if recorded.is_ok() {
            rec.submit_and_wait()?;
        }
        self.rec = rec;
        recorded?;
        let g = full_frame(&self.instant, f, self.full.is_some());
        let Some(full) = self.full.as_mut() else {
            return self.inner.render_view(&g);
        };
        full.decoder
            .reserve((f.camera.width() * f.camera.height()) as usize)?;
        let full = self.full.as_ref().expect("checked above");
        self.inner.render_frame_with(&g, full.channels())?;
        let mut rec = std::mem::replace(&mut self.rec, Recorder::new(&self.ctx)?);
        rec.begin()?;
        let decoded = self
            .decoder_frame(full, f)
            .and_then(|frame| full.decoder.record_forward(&mut rec, &frame));
        if decoded.is_ok() {
            rec.barrier();
            rec.submit_and_wait()?;
        }
        self.rec = rec;
        decoded?;
        let pixels = (f.camera.width() * f.camera.height()) as usize;
        full.decoder.image().read_range(0, 3 * pixels)
    }

    fn extra_lrs(&self, _iteration: u32, extent: f64) -> Vec<f64> {
        let r = &self.rates;
        let mut lrs = vec![r.motion * extent, r.omega, r.t_center, r.t_log_scale];
        if let Some(f) = &r.full {
            lrs.extend([f.features, f.time_features]);
        }
        lrs
    }

    /// The temporal groups of a point added at this frame; the full model's new points carry
    /// their colour as the base colour only (the official guided sampling's `[rgb, 0, 0, 0]`).
    fn new_gaussian_extras(&self) -> Vec<Vec<f32>> {
        let mut rows = vec![vec![0.0; 9], vec![0.0; 4], vec![self.time], vec![0.0]];
        if self.full.is_some() {
            rows.extend([vec![0.0; 3], vec![0.0; 3]]);
        }
        rows
    }

    fn raw_colour(&self) -> bool {
        self.full.is_some()
    }

    fn record_before_step(
        &mut self,
        rec: &mut Recorder,
        state: &SplatState,
        grads: &GpuSplats,
        iteration: u32,
    ) -> Result<()> {
        match self.omega_freeze.as_mut() {
            Some(f) => f.record(rec, state, grads, iteration),
            None => Ok(()),
        }
    }

    fn record_model_step(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        step: u32,
        _iteration: u32,
    ) -> Result<()> {
        let Some(f) = &self.full else {
            return Ok(());
        };
        f.adam.record_flat(
            ctx,
            rec,
            &f.weights,
            &f.weight_grads,
            &f.m,
            &f.v,
            decoder::WEIGHTS,
            step,
            f.rates.decoder,
        )
    }

    fn model_state(&self) -> Result<Option<serde_json::Value>> {
        let mut state = serde_json::Map::new();
        if let Some(f) = &self.full {
            state.insert(
                "decoder_weights".into(),
                serde_json::json!(f.weights.read()?),
            );
            state.insert("decoder_m".into(), serde_json::json!(f.m.read()?));
            state.insert("decoder_v".into(), serde_json::json!(f.v.read()?));
        }
        if let Some(f) = self.omega_freeze.as_ref().filter(|f| f.selected) {
            state.insert("omega_selected".into(), serde_json::json!(f.selected));
        }
        Ok((!state.is_empty()).then(|| state.into()))
    }

    fn restore_model_state(&mut self, state: &serde_json::Value) -> Result<()> {
        if state.get("omega_selected") == Some(&serde_json::json!(true)) {
            let Some(f) = self.omega_freeze.as_mut() else {
                anyhow::bail!(
                    "checkpoint model state: the angular-velocity split was made, but \
                               this run has it off"
                );
            };
            f.selected = true;
        }
        if state.get("decoder_weights").is_none() {
            return Ok(());
        }
        let Some(f) = &self.full else {
            anyhow::bail!(
                "the checkpoint holds decoder weights but this run is SpacetimeGaussians lite; \
                 resume it with --model spacetime-full"
            );
        };
        for (key, buf) in [
            ("decoder_weights", &f.weights),
            ("decoder_m", &f.m),
            ("decoder_v", &f.v),
        ] {
            let values: Vec<f32> = state
                .get(key)
                .and_then(|v| serde_json::from_value(v.clone()).ok())
                .ok_or_else(|| anyhow::anyhow!("checkpoint model state: '{key}' missing"))?;
            ensure!(
                values.len() == decoder::WEIGHTS && values.iter().all(|v| v.is_finite()),
                "checkpoint model state: '{key}' holds {} values (finite {}), the decoder {}",
                values.len(),
                values.iter().all(|v| v.is_finite()),
                decoder::WEIGHTS
            );
            buf.upload(&values)?;
        }
        Ok(())
    }

    /// The decoder's weights (`crate::splats::decoder_json`), written as
    /// `NAME.decoder.json` beside `NAME.ply`.
    fn export_files(&self) -> Result<Vec<(String, String)>> {
        let Some(f) = &self.full else {
            return Ok(Vec::new());
        };
        let json = crate::splats::decoder_json::to_json(&f.weights.read()?)?;
        Ok(vec![("decoder.json".into(), json)])
    }

    fn frame_positions(&self) -> Option<&dyn FramePositions> {
        Some(self)
    }

    fn record_new_gaussians(
        &mut self,
        rec: &mut Recorder,
        state: &SplatState,
        new: std::ops::Range<usize>,
        iteration: u32,
    ) -> Result<()> {
        let Some(pipe) = &self.random_centres else {
            return Ok(());
        };
        let centres = temporal(&state.params)?.t_center;
        ensure!(
            new.end <= centres.len() && new.start <= new.end,
            "SpacetimeGaussians: new rows {new:?} outside the {} temporal centres",
            centres.len()
        );
        if new.is_empty() {
            return Ok(());
        }
        rec.barrier();
        rec.dispatch_named(
            pipe,
            &[("t_center", centres)],
            &CentresPush {
                first: new.start as u32,
                end: new.end as u32,
                seed: self.seed,
                step: iteration,
            },
            self.ctx.groups_1d(new.len() as u64, WG),
        );
        rec.barrier();
        Ok(())
    }

    fn export(
        &mut self,
        _params: &GpuSplats,
        _cameras: &GpuBuffer<CameraGpu>,
        _iteration: u32,
        model: GaussianParams,
    ) -> Result<GaussianParams> {
        Ok(model)
    }
}

/// LPM in time: zones are tested against the centres at the trained frame's time, and a
/// Gaussian whose temporal weight there is below [`PRESENT_MIN_WEIGHT`] is absent (neither
/// inside nor in front of a zone, not counted), so a zone acts on what the frame shows.
impl FramePositions for SpacetimePasses {
    fn record_frame_positions(
        &self,
        rec: &mut Recorder,
        params: &GpuSplats,
        count: usize,
        out: &GpuBuffer<f32>,
    ) -> Result<()> {
        self.step.record_positions(
            rec,
            &temporal(params)?,
            out,
            At {
                count,
                t: self.time,
            },
            PRESENT_MIN_WEIGHT,
        )
    }
}
