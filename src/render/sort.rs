//! Key–value GPU radix sort: u32 keys, u32 values, 4 or 5 bits a pass (as few passes as the
//! bits in use need, the narrow digit wherever it does not cost a pass), or 8 bits a pass ranked
//! by subgroup ballots ([`Digits::Byte`]). Each pass is reduce-then-scan: per-block digit
//! histograms, one exclusive scan of all histograms, then a stable scatter. No decoupled
//! look-back: Vulkan gives no forward-progress guarantee between workgroups.

use super::dispatch_size::DispatchSize;
use super::scan::PrefixScan;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use std::sync::Arc;

/// The keys a block (workgroup) sorts: `wg` invocations of `items` keys each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockShape {
    pub wg: u32,
    pub items: u32,
}

impl BlockShape {
    /// GPUs: 256 invocations of 8 keys; blocks of 2,048 keys keep many workgroups in flight.
    pub const GPU: Self = Self { wg: 256, items: 8 };
    /// CPU drivers: 64 invocations of 256 keys. Lavapipe runs a workgroup on one thread and pays
    /// per block for what every subgroup does whatever its keys (the scatter's subgroup scans,
    /// each subgroup adding the totals of the subgroups before it, the histogram loads), so big
    /// blocks with few invocations sort faster there. 256 × 64 (the shape until 2026-11-27)
    /// against this one, both 16,384 keys, alternated on one machine: training's depth sort
    /// 12.4–13.1 → 4.9–6.0 ms at 3,000 Gaussians, 36–37 → 25–27 ms at 56k (Truck `-r 4`), and
    /// the tile sort of a 100k-Gaussian frame at 1352×1014 0.28–0.29 of the rasterize time
    /// against 0.35–0.36 (docs/results/speed-lavapipe.md).
    /// Earlier, at 256 invocations (`cargo bench --bench sort`, 262k 45-bit keys): 8 keys an
    /// invocation 290 ms, 16 208, 32 157, 64 129, 128 144.
    pub const CPU: Self = Self { wg: 64, items: 256 };

    /// Keys a block holds.
    pub fn keys(self) -> u64 {
        self.wg as u64 * self.items as u64
    }
}

/// The narrow digit, and the wide one used only where it saves a pass: a 5-bit scatter keeps
/// twice the per-invocation counters of a 4-bit one, so it costs more a key.
const NARROW_BITS: u32 = 4;
const WIDE_BITS: u32 = 5;
/// The ballot-ranked scatter's digit.
const BYTE_BITS: u32 = 8;

/// The digit widths a sorter uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Digits {
    /// 4-bit passes only.
    Narrow,
    /// 4-bit passes, widened to 5 bits where that saves a pass (13 bits: 5 + 4 + 4).
    Wide,
    /// 8-bit passes (the last one masked to the bits left), ranked by subgroup ballots
    /// (`glsl/sort/scatter_ranked.comp`): 31-bit depths in 4 passes instead of 7, 13-bit tile
    /// ids in 2 instead of 3, each pass with 8 ballots a key and a histogram of 256 digits a
    /// block. For GPUs; not the default until timed on one (`--sort-digits 8` to try it).
    Byte,
}

impl Digits {
    /// The widest digit's bits.
    pub fn max_bits(self) -> u32 {
        match self {
            Digits::Narrow => NARROW_BITS,
            Digits::Wide => WIDE_BITS,
            Digits::Byte => BYTE_BITS,
        }
    }

    /// Histogram entries a block at the widest digit.
    fn max_radix(self) -> u64 {
        1 << self.max_bits()
    }

