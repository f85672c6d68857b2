//! SpacetimeGaussians' full-model decoder on the GPU (`glsl/spacetime/decode*.comp`; the f64
//! oracle is [`crate::reference::decoder`]): the blended base colour (3 channels) and features
//! (6) of a frame become RGB through a 90-weight per-pixel MLP; backward, the RGB gradient
//! becomes the rasterizer backward's colour and feature gradients, and the weights' gradient is
//! reduced over all pixels in a fixed order (per-workgroup rows, then one workgroup per weight).
//! One invocation per pixel on GPUs, eight on CPU drivers (each weight load is shared by the
//! invocation's pixels); no host work, no readback.

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::layout::CameraGpu;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::decoder_json::{FEATURE_CHANNELS, WEIGHTS};

const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CameraPush {
    camera_index: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ReducePush {
    rows: u32,
    weights: u32,
    accumulate: u32,
    scale: f32,
}

/// One frame's decoder inputs: the rasterizer's base image (3 per pixel) and feature image
/// ([`FEATURE_CHANNELS`] per pixel), seen from `cameras[camera_index]`.
pub struct DecoderFrame<'a> {
    pub cameras: &'a GpuBuffer<CameraGpu>,
    pub camera_index: u32,
    /// Host copy of `cameras[camera_index]` (sizes the dispatch).
    pub camera: &'a CameraGpu,
    pub base: &'a GpuBuffer<f32>,
    pub features: &'a GpuBuffer<f32>,
    /// [`WEIGHTS`] floats.
    pub weights: &'a GpuBuffer<f32>,
}

/// The decoder's pipelines and its per-pixel buffers (grown to the largest frame seen).
pub struct Decoder {
    ctx: Arc<GpuContext>,
    forward: ComputePipeline,
    backward: ComputePipeline,
    reduce: ComputePipeline,
    /// Pixels each invocation of the forward and backward decodes.
    per_invocation: u32,
    pixels: usize,
    rgb: GpuBuffer<f32>,
    dl_dbase: GpuBuffer<f32>,
    dl_dfeatures: GpuBuffer<f32>,
    partial: GpuBuffer<f32>,
}

impl Decoder {
    /// With the device's pixels per invocation (8 on CPU drivers, 1 on GPUs; as the
    /// rasterizers, [`super::backward::default_pixels_per_invocation`]).
    pub fn new(ctx: &Arc<GpuContext>) -> Result<Self> {
        Self::with_pixels_per_invocation(
            ctx,
            super::backward::default_pixels_per_invocation(&ctx.info),
        )
    }

    /// With `per_invocation` pixels decoded by each invocation (1 to 16; tests run every
    /// layout on one device).
    pub fn with_pixels_per_invocation(ctx: &Arc<GpuContext>, per_invocation: u32) -> Result<Self> {
        use std::mem::size_of;
        ensure!(
            (1..=16).contains(&per_invocation),
            "decoder: {per_invocation} pixels per invocation (1 to 16)"
        );
        let pipe = |name: &str, spirv: &[u8], buffers: u32, push: usize, constants: &[u32]| {
            ComputePipeline::new(ctx, name, spirv, buffers, push as u32, WG, constants)
        };
        let dl = BufferKind::DeviceLocal;
        Ok(Self {
            ctx: ctx.clone(),
            forward: pipe(
                "spacetime/decode",
                shaders::SPACETIME_DECODE,
                5,
                size_of::<CameraPush>(),
                &[per_invocation],
            )?,
            backward: pipe(
                "spacetime/decode_backward",
                shaders::SPACETIME_DECODE_BACKWARD,
                8,
                size_of::<CameraPush>(),
                &[per_invocation],
            )?,
            reduce: pipe(
                "spacetime/decode_reduce",
                shaders::SPACETIME_DECODE_REDUCE,
                2,
                size_of::<ReducePush>(),
                &[],
            )?,
            per_invocation,
            pixels: 0,
            rgb: GpuBuffer::new(ctx, "decoded image", 1, dl)?,
            dl_dbase: GpuBuffer::new(ctx, "dL/d(base image)", 1, dl)?,
            dl_dfeatures: GpuBuffer::new(ctx, "dL/d(feature image)", 1, dl)?,
            partial: GpuBuffer::new(ctx, "decoder weight partials", 1, dl)?,
        })
    }

