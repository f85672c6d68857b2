//! Dispatches sized on the GPU: group counts computed from a count in a GPU buffer, for passes
//! whose real size is only known on the device (the frame's pairs, the live Gaussians), so they
//! run as many workgroups as there is work rather than as the buffers' capacity
//! (glsl/util/dispatch_size.comp says what that costs on CPU drivers).

use std::sync::Arc;

use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push {
    count_index: u32,
    per_group: u32,
    max_x: u32,
    slot: u32,
}

/// Room for `slots` indirect dispatch arguments (3 × u32 each) and the kernel that fills them.
pub struct DispatchSize {
    pipeline: ComputePipeline,
    args: GpuBuffer<u32>,
    max_x: u32,
}

impl DispatchSize {
    pub fn new(ctx: &Arc<GpuContext>, slots: usize) -> anyhow::Result<Self> {
        Ok(Self {
            pipeline: ComputePipeline::new(
                ctx,
                "util/dispatch_size",
                shaders::UTIL_DISPATCH_SIZE,
                2,
                std::mem::size_of::<Push>() as u32,
                1,
                &[],
            )?,
            args: GpuBuffer::new(
                ctx,
                "indirect dispatch sizes",
                3 * slots.max(1),
                BufferKind::DeviceLocal,
            )?,
            max_x: ctx.info.max_workgroup_count[0],
        })
    }

    /// Records, into `slot`, the groups for `counts[count_index]` items at `per_group` items a
    /// workgroup, with the barriers before (the count's writer) and after (the indirect read).
    pub fn record(
        &self,
        rec: &mut Recorder,
        counts: &GpuBuffer<u32>,
        count_index: u32,
        per_group: u64,
        slot: u32,
    ) {
        assert!(
            (slot as usize + 1) * 3 <= self.args.len(),
            "dispatch size slot {slot} out of range"
        );
        rec.barrier();
        rec.dispatch_named(
            &self.pipeline,
            &[("counts", counts), ("args", &self.args)],
            &Push {
                count_index,
                per_group: per_group.clamp(1, u32::MAX as u64) as u32,
                max_x: self.max_x,
                slot,
            },
            [1, 1, 1],
        );
        rec.barrier();
    }

    /// The arguments buffer and the element offset of `slot`, for [`Recorder::dispatch_indirect`].
    pub fn args(&self, slot: u32) -> (&GpuBuffer<u32>, usize) {
        (&self.args, slot as usize * 3)
    }
}
