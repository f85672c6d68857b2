//! The surfel backward pass on the GPU, in two kernels that follow
//! [`crate::reference::surfel::backward()`] step by step:
//!
//! 1. `glsl/surfel/rasterize_backward.comp` (or its `_cas` twin on devices without float
//!    atomics): per tile, every pixel walks its list back to front and accumulates, per
//!    surfel, the gradients of `M`'s rows, the box centre, the clamped colour, the opacity and
//!    the normal into [`SurfelBackward::grad_geom`] (18 floats per surfel, in two buffers of 9).
//! 2. `glsl/surfel/preprocess_backward.comp`: per surfel, through the box-centre formula,
//!    `M`'s columns, the normal flip, the quaternion, the sigmoid and the SH colour to the
//!    parameters, plus the official densification statistic `view_grad_norm`.
//!
//! Inputs per pixel: `dL/d(image)` (3 floats, 3DGS's layout) and `dL/d(maps)`
//! ([`MAP_GRADS_STRIDE`] floats: alpha, depth numerator, median depth, normal (3),
//! distortion, unused): what the photometric loss and the regularisers produce.

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::forward::SurfelRenderer;
use super::layout::SurfelConstants;
use crate::gpu::{
    Bindable, BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder, TimestampPool,
};
use crate::render::backward::{
    backward_pixels_per_invocation, backward_workgroup, full_kernel, subgroup_atomics,
};
use crate::render::layout::CameraGpu;
use crate::shaders;
use crate::splats::gpu::{grown_capacity, GpuSplats, GRAD_BINDINGS, PARAM_BINDINGS};
use crate::splats::model::sh_rest_coeffs;

/// Floats per surfel of [`SurfelBackward::grad_geom`]: `dL/d(h₁ (3), h₂ (3), h₃ (3), box
/// centre (2), rgb (3), opacity, normal (3))`.
pub const GRAD_GEOM_STRIDE: usize = 18;
/// Floats per surfel of each of the two buffers [`SurfelBackward::grad_geom`] holds them in
/// (the rows of `M`; the rest): one buffer of 72 bytes a surfel would pass a 128 MiB storage
/// binding at 1.86 M surfels, the two of 36 bytes at 3.7 M.
pub const GRAD_GEOM_HALF: usize = 9;
/// Floats per pixel of `dL/d(maps)`.
pub const MAP_GRADS_STRIDE: usize = 8;
const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RasterPush {
    sc: SurfelConstants,
    background: [f32; 4],
    camera_index: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PreprocessPush {
    sc: SurfelConstants,
    camera_index: u32,
    count: u32,
    sh_degree: u32,
    rest_coeffs: u32,
    scale_stride: u32,
    _pad: [u32; 3],
}

/// What [`SurfelBackward::record`] reads and writes besides the renderer's last frame.
pub struct SurfelBackwardArgs<'a> {
    pub cameras: &'a GpuBuffer<CameraGpu>,
    pub camera_index: u32,
    /// Host copy of `cameras[camera_index]` (sizes for the dispatch and the checks).
    pub camera: &'a CameraGpu,
    /// `dL/d(image)`, `[(y·W + x)·3 + c]`.
    pub dl_dimage: &'a GpuBuffer<f32>,
    /// `dL/d(maps)`, [`MAP_GRADS_STRIDE`] floats per pixel.
    pub dl_dmaps: &'a GpuBuffer<f32>,
    /// The surfels the forward rendered, and their log-scale stride.
    pub splats: &'a GpuSplats,
    pub scale_stride: u32,
    /// Output: the parameters' layout, surfels `0..count` written.
    pub grads: &'a GpuSplats,
    /// Output: f32 per surfel, the official densification statistic of this view.
    pub view_grad_norm: &'a GpuBuffer<f32>,
    pub count: usize,
    /// Active SH degree of the forward (≤ `splats.sh_degree`).
    pub sh_degree: u32,
    pub constants: SurfelConstants,
    pub background: [f32; 3],
}

/// The surfel backward's pipelines and its per-surfel intermediate buffer.
pub struct SurfelBackward {
    raster: ComputePipeline,
    preprocess: ComputePipeline,
    /// `dL/d(h₁, h₂, h₃)` and `dL/d(box centre, rgb, opacity, normal)`, 9 floats a surfel each.
    grad_geom: [GpuBuffer<f32>; 2],
    capacity: usize,
}

