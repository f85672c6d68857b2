//! SpacetimeGaussians' temporal step on the GPU (`glsl/spacetime/temporal{,_backward}.comp`; the
//! f64 oracle is `crate::reference::spacetime`): the model at time `t` written as still 3D
//! Gaussians (positions, quaternions, opacity logits) that the 3DGS preprocess, rasterizer and
//! their backward draw unchanged, and the still Gaussians' gradients taken back to the temporal
//! parameters. One invocation per Gaussian, no host work.

use std::sync::Arc;

use anyhow::ensure;

use super::layout::RenderConstants;
use crate::gpu::{ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::GpuSplats;

const WG: u32 = 128;

/// The extra groups, in their order: motion (m₁, m₂, m₃), angular velocity, temporal centre,
/// temporal log-scale, named as the official PLY names them (`motion_0`..`motion_8`,
/// `omega_0`..`omega_3`, `trbf_center`, `trbf_scale`).
pub const GROUPS: [(&str, usize); 4] = [
    ("motion", 9),
    ("omega", 4),
    ("trbf_center", 1),
    ("trbf_scale", 1),
];

/// The extra groups as [`ExtraGroup`](crate::splats::ExtraGroup)s.
pub fn extra_groups() -> Vec<crate::splats::ExtraGroup> {
    GROUPS
        .iter()
        .map(|&(n, s)| crate::splats::ExtraGroup::new(n, s))
        .collect()
}

/// The near plane of SpacetimeGaussians' renders, in the training frame (a fraction of the
/// scene's extent, [`crate::scene::frame`]). The official code draws with the Inria rasterizer,
/// which culls every Gaussian whose camera z is at most 0.2 world units (`in_frustum`); on
/// Panoptic, whose cameras' extent is 3.4 units, that is 0.06 of the extent, the value here
/// (the engine's still models use gsplat's 0.01 of it). On multi-camera video the difference is
/// not cosmetic: Panoptic's cameras sit in the dome's wall, which the scene's other cameras see
/// and the model reconstructs, so with 0.01 the wall's Gaussians a few centimetres from a
/// held-out camera covered its whole view (test camera 15 at 6 dB).
pub const SPACETIME_NEAR: f32 = 0.06;

/// Floats per Gaussian of each temporal group.
pub const MOTION_STRIDE: usize = 9;
pub const OMEGA_STRIDE: usize = 4;

/// The parameters the temporal step reads, or their gradients (flat f32, Gaussian `i` at
/// `i × stride`): positions 3, motion 9 (`m₁, m₂, m₃` as xyz triples), rotations 4 (w, x, y, z),
/// angular velocities 4, opacity logits 1, temporal centres 1, temporal log-scales 1.
pub struct TemporalBuffers<'a> {
    pub positions: &'a GpuBuffer<f32>,
    pub motion: &'a GpuBuffer<f32>,
    pub rotations: &'a GpuBuffer<f32>,
    pub omega: &'a GpuBuffer<f32>,
    pub opacity_logits: &'a GpuBuffer<f32>,
    pub t_center: &'a GpuBuffer<f32>,
    pub t_log_scale: &'a GpuBuffer<f32>,
}

impl<'a> TemporalBuffers<'a> {
    /// The temporal groups of a model that has them ([`GROUPS`] as extra groups).
    pub fn of(s: &'a GpuSplats) -> anyhow::Result<Self> {
        let group = |name: &str| {
            s.extra_group(name).ok_or_else(|| {
                anyhow::anyhow!("SpacetimeGaussians: the model has no '{name}' group")
            })
        };
        Ok(TemporalBuffers {
            positions: &s.positions,
            motion: group("motion")?,
            rotations: &s.rotations,
            omega: group("omega")?,
            opacity_logits: &s.opacity_logits,
            t_center: group("trbf_center")?,
            t_log_scale: group("trbf_scale")?,
        })
    }

