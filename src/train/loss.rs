//! The training loss on the GPU: `(1 − w)·L1 + w·(1 − SSIM)` of the rendered image against the
//! ground truth, and its gradient with respect to the rendered image.
//!
//! Same definition as [`crate::metrics`] (its f64 `loss_terms_and_grad` is the oracle): SSIM with
//! an 11×11 Gaussian window (σ = 1.5), zero padding, C1 = 0.01², C2 = 0.03², averaged over pixels
//! and channels. The ground truth is packed RGBA8 (`r` in the low byte) composited over a
//! background colour: `gt = rgb·a + bg·(1 − a)`.
//!
//! Two layouts ([`LossLayout`]), the same definition and tests for both:
//!
//! *Segments* (the default on every device; it suits CPU drivers): five dispatches; the blurs
//! are separable 11-tap passes in which each invocation produces a segment of outputs from
//! inputs held in registers (see `glsl/train/loss_common.glsl`):
//! 1. `ssim_fwd_h`: horizontal blur of x, y, x², y², xy (15 maps);
//! 2. `ssim_fwd_v`: vertical blur, SSIM per pixel and its derivatives with respect to the
//!    blurred moments (9 maps), per-tile sums of |x − y| and SSIM;
//! 3. `loss_reduce` (one workgroup, fixed order: deterministic) and `ssim_bwd_h` (horizontal blur
//!    of the 9 maps), independent of each other;
//! 4. `ssim_bwd_v`: vertical blur and the gradient, written over the whole output.
//!
//! *Tiles* (for GPUs; chosen by hand until timed on one, [`Loss::new`]): three dispatches; a
//! workgroup owns a 16×16 block, one pixel an invocation, and blurs in shared memory, so neither
//! the 15 moment maps nor the horizontally blurred derivatives go through global memory and
//! every access is coalesced:
//! 1. `ssim_fwd_tile`: both blurs, SSIM and its 9 derivative maps, per-block sums;
//! 2. `loss_reduce` and `ssim_bwd_tile` (both blurs of the 9 maps and the gradient).

use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use anyhow::{bail, Result};
use std::sync::Arc;

/// Floats per loss slot in `loss_out`: L1, SSIM, total.
pub const LOSS_SLOT_FLOATS: usize = 3;

/// Invocations per workgroup of the blur passes: adjacent rows (horizontal passes) or columns
/// (vertical passes).
const BLUR_WG: u32 = 32;
/// Outputs per invocation along the blur direction: must equal `SEG` in
/// `glsl/train/loss_common.glsl`.
const SEG: u32 = 16;
const REDUCE_WG: u32 = 256;
/// Pixels along a side of the tile layout's blocks: must equal `TILE` in
/// `glsl/train/ssim_fwd_tile.comp` and `ssim_bwd_tile.comp`.
const TILE: u32 = 16;

/// How the loss kernels share out the image (module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LossLayout {
    /// Row and column segments, inputs in registers: suits CPU drivers, where every load is a
    /// per-lane gather and shared memory a loop over lanes.
    Segments,
    /// 16×16 blocks blurred in shared memory, one pixel an invocation: for GPUs (7× slower on
    /// lavapipe).
    Tiles,
}

impl LossLayout {
    /// The layout's name on the command line (`train --loss-layout`).
    pub fn name(self) -> &'static str {
        match self {
            LossLayout::Segments => "segments",
            LossLayout::Tiles => "tiles",
        }
    }

    /// Parses a layout name ([`LossLayout::name`]).
    pub fn parse(s: &str) -> std::result::Result<LossLayout, String> {
        match s {
            "segments" => Ok(LossLayout::Segments),
            "tiles" => Ok(LossLayout::Tiles),
            _ => Err(format!("unknown loss layout '{s}': use segments or tiles")),
        }
    }
}

/// Moment maps per channel after the forward horizontal pass (μx, μy, E[x²], E[y²], E[xy]).
const FWD_MAPS: usize = 5;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LossPush {
    width: u32,
    height: u32,
    gt_offset: u32,
    loss_slot: u32,
    background: [f32; 3],
    ssim_weight: f32,
    inv_n: f32,
    partial_count: u32,
}