impl SurfelBackward {
    /// Float atomics where the device has them (`compare_swap` forces the other path, for
    /// tests).
    pub fn new(ctx: &Arc<GpuContext>, capacity: usize, compare_swap: bool) -> Result<Self> {
        let pixels = backward_pixels_per_invocation(&ctx.info);
        Self::with_pixels(ctx, capacity, compare_swap, pixels)
    }

    /// As [`SurfelBackward::new`] with `pixels` (one of
    /// [`crate::render::backward::pixel_layouts`]) pixels per invocation of the rasterizer
    /// backward instead of the device's default: tests run the GPU layout (1, sums through
    /// shared memory) on a CPU driver this way.
    pub fn with_pixels(
        ctx: &Arc<GpuContext>,
        capacity: usize,
        compare_swap: bool,
        pixels: u32,
    ) -> Result<Self> {
        let wg = backward_workgroup(&ctx.info, pixels, "2DGS backward")?;
        let float_atomics = ctx.info.float_atomic_add && !compare_swap;
        // A device without float atomics or shuffles gets SPIR-V that declares neither.
        let (name, spirv) = if full_kernel(&ctx.info) {
            (
                "surfel/rasterize_backward",
                shaders::SURFEL_RASTERIZE_BACKWARD,
            )
        } else {
            (
                "surfel/rasterize_backward_cas",
                shaders::SURFEL_RASTERIZE_BACKWARD_CAS,
            )
        };
        let raster = ComputePipeline::new(
            ctx,
            name,
            spirv,
            14,
            std::mem::size_of::<RasterPush>() as u32,
            wg,
            &[
                float_atomics as u32,
                pixels,
                subgroup_atomics(&ctx.info, pixels) as u32,
            ],
        )?;
        let preprocess = ComputePipeline::new(
            ctx,
            "surfel/preprocess_backward",
            shaders::SURFEL_PREPROCESS_BACKWARD,
            25,
            std::mem::size_of::<PreprocessPush>() as u32,
            WG,
            &[],
        )?;
        let capacity = capacity.max(1);
        Ok(Self {
            raster,
            preprocess,
            grad_geom: Self::alloc(ctx, capacity)?,
            capacity,
        })
    }

    fn alloc(ctx: &Arc<GpuContext>, capacity: usize) -> Result<[GpuBuffer<f32>; 2]> {
        let half = |name| {
            GpuBuffer::new(
                ctx,
                name,
                capacity * GRAD_GEOM_HALF,
                BufferKind::DeviceLocal,
            )
        };
        Ok([half("surfel grad rows")?, half("surfel grad rest")?])
    }

    /// The per-surfel gradients of the last recorded rasterize backward: slots 0..9 and 9..18
    /// of [`GRAD_GEOM_STRIDE`], [`GRAD_GEOM_HALF`] floats a surfel each.
    pub fn grad_geom(&self) -> &[GpuBuffer<f32>; 2] {
        &self.grad_geom
    }

    /// Makes room for `count` surfels (geometric growth); only when no recorded work that uses
    /// this `SurfelBackward` is pending.
    pub fn reserve(&mut self, ctx: &Arc<GpuContext>, count: usize) -> Result<()> {
        if count > self.capacity {
            self.capacity = grown_capacity(count);
            self.grad_geom = Self::alloc(ctx, self.capacity)?;
        }
        Ok(())
    }

