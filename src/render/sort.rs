//! Key–value GPU radix sort: 64-bit keys (as low/high u32 words), u32 values, 4 bits a pass,
//! only the bits in use. Each pass is reduce-then-scan: per-block digit histograms, one
//! exclusive scan of all histograms, then a stable scatter. No decoupled look-back: Vulkan gives
//! no forward-progress guarantee between workgroups.

use super::scan::PrefixScan;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use std::sync::Arc;

const WG: u32 = 256;
const ITEMS: u32 = 8;
/// Keys per block; must stay below 65536 (the scatter packs per-digit counts in 16 bits).
pub const SORT_BLOCK: u64 = (WG * ITEMS) as u64;
const RADIX: u64 = 16;
const BITS_PER_PASS: u32 = 4;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct UpPush {
    count_index: u32,
    hist_len_index: u32,
    shift: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ScatterPush {
    count_index: u32,
    shift: u32,
}

/// Which buffers hold the sorted result after [`RadixSort::record`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SortedIn {
    /// The input buffers (an even number of passes).
    Input,
    /// The scratch buffers (an odd number of passes).
    Scratch,
}

/// A radix sorter for up to `capacity` pairs.
pub struct RadixSort {
    upsweep: ComputePipeline,
    scatter: ComputePipeline,
    scan: PrefixScan,
    hist: GpuBuffer<u32>,
    capacity: u64,
}

impl RadixSort {
    pub fn new(ctx: &Arc<GpuContext>, capacity: u64) -> anyhow::Result<Self> {
        let capacity = capacity.max(1);
        let upsweep = ComputePipeline::new(
            ctx,
            "sort/upsweep",
            shaders::SORT_UPSWEEP,
            3,
            12,
            WG,
            &[ITEMS],
        )?;
        let scatter = ComputePipeline::new(
            ctx,
            "sort/scatter",
            shaders::SORT_SCATTER,
            6,
            8,
            WG,
            &[ITEMS],
        )?;
        let hist_len = RADIX * capacity.div_ceil(SORT_BLOCK);
        let scan = PrefixScan::new(ctx, hist_len)?;
        let hist = GpuBuffer::new(
            ctx,
            "sort histograms",
            hist_len as usize,
            BufferKind::DeviceLocal,
        )?;
        Ok(Self {
            upsweep,
            scatter,
            scan,
            hist,
            capacity,
        })
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Number of passes for keys using the low `bits` bits.
    pub fn passes(bits: u32) -> u32 {
        bits.min(64).div_ceil(BITS_PER_PASS)
    }

    /// Records a stable sort of the first `counts[count_index]` pairs of (`keys`, `values`) by
    /// the low `bits` bits of the keys. `counts[hist_len_index]` is used as scratch. The
    /// result ends in the input or the scratch buffers, as returned.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        keys: &GpuBuffer<[u32; 2]>,
        values: &GpuBuffer<u32>,
        scratch_keys: &GpuBuffer<[u32; 2]>,
        scratch_values: &GpuBuffer<u32>,
        counts: &GpuBuffer<u32>,
        count_index: u32,
        hist_len_index: u32,
        bits: u32,
    ) -> SortedIn {
        let groups = ctx.groups_1d(self.capacity.div_ceil(SORT_BLOCK), 1);
        let mut from_input = true;
        for pass in 0..Self::passes(bits) {
            let shift = pass * BITS_PER_PASS;
            let (ki, vi, ko, vo) = if from_input {
                (keys, values, scratch_keys, scratch_values)
            } else {
                (scratch_keys, scratch_values, keys, values)
            };
            rec.barrier();
            rec.dispatch(
                &self.upsweep,
                &[ki, &self.hist, counts],
                &UpPush {
                    count_index,
                    hist_len_index,
                    shift,
                },
                groups,
            );
            self.scan
                .record(ctx, rec, &self.hist, counts, hist_len_index, None);
            rec.dispatch(
                &self.scatter,
                &[ki, vi, ko, vo, &self.hist, counts],
                &ScatterPush { count_index, shift },
                groups,
            );
            from_input = !from_input;
        }
        rec.barrier();
        if from_input {
            SortedIn::Input
        } else {
            SortedIn::Scratch
        }
    }
}