/// The loss kernels and their scratch buffers, sized for images up to `max_width × max_height`.
pub struct Loss {
    layout: LossLayout,
    /// The layout's own kernels (only those are built).
    kernels: Kernels,
    reduce: ComputePipeline,
    /// Per channel: the 5 forward moment maps, later reused for the 3 horizontally blurred
    /// backward maps (the segment layout only).
    moments: Option<[GpuBuffer<f32>; 3]>,
    /// Per channel: dS/dμx, dS/dE[x²], dS/dE[xy].
    derivs: [GpuBuffer<f32>; 3],
    /// Per workgroup of the pass that sums: (sum |x − y|, sum SSIM).
    partials: GpuBuffer<f32>,
    max_width: u32,
    max_height: u32,
}

/// The passes of one layout.
enum Kernels {
    Segments {
        fwd_h: ComputePipeline,
        fwd_v: ComputePipeline,
        bwd_h: ComputePipeline,
        bwd_v: ComputePipeline,
    },
    Tiles {
        fwd: ComputePipeline,
        bwd: ComputePipeline,
    },
}

/// Workgroups of the vertical passes: columns in x, row segments in y.
fn v_groups(w: u32, h: u32) -> [u32; 3] {
    [w.div_ceil(BLUR_WG), h.div_ceil(SEG), 1]
}

/// Workgroups of the horizontal passes: rows in x, column segments in y.
fn h_groups(w: u32, h: u32) -> [u32; 3] {
    [h.div_ceil(BLUR_WG), w.div_ceil(SEG), 1]
}

/// Workgroups of the tile layout: 16×16 blocks.
fn tile_groups(w: u32, h: u32) -> [u32; 3] {
    [w.div_ceil(TILE), h.div_ceil(TILE), 1]
}

/// Workgroups of the pass that writes the partial sums (`ssim_fwd_v` or `ssim_fwd_tile`).
fn sum_groups(layout: LossLayout, w: u32, h: u32) -> [u32; 3] {
    match layout {
        LossLayout::Segments => v_groups(w, h),
        LossLayout::Tiles => tile_groups(w, h),
    }
}

impl Loss {
    /// The loss in the segment layout, on every device: the tile layout is built for GPUs and
    /// checked like it, but not yet timed on one (on lavapipe it is 7× slower), so it is chosen
    /// by hand (`train --loss-layout tiles`) until a GPU measurement says which is faster there.
    pub fn new(ctx: &Arc<GpuContext>, max_width: u32, max_height: u32) -> Result<Self> {
        Self::with_layout(ctx, max_width, max_height, LossLayout::Segments)
    }

    /// The loss in `layout` (tests run both on any device).
    pub fn with_layout(
        ctx: &Arc<GpuContext>,
        max_width: u32,
        max_height: u32,
        layout: LossLayout,
    ) -> Result<Self> {
        let pipe = |name: &str, spv: &[u8], buffers: u32, wg: u32| {
            ComputePipeline::new(
                ctx,
                name,
                spv,
                buffers,
                std::mem::size_of::<LossPush>() as u32,
                wg,
                &[],
            )
        };
        let kernels = match layout {
            LossLayout::Tiles => Kernels::Tiles {
                fwd: pipe(
                    "train/ssim_fwd_tile",
                    shaders::TRAIN_SSIM_FWD_TILE,
                    6,
                    TILE * TILE,
                )?,
                bwd: pipe(
                    "train/ssim_bwd_tile",
                    shaders::TRAIN_SSIM_BWD_TILE,
                    6,
                    TILE * TILE,
                )?,
            },
            LossLayout::Segments => Kernels::Segments {
                fwd_h: pipe("train/ssim_fwd_h", shaders::TRAIN_SSIM_FWD_H, 5, BLUR_WG)?,
                fwd_v: pipe("train/ssim_fwd_v", shaders::TRAIN_SSIM_FWD_V, 9, BLUR_WG)?,
                bwd_h: pipe("train/ssim_bwd_h", shaders::TRAIN_SSIM_BWD_H, 6, BLUR_WG)?,
                bwd_v: pipe("train/ssim_bwd_v", shaders::TRAIN_SSIM_BWD_V, 6, BLUR_WG)?,
            },
        };
        let reduce = pipe(
            "train/loss_reduce",
            shaders::TRAIN_LOSS_REDUCE,
            2,
            REDUCE_WG,
        )?;
        let (moments, derivs, partials) = Self::alloc(ctx, layout, max_width, max_height)?;
        Ok(Self {
            layout,
            kernels,
            reduce,
            moments,
            derivs,
            partials,
            max_width: max_width.max(1),
            max_height: max_height.max(1),
        })
    }