    /// Grows the per-pixel buffers for `pixels` (only between submissions that use them).
    pub fn reserve(&mut self, pixels: usize) -> Result<()> {
        if pixels <= self.pixels {
            return Ok(());
        }
        let dl = BufferKind::DeviceLocal;
        let rows = self.rows(pixels);
        self.rgb = GpuBuffer::new(&self.ctx, "decoded image", 3 * pixels, dl)?;
        self.dl_dbase = GpuBuffer::new(&self.ctx, "dL/d(base image)", 3 * pixels, dl)?;
        self.dl_dfeatures = GpuBuffer::new(
            &self.ctx,
            "dL/d(feature image)",
            FEATURE_CHANNELS * pixels,
            dl,
        )?;
        self.partial = GpuBuffer::new(&self.ctx, "decoder weight partials", rows * WEIGHTS, dl)?;
        self.pixels = pixels;
        Ok(())
    }

    /// The workgroups of either pass for `pixels`.
    fn groups(&self, pixels: usize) -> [u32; 3] {
        let invocations = pixels.div_ceil(self.per_invocation as usize);
        self.ctx.groups_1d(invocations as u64, WG)
    }

    /// Workgroups (and partial rows) of the backward for `pixels`.
    fn rows(&self, pixels: usize) -> usize {
        let g = self.groups(pixels);
        g[0] as usize * g[1] as usize
    }

    /// The last decoded frame, RGB interleaved.
    pub fn image(&self) -> &GpuBuffer<f32> {
        &self.rgb
    }

    /// The last backward's gradient of the base image (3 per pixel).
    pub fn dl_dbase(&self) -> &GpuBuffer<f32> {
        &self.dl_dbase
    }

    /// The last backward's gradient of the feature image ([`FEATURE_CHANNELS`] per pixel).
    pub fn dl_dfeatures(&self) -> &GpuBuffer<f32> {
        &self.dl_dfeatures
    }

    fn check(&self, f: &DecoderFrame) -> Result<usize> {
        let pixels = (f.camera.width() * f.camera.height()) as usize;
        ensure!(
            pixels <= self.pixels,
            "decoder: a {}×{} frame, room for {} pixels (reserve first)",
            f.camera.width(),
            f.camera.height(),
            self.pixels
        );
        for (name, len, need) in [
            ("base image", f.base.len(), 3 * pixels),
            ("feature image", f.features.len(), FEATURE_CHANNELS * pixels),
            ("weights", f.weights.len(), WEIGHTS),
            ("cameras", f.cameras.len(), f.camera_index as usize + 1),
        ] {
            ensure!(
                len >= need,
                "decoder: the {name} hold {len}, the frame needs {need}"
            );
        }
        Ok(pixels)
    }

    /// Records the decoding of one frame into [`Decoder::image`] (no barriers).
    pub fn record_forward(&self, rec: &mut Recorder, f: &DecoderFrame) -> Result<()> {
        let pixels = self.check(f)?;
        rec.dispatch_named(
            &self.forward,
            &[
                ("cameras", f.cameras),
                ("base_image", f.base),
                ("feature_image", f.features),
                ("dec_w", f.weights),
                ("rgb", &self.rgb),
            ],
            &CameraPush {
                camera_index: f.camera_index,
            },
            self.groups(pixels),
        );
        Ok(())
    }