    /// The digits chosen for a device: `--sort-digits` ([`GpuContext::sort_digit_bits`]) when
    /// given (4: [`Digits::Wide`], 8: [`Digits::Byte`]), else [`Digits::Wide`].
    pub fn for_device(ctx: &GpuContext) -> Self {
        match ctx.sort_digit_bits {
            Some(8) => Digits::Byte,
            _ => Digits::Wide,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct UpPush {
    count_index: u32,
    hist_len_index: u32,
    shift: u32,
    digit_mask: u32,
    drop_keys: u32,
    drop_key: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ScatterPush {
    count_index: u32,
    shift: u32,
    digit_mask: u32,
    drop_keys: u32,
    drop_key: u32,
}

/// Keys to leave out of a sort: every key equal to `key` (all 32 bits) is dropped by the first
/// pass, and the later passes sort only the `counts[kept_index]` keys kept, which end first in
/// the output, in order; nothing is written past them. The renderer drops culled Gaussians this
/// way: they cost one pass instead of all, and no extra pass compacts them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DropKeys {
    pub key: u32,
    pub kept_index: u32,
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
    /// The keys a workgroup sorts.
    shape: BlockShape,
    /// The digit widths of the passes ([`RadixSort::pass_widths`]).
    digits: Digits,
    /// Whether the kernels can drop keys ([`RadixSort::dropping`]).
    drops: bool,
    /// The upsweep and scatter pipelines of each digit width the sorter uses.
    pipes: Vec<(u32, [ComputePipeline; 2])>,
    scan: PrefixScan,
    hist: GpuBuffer<u32>,
    /// The passes' group counts, from the count on the GPU (not the capacity).
    sizes: DispatchSize,
    capacity: u64,
}

impl RadixSort {
    /// A sorter with the digits and block size suited to the device ([`Digits::for_device`],
    /// [`RadixSort::device_shape`]).
    pub fn new(ctx: &Arc<GpuContext>, capacity: u64) -> anyhow::Result<Self> {
        let digits = Digits::for_device(ctx);
        Self::with_options(ctx, capacity, Self::shape_for(ctx, digits), digits, false)
    }

    /// [`RadixSort::new`] whose sorts may drop keys ([`RadixSort::record_dropping`]).
    pub fn dropping(ctx: &Arc<GpuContext>, capacity: u64) -> anyhow::Result<Self> {
        let digits = Digits::for_device(ctx);
        Self::with_options(ctx, capacity, Self::shape_for(ctx, digits), digits, true)
    }

    /// The block shape suited to the device for 4- and 5-bit digits ([`BlockShape::CPU`] on
    /// CPU drivers).
    pub fn device_shape(ctx: &GpuContext) -> BlockShape {
        if ctx.info.device_type.starts_with("CPU") {
            BlockShape::CPU
        } else {
            BlockShape::GPU
        }
    }

    /// The block shape for `digits` on the device: byte digits always take [`BlockShape::GPU`]
    /// (their block is ordered in shared memory, which CPU drivers' big blocks do not fit).
    pub fn shape_for(ctx: &GpuContext, digits: Digits) -> BlockShape {
        match digits {
            Digits::Byte => BlockShape::GPU,
            _ => Self::device_shape(ctx),
        }
    }

    /// A sorter with blocks of `shape`, 4-bit passes only (tests cover both shapes on any
    /// device).
    pub fn with_shape(
        ctx: &Arc<GpuContext>,
        capacity: u64,
        shape: BlockShape,
    ) -> anyhow::Result<Self> {
        Self::with_options(ctx, capacity, shape, Digits::Narrow, false)
    }

    /// Shared memory the ballot-ranked scatter of blocks of `shape` takes on the device, in
    /// bytes (`glsl/sort/scatter_ranked.comp`: the larger of the per-subgroup counters and the
    /// block's pairs, the digits' two starts, the workgroup scan's sums).
    pub fn ranked_shared_bytes(info: &crate::gpu::DeviceInfo, shape: BlockShape) -> u64 {
        let subgroups = (shape.wg / info.min_subgroup_size.max(1)).max(1) as u64;
        let counters = (1u64 << BYTE_BITS) / 2 * subgroups;
        4 * counters.max(2 * shape.keys()) + 2 * 4 * (1 << BYTE_BITS) + 4 * shape.wg as u64 + 4
    }

    /// A sorter with blocks of `shape` and `digits`; `drops` sorts that drop keys (the kernels
    /// of a sorter that never drops leave the test out: it cost the tile sort about a tenth on
    /// lavapipe). A block must hold fewer than 65536 keys (the scatters pack per-digit counts
    /// in 16 bits) and have an invocation per digit of the widest pass.
    pub fn with_options(
        ctx: &Arc<GpuContext>,
        capacity: u64,
        shape: BlockShape,
        digits: Digits,
        drops: bool,
    ) -> anyhow::Result<Self> {
        anyhow::ensure!(
            shape.items >= 1 && shape.keys() < 65536,
            "radix sort: blocks of {} × {} keys: 65536 keys or more",
            shape.wg,
            shape.items
        );
        let max_radix = digits.max_radix();
        anyhow::ensure!(
            shape.wg as u64 >= max_radix,
            "radix sort: blocks of {} invocations: fewer than the {max_radix} digits of a pass",
            shape.wg
        );
        if digits == Digits::Byte {
            let need = Self::ranked_shared_bytes(&ctx.info, shape);
            anyhow::ensure!(
                need <= ctx.info.max_shared_memory as u64,
                "radix sort: 8-bit digits in blocks of {} × {} keys need {need} bytes of shared \
                 memory; this device has {}. Fix: sort with 4-bit digits (--sort-digits 4)",
                shape.wg,
                shape.items,
                ctx.info.max_shared_memory
            );
        }
        let capacity = capacity.max(1);
        let reorder = Self::reorders(&ctx.info, shape);
        let pipes = |digit_bits: u32| -> anyhow::Result<(u32, [ComputePipeline; 2])> {
            let (scatter_name, scatter_spirv, last) = if digit_bits == BYTE_BITS {
                (
                    "sort/scatter_ranked",
                    shaders::SORT_SCATTER_RANKED,
                    ctx.info.min_subgroup_size.max(1),
                )
            } else {
                ("sort/scatter", shaders::SORT_SCATTER, u32::from(reorder))
            };
            let constants = [shape.items, digit_bits, u32::from(drops), last];
            Ok((
                digit_bits,
                [
                    ComputePipeline::new(
                        ctx,
                        "sort/upsweep",
                        shaders::SORT_UPSWEEP,
                        3,
                        std::mem::size_of::<UpPush>() as u32,
                        shape.wg,
                        &constants,
                    )?,
                    ComputePipeline::new(
                        ctx,
                        scatter_name,
                        scatter_spirv,
                        6,
                        std::mem::size_of::<ScatterPush>() as u32,
                        shape.wg,
                        &constants,
                    )?,
                ],
            ))
        };
        let widths: &[u32] = match digits {
            Digits::Narrow => &[NARROW_BITS],
            Digits::Wide => &[NARROW_BITS, WIDE_BITS],
            Digits::Byte => &[BYTE_BITS],
        };
        let pipes = widths
            .iter()
            .map(|&w| pipes(w))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let hist_len = max_radix * capacity.div_ceil(shape.keys());
        let scan = PrefixScan::new(ctx, hist_len)?;
        let hist = GpuBuffer::new(
            ctx,
            "sort histograms",
            hist_len as usize,
            BufferKind::DeviceLocal,
        )?;
        Ok(Self {
            shape,
            digits,
            drops,
            pipes,
            scan,
            hist,
            sizes: DispatchSize::new(ctx, 2)?,
            capacity,
        })
    }

    /// Whether the scatter of blocks of `shape` orders each block in shared memory before
    /// writing it out (see `glsl/sort/scatter.comp`): where a block's keys and values fit beside
    /// the scatter's other shared arrays, i.e. GPUs' blocks (8 keys an invocation), not
    /// lavapipe's (256; its stores are per lane anyway, so coalescing gains nothing there).
    pub fn reorders(info: &crate::gpu::DeviceInfo, shape: BlockShape) -> bool {
        // The block's pairs share their memory with the subgroups' totals (room for subgroups
        // of one); beside them, the digits' two starts.
        let radix = 1u64 << WIDE_BITS;
        let pool = (2 * 4 * shape.keys()).max(4 * shape.wg as u64 * (radix / 2));
        shape.items <= BlockShape::GPU.items
            && pool + 2 * 4 * radix <= info.max_shared_memory as u64
    }

    /// The keys a workgroup sorts.
    pub fn shape(&self) -> BlockShape {
        self.shape
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// The digits this sorter uses.
    pub fn digits(&self) -> Digits {
        self.digits
    }

    /// The digit width of each pass for keys using the low `bits` bits, low digits first: as
    /// many 4-bit passes as the bits need, unless 5-bit digits ([`Digits::Wide`]) need fewer
    /// passes; then only as many passes are widened as that takes (13 bits: 5, 4, 4; 32 bits:
    /// four 5-bit and three 4-bit passes). [`Digits::Byte`]: 8-bit passes. The last pass may
    /// hold fewer bits than its width.
    pub fn pass_widths(bits: u32, digits: Digits) -> Vec<u32> {
        let bits = bits.min(32);
        if digits == Digits::Byte {
            return vec![BYTE_BITS; bits.div_ceil(BYTE_BITS) as usize];
        }
        let wide = digits == Digits::Wide;
        let narrow = bits.div_ceil(NARROW_BITS);
        let fewest = bits.div_ceil(WIDE_BITS);
        if !wide || fewest == narrow {
            return vec![NARROW_BITS; narrow as usize];
        }
        let widened = bits.saturating_sub(NARROW_BITS * fewest);
        (0..fewest)
            .map(|p| if p < widened { WIDE_BITS } else { NARROW_BITS })
            .collect()
    }

    /// Number of passes this sorter makes for keys using the low `bits` bits.
    pub fn passes(&self, bits: u32) -> u32 {
        Self::pass_widths(bits, self.digits).len() as u32
    }

    /// Records a stable sort of the first `counts[count_index]` pairs of (`keys`, `values`) by
    /// the low `bits` bits of the keys. `counts[hist_len_index]` is used as scratch. The
    /// result ends in the input or the scratch buffers, as returned.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
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
        self.record_dropping(
            rec,
            [keys, values, scratch_keys, scratch_values],
            counts,
            count_index,
            hist_len_index,
            bits,
            None,
        )
    }

    /// [`RadixSort::record`] of `[keys, values, scratch keys, scratch values]`, leaving out
    /// the keys `drop` names (when given; then `bits` must be at least 1).
    #[allow(clippy::too_many_arguments)]
    pub fn record_dropping(
        &self,
        rec: &mut Recorder,
        [keys, values, scratch_keys, scratch_values]: [&GpuBuffer<u32>; 4],
        counts: &GpuBuffer<u32>,
        count_index: u32,
        hist_len_index: u32,
        bits: u32,
        drop: Option<DropKeys>,
    ) -> SortedIn {
        assert!(
            drop.is_none() || (bits > 0 && self.drops),
            "radix sort: dropping keys needs a pass and a sorter made by RadixSort::dropping"
        );
        // As many blocks as there are keys this time, not as the capacity holds.
        self.sizes
            .record(rec, counts, count_index, self.shape.keys(), 0);
        let mut from_input = true;
        let mut shift = 0;
        for (pass, width) in Self::pass_widths(bits, self.digits).into_iter().enumerate() {
            // The first pass drops; the later ones sort what it kept.
            let dropping = drop.filter(|_| pass == 0);
            let count_index = match drop {
                Some(d) if pass > 0 => d.kept_index,
                _ => count_index,
            };
            let (args, at) = self.sizes.args(u32::from(drop.is_some() && pass > 0));
            // The last pass takes only the bits left.
            let digit_mask = (1u32 << width.min(bits.min(32) - shift)) - 1;
            let [upsweep, scatter] = &self
                .pipes
                .iter()
                .find(|(w, _)| *w == width)
                .expect("a pipeline for every pass width")
                .1;
            let (ki, vi, ko, vo) = if from_input {
                (keys, values, scratch_keys, scratch_values)
            } else {
                (scratch_keys, scratch_values, keys, values)
            };
            rec.barrier();
            rec.dispatch_indirect_named(
                upsweep,
                &[("keys", ki), ("hist", &self.hist), ("counts", counts)],
                &UpPush {
                    count_index,
                    hist_len_index,
                    shift,
                    digit_mask,
                    drop_keys: u32::from(dropping.is_some()),
                    drop_key: dropping.map_or(0, |d| d.key),
                },
                args,
                at,
            );
            // The histograms' total is the number of keys kept.
            let total = dropping.map(|d| d.kept_index);
            self.scan
                .record(rec, &self.hist, counts, hist_len_index, total);
            rec.dispatch_indirect_named(
                scatter,
                &[
                    ("keys_in", ki),
                    ("vals_in", vi),
                    ("keys_out", ko),
                    ("vals_out", vo),
                    ("hist", &self.hist),
                    ("counts", counts),
                ],
                &ScatterPush {
                    count_index,
                    shift,
                    digit_mask,
                    drop_keys: u32::from(dropping.is_some()),
                    drop_key: dropping.map_or(0, |d| d.key),
                },
                args,
                at,
            );
            if let Some(d) = dropping {
                // The later passes' group counts, from the kept count.
                self.sizes
                    .record(rec, counts, d.kept_index, self.shape.keys(), 1);
            }
            from_input = !from_input;
            shift += width;
        }
        rec.barrier();
        if from_input {
            SortedIn::Input
        } else {
            SortedIn::Scratch
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Digits, RadixSort};

    #[test]
    fn pass_widths_cover_the_bits_in_the_fewest_passes() {
        for bits in 0..=40u32 {
            for digits in [Digits::Narrow, Digits::Wide, Digits::Byte] {
                let widths = RadixSort::pass_widths(bits, digits);
                let covered: u32 = widths.iter().sum();
                let want = bits.min(32);
                let widest = digits.max_bits();
                // Every bit is sorted, and no pass could be dropped.
                assert!(covered >= want, "{bits} bits, {digits:?}: {widths:?}");
                assert!(covered < want + widest || want == 0, "{bits}: {widths:?}");
                assert_eq!(
                    widths.len() as u32,
                    want.div_ceil(widest),
                    "{bits} bits, {digits:?}"
                );
                // 5-bit digits only when allowed, and only as many as the saved pass needs.
                let wide_passes = widths.iter().filter(|&&w| w == 5).count() as u32;
                assert!(digits == Digits::Wide || wide_passes == 0);
                match digits {
                    Digits::Byte => assert!(widths.iter().all(|&w| w == 8)),
                    _ => assert!(widths.iter().all(|&w| w == 4 || w == 5)),
                }
                // Widened passes fill the bits exactly: one fewer would leave a bit unsorted.
                if wide_passes > 0 {
                    assert_eq!(covered, want, "{bits}: {widths:?}");
                }
            }
        }
        let wide = Digits::Wide;
        assert_eq!(RadixSort::pass_widths(13, wide), [5, 4, 4]);
        assert_eq!(RadixSort::pass_widths(12, wide), [4, 4, 4]);
        assert_eq!(RadixSort::pass_widths(8, wide), [4, 4]);
        assert_eq!(RadixSort::pass_widths(31, wide), [5, 5, 5, 4, 4, 4, 4]);
        assert_eq!(RadixSort::pass_widths(32, wide), [5, 5, 5, 5, 4, 4, 4]);
        assert_eq!(RadixSort::pass_widths(32, Digits::Narrow), [4; 8]);
        assert_eq!(RadixSort::pass_widths(31, Digits::Byte), [8; 4]);
        assert_eq!(RadixSort::pass_widths(13, Digits::Byte), [8; 2]);
        assert!(RadixSort::pass_widths(0, wide).is_empty());
    }
}
