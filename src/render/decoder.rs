//! SpacetimeGaussians' full-model decoder on the GPU (`glsl/spacetime/decode*.comp`; the f64
//! oracle is [`crate::reference::decoder`]): the blended base colour (3 channels) and features
//! (6) of a frame become RGB through a 90-weight per-pixel MLP; backward, the RGB gradient
//! becomes the rasterizer backward's colour and feature gradients, and the weights' gradient is
//! reduced over all pixels in a fixed order (per-workgroup rows, then one workgroup per weight).
//! One invocation per pixel, no host work, no readback.

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::layout::CameraGpu;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::reference::decoder::{FEATURE_CHANNELS, WEIGHTS};
use crate::shaders;

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
    pixels: usize,
    rgb: GpuBuffer<f32>,
    dl_dbase: GpuBuffer<f32>,
    dl_dfeatures: GpuBuffer<f32>,
    partial: GpuBuffer<f32>,
}

impl Decoder {
    pub fn new(ctx: &Arc<GpuContext>) -> Result<Self> {
        use std::mem::size_of;
        let pipe = |name: &str, spirv: &[u8], buffers: u32, push: usize| {
            ComputePipeline::new(ctx, name, spirv, buffers, push as u32, WG, &[])
        };
        let dl = BufferKind::DeviceLocal;
        Ok(Self {
            ctx: ctx.clone(),
            forward: pipe(
                "spacetime/decode",
                shaders::SPACETIME_DECODE,
                5,
                size_of::<CameraPush>(),
            )?,
            backward: pipe(
                "spacetime/decode_backward",
                shaders::SPACETIME_DECODE_BACKWARD,
                8,
                size_of::<CameraPush>(),
            )?,
            reduce: pipe(
                "spacetime/decode_reduce",
                shaders::SPACETIME_DECODE_REDUCE,
                2,
                size_of::<ReducePush>(),
            )?,
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

    /// Workgroups (and partial rows) of the backward for `pixels`.
    fn rows(&self, pixels: usize) -> usize {
        let g = self.ctx.groups_1d(pixels as u64, WG);
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
        rec.dispatch(
            &self.forward,
            &[f.cameras, f.base, f.features, f.weights, &self.rgb],
            &CameraPush {
                camera_index: f.camera_index,
            },
            self.ctx.groups_1d(pixels as u64, WG),
        );
        Ok(())
    }

    /// Records the backward of one frame from `dl_drgb` (3 per pixel): [`Decoder::dl_dbase`]
    /// and [`Decoder::dl_dfeatures`] written, the weights' gradient written into
    /// `weight_grads` or, with `accumulate`, added to it. Barriers inside between its two
    /// kernels, none around.
    pub fn record_backward(
        &self,
        rec: &mut Recorder,
        f: &DecoderFrame,
        dl_drgb: &GpuBuffer<f32>,
        weight_grads: &GpuBuffer<f32>,
        accumulate: bool,
    ) -> Result<()> {
        let pixels = self.check(f)?;
        ensure!(
            dl_drgb.len() >= 3 * pixels && weight_grads.len() >= WEIGHTS,
            "decoder backward: {} RGB gradients for {pixels} pixels, {} weight gradients for {WEIGHTS}",
            dl_drgb.len(),
            weight_grads.len()
        );
        rec.dispatch(
            &self.backward,
            &[
                f.cameras,
                f.base,
                f.features,
                f.weights,
                dl_drgb,
                &self.dl_dbase,
                &self.dl_dfeatures,
                &self.partial,
            ],
            &CameraPush {
                camera_index: f.camera_index,
            },
            self.ctx.groups_1d(pixels as u64, WG),
        );
        rec.barrier();
        rec.dispatch(
            &self.reduce,
            &[&self.partial, weight_grads],
            &ReducePush {
                rows: self.rows(pixels) as u32,
                weights: WEIGHTS as u32,
                accumulate: accumulate as u32,
            },
            [WEIGHTS as u32, 1, 1],
        );
        Ok(())
    }
}