    /// Records the backward of `renderer`'s last frame: a barrier, the zeroing of `grad_geom`,
    /// the rasterizer backward, a barrier, the preprocess backward (timestamps "rasterize
    /// backward" and "preprocess backward" when a pool is given). The caller puts a barrier
    /// before reading the outputs.
    pub fn record(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        renderer: &SurfelRenderer,
        a: &SurfelBackwardArgs,
        mut pool: Option<&mut TimestampPool>,
    ) -> Result<()> {
        self.check(a)?;
        let f = &renderer.base.frame;
        let sf = &renderer.surfel;
        rec.barrier();
        for b in &self.grad_geom {
            rec.fill(b, 0);
        }
        rec.barrier();
        rec.dispatch_named(
            &self.raster,
            &[
                ("cameras", a.cameras),
                ("splats", &f.projected.splats),
                ("geom", &sf.geom),
                ("tile_ranges", &f.tile_ranges),
                ("sorted_ids", renderer.base.sorted_ids()),
                ("final_t", &f.final_t),
                ("last_index", &f.last_index),
                ("median_index", &sf.median_index),
                ("maps", &sf.maps),
                ("dl_dimage", a.dl_dimage),
                ("dl_dmaps", a.dl_dmaps),
                ("grad_rows_bits", &self.grad_geom[0]),
                ("grad_rest_bits", &self.grad_geom[1]),
                ("normals", &sf.normals),
            ],
            &RasterPush {
                sc: a.constants,
                background: [a.background[0], a.background[1], a.background[2], 0.0],
                camera_index: a.camera_index,
                _pad: [0; 3],
            },
            ctx.groups_1d(a.camera.tile_count() as u64, 1),
        );
        if let Some(p) = pool.as_deref_mut() {
            rec.timestamp(p, "rasterize backward");
        }
        rec.barrier();
        let s = a.splats;
        let g = a.grads;
        if a.count > 0 {
            let own: [(&str, &dyn Bindable); 5] = [
                ("cameras", a.cameras),
                ("bounds", &f.projected.bounds),
                ("grad_rows", &self.grad_geom[0]),
                ("grad_rest", &self.grad_geom[1]),
                ("view_grad_norm", a.view_grad_norm),
            ];
            let buffers: Vec<(&str, &dyn Bindable)> = own
                .into_iter()
                .chain(s.bindings(&PARAM_BINDINGS))
                .chain(g.bindings(&GRAD_BINDINGS))
                .collect();
            rec.dispatch_named(
                &self.preprocess,
                &buffers,
                &PreprocessPush {
                    sc: a.constants,
                    camera_index: a.camera_index,
                    count: a.count as u32,
                    sh_degree: a.sh_degree,
                    rest_coeffs: sh_rest_coeffs(s.sh_degree) as u32,
                    scale_stride: a.scale_stride,
                    _pad: [0; 3],
                },
                ctx.groups_1d(a.count as u64, WG),
            );
        }
        if let Some(p) = pool {
            rec.timestamp(p, "preprocess backward");
        }
        Ok(())
    }

    /// Sizes and degrees of the arguments (host side).
    fn check(&self, a: &SurfelBackwardArgs) -> Result<()> {
        let n = a.count;
        let px = a.camera.width() as usize * a.camera.height() as usize;
        ensure!(
            n <= self.capacity,
            "GPU surfel backward: {n} surfels but room for {}; call SurfelBackward::reserve first",
            self.capacity
        );
        ensure!(
            (a.camera_index as usize) < a.cameras.len(),
            "GPU surfel backward: camera index {} but {} cameras",
            a.camera_index,
            a.cameras.len()
        );
        ensure!(
            n <= a.splats.count && n <= a.grads.count,
            "GPU surfel backward: count {n} exceeds the splats ({}) or gradient ({}) count",
            a.splats.count,
            a.grads.count
        );
        ensure!(
            a.grads.sh_degree == a.splats.sh_degree && a.sh_degree <= a.splats.sh_degree,
            "GPU surfel backward: active SH degree {} with stored degree {} and gradient degree \
             {}",
            a.sh_degree,
            a.splats.sh_degree,
            a.grads.sh_degree
        );
        ensure!(
            a.scale_stride >= 2 && a.splats.log_scales.len() >= n * a.scale_stride as usize,
            "GPU surfel backward: log-scale stride {} does not fit the {n} surfels' buffer",
            a.scale_stride
        );
        for (name, len, need) in [
            ("view_grad_norm", a.view_grad_norm.len(), n),
            ("dl_dimage", a.dl_dimage.len(), px * 3),
            ("dl_dmaps", a.dl_dmaps.len(), px * MAP_GRADS_STRIDE),
        ] {
            ensure!(
                len >= need,
                "GPU surfel backward: buffer {name} has {len} elements, needs {need}; size it \
                 for this camera and surfel count"
            );
        }
        Ok(())
    }
}
