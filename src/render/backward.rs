//! The GPU backward pass of the renderer: from `dL/d(image)` to the gradients of every Gaussian
//! parameter, in two kernels that follow [`crate::reference::backward()`] step by step.
//!
//! 1. `glsl/backward/rasterize_backward.comp`: one 16×16 workgroup per tile; each pixel walks
//!    its tile list back to front from its `last_index`, recovering the transmittance in front
//!    of each splat as `T / (1 − alpha)` from `final_t`, and accumulates the gradients of
//!    mean2d, conic, colour and opacity into the intermediate [`Backward::grad2d`] buffer
//!    (summed over each subgroup first, then added atomically: float `atomicAdd` where the
//!    device has it, a compare-and-swap loop on the bits otherwise).
//! 2. `glsl/backward/preprocess_backward.comp`: one invocation per Gaussian carries those to
//!    positions (through the projection, the EWA Jacobian, the camera transform and the SH view
//!    direction), log-scales, quaternions, opacity logits and SH coefficients, and writes the
//!    per-view density-control statistic `view_grad_norm`.
//!
//! # Clamps (each one is also commented where the GLSL applies it)
//! - `power > 0` (only possible through rounding): the splat is skipped at that pixel.
//! - `alpha = min(alpha_max, opacity·exp(power))`: when the clamp is active no gradient reaches
//!   opacity, conic or mean2d through alpha (colour still gets `alpha·T·dL/dC`).
//! - `alpha < alpha_min`: skipped (it did not contribute in the forward).
//! - Smooth mode (`RenderConstants::smooth`): neither the alpha_min skip nor the alpha_max clamp.
//! - Colour clamped at 0 (`ProjectedBoundsGpu::flags`): that channel passes no gradient to the SH
//!   coefficients nor to the position through the view direction.
//! - Determinant `max(det, det_min)`: no gradient through det while active. The determinant is
//!   computed as `|A₀ × A₁|² + eps2d·(a + c) + eps2d²` with `A = J W M` (equal to
//!   `(a + eps2d)(c + eps2d) − b²`, without its cancellation for large thin footprints).
//! - EWA Jacobian `x/z`, `y/z` clamped to `fov_clamp` half-FoV tangents from the principal point:
//!   a clamped ratio is a constant, no gradient through it.
//! - Quaternion with `|q|² < 1e-24` or not finite: identity rotation, no gradient.
//! - SH coefficients above the active degree: gradient 0. Opacity: `σ(x)·σ(−x)` (no `1 − σ`
//!   cancellation at large logits).
//! - Culled Gaussians (`radius == 0`) and Gaussians whose 2D gradients are all zero get zero
//!   gradients (the backward is linear in the 2D gradients, so the latter is exact).
//!
//! # Buffers
//! - `grad2d` (owned here): f32 × 9 per Gaussian, `[mean_x, mean_y, conic_a, conic_b, conic_c,
//!   r, g, b, opacity]` (the gradient of the conic entries with `b` counted once, of the colour
//!   after the clamp, of the activated opacity), zeroed and accumulated by every `record`.
//! - Output gradients: a [`GpuSplats`]-shaped set (`GpuSplats::zeroed(ctx, "grad_", ...)`), all
//!   of Gaussians `0..count` written (not accumulated).
//! - `view_grad_norm`: f32 per Gaussian, `|(dL/du · W/2, dL/dv · H/2)|`, 0 when culled.

