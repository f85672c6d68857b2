//! Multi-level exclusive prefix sum of u32 on the GPU (reduce-then-scan, no inter-workgroup
//! waiting, so it needs no forward-progress guarantee). The element count is read on the GPU
//! from a counts buffer, so it can come from an earlier kernel without a host round trip.

use super::dispatch_size::DispatchSize;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use std::sync::Arc;

const WG: u32 = 256;
const ITEMS: u32 = 8;
/// Elements scanned by one workgroup.
pub const SCAN_BLOCK: u64 = (WG * ITEMS) as u64;

/// Reusable scan for arrays of up to `capacity` elements.
pub struct PrefixScan {
    reduce: ComputePipeline,
    downsweep: ComputePipeline,
    /// Partial sums per level above the data: level 1 has ceil(cap / B) entries, ...
    levels: Vec<GpuBuffer<u32>>,
    capacity: u64,
    dummy: GpuBuffer<u32>,
    /// Per level below the top, the group count for this scan's element count (read on the
    /// GPU): a scan of a few elements in a large buffer runs a few workgroups, not the
    /// capacity's.
    sizes: DispatchSize,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ReducePush {
    count_index: u32,
    divisor: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DownPush {
    count_index: u32,
    divisor: u32,
    has_partials: u32,
    total_index: u32,
}

impl PrefixScan {
    pub fn new(ctx: &Arc<GpuContext>, capacity: u64) -> anyhow::Result<Self> {
        let reduce =
            ComputePipeline::new(ctx, "scan/reduce", shaders::SCAN_REDUCE, 3, 8, WG, &[ITEMS])?;
        let downsweep = ComputePipeline::new(
            ctx,
            "scan/downsweep",
            shaders::SCAN_DOWNSWEEP,
            3,
            16,
            WG,
            &[ITEMS],
        )?;
        let mut levels = Vec::new();
        let mut n = capacity.max(1);
        while n > SCAN_BLOCK {
            n = n.div_ceil(SCAN_BLOCK);
            levels.push(GpuBuffer::new(
                ctx,
                "scan partials",
                n as usize,
                BufferKind::DeviceLocal,
            )?);
        }
        let dummy = GpuBuffer::new(ctx, "scan dummy", 1, BufferKind::DeviceLocal)?;
        let sizes = DispatchSize::new(ctx, levels.len())?;
        Ok(Self {
            reduce,
            downsweep,
            levels,
            capacity: capacity.max(1),
            dummy,
            sizes,
        })
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Records an in-place exclusive scan of the first `counts[count_index]` elements of `data`
    /// (at most `capacity`). When `total_index` is given, the sum of all elements is written to
    /// `counts[total_index]`. Barriers are included before and after.
    pub fn record(
        &self,
        rec: &mut Recorder,
        data: &GpuBuffer<u32>,
        counts: &GpuBuffer<u32>,
        count_index: u32,
        total_index: Option<u32>,
    ) {
        rec.barrier();
        let total_index = total_index.unwrap_or(u32::MAX);
        // Level l holds ceil(count / B^l) elements and needs ceil(count / B^(l+1)) groups
        // (the divisor saturates at u32::MAX, where one group is what any u32 count needs).
        // The top level holds at most B elements by construction: one group, no sizing (a
        // scan that fits one block, such as a sort's histograms, adds no dispatch).
        let top = self.levels.len();
        for l in 0..top {
            let per_group = SCAN_BLOCK.saturating_pow(l as u32 + 1);
            self.sizes
                .record(rec, counts, count_index, per_group, l as u32);
        }
        // Up: data -> level 1 -> level 2 ...
        let mut divisor = 1u64;
        for (l, partials) in self.levels.iter().enumerate() {
            let src: &GpuBuffer<u32> = if l == 0 { data } else { &self.levels[l - 1] };
            let (args, at) = self.sizes.args(l as u32);
            rec.dispatch_indirect_named(
                &self.reduce,
                &[("data", src), ("partials", partials), ("counts", counts)],
                &ReducePush {
                    count_index,
                    divisor: divisor as u32,
                },
                args,
                at,
            );
            rec.barrier();
            divisor *= SCAN_BLOCK;
        }
        // Down: scan the top level in one workgroup, then each level below with its offsets.
        for l in (0..=top).rev() {
            let buf: &GpuBuffer<u32> = if l == 0 { data } else { &self.levels[l - 1] };
            let partials: &GpuBuffer<u32> = if l == top {
                &self.dummy
            } else {
                &self.levels[l]
            };
            let divisor = SCAN_BLOCK.pow(l as u32) as u32;
            let push = DownPush {
                count_index,
                divisor,
                has_partials: (l != top) as u32,
                total_index: if l == top { total_index } else { u32::MAX },
            };
            if l == top {
                rec.dispatch_named(
                    &self.downsweep,
                    &[("data", buf), ("partials", partials), ("counts", counts)],
                    &push,
                    [1, 1, 1],
                );
            } else {
                let (args, at) = self.sizes.args(l as u32);
                rec.dispatch_indirect_named(
                    &self.downsweep,
                    &[("data", buf), ("partials", partials), ("counts", counts)],
                    &push,
                    args,
                    at,
                );
            }
            rec.barrier();
        }
    }
}