    fn check(&self, what: &str, count: usize) -> anyhow::Result<()> {
        let groups = [
            ("positions", self.positions.len(), 3),
            ("motion", self.motion.len(), MOTION_STRIDE),
            ("rotations", self.rotations.len(), 4),
            ("omega", self.omega.len(), OMEGA_STRIDE),
            ("opacity logits", self.opacity_logits.len(), 1),
            ("temporal centres", self.t_center.len(), 1),
            ("temporal log-scales", self.t_log_scale.len(), 1),
        ];
        for (name, len, stride) in groups {
            ensure!(
                len >= count * stride,
                "temporal step: {what} {name} hold {len} floats, {count} Gaussians need {}",
                count * stride
            );
        }
        Ok(())
    }
}

/// The still Gaussians at one time, or their gradients: positions 3, rotations 4, opacity
/// logits 1 per Gaussian.
pub struct InstantBuffers<'a> {
    pub positions: &'a GpuBuffer<f32>,
    pub rotations: &'a GpuBuffer<f32>,
    pub opacity_logits: &'a GpuBuffer<f32>,
}

impl<'a> InstantBuffers<'a> {
    /// The positions, rotations and opacity logits of a still model.
    pub fn of(s: &'a GpuSplats) -> Self {
        InstantBuffers {
            positions: &s.positions,
            rotations: &s.rotations,
            opacity_logits: &s.opacity_logits,
        }
    }