use super::layout::{CameraGpu, RenderConstants};
use super::projected::ProjectedBuffers;
use crate::gpu::{Bindable, BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::{grown_capacity, GpuSplats, GRAD_BINDINGS, PARAM_BINDINGS};
use crate::splats::model::sh_rest_coeffs;
use anyhow::{ensure, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;

/// Floats per Gaussian in [`Backward::grad2d`].
pub const GRAD2D_STRIDE: usize = 9;
/// Invocations per workgroup: one tile of 16×16 pixels, and the preprocess block size.
const WG: u32 = 256;

/// Pixels per invocation of the forward rasterizer: 8 on CPU drivers, where a subgroup is a
/// SIMD loop whose per-splat loads and loop overhead cost the same for every lane (see
/// `glsl/render/rasterize.comp`), 1 on GPUs; 1 whenever 8 would leave a partial subgroup.
pub fn default_pixels_per_invocation(info: &crate::gpu::DeviceInfo) -> u32 {
    cpu_pixels_per_invocation(info, 8)
}

/// Pixels per invocation of the 2DGS rasterizer backward: 16 on CPU drivers (its per-surfel
/// reduction is dearer than the forward's loads; measured on the 3DGS backward before it got
/// per-subgroup splat lists, lavapipe, 12k Gaussians at 162×242: 1 → 200 ms, 4 → 77 ms,
/// 8 → 55–68 ms, 16 → 48 ms), 1 on GPUs. The 3DGS backward takes
/// [`default_pixels_per_invocation`] (8 measured best with its lists and per-subgroup sums).
pub fn backward_pixels_per_invocation(info: &crate::gpu::DeviceInfo) -> u32 {
    cpu_pixels_per_invocation(info, 16)
}

/// `want` (a power of two ≤ 16) on CPU devices, halved until the workgroup (256 / pixels) is a
/// whole number of subgroups; 1 on other devices.
fn cpu_pixels_per_invocation(info: &crate::gpu::DeviceInfo, want: u32) -> u32 {
    if !info.device_type.starts_with("CPU") {
        return 1;
    }
    let mut p = want;
    while p > 1 && !(WG / p).is_multiple_of(info.subgroup_size.max(1)) {
        p /= 2;
    }
    p
}

/// Feature channels the rasterizer backward can carry (its per-splat sums hold at most 64
/// floats: 9 gradients, the pixel count, the absolute gradient and the channels).
pub const MAX_FEATURE_CHANNELS: u32 = 48;

/// The most per-pixel feature gradients one invocation of the rasterizer backward holds
/// (pixels an invocation × feature channels). Lavapipe computed wrong gradients at 16 pixels and
/// 48 channels (768) on some random scenes, where 8 × 48 and 16 × 24 matched the reference on
/// every scene tried (tests/gpu/backward.rs); the cause inside the driver is not known, so
/// larger products are refused on every device.
pub const MAX_PIXEL_FEATURES: u32 = 384;

/// Whether the rasterizer backward sums each splat's gradients per subgroup straight into
/// global memory (a transposing butterfly of shuffles, one atomic instruction for all lanes)
/// instead of through shared memory: with several pixels an invocation, i.e. on CPU drivers,
/// where every shared-memory access and reduction is a loop over the lanes (see
/// `glsl/backward/rasterize_backward.glsl`); it needs the subgroup shuffles.
pub(crate) fn subgroup_atomics(info: &crate::gpu::DeviceInfo, pixels: u32) -> bool {
    pixels > 1 && full_kernel(info)
}

/// Whether the device takes `rasterize_backward.comp` (float atomic add and shuffles in its
/// SPIR-V) rather than `rasterize_backward_cas.comp` (neither).
pub(crate) fn full_kernel(info: &crate::gpu::DeviceInfo) -> bool {
    info.float_atomic_add && info.subgroup_shuffle
}

/// The workgroup size of a rasterizer backward with `pixels` pixels per invocation (1, 2, 4, 8
/// or 16, giving whole subgroups), or an error naming `what` and the choices.
pub(crate) fn backward_workgroup(
    info: &crate::gpu::DeviceInfo,
    pixels: u32,
    what: &str,
) -> Result<u32> {
    raster_workgroup(info, pixels, 16, what)
}

/// As [`backward_workgroup`] for a rasterizer that takes at most `max_pixels` pixels an
/// invocation (the 3DGS forward: 8).
pub(crate) fn raster_workgroup(
    info: &crate::gpu::DeviceInfo,
    pixels: u32,
    max_pixels: u32,
    what: &str,
) -> Result<u32> {
    let layouts: Vec<u32> = pixel_layouts(info)
        .into_iter()
        .filter(|&p| p <= max_pixels)
        .collect();
    ensure!(
        layouts.contains(&pixels),
        "{what}: {pixels} pixels per invocation is not a layout it runs here (a power of two up \
         to {max_pixels} that leaves the tile's {WG} pixels in whole subgroups of {}); this \
         device takes {}",
        info.subgroup_size,
        listed(&layouts)
    );
    Ok(WG / pixels)
}

/// The pixels-per-invocation layouts of the rasterizer backwards that `info`'s device can run:
/// 1, 2, 4, 8 or 16 pixels, leaving whole subgroups in a tile's `WG` pixels (all five at
/// lavapipe's 8, up to 8 at NVIDIA's 32, up to 4 at AMD's 64).
pub fn pixel_layouts(info: &crate::gpu::DeviceInfo) -> Vec<u32> {
    [1, 2, 4, 8, 16]
        .into_iter()
        .filter(|p| (WG / p).is_multiple_of(info.subgroup_size.max(1)))
        .collect()
}

/// "1, 2, 4 or 8".
fn listed(values: &[u32]) -> String {
    match values {
        [] => "none".into(),
        [one] => one.to_string(),
        [init @ .., last] => {
            let init: Vec<String> = init.iter().map(u32::to_string).collect();
            format!("{} or {last}", init.join(", "))
        }
    }
}

/// How the rasterizer backward adds gradients into global memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AtomicMode {
    /// Float `atomicAdd` when the device supports it (`ctx.info.float_atomic_add`), else
    /// compare-and-swap.
    Auto,
    /// Always the compare-and-swap loop (tests use it to cover that path on any device).
    CompareSwap,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct RasterPush {
    constants: RenderConstants,
    background: [f32; 4],
    camera_index: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PreprocessPush {
    constants: RenderConstants,
    camera_index: u32,
    count: u32,
    sh_degree: u32,
    rest_coeffs: u32,
}

/// Everything [`Backward::record`] reads and writes. All buffers are the contract buffers of
/// [`super::layout`]; they must hold the forward pass of the same camera, splats and constants.
pub struct BackwardArgs<'a> {
    /// All cameras; the kernels read `cameras[camera_index]`.
    pub cameras: &'a GpuBuffer<CameraGpu>,
    pub camera_index: u32,
    /// Host copy of `cameras[camera_index]`: gives the image and tile-grid sizes for the
    /// dispatch and the argument checks (no readback).
    pub camera: &'a CameraGpu,
    /// Per Gaussian (at least `count`).
    pub projected: &'a ProjectedBuffers,
    /// Per tile, `[start, end)` into `sorted_ids`.
    pub tile_ranges: &'a GpuBuffer<[u32; 2]>,
    pub sorted_ids: &'a GpuBuffer<u32>,
    /// Per pixel.
    pub final_t: &'a GpuBuffer<f32>,
    pub last_index: &'a GpuBuffer<u32>,
    /// `dL/d(image)`, `[(y·W + x)·3 + c]`.
    pub dl_dimage: &'a GpuBuffer<f32>,
    /// The parameters the forward pass rendered.
    pub splats: &'a GpuSplats,
    /// Output: same layout as `splats` (same stored SH degree), Gaussians `0..count` written.
    pub grads: &'a GpuSplats,
    /// Output: f32 per Gaussian.
    pub view_grad_norm: &'a GpuBuffer<f32>,
    /// The forward's 3D filter ([`super::forward::FrameSettings::filter3d`]), if any.
    pub filter3d: Option<&'a GpuBuffer<f32>>,
    /// Output (when given): u32 per Gaussian, the number of pixels it contributed to
    /// (Pixel-GS's n_v(i)); zeroed by the pass. Needs [`Backward::with_pixel_counts`].
    pub pixel_count: Option<&'a GpuBuffer<u32>>,
    /// Output (when given): f32 per Gaussian, Σ over its pixels of |dL/dx_p|·W/2 + |dL/dy_p|·H/2
    /// (the absolute-gradient densification statistic of Gaussian Opacity Fields, which
    /// Mip-Splatting's official code uses); zeroed by the pass. Needs
    /// [`Backward::with_abs_grad`].
    pub abs_grad: Option<&'a GpuBuffer<f32>>,
    pub count: usize,
    /// Active SH degree of the forward pass (≤ `splats.sh_degree`).
    pub sh_degree: u32,
    pub constants: RenderConstants,
    pub background: [f32; 3],
    /// The forward's feature channels ([`super::forward::FrameSettings::features`]), if any.
    pub features: Option<FeatureGrads<'a>>,
}

/// The rasterizer backward's optional outputs (specialisation constants of one kernel).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RasterVariant {
    /// Pixels each splat contributed to ([`BackwardArgs::pixel_count`]).
    pub count_pixels: bool,
    /// The absolute mean-gradient sum ([`BackwardArgs::abs_grad`]).
    pub abs_grad: bool,
    /// Feature channels ([`BackwardArgs::features`]).
    pub extra: u32,
}

/// Feature channels of a forward pass and their gradients.
pub struct FeatureGrads<'a> {
    /// Per Gaussian, `[g·channels + c]`, as the forward read them.
    pub values: &'a GpuBuffer<f32>,
    /// `dL/d(feature image)`, `[pix·channels + c]`.
    pub dl_dimage: &'a GpuBuffer<f32>,
    /// Output, `[g·channels + c]` for Gaussians `0..count` (zeroed, then accumulated).
    pub grads: &'a GpuBuffer<f32>,
    pub channels: u32,
}

