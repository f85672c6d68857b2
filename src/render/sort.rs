//! Key–value GPU radix sort: u32 keys, u32 values, 4 bits a pass,
//! only the bits in use. Each pass is reduce-then-scan: per-block digit histograms, one
//! exclusive scan of all histograms, then a stable scatter. No decoupled look-back: Vulkan gives
//! no forward-progress guarantee between workgroups.

use super::dispatch_size::DispatchSize;
use super::scan::PrefixScan;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use std::sync::Arc;

const WG: u32 = 256;
/// Keys per invocation on GPUs: blocks of 2048 keys keep many workgroups in flight.
const GPU_ITEMS: u32 = 8;
/// Keys per invocation on CPU drivers. Lavapipe pays a large fixed cost per workgroup and per
/// invocation (coroutine set-up, the subgroup scans), so bigger blocks sort faster there:
/// `cargo bench --bench sort`, 262k 45-bit keys (the 64-bit keys of the time), 2 loaded cores:
/// 8 → 290 ms, 16 → 208, 32 → 157, 64 → 129, 128 → 144.
const CPU_ITEMS: u32 = 64;
const RADIX: u64 = 16;
const BITS_PER_PASS: u32 = 4;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct UpPush {
    count_index: u32,
    hist_len_index: u32,
    shift: u32,
    digit_mask: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ScatterPush {
    count_index: u32,
    shift: u32,
    digit_mask: u32,
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
    /// Keys per invocation; a block (workgroup) sorts `WG · items` keys.
    items: u32,
    upsweep: ComputePipeline,
    scatter: ComputePipeline,
    scan: PrefixScan,
    hist: GpuBuffer<u32>,
    /// The passes' group counts, from the count on the GPU (not the capacity).
    sizes: DispatchSize,
    capacity: u64,
}

impl RadixSort {
    /// A sorter with the block size suited to the device (see [`CPU_ITEMS`]).
    pub fn new(ctx: &Arc<GpuContext>, capacity: u64) -> anyhow::Result<Self> {
        let items = if ctx.info.device_type.starts_with("CPU") {
            CPU_ITEMS
        } else {
            GPU_ITEMS
        };
        Self::with_items(ctx, capacity, items)
    }

    /// A sorter whose invocations take `items` keys each (tests cover both block sizes on any
    /// device). A block must hold fewer than 65536 keys: the scatter packs per-digit counts in
    /// 16 bits.
    pub fn with_items(ctx: &Arc<GpuContext>, capacity: u64, items: u32) -> anyhow::Result<Self> {
        anyhow::ensure!(
            items >= 1 && (WG as u64) * (items as u64) < 65536,
            "radix sort: {items} keys per invocation makes blocks of 65536 keys or more"
        );
        let capacity = capacity.max(1);
        let upsweep = ComputePipeline::new(
            ctx,
            "sort/upsweep",
            shaders::SORT_UPSWEEP,
            3,
            16,
            WG,
            &[items],
        )?;
        let scatter = ComputePipeline::new(
            ctx,
            "sort/scatter",
            shaders::SORT_SCATTER,
            6,
            12,
            WG,
            &[items],
        )?;
        let hist_len = RADIX * capacity.div_ceil(Self::block_of(items));
        let scan = PrefixScan::new(ctx, hist_len)?;
        let hist = GpuBuffer::new(
            ctx,
            "sort histograms",
            hist_len as usize,
            BufferKind::DeviceLocal,
        )?;
        Ok(Self {
            items,
            upsweep,
            scatter,
            scan,
            hist,
            sizes: DispatchSize::new(ctx, 1)?,
            capacity,
        })
    }

    fn block_of(items: u32) -> u64 {
        WG as u64 * items as u64
    }

    /// Keys per invocation.
    pub fn items(&self) -> u32 {
        self.items
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Number of passes for keys using the low `bits` bits.
    pub fn passes(bits: u32) -> u32 {
        bits.min(32).div_ceil(BITS_PER_PASS)
    }

    /// Records a stable sort of the first `counts[count_index]` pairs of (`keys`, `values`) by
    /// the low `bits` bits of the keys. `counts[hist_len_index]` is used as scratch. The
    /// result ends in the input or the scratch buffers, as returned.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        keys: &GpuBuffer<u32>,
        values: &GpuBuffer<u32>,
        scratch_keys: &GpuBuffer<u32>,
        scratch_values: &GpuBuffer<u32>,
        counts: &GpuBuffer<u32>,
        count_index: u32,
        hist_len_index: u32,
        bits: u32,
    ) -> SortedIn {
        // As many blocks as there are keys this time, not as the capacity holds.
        self.sizes
            .record(rec, counts, count_index, Self::block_of(self.items), 0);
        let (args, at) = self.sizes.args(0);
        let mut from_input = true;
        for pass in 0..Self::passes(bits) {
            let shift = pass * BITS_PER_PASS;
            // The last pass of a width that is not a multiple of 4 takes only the bits left.
            let digit_mask = (1u32 << BITS_PER_PASS.min(bits.min(32) - shift)) - 1;
            let (ki, vi, ko, vo) = if from_input {
                (keys, values, scratch_keys, scratch_values)
            } else {
                (scratch_keys, scratch_values, keys, values)
            };
            rec.barrier();
            rec.dispatch_indirect(
                &self.upsweep,
                &[ki, &self.hist, counts],
                &UpPush {
                    count_index,
                    hist_len_index,
                    shift,
                    digit_mask,
                },
                args,
                at,
            );
            self.scan
                .record(ctx, rec, &self.hist, counts, hist_len_index, None);
            rec.dispatch_indirect(
                &self.scatter,
                &[ki, vi, ko, vo, &self.hist, counts],
                &ScatterPush {
                    count_index,
                    shift,
                    digit_mask,
                },
                args,
                at,
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
