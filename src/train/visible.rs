//! Visible Adam (`train --visible-adam`): the optimiser step updates only the Gaussians this
//! step's views see, as gsplat's `visible_adam` and the Inria code's `sparse_adam` do. The
//! unseen Gaussians keep their parameters and both Adam moments: no decay of their moments and
//! no drift on old momentum, which makes it a different optimiser from the dense default, not
//! a faster way to the same numbers; what it saves is the Adam work on unseen Gaussians (a
//! bonsai training view sees about a third of the model).
//!
//! "Seen" is the renderer's own test: a radius > 0 out of the view's preprocess (a culled
//! Gaussian has no tile, no pixel and no gradient). The mask has one `u32` per Gaussian; each
//! view of the step marks it (`glsl/train/mark_visible.comp`, the first view writes, batched
//! views OR in) and the Adam step reads it (`glsl/train/adam_visible.comp`).

use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::render::layout::ProjectedBoundsGpu;
use crate::shaders;
use anyhow::ensure;
use std::sync::Arc;

const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MarkPush {
    count: u32,
    first: u32,
}

/// The per-Gaussian "seen this step" mask and the kernel that marks it.
pub struct VisibleMask {
    pipe: ComputePipeline,
    mask: GpuBuffer<u32>,
}

impl VisibleMask {
    /// A mask for up to `capacity` Gaussians.
    pub fn new(ctx: &Arc<GpuContext>, capacity: usize) -> anyhow::Result<Self> {
        let pipe = ComputePipeline::new(
            ctx,
            "train/mark_visible",
            shaders::TRAIN_MARK_VISIBLE,
            2,
            std::mem::size_of::<MarkPush>() as u32,
            WG,
            &[],
        )?;
        let mask = GpuBuffer::new(ctx, "visible mask", capacity, BufferKind::DeviceLocal)?;
        Ok(Self { pipe, mask })
    }

    /// Room for `capacity` Gaussians. The contents are not kept: every step rewrites the mask
    /// before its Adam step reads it.
    pub fn reserve(&mut self, ctx: &Arc<GpuContext>, capacity: usize) -> anyhow::Result<()> {
        if self.mask.len() < capacity {
            // Free the old buffer first: nothing in it is needed.
            self.mask = GpuBuffer::new(ctx, "visible mask", 0, BufferKind::DeviceLocal)?;
            self.mask = GpuBuffer::new(ctx, "visible mask", capacity, BufferKind::DeviceLocal)?;
        }
        Ok(())
    }

    /// Records the marking of the Gaussians one view sees, from that view's `bounds` (the
    /// first `count` Gaussians): `first` for the step's first view (the mask is written), the
    /// later views of a batched step OR into it. The bounds must be complete (the view's
    /// preprocess behind a barrier); the mask is read after the next barrier.
    pub fn record_view(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        bounds: &GpuBuffer<ProjectedBoundsGpu>,
        count: usize,
        first: bool,
    ) -> anyhow::Result<()> {
        ensure!(
            count <= self.mask.len() && count <= bounds.len(),
            "visible mask: {count} Gaussians, the mask holds {} and the bounds {}",
            self.mask.len(),
            bounds.len()
        );
        if count == 0 {
            return Ok(());
        }
        let push = MarkPush {
            count: count as u32,
            first: first as u32,
        };
        rec.dispatch(
            &self.pipe,
            &[bounds, &self.mask],
            &push,
            ctx.groups_1d(count as u64, WG),
        );
        Ok(())
    }

    /// The mask (one entry per Gaussian, non-zero = seen this step).
    pub fn mask(&self) -> &GpuBuffer<u32> {
        &self.mask
    }
}