/// The backward pass's pipelines and its intermediate per-Gaussian buffer.
pub struct Backward {
    raster: ComputePipeline,
    /// Rasterizer backward variants with more outputs, built on request.
    variants: Vec<(RasterVariant, ComputePipeline)>,
    /// Bound at binding 8 when no pixel counts are asked for (never written).
    no_counts: GpuBuffer<u32>,
    /// Bound in place of an absent 3D filter (never read).
    no_filter: GpuBuffer<f32>,
    pixels: u32,
    preprocess: ComputePipeline,
    grad2d: GpuBuffer<f32>,
    capacity: usize,
    float_atomics: bool,
}

impl Backward {
    /// Pipelines and a `grad2d` buffer for `capacity` Gaussians, float atomics when available.
    pub fn new(ctx: &Arc<GpuContext>, capacity: usize) -> Result<Self> {
        Self::with_atomics(ctx, capacity, AtomicMode::Auto)
    }

    pub fn with_atomics(ctx: &Arc<GpuContext>, capacity: usize, mode: AtomicMode) -> Result<Self> {
        Self::with_pixels(
            ctx,
            capacity,
            mode,
            default_pixels_per_invocation(&ctx.info),
        )
    }

    /// As [`Backward::with_atomics`], with `pixels` (one of [`pixel_layouts`]) pixels per
    /// invocation of the rasterizer backward instead of the device's default (benchmarks compare
    /// them).
    pub fn with_pixels(
        ctx: &Arc<GpuContext>,
        capacity: usize,
        mode: AtomicMode,
        pixels: u32,
    ) -> Result<Self> {
        backward_workgroup(&ctx.info, pixels, "GPU backward")?;
        let float_atomics = mode == AtomicMode::Auto && ctx.info.float_atomic_add;
        let raster = Self::raster_pipeline(ctx, float_atomics, pixels, RasterVariant::default())?;
        let preprocess = ComputePipeline::new(
            ctx,
            "backward/preprocess_backward",
            shaders::BACKWARD_PREPROCESS_BACKWARD,
            25,
            std::mem::size_of::<PreprocessPush>() as u32,
            WG,
            &[],
        )?;
        let capacity = capacity.max(1);
        Ok(Self {
            raster,
            variants: Vec::new(),
            no_counts: GpuBuffer::new(ctx, "no pixel counts", 1, BufferKind::DeviceLocal)?,
            no_filter: GpuBuffer::new(ctx, "no 3D filter", 1, BufferKind::DeviceLocal)?,
            pixels,
            preprocess,
            grad2d: Self::alloc_grad2d(ctx, capacity)?,
            capacity,
            float_atomics,
        })
    }

