//! A scene's loss masks on the device ([`crate::scene::loss_masks`]): every masked view's cells
//! as bits in one buffer, and the pass that zeroes dL/d(image) at a view's unlearned cells
//! (`glsl/train/mask_grads.comp`; oracle [`crate::reference::loss_mask`]). The trainer records
//! it after the loss, before the backward pass reads the gradient.

use std::sync::Arc;

use anyhow::ensure;

use crate::gpu::{ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::scene::loss_masks::LossMasks;
use crate::shaders;

const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MaskPush {
    width: u32,
    height: u32,
    mask_offset: u32,
    cols: u32,
    rows: u32,
}

/// `cells` as bits, row-major from bit 0 of the first word.
pub fn pack_cells(cells: &[bool]) -> Vec<u32> {
    let mut words = vec![0u32; cells.len().div_ceil(32)];
    for (i, _) in cells.iter().enumerate().filter(|(_, &b)| b) {
        words[i / 32] |= 1 << (i % 32);
    }
    words
}

pub struct GpuLossMasks {
    ctx: Arc<GpuContext>,
    pipe: ComputePipeline,
    bits: GpuBuffer<u32>,
    cols: u32,
    rows: u32,
    /// Per view: its first word in `bits`, or `None` (every pixel learned).
    offsets: Vec<Option<u32>>,
}

impl GpuLossMasks {
    pub fn new(ctx: &Arc<GpuContext>, masks: &LossMasks) -> anyhow::Result<Self> {
        let cells = (masks.cols * masks.rows) as usize;
        let mut words = Vec::new();
        let mut offsets = Vec::with_capacity(masks.views.len());
        for m in &masks.views {
            match m {
                Some(c) => {
                    ensure!(
                        c.len() == cells,
                        "loss masks: a view has {} cells, the grid {cells}",
                        c.len()
                    );
                    offsets.push(Some(words.len() as u32));
                    words.extend(pack_cells(c));
                }
                None => offsets.push(None),
            }
        }
        Ok(Self {
            ctx: ctx.clone(),
            pipe: ComputePipeline::new(
                ctx,
                "train/mask_grads",
                shaders::TRAIN_MASK_GRADS,
                2,
                std::mem::size_of::<MaskPush>() as u32,
                WG,
                &[],
            )?,
            bits: GpuBuffer::from_slice(ctx, "loss mask bits", &words)?,
            cols: masks.cols,
            rows: masks.rows,
            offsets,
        })
    }

    /// Records the mask of view `view` (a `width × height` image) on `grad`, with barriers
    /// before (the loss wrote it) and after (the backward reads it); nothing for a view
    /// without a mask.
    pub fn record(
        &self,
        rec: &mut Recorder,
        view: usize,
        width: u32,
        height: u32,
        grad: &GpuBuffer<f32>,
    ) -> anyhow::Result<()> {
        let Some(&Some(offset)) = self.offsets.get(view) else {
            return Ok(());
        };
        let px = width as u64 * height as u64;
        ensure!(
            grad.len() as u64 >= 3 * px,
            "loss mask: gradient buffer '{}' holds {} floats, a {width}×{height} image needs {}",
            grad.name(),
            grad.len(),
            3 * px
        );
        rec.barrier();
        rec.dispatch_named(
            &self.pipe,
            &[("mask", &self.bits), ("grad", grad)],
            &MaskPush {
                width,
                height,
                mask_offset: offset,
                cols: self.cols,
                rows: self.rows,
            },
            self.ctx.groups_1d(px, WG),
        );
        rec.barrier();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn cells_pack_row_major_from_bit_zero() {
        let mut cells = vec![false; 70];
        for i in [0, 5, 31, 32, 69] {
            cells[i] = true;
        }
        let w = super::pack_cells(&cells);
        assert_eq!(w, vec![1 | 1 << 5 | 1 << 31, 1, 1 << 5]);
    }
}