    /// Records the backward of one frame from `dl_drgb` (3 per pixel): [`Decoder::dl_dbase`]
    /// and [`Decoder::dl_dfeatures`] written, the weights' gradient times `scale` written into
    /// `weight_grads` or, with `accumulate`, added to it (a batch of `n` views: each adds its
    /// gradient / `n`, as the trainer's per-Gaussian mean). Barriers inside between its two
    /// kernels, none around.
    pub fn record_backward(
        &self,
        rec: &mut Recorder,
        f: &DecoderFrame,
        dl_drgb: &GpuBuffer<f32>,
        weight_grads: &GpuBuffer<f32>,
        accumulate: bool,
        scale: f32,
    ) -> Result<()> {
        let pixels = self.check(f)?;
        ensure!(
            dl_drgb.len() >= 3 * pixels && weight_grads.len() >= WEIGHTS,
            "decoder backward: {} RGB gradients for {pixels} pixels, {} weight gradients for {WEIGHTS}",
            dl_drgb.len(),
            weight_grads.len()
        );
        rec.dispatch_named(
            &self.backward,
            &[
                ("cameras", f.cameras),
                ("base_image", f.base),
                ("feature_image", f.features),
                ("w", f.weights),
                ("dl_drgb", dl_drgb),
                ("dl_dbase", &self.dl_dbase),
                ("dl_dfeatures", &self.dl_dfeatures),
                ("partial", &self.partial),
            ],
            &CameraPush {
                camera_index: f.camera_index,
            },
            self.groups(pixels),
        );
        rec.barrier();
        rec.dispatch_named(
            &self.reduce,
            &[("partial", &self.partial), ("grads", weight_grads)],
            &ReducePush {
                rows: self.rows(pixels) as u32,
                weights: WEIGHTS as u32,
                accumulate: accumulate as u32,
                scale,
            },
            [WEIGHTS as u32, 1, 1],
        );
        Ok(())
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct TimePush {
    count: u32,
    t: f32,
}

/// The full model's per-Gaussian feature channels at a time (`glsl/spacetime/features_at_time
/// .comp`, oracle [`crate::reference::decoder::time_features`]) and their backward.
pub struct TimeFeatures {
    ctx: Arc<GpuContext>,
    forward: ComputePipeline,
    backward: ComputePipeline,
}

/// The full model's feature groups (3 floats per Gaussian each) and temporal centres.
pub struct FeatureGroups<'a> {
    pub f_spec: &'a GpuBuffer<f32>,
    pub f_t: &'a GpuBuffer<f32>,
    pub t_center: &'a GpuBuffer<f32>,
}

impl FeatureGroups<'_> {
    fn check(&self, count: usize) -> Result<()> {
        for (name, len, stride) in [
            ("f_spec", self.f_spec.len(), 3),
            ("f_t", self.f_t.len(), 3),
            ("temporal centres", self.t_center.len(), 1),
        ] {
            ensure!(
                len >= count * stride,
                "time features: {name} hold {len} floats, {count} Gaussians need {}",
                count * stride
            );
        }
        Ok(())
    }
}

impl TimeFeatures {
    pub fn new(ctx: &Arc<GpuContext>) -> Result<Self> {
        let push = std::mem::size_of::<TimePush>() as u32;
        Ok(Self {
            ctx: ctx.clone(),
            forward: ComputePipeline::new(
                ctx,
                "spacetime/features_at_time",
                shaders::SPACETIME_FEATURES_AT_TIME,
                4,
                push,
                WG,
                &[],
            )?,
            backward: ComputePipeline::new(
                ctx,
                "spacetime/features_backward",
                shaders::SPACETIME_FEATURES_BACKWARD,
                4,
                push,
                WG,
                &[],
            )?,
        })
    }

    /// Records `out[6i..6i + 6] = [f_spec, (t − c)·f_t]` for the first `count` Gaussians (no
    /// barriers).
    pub fn record_forward(
        &self,
        rec: &mut Recorder,
        groups: &FeatureGroups,
        out: &GpuBuffer<f32>,
        count: usize,
        t: f32,
    ) -> Result<()> {
        groups.check(count)?;
        ensure!(
            out.len() >= FEATURE_CHANNELS * count && t.is_finite(),
            "time features: {} output floats for {count} Gaussians at time {t}",
            out.len()
        );
        if count == 0 {
            return Ok(());
        }
        rec.dispatch_named(
            &self.forward,
            &[
                ("f_spec", groups.f_spec),
                ("f_t", groups.f_t),
                ("t_center", groups.t_center),
                ("features", out),
            ],
            &TimePush {
                count: count as u32,
                t,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        Ok(())
    }

    /// Records the feature groups' gradients (`grads.f_spec`, `grads.f_t`, written) from the
    /// channels' (`d_features`, 6 per Gaussian); reads `params.t_center` only. No barriers.
    pub fn record_backward(
        &self,
        rec: &mut Recorder,
        params: &FeatureGroups,
        d_features: &GpuBuffer<f32>,
        grads: &FeatureGroups,
        count: usize,
        t: f32,
    ) -> Result<()> {
        params.check(count)?;
        grads.check(count)?;
        ensure!(
            d_features.len() >= FEATURE_CHANNELS * count && t.is_finite(),
            "time features backward: {} gradient floats for {count} Gaussians at time {t}",
            d_features.len()
        );
        if count == 0 {
            return Ok(());
        }
        rec.dispatch_named(
            &self.backward,
            &[
                ("t_center", params.t_center),
                ("d_features", d_features),
                ("d_f_spec", grads.f_spec),
                ("d_f_t", grads.f_t),
            ],
            &TimePush {
                count: count as u32,
                t,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        Ok(())
    }
}