    /// The rasterizer backward pipeline with `v`'s extra outputs.
    fn raster_pipeline(
        ctx: &Arc<GpuContext>,
        float_atomics: bool,
        pixels: u32,
        v: RasterVariant,
    ) -> Result<ComputePipeline> {
        let wg = WG / pixels.max(1);
        ensure!(
            v.extra <= MAX_FEATURE_CHANNELS,
            "GPU backward: {} feature channels; the rasterizer backward carries at most {MAX_FEATURE_CHANNELS}",
            v.extra
        );
        ensure!(
            pixels * v.extra <= MAX_PIXEL_FEATURES,
            "GPU backward: {} feature channels at {pixels} pixels an invocation ({} per-pixel \
             feature gradients an invocation, at most {MAX_PIXEL_FEATURES}); use fewer pixels an \
             invocation or fewer channels",
            v.extra,
            pixels * v.extra
        );
        let spec = [
            float_atomics as u32,
            pixels,
            v.count_pixels as u32,
            v.extra,
            v.abs_grad as u32,
            subgroup_atomics(&ctx.info, pixels) as u32,
        ];
        let push = std::mem::size_of::<RasterPush>() as u32;
        // A device without float atomics or shuffles gets SPIR-V that declares neither.
        let (name, spirv) = if full_kernel(&ctx.info) {
            (
                "backward/rasterize_backward",
                shaders::BACKWARD_RASTERIZE_BACKWARD,
            )
        } else {
            (
                "backward/rasterize_backward_cas",
                shaders::BACKWARD_RASTERIZE_BACKWARD_CAS,
            )
        };
        ComputePipeline::new(ctx, name, spirv, 13, push, wg, &spec)
    }