    fn check(&self, what: &str, count: usize) -> anyhow::Result<()> {
        for (name, len, stride) in [
            ("positions", self.positions.len(), 3),
            ("rotations", self.rotations.len(), 4),
            ("opacity logits", self.opacity_logits.len(), 1),
        ] {
            ensure!(
                len >= count * stride,
                "temporal step: {what} {name} hold {len} floats, {count} Gaussians need {}",
                count * stride
            );
        }
        Ok(())
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ForwardPush {
    count: u32,
    t: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BackwardPush {
    count: u32,
    t: f32,
    accumulate: u32,
}

/// Which Gaussians at which time: the first `count`, at `t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct At {
    pub count: usize,
    pub t: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PositionsPush {
    count: u32,
    t: f32,
    max_u2: f32,
}

pub struct TemporalStep {
    ctx: Arc<GpuContext>,
    forward: ComputePipeline,
    backward: ComputePipeline,
    positions: ComputePipeline,
}

impl TemporalStep {
    pub fn new(ctx: &Arc<GpuContext>) -> anyhow::Result<Self> {
        use std::mem::size_of;
        Ok(Self {
            ctx: ctx.clone(),
            forward: ComputePipeline::new(
                ctx,
                "spacetime/temporal",
                shaders::SPACETIME_TEMPORAL,
                10,
                size_of::<ForwardPush>() as u32,
                WG,
                &[],
            )?,
            backward: ComputePipeline::new(
                ctx,
                "spacetime/temporal_backward",
                shaders::SPACETIME_TEMPORAL_BACKWARD,
                13,
                size_of::<BackwardPush>() as u32,
                WG,
                &[],
            )?,
            positions: ComputePipeline::new(
                ctx,
                "spacetime/positions_at_time",
                shaders::SPACETIME_POSITIONS_AT_TIME,
                5,
                size_of::<PositionsPush>() as u32,
                WG,
                &[],
            )?,
        })
    }

    /// Records the first `at.count` Gaussians of `params` at time `at.t` into `out` (no
    /// barriers: the caller orders it against the passes around it).
    pub fn record_forward(
        &self,
        rec: &mut Recorder,
        params: &TemporalBuffers,
        out: &InstantBuffers,
        at: At,
    ) -> anyhow::Result<()> {
        let At { count, t } = at;
        params.check("parameter", count)?;
        out.check("output", count)?;
        ensure!(t.is_finite(), "temporal step: time {t} is not finite");
        if count == 0 {
            return Ok(());
        }
        rec.dispatch_named(
            &self.forward,
            &[
                ("positions", params.positions),
                ("motion", params.motion),
                ("rotations", params.rotations),
                ("omega", params.omega),
                ("opacity_logits", params.opacity_logits),
                ("t_center", params.t_center),
                ("t_log_scale", params.t_log_scale),
                ("out_positions", out.positions),
                ("out_rotations", out.rotations),
                ("out_opacity_logits", out.opacity_logits),
            ],
            &ForwardPush {
                count: count as u32,
                t,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        Ok(())
    }

    /// Records the temporal parameters' gradients of the first `at.count` Gaussians from the
    /// still Gaussians' (`d_instant`) at time `at.t`: written into `grads`, or added to them with
    /// `accumulate` (several views in one step). Only `params`' opacity logits and temporal
    /// centres and scales are read.
    pub fn record_backward(
        &self,
        rec: &mut Recorder,
        params: &TemporalBuffers,
        d_instant: &InstantBuffers,
        grads: &TemporalBuffers,
        at: At,
        accumulate: bool,
    ) -> anyhow::Result<()> {
        let At { count, t } = at;
        params.check("parameter", count)?;
        d_instant.check("instant gradient", count)?;
        grads.check("gradient", count)?;
        ensure!(t.is_finite(), "temporal step: time {t} is not finite");
        if count == 0 {
            return Ok(());
        }
        rec.dispatch_named(
            &self.backward,
            &[
                ("opacity_logits", params.opacity_logits),
                ("t_center", params.t_center),
                ("t_log_scale", params.t_log_scale),
                ("d_positions_t", d_instant.positions),
                ("d_rotations_t", d_instant.rotations),
                ("d_opacity_t", d_instant.opacity_logits),
                ("d_positions", grads.positions),
                ("d_motion", grads.motion),
                ("d_rotations", grads.rotations),
                ("d_omega", grads.omega),
                ("d_opacity_logits", grads.opacity_logits),
                ("d_t_center", grads.t_center),
                ("d_t_log_scale", grads.t_log_scale),
            ],
            &BackwardPush {
                count: count as u32,
                t,
                accumulate: accumulate as u32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        Ok(())
    }

    /// Records the centres of the first `at.count` Gaussians of `params` at time `at.t` into
    /// `out` (3 floats each), NaN for those whose temporal weight there is below `min_weight`
    /// (LPM in time: [`crate::reference::spacetime::frame_position`]). No barriers.
    pub fn record_positions(
        &self,
        rec: &mut Recorder,
        params: &TemporalBuffers,
        out: &GpuBuffer<f32>,
        at: At,
        min_weight: f64,
    ) -> anyhow::Result<()> {
        let At { count, t } = at;
        params.check("parameter", count)?;
        ensure!(
            out.len() >= 3 * count,
            "temporal positions: the output holds {} floats, {count} Gaussians need {}",
            out.len(),
            3 * count
        );
        ensure!(t.is_finite(), "temporal positions: time {t} is not finite");
        ensure!(
            min_weight > 0.0 && min_weight <= 1.0,
            "temporal positions: the presence weight {min_weight} must lie in (0, 1]"
        );
        if count == 0 {
            return Ok(());
        }
        rec.dispatch_named(
            &self.positions,
            &[
                ("positions", params.positions),
                ("motion", params.motion),
                ("t_center", params.t_center),
                ("t_log_scale", params.t_log_scale),
                ("out_positions", out),
            ],
            &PositionsPush {
                count: count as u32,
                t,
                max_u2: -(min_weight.ln()) as f32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        Ok(())
    }
}

/// A video model drawn at any time as still Gaussians, as a player does: each displayed time,
/// the temporal step writes the model at that time into `instant`, which any 3DGS renderer
/// draws (`bench fps`, `bench trade`'s FPS, `render`, `eval`). Scales and colour are copied
/// once. The full model (`TimedModel::full`) also writes its feature channels at that time,
/// and the rasterizer decodes each pixel in its epilogue (the frame's image is the RGB).
pub struct TimedModel {
    step: TemporalStep,
    pub instant: GpuSplats,
    full: Option<FullDecoding>,
}

/// The full model's per-time features and its decoder's weights.
struct FullDecoding {
    features: super::decoder::TimeFeatures,
    instant_features: GpuBuffer<f32>,
    weights: GpuBuffer<f32>,
}

impl TimedModel {
    /// For the video model `model` (its temporal groups as extra groups); with `decoder`
    /// weights, the full model (its `f_spec`, `f_t` groups too).
    pub fn new(
        ctx: &Arc<GpuContext>,
        model: &GpuSplats,
        decoder: Option<&[f32]>,
    ) -> anyhow::Result<Self> {
        use crate::splats::decoder_json::{FEATURE_CHANNELS, WEIGHTS};
        TemporalBuffers::of(model)?;
        let n = model.count;
        let instant = GpuSplats::zeroed(ctx, "instant ", 0, n, n.max(1))?;
        let full = match decoder {
            Some(w) => {
                ensure!(
                    w.len() == WEIGHTS && w.iter().all(|v| v.is_finite()),
                    "the full model's decoder has {WEIGHTS} finite weights, not these {}",
                    w.len()
                );
                Some(FullDecoding {
                    features: super::decoder::TimeFeatures::new(ctx)?,
                    instant_features: GpuBuffer::new(
                        ctx,
                        "instant features",
                        FEATURE_CHANNELS * n.max(1),
                        crate::gpu::BufferKind::DeviceLocal,
                    )?,
                    weights: GpuBuffer::from_slice(ctx, "decoder weights", w)?,
                })
            }
            None => None,
        };
        let mut rec = Recorder::new(ctx)?;
        rec.begin()?;
        rec.copy(&model.log_scales, &instant.log_scales, 3 * n);
        rec.copy(&model.sh_dc, &instant.sh_dc, 3 * n);
        rec.submit_and_wait()?;
        Ok(Self {
            step: TemporalStep::new(ctx)?,
            instant,
            full,
        })
    }

    /// Records `model` at time `t` into `self.instant` (and the full model's features), then a
    /// barrier.
    pub fn record(&self, rec: &mut Recorder, model: &GpuSplats, t: f32) -> anyhow::Result<()> {
        self.step.record_forward(
            rec,
            &TemporalBuffers::of(model)?,
            &InstantBuffers::of(&self.instant),
            At {
                count: model.count,
                t,
            },
        )?;
        if let Some(f) = &self.full {
            let group = |name: &str| {
                model
                    .extra_group(name)
                    .ok_or_else(|| anyhow::anyhow!("the full model has no '{name}' group"))
            };
            f.features.record_forward(
                rec,
                &super::decoder::FeatureGroups {
                    f_spec: group("f_spec")?,
                    f_t: group("f_t")?,
                    t_center: group("trbf_center")?,
                },
                &f.instant_features,
                model.count,
                t,
            )?;
        }
        rec.barrier();
        Ok(())
    }

    /// The frame settings that draw `self.instant`: the full model's raw base colour and
    /// feature channels over black, decoded into RGB by the rasterizer, else 3DGS's with
    /// `background`.
    pub fn settings(&self, background: [f32; 3]) -> super::forward::FrameSettings<'_> {
        let mut constants = RenderConstants::default().with_near(SPACETIME_NEAR);
        let (background, features) = match &self.full {
            Some(f) => {
                constants.flags |= RenderConstants::RAW_COLOUR;
                let channels = super::forward::FeatureChannels {
                    values: &f.instant_features,
                    channels: crate::splats::decoder_json::FEATURE_CHANNELS as u32,
                    decoded_by: Some(&f.weights),
                };
                ([0.0; 3], Some(channels))
            }
            None => (background, None),
        };
        super::forward::FrameSettings {
            sh_degree: 0,
            background,
            constants,
            filter3d: None,
            features,
        }
    }
}