    /// The layout these kernels run in.
    pub fn layout(&self) -> LossLayout {
        self.layout
    }

    #[allow(clippy::type_complexity)]
    fn alloc(
        ctx: &Arc<GpuContext>,
        layout: LossLayout,
        w: u32,
        h: u32,
    ) -> Result<(
        Option<[GpuBuffer<f32>; 3]>,
        [GpuBuffer<f32>; 3],
        GpuBuffer<f32>,
    )> {
        let px = w.max(1) as usize * h.max(1) as usize;
        let chan = |what: &str, maps: usize| -> Result<[GpuBuffer<f32>; 3]> {
            let b = |c: &str| {
                GpuBuffer::new(
                    ctx,
                    &format!("loss {what} {c}"),
                    maps * px,
                    BufferKind::DeviceLocal,
                )
            };
            Ok([b("r")?, b("g")?, b("b")?])
        };
        let moments = match layout {
            LossLayout::Segments => Some(chan("moments", FWD_MAPS)?),
            LossLayout::Tiles => None,
        };
        let derivs = chan("ssim derivatives", 3)?;
        let g = sum_groups(layout, w.max(1), h.max(1));
        let partials = GpuBuffer::new(
            ctx,
            "loss partial sums",
            2 * (g[0] * g[1]) as usize,
            BufferKind::DeviceLocal,
        )?;
        Ok((moments, derivs, partials))
    }

    /// Largest image size the scratch buffers hold.
    pub fn max_size(&self) -> (u32, u32) {
        (self.max_width, self.max_height)
    }

    /// Grows the scratch buffers to hold `width × height` images (never shrinks). Call it only
    /// when no recorded work that uses this `Loss` is pending: the old buffers are freed here.
    pub fn ensure_size(&mut self, ctx: &Arc<GpuContext>, width: u32, height: u32) -> Result<()> {
        if width <= self.max_width && height <= self.max_height {
            return Ok(());
        }
        let w = width.max(self.max_width);
        let h = height.max(self.max_height);
        let (moments, derivs, partials) = Self::alloc(ctx, self.layout, w, h)?;
        self.moments = moments;
        self.derivs = derivs;
        self.partials = partials;
        self.max_width = w;
        self.max_height = h;
        Ok(())
    }