    /// Also builds the rasterizer backward with `v`'s outputs, so that arguments asking for
    /// exactly those may be given.
    pub fn with_variant(mut self, ctx: &Arc<GpuContext>, v: RasterVariant) -> Result<Self> {
        if v != RasterVariant::default() && !self.variants.iter().any(|(k, _)| *k == v) {
            let pipe = Self::raster_pipeline(ctx, self.float_atomics, self.pixels, v)?;
            self.variants.push((v, pipe));
        }
        Ok(self)
    }

    /// Also builds the pixel-counting variant, so that [`BackwardArgs::pixel_count`] may be
    /// given (Pixel-GS's statistic needs it).
    pub fn with_pixel_counts(self, ctx: &Arc<GpuContext>) -> Result<Self> {
        self.with_variant(
            ctx,
            RasterVariant {
                count_pixels: true,
                ..Default::default()
            },
        )
    }

    /// Also builds the absolute-gradient variant, so that [`BackwardArgs::abs_grad`] may be
    /// given.
    pub fn with_abs_grad(self, ctx: &Arc<GpuContext>) -> Result<Self> {
        self.with_variant(
            ctx,
            RasterVariant {
                abs_grad: true,
                ..Default::default()
            },
        )
    }

    /// Also builds the variant with `channels` feature channels, so that
    /// [`BackwardArgs::features`] may be given.
    pub fn with_feature_channels(self, ctx: &Arc<GpuContext>, channels: u32) -> Result<Self> {
        ensure!(channels > 0, "GPU backward: 0 feature channels");
        self.with_variant(
            ctx,
            RasterVariant {
                extra: channels,
                ..Default::default()
            },
        )
    }

    fn alloc_grad2d(ctx: &Arc<GpuContext>, capacity: usize) -> Result<GpuBuffer<f32>> {
        GpuBuffer::new(
            ctx,
            "backward grad2d",
            capacity * GRAD2D_STRIDE,
            BufferKind::DeviceLocal,
        )
    }

    /// Number of Gaussians `grad2d` holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Whether the rasterizer backward adds with float atomics (else compare-and-swap).
    pub fn uses_float_atomics(&self) -> bool {
        self.float_atomics
    }

    /// The per-Gaussian 2D gradients of the last recorded pass (layout in the module docs).
    pub fn grad2d(&self) -> &GpuBuffer<f32> {
        &self.grad2d
    }

