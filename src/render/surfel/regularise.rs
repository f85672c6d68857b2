//! The 2DGS regularisers on the GPU (normal consistency and depth distortion, docs/algorithms/base-models.md
//! §1.4), three kernels mirroring [`crate::reference::surfel::regularise`]:
//! `glsl/surfel/surface_depth.comp` (the surface-depth map), `normal_consistency.comp` (the
//! depth normals, the loss terms, the rendered normal's gradient and the difference gradients)
//! and `regularise_gather.comp` (the surface depth's gradient into the depth, alpha and median
//! maps). They write every slot of `dL/d(maps)` (the distortion's is its constant weight), so
//! [`super::backward::SurfelBackward`] can always read it: zero weights give zero gradients.

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::backward::MAP_GRADS_STRIDE;
use super::forward::SurfelRenderer;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::render::layout::CameraGpu;
use crate::shaders;

const WG: u32 = 256;

/// The regularisers' weights for one iteration (zero when a term is not active yet).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegulariserWeights {
    /// λ of the normal-consistency term (official 0.05 after iteration 7000).
    pub normal: f32,
    /// λ of the depth-distortion term (official code 0; 1000 in its DTU script; after 3000).
    pub distortion: f32,
    /// 0: the surface depth is the expected depth; 1: the median depth (official DTU/TnT).
    pub depth_ratio: f32,
}

/// The regularisers' pipelines and per-pixel scratch buffers.
pub struct SurfelRegularisers {
    ctx: Arc<GpuContext>,
    surface_depth: ComputePipeline,
    normal: ComputePipeline,
    gather: ComputePipeline,
    /// Per pixel: the surface depth.
    pub surf_depth: GpuBuffer<f32>,
    /// Per pixel: dL/da, dL/dc (6 floats).
    diff_grads: GpuBuffer<f32>,
    /// Per pixel: the normal-consistency term `1 − N·n̂·alpha`.
    pub terms: GpuBuffer<f32>,
    pixels: usize,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DepthPush {
    pixels: u32,
    depth_ratio: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct NormalPush {
    camera_index: u32,
    weight: f32,
    distortion_weight: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GatherPush {
    camera_index: u32,
    depth_ratio: f32,
}

impl SurfelRegularisers {
    pub fn new(ctx: &Arc<GpuContext>, pixels: usize) -> Result<Self> {
        let pipe = |name: &str, spirv: &[u8], buffers: u32, push: usize| {
            ComputePipeline::new(ctx, name, spirv, buffers, push as u32, WG, &[])
        };
        let pixels = pixels.max(1);
        let dl = BufferKind::DeviceLocal;
        Ok(Self {
            ctx: ctx.clone(),
            surface_depth: pipe(
                "surfel/surface_depth",
                shaders::SURFEL_SURFACE_DEPTH,
                3,
                std::mem::size_of::<DepthPush>(),
            )?,
            normal: pipe(
                "surfel/normal_consistency",
                shaders::SURFEL_NORMAL_CONSISTENCY,
                7,
                std::mem::size_of::<NormalPush>(),
            )?,
            gather: pipe(
                "surfel/regularise_gather",
                shaders::SURFEL_REGULARISE_GATHER,
                5,
                std::mem::size_of::<GatherPush>(),
            )?,
            surf_depth: GpuBuffer::new(ctx, "surface depth", pixels, dl)?,
            diff_grads: GpuBuffer::new(ctx, "depth difference grads", pixels * 6, dl)?,
            terms: GpuBuffer::new(ctx, "normal consistency terms", pixels, dl)?,
            pixels,
        })
    }

    /// Makes room for `pixels` pixels (only when no recorded work using these is pending).
    pub fn reserve(&mut self, pixels: usize) -> Result<()> {
        if pixels > self.pixels {
            *self = Self::new(&self.ctx, pixels)?;
        }
        Ok(())
    }

    /// Records the three passes on `renderer`'s last frame of `cameras[camera_index]` (host
    /// copy `camera`), writing `dl_dmaps` ([`MAP_GRADS_STRIDE`] floats per pixel).
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        rec: &mut Recorder,
        renderer: &SurfelRenderer,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        weights: &RegulariserWeights,
        dl_dmaps: &GpuBuffer<f32>,
    ) -> Result<()> {
        let px = camera.width() as usize * camera.height() as usize;
        ensure!(
            px <= self.pixels && dl_dmaps.len() >= px * MAP_GRADS_STRIDE,
            "surfel regularisers: {px} pixels but room for {} (dL/dmaps holds {} floats); \
             reserve first",
            self.pixels,
            dl_dmaps.len()
        );
        let f = &renderer.base.frame;
        let maps = &renderer.surfel.maps;
        let groups = self.ctx.groups_1d(px as u64, WG);
        let inv_p = 1.0 / px.max(1) as f32;
        rec.dispatch_named(
            &self.surface_depth,
            &[
                ("maps", maps),
                ("final_t", &f.final_t),
                ("surf_depth", &self.surf_depth),
            ],
            &DepthPush {
                pixels: px as u32,
                depth_ratio: weights.depth_ratio,
            },
            groups,
        );
        rec.barrier();
        rec.dispatch_named(
            &self.normal,
            &[
                ("cameras", cameras),
                ("maps", maps),
                ("final_t", &f.final_t),
                ("surf_depth", &self.surf_depth),
                ("diff_grads", &self.diff_grads),
                ("dl_dmaps", dl_dmaps),
                ("terms", &self.terms),
            ],
            &NormalPush {
                camera_index,
                weight: weights.normal * inv_p,
                distortion_weight: weights.distortion * inv_p,
            },
            groups,
        );
        rec.barrier();
        rec.dispatch_named(
            &self.gather,
            &[
                ("cameras", cameras),
                ("maps", maps),
                ("final_t", &f.final_t),
                ("diff_grads", &self.diff_grads),
                ("dl_dmaps", dl_dmaps),
            ],
            &GatherPush {
                camera_index,
                depth_ratio: weights.depth_ratio,
            },
            groups,
        );
        rec.barrier();
        Ok(())
    }
}