    /// Records the loss of `image` (W×H RGB f32 interleaved) against the ground truth at
    /// `gt[gt_offset_px .. gt_offset_px + W·H]` (packed RGBA8) composited over `background`.
    /// Writes dL/d(image) over all of `grad_out` (W×H×3, same layout as the image) and
    /// `loss_out[3·loss_index ..][..3]` = L1, SSIM, total, with total = (1 − w)·L1 + w·(1 − SSIM)
    /// and w = `ssim_weight` (0.2 in 3DGS).
    ///
    /// Barriers are recorded before (the image may have just been written) and after (the
    /// gradient and loss are ready for the next dispatch).
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        rec: &mut Recorder,
        image: &GpuBuffer<f32>,
        gt: &GpuBuffer<u32>,
        gt_offset_px: u32,
        width: u32,
        height: u32,
        background: [f32; 3],
        grad_out: &GpuBuffer<f32>,
        loss_out: &GpuBuffer<f32>,
        loss_index: u32,
        ssim_weight: f32,
    ) -> Result<()> {
        if width == 0 || height == 0 {
            bail!("loss: the image is {width}×{height}, which has no pixels");
        }
        if width > self.max_width || height > self.max_height {
            bail!(
                "loss: a {width}×{height} image exceeds the scratch size {}×{} (call Loss::ensure_size first)",
                self.max_width,
                self.max_height
            );
        }
        let px = width as usize * height as usize;
        if image.len() < 3 * px {
            bail!(
                "loss: image buffer '{}' has {} floats, a {width}×{height} RGB image needs {}",
                image.name(),
                image.len(),
                3 * px
            );
        }
        if grad_out.len() < 3 * px {
            bail!(
                "loss: gradient buffer '{}' has {} floats, a {width}×{height} RGB image needs {}",
                grad_out.name(),
                grad_out.len(),
                3 * px
            );
        }
        if gt_offset_px as usize + px > gt.len() {
            bail!(
                "loss: ground truth pixels {gt_offset_px}..{} are outside buffer '{}' of {} pixels",
                gt_offset_px as usize + px,
                gt.name(),
                gt.len()
            );
        }
        if (loss_index as usize + 1) * LOSS_SLOT_FLOATS > loss_out.len() {
            bail!(
                "loss: slot {loss_index} needs {} floats in '{}', which has {}",
                (loss_index as usize + 1) * LOSS_SLOT_FLOATS,
                loss_out.name(),
                loss_out.len()
            );
        }
        if !(0.0..=1.0).contains(&ssim_weight) {
            bail!("loss: ssim_weight {ssim_weight} is outside [0, 1]");
        }
        let sums = sum_groups(self.layout, width, height);
        let push = LossPush {
            width,
            height,
            gt_offset: gt_offset_px,
            loss_slot: loss_index,
            background,
            ssim_weight,
            inv_n: 1.0 / (3 * px) as f32,
            partial_count: sums[0] * sums[1],
        };
        let [d0, d1, d2] = &self.derivs;
        rec.barrier();
        match (&self.kernels, &self.moments) {
            (Kernels::Tiles { fwd, bwd }, _) => {
                rec.dispatch_named(
                    fwd,
                    &[
                        ("image", image),
                        ("gt", gt),
                        ("out0", d0),
                        ("out1", d1),
                        ("out2", d2),
                        ("partials", &self.partials),
                    ],
                    &push,
                    sums,
                );
                rec.barrier();
                rec.dispatch_named(
                    &self.reduce,
                    &[("partials", &self.partials), ("loss_out", loss_out)],
                    &push,
                    [1, 1, 1],
                );
                rec.dispatch_named(
                    bwd,
                    &[
                        ("image", image),
                        ("gt", gt),
                        ("in0", d0),
                        ("in1", d1),
                        ("in2", d2),
                        ("grad", grad_out),
                    ],
                    &push,
                    sums,
                );
            }
            (
                Kernels::Segments {
                    fwd_h,
                    fwd_v,
                    bwd_h,
                    bwd_v,
                },
                Some([m0, m1, m2]),
            ) => {
                let hg = h_groups(width, height);
                rec.dispatch_named(
                    fwd_h,
                    &[
                        ("image", image),
                        ("gt", gt),
                        ("out0", m0),
                        ("out1", m1),
                        ("out2", m2),
                    ],
                    &push,
                    hg,
                );
                rec.barrier();
                rec.dispatch_named(
                    fwd_v,
                    &[
                        ("image", image),
                        ("gt", gt),
                        ("in0", m0),
                        ("in1", m1),
                        ("in2", m2),
                        ("out0", d0),
                        ("out1", d1),
                        ("out2", d2),
                        ("partials", &self.partials),
                    ],
                    &push,
                    sums,
                );
                rec.barrier();
                rec.dispatch_named(
                    &self.reduce,
                    &[("partials", &self.partials), ("loss_out", loss_out)],
                    &push,
                    [1, 1, 1],
                );
                rec.dispatch_named(
                    bwd_h,
                    &[
                        ("in0", d0),
                        ("in1", d1),
                        ("in2", d2),
                        ("out0", m0),
                        ("out1", m1),
                        ("out2", m2),
                    ],
                    &push,
                    hg,
                );
                rec.barrier();
                rec.dispatch_named(
                    bwd_v,
                    &[
                        ("image", image),
                        ("gt", gt),
                        ("in0", m0),
                        ("in1", m1),
                        ("in2", m2),
                        ("grad", grad_out),
                    ],
                    &push,
                    sums,
                );
            }
            (Kernels::Segments { .. }, None) => {
                bail!("loss: the segment layout's moment maps are missing")
            }
        }
        rec.barrier();
        Ok(())
    }
}