    /// Makes room for `count` Gaussians (geometric growth). Reallocates `grad2d`: call it only
    /// when no recorded work that uses this `Backward` is pending.
    pub fn reserve(&mut self, ctx: &Arc<GpuContext>, count: usize) -> Result<()> {
        if count > self.capacity {
            let capacity = grown_capacity(count);
            // Freed first: its contents are rewritten every pass.
            self.grad2d = Self::alloc_grad2d(ctx, 0)?;
            self.grad2d = Self::alloc_grad2d(ctx, capacity)?;
            self.capacity = capacity;
        }
        Ok(())
    }

    /// Records the whole backward pass into `rec`: a barrier (so the forward's outputs and any
    /// earlier use of `grad2d` are complete), the zeroing of `grad2d`, the rasterizer backward,
    /// a barrier, the preprocess backward. The caller puts a barrier before reading the outputs.
    pub fn record(&self, ctx: &GpuContext, rec: &mut Recorder, a: &BackwardArgs) -> Result<()> {
        self.record_timed(ctx, rec, a, None)
    }

    /// [`Backward::record`] with GPU timestamps "rasterize backward" and "preprocess backward"
    /// written into `pool` after each half.
    pub fn record_timed(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        a: &BackwardArgs,
        mut pool: Option<&mut crate::gpu::TimestampPool>,
    ) -> Result<()> {
        self.check(a)?;
        let want = RasterVariant {
            count_pixels: a.pixel_count.is_some(),
            abs_grad: a.abs_grad.is_some(),
            extra: a.features.as_ref().map_or(0, |f| f.channels),
        };
        let raster = if want == RasterVariant::default() {
            &self.raster
        } else {
            match self.variants.iter().find(|(k, _)| *k == want) {
                Some((_, p)) => p,
                None => anyhow::bail!(
                    "GPU backward: {want:?} was asked for, but this Backward was not built for \
                     it; build it with Backward::with_variant (or with_pixel_counts, \
                     with_abs_grad, with_feature_channels)"
                ),
            }
        };
        let counts = a.pixel_count.unwrap_or(&self.no_counts);
        rec.barrier();
        rec.fill(&self.grad2d, 0);
        if a.pixel_count.is_some() {
            rec.fill_range(counts, a.count, 0);
        }
        if let Some(b) = a.abs_grad {
            rec.fill_range(b, a.count, 0);
        }
        if let Some(f) = &a.features {
            rec.fill_range(f.grads, a.count * f.channels as usize, 0);
        }
        rec.barrier();
        let raster_push = RasterPush {
            constants: a.constants,
            background: [a.background[0], a.background[1], a.background[2], 0.0],
            camera_index: a.camera_index,
            _pad: [0; 3],
        };
        rec.dispatch_named(
            raster,
            &[
                ("cameras", a.cameras),
                ("splats", &a.projected.splats),
                ("tile_ranges", a.tile_ranges),
                ("sorted_ids", a.sorted_ids),
                ("final_t", a.final_t),
                ("last_index", a.last_index),
                ("dl_dimage", a.dl_dimage),
                ("grad2d_bits", &self.grad2d),
                ("pixel_count", counts),
                (
                    "features",
                    a.features.as_ref().map_or(&self.no_filter, |f| f.values),
                ),
                (
                    "dl_dfeature_image",
                    a.features.as_ref().map_or(&self.no_filter, |f| f.dl_dimage),
                ),
                (
                    "g_features_bits",
                    a.features.as_ref().map_or(&self.no_filter, |f| f.grads),
                ),
                ("abs_grad_bits", a.abs_grad.unwrap_or(&self.no_filter)),
            ],
            &raster_push,
            ctx.groups_1d(a.camera.tile_count() as u64, 1),
        );
        if let Some(p) = pool.as_deref_mut() {
            rec.timestamp(p, "rasterize backward");
        }
        rec.barrier();
        let mut constants = a.constants;
        if a.filter3d.is_some() {
            constants.flags |= RenderConstants::FILTER_3D;
        }
        let push = PreprocessPush {
            constants,
            camera_index: a.camera_index,
            count: a.count as u32,
            sh_degree: a.sh_degree,
            rest_coeffs: sh_rest_coeffs(a.splats.sh_degree) as u32,
        };
        let s = a.splats;
        let g = a.grads;
        if a.count > 0 {
            let own: [(&str, &dyn Bindable); 5] = [
                ("cameras", a.cameras),
                ("bounds", &a.projected.bounds),
                ("grad2d", &self.grad2d),
                ("view_grad_norm", a.view_grad_norm),
                ("filter3d", a.filter3d.unwrap_or(&self.no_filter)),
            ];
            let buffers: Vec<(&str, &dyn Bindable)> = own
                .into_iter()
                .chain(s.bindings(&PARAM_BINDINGS))
                .chain(g.bindings(&GRAD_BINDINGS))
                .collect();
            rec.dispatch_named(
                &self.preprocess,
                &buffers,
                &push,
                ctx.groups_1d(a.count as u64, WG),
            );
        }
        if let Some(p) = pool {
            rec.timestamp(p, "preprocess backward");
        }
        Ok(())
    }

    /// Sizes and degrees of the arguments (host-side, no GPU access).
    fn check(&self, a: &BackwardArgs) -> Result<()> {
        let n = a.count;
        let (w, h) = (a.camera.width() as usize, a.camera.height() as usize);
        ensure!(
            n <= self.capacity,
            "GPU backward: {n} Gaussians but room for {}; call Backward::reserve first",
            self.capacity
        );
        ensure!(
            (a.camera_index as usize) < a.cameras.len(),
            "GPU backward: camera index {} but {} cameras; pass an index into `cameras`",
            a.camera_index,
            a.cameras.len()
        );
        ensure!(
            n <= a.splats.count && n <= a.grads.count,
            "GPU backward: count {n} exceeds the splats ({}) or gradient ({}) count; pass the \
             forward pass's Gaussian count and gradients sized for it",
            a.splats.count,
            a.grads.count
        );
        ensure!(
            a.grads.sh_degree == a.splats.sh_degree && a.sh_degree <= a.splats.sh_degree,
            "GPU backward: active SH degree {} with stored degree {} and gradient degree {}; the \
             gradients need the parameters' layout and the active degree cannot exceed it",
            a.sh_degree,
            a.splats.sh_degree,
            a.grads.sh_degree
        );
        for (name, len, need) in [
            ("projected", a.projected.len(), n),
            ("view_grad_norm", a.view_grad_norm.len(), n),
            ("filter3d", a.filter3d.map_or(usize::MAX, |f| f.len()), n),
            (
                "pixel_count",
                a.pixel_count.map_or(usize::MAX, |c| c.len()),
                n,
            ),
            ("abs_grad", a.abs_grad.map_or(usize::MAX, |c| c.len()), n),
            (
                "tile_ranges",
                a.tile_ranges.len(),
                a.camera.tile_count() as usize,
            ),
            ("final_t", a.final_t.len(), w * h),
            ("last_index", a.last_index.len(), w * h),
            ("dl_dimage", a.dl_dimage.len(), w * h * 3),
        ] {
            ensure!(
                len >= need,
                "GPU backward: buffer {name} has {len} elements, needs {need}; size it for this \
                 camera and Gaussian count"
            );
        }
        let channels = a.features.as_ref().map_or(0, |f| f.channels as usize);
        for (name, len, need) in a.features.iter().flat_map(|f| {
            [
                ("feature values", f.values.len(), n * channels),
                ("feature gradients", f.grads.len(), n * channels),
                ("dL/d(feature image)", f.dl_dimage.len(), w * h * channels),
            ]
        }) {
            ensure!(
                len >= need,
                "GPU backward: buffer {name} has {len} elements, needs {need}; size it for this \
                 camera and Gaussian count"
            );
        }
        for (params, grads) in a.splats.groups().iter().zip(a.grads.groups()) {
            ensure!(
                params.0.len() >= n * params.1 && grads.0.len() >= n * grads.1,
                "GPU backward: parameter buffer {} or gradient buffer {} is shorter than {n} \
                 Gaussians of stride {}; grow it (GpuSplats capacity) first",
                params.0.name(),
                grads.0.name(),
                params.1
            );
        }
        Ok(())
    }
}
