//! LPM's GPU passes (docs/algorithms/lpm.md steps 1–2 and 7–8), recorded into a caller's [`Recorder`] with no
//! host wait inside:
//!
//! * [`LpmGpu::record_error_blocks`]: render + ground truth → error map → its quantile → per-block
//!   counts of error pixels. Only the counts go to the host, for
//!   [`BlockMask::from_error_counts`](super::regions::BlockMask::from_error_counts).
//! * [`LpmGpu::record_membership`]: per-Gaussian inside / in-front flags and per-zone counts.
//! * [`LpmGpu::record_opacity_reset`]: the quantile of the opacities inside zones and the reset of
//!   the in-front Gaussians above it.
//!
//! Quantiles are exact order statistics, found by a 4-pass radix selection (8 bits per pass, the
//! f32 total order as a u32 key; `glsl/lpm/select_*.comp`), not a histogram approximation. The
//! error map itself is computed in f32 (the CPU's [`error_map`](super::regions::error_map) in
//! f64), so error values agree to about 1e-6 relative; given the same map, the threshold and the
//! counts are the CPU's (see `select_pick.comp` for the one-ulp caveat of the interpolation).
//!
//! Each `record_*` call starts and ends with a barrier, so it sees the caller's earlier writes and
//! its outputs are visible to what follows. The scratch buffers belong to the `LpmGpu`: record one
//! `LpmGpu`'s passes into one recorder at a time.

use super::record::ZoneRecord;
use super::regions::RegionSettings;
use super::reset_settings::{OpacityResetSettings, OpacityResetStats, SHARE_DENOMINATOR};
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;

const WG: u32 = 256;
const MEMBERSHIP_ITEMS: u32 = 4;
const ZONE_BATCH: u32 = 128;
const HIST_ITEMS: u32 = 16;
const SUM_ITEMS: u32 = 8;
const RADIX: usize = 256;
/// Selection state slots (glsl/lpm/select_state.glsl).
const SEL_N: usize = 0;
const SEL_VALID: usize = 1;
const SEL_THRESHOLD: usize = 6;
const SEL_RESET: usize = 7;
const SEL_STATE_LEN: usize = 8;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct MembershipPush {
    count: u32,
    zone_count: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct HistPush {
    count: u32,
    pass: u32,
    flag_mask: u32,
    ranks: u32,
    weighted: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PickPush {
    pass: u32,
    mode: u32,
    n: u32,
    rank_lo: u32,
    frac: f32,
    top_num: u32,
    top_den: u32,
    ranks: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ResetPush {
    count: u32,
    reset_logit: f32,
    filtered: u32,
}

/// Mip-Splatting's 3D filter, for an opacity reset on the drawn opacity σ(x)·ρ: the filter's
/// values and the Gaussians' log-scales (for ρ), and a scratch of at least `count` floats for
/// the effective logits.
pub struct FilteredOpacity<'a> {
    pub filter3d: &'a GpuBuffer<f32>,
    pub log_scales: &'a GpuBuffer<f32>,
    pub effective: &'a GpuBuffer<f32>,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ImagePush {
    pixels: u32,
    gt_offset: u32,
    bg: [f32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct MeanPush {
    groups: u32,
    pixels: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct BlocksPush {
    width: u32,
    height: u32,
    block: u32,
    blocks_x: u32,
    blocks: u32,
}

/// State and histograms of one radix selection.
struct Selection {
    state: GpuBuffer<u32>,
    hist: GpuBuffer<u32>,
}

impl Selection {
    fn new(ctx: &Arc<GpuContext>, name: &str) -> anyhow::Result<Self> {
        Ok(Self {
            state: GpuBuffer::new(ctx, name, SEL_STATE_LEN, BufferKind::DeviceLocal)?,
            hist: GpuBuffer::new(ctx, name, 4 * 2 * RADIX, BufferKind::DeviceLocal)?,
        })
    }
}

/// One frame's images for [`LpmGpu::record_error_blocks`].
#[derive(Clone, Copy)]
pub struct ErrorImages<'a> {
    /// The render, f32 RGB interleaved, `[(y·width + x)·3 + c]`.
    pub render: &'a GpuBuffer<f32>,
    /// Ground truth, one packed RGBA8 u32 per pixel (r in the low byte, straight alpha); this
    /// image's pixel (x, y) is `gt[gt_offset + y·width + x]`.
    pub gt: &'a GpuBuffer<u32>,
    pub gt_offset: u32,
    pub width: u32,
    pub height: u32,
    /// The ground truth is composited on it: `rgb·a + background·(1 − a)`.
    pub background: [f32; 3],
}

/// Blocks per row and per column of a `width × height` image cut in `block`-pixel blocks.
pub fn block_grid(width: u32, height: u32, block: u32) -> (u32, u32) {
    (width.div_ceil(block), height.div_ceil(block))
}

/// The LPM kernels and their scratch buffers.
pub struct LpmGpu {
    ctx: Arc<GpuContext>,
    membership: ComputePipeline,
    select_histogram: ComputePipeline,
    select_pick: ComputePipeline,
    opacity_reset: ComputePipeline,
    effective_logits: ComputePipeline,
    error_sums: ComputePipeline,
    error_mean: ComputePipeline,
    error_map: ComputePipeline,
    error_blocks: ComputePipeline,
    max_pixels: u32,
    error: GpuBuffer<f32>,
    partials: GpuBuffer<f32>,
    scales: GpuBuffer<f32>,
    error_select: Selection,
    opacity_select: Selection,
    rank_select: Selection,
    no_flags: GpuBuffer<u32>,
}

impl LpmGpu {
    /// Builds the kernels; `max_pixels` bounds the images [`Self::record_error_blocks`] accepts.
    pub fn new(ctx: &Arc<GpuContext>, max_pixels: u32) -> anyhow::Result<Self> {
        let pipe = |name: &str, spv: &[u8], buffers: u32, push: usize, extra: &[u32]| {
            ComputePipeline::new(ctx, name, spv, buffers, push as u32, WG, extra)
        };
        use std::mem::size_of;
        let max_pixels = max_pixels.max(1);
        let sum_groups = (max_pixels as usize).div_ceil((WG * SUM_ITEMS) as usize);
        Ok(Self {
            ctx: ctx.clone(),
            membership: pipe(
                "lpm/zone_membership",
                shaders::LPM_ZONE_MEMBERSHIP,
                4,
                size_of::<MembershipPush>(),
                &[MEMBERSHIP_ITEMS, ZONE_BATCH],
            )?,
            select_histogram: pipe(
                "lpm/select_histogram",
                shaders::LPM_SELECT_HISTOGRAM,
                4,
                size_of::<HistPush>(),
                &[HIST_ITEMS],
            )?,
            select_pick: pipe(
                "lpm/select_pick",
                shaders::LPM_SELECT_PICK,
                2,
                size_of::<PickPush>(),
                &[],
            )?,
            opacity_reset: pipe(
                "lpm/opacity_reset",
                shaders::LPM_OPACITY_RESET,
                6,
                size_of::<ResetPush>(),
                &[],
            )?,
            effective_logits: pipe(
                "lpm/effective_logits",
                shaders::LPM_EFFECTIVE_LOGITS,
                4,
                size_of::<u32>(),
                &[],
            )?,
            error_sums: pipe(
                "lpm/error_sums",
                shaders::LPM_ERROR_SUMS,
                3,
                size_of::<ImagePush>(),
                &[SUM_ITEMS],
            )?,
            error_mean: pipe(
                "lpm/error_mean",
                shaders::LPM_ERROR_MEAN,
                2,
                size_of::<MeanPush>(),
                &[],
            )?,
            error_map: pipe(
                "lpm/error_map",
                shaders::LPM_ERROR_MAP,
                4,
                size_of::<ImagePush>(),
                &[],
            )?,
            error_blocks: pipe(
                "lpm/error_blocks",
                shaders::LPM_ERROR_BLOCKS,
                3,
                size_of::<BlocksPush>(),
                &[],
            )?,
            max_pixels,
            error: GpuBuffer::new(
                ctx,
                "lpm error map",
                max_pixels as usize,
                BufferKind::DeviceLocal,
            )?,
            partials: GpuBuffer::new(
                ctx,
                "lpm error partial sums",
                2 * sum_groups,
                BufferKind::DeviceLocal,
            )?,
            scales: GpuBuffer::new(ctx, "lpm error scales", 2, BufferKind::DeviceLocal)?,
            error_select: Selection::new(ctx, "lpm error quantile")?,
            opacity_select: Selection::new(ctx, "lpm opacity quantile")?,
            rank_select: Selection::new(ctx, "lpm rank selection")?,
            no_flags: GpuBuffer::new(ctx, "lpm no flags", 1, BufferKind::DeviceLocal)?,
        })
    }

    pub fn max_pixels(&self) -> u32 {
        self.max_pixels
    }

    /// Records the membership pass: `flags[i]` for the first `count` Gaussians
    /// ([`FLAG_INSIDE`](super::reset_settings::FLAG_INSIDE) |
    /// [`FLAG_IN_FRONT`](super::reset_settings::FLAG_IN_FRONT); entries past `count` untouched) and
    /// `zone_inside[z]` for the first `zone_count` zones (the whole buffer is zeroed first).
    /// `positions` holds xyz per Gaussian.
    #[allow(clippy::too_many_arguments)]
    pub fn record_membership(
        &self,
        rec: &mut Recorder,
        positions: &GpuBuffer<f32>,
        count: u32,
        zones: &GpuBuffer<ZoneRecord>,
        zone_count: u32,
        flags: &GpuBuffer<u32>,
        zone_inside: &GpuBuffer<u32>,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            positions.len() >= 3 * count as usize && flags.len() >= count as usize,
            "LPM membership: {count} Gaussians need {} position floats and {count} flags, the \
             buffers hold {} and {}",
            3 * count as usize,
            positions.len(),
            flags.len()
        );
        anyhow::ensure!(
            zones.len() >= zone_count as usize && zone_inside.len() >= zone_count as usize,
            "LPM membership: {zone_count} zones, but the zone buffer holds {} and the count buffer {}",
            zones.len(),
            zone_inside.len()
        );
        rec.barrier();
        rec.fill(zone_inside, 0);
        rec.barrier();
        rec.dispatch_named(
            &self.membership,
            &[
                ("positions", positions),
                ("zones", zones),
                ("flags", flags),
                ("zone_inside", zone_inside),
            ],
            &MembershipPush { count, zone_count },
            self.ctx
                .groups_1d((count as u64).div_ceil(MEMBERSHIP_ITEMS as u64), WG),
        );
        rec.barrier();
        Ok(())
    }

    /// The four histogram + pick passes of one selection (`values` are f32 bits).
    #[allow(clippy::too_many_arguments)]
    fn record_selection(
        &self,
        rec: &mut Recorder,
        sel: &Selection,
        values: &GpuBuffer<f32>,
        flags: &GpuBuffer<u32>,
        count: u32,
        flag_mask: u32,
        weighted: bool,
        pick: PickPush,
    ) {
        rec.fill(&sel.state, 0);
        rec.fill(&sel.hist, 0);
        rec.barrier();
        let groups = self
            .ctx
            .groups_1d((count as u64).div_ceil(HIST_ITEMS as u64), WG);
        for pass in 0..4 {
            rec.dispatch_named(
                &self.select_histogram,
                &[
                    ("values", values),
                    ("flags", flags),
                    ("state", &sel.state),
                    ("hist", &sel.hist),
                ],
                &HistPush {
                    count,
                    pass,
                    flag_mask,
                    ranks: pick.ranks,
                    weighted: weighted as u32,
                },
                groups,
            );
            rec.barrier();
            rec.dispatch_named(
                &self.select_pick,
                &[("state", &sel.state), ("hist", &sel.hist)],
                &PickPush { pass, ..pick },
                [1, 1, 1],
            );
            rec.barrier();
        }
    }

    /// Records the LPM opacity reset over the first `count` Gaussians, given the flags of
    /// [`Self::record_membership`]: the threshold is selected among the logits of the Gaussians
    /// with `s.threshold_set` (`FLAG_INSIDE` or `FLAG_IN_BALL`), and every `FLAG_IN_FRONT` Gaussian at or above it gets
    /// `logit(s.opacity)` (see [`OpacityResetSettings`]). With `filtered` (Mip-Splatting) both
    /// the ranking and the reset act on the drawn opacity σ(x)·ρ. Read the outcome with
    /// [`Self::read_opacity_reset_stats`] after the submission has completed.
    pub fn record_opacity_reset(
        &self,
        rec: &mut Recorder,
        flags: &GpuBuffer<u32>,
        opacity_logits: &GpuBuffer<f32>,
        count: u32,
        s: &OpacityResetSettings,
        filtered: Option<&FilteredOpacity>,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            flags.len() >= count as usize && opacity_logits.len() >= count as usize,
            "LPM opacity reset: {count} Gaussians, but the flag buffer holds {} and the opacity \
             buffer {}",
            flags.len(),
            opacity_logits.len()
        );
        if let Some(f) = filtered {
            let n = count as usize;
            anyhow::ensure!(
                f.filter3d.len() >= n && f.log_scales.len() >= 3 * n && f.effective.len() >= n,
                "LPM opacity reset: {count} Gaussians, but {} filter values, {} log-scale \
                 floats and {} scratch floats",
                f.filter3d.len(),
                f.log_scales.len(),
                f.effective.len()
            );
        }
        let top_num = s.top_basis_points()?;
        let reset_logit = s.reset_logit()?;
        rec.barrier();
        if let Some(f) = filtered {
            rec.dispatch_named(
                &self.effective_logits,
                &[
                    ("logits", opacity_logits),
                    ("log_scales", f.log_scales),
                    ("filter3d", f.filter3d),
                    ("effective", f.effective),
                ],
                &count,
                self.ctx.groups_1d(count as u64, WG),
            );
            rec.barrier();
        }
        self.record_selection(
            rec,
            &self.opacity_select,
            filtered.map_or(opacity_logits, |f| f.effective),
            flags,
            count,
            s.threshold_set,
            false,
            PickPush {
                pass: 0,
                mode: 1,
                n: 0,
                rank_lo: 0,
                frac: 0.0,
                top_num,
                top_den: SHARE_DENOMINATOR,
                ranks: 1,
            },
        );
        rec.dispatch_named(
            &self.opacity_reset,
            &[
                ("flags", flags),
                ("logits", opacity_logits),
                ("state", &self.opacity_select.state),
                (
                    "effective",
                    filtered.map_or(opacity_logits, |f| f.effective),
                ),
                (
                    "log_scales",
                    filtered.map_or(opacity_logits, |f| f.log_scales),
                ),
                ("filter3d", filtered.map_or(opacity_logits, |f| f.filter3d)),
            ],
            &ResetPush {
                count,
                reset_logit,
                filtered: filtered.is_some() as u32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
        Ok(())
    }

    /// What the last recorded opacity reset did (call after its submission completed).
    pub fn read_opacity_reset_stats(&self) -> anyhow::Result<OpacityResetStats> {
        let st = self.opacity_select.state.read()?;
        let valid = st[SEL_VALID] != 0;
        Ok(OpacityResetStats {
            inside: st[SEL_N],
            threshold_logit: valid.then(|| f32::from_bits(st[SEL_THRESHOLD])),
            reset: st[SEL_RESET],
        })
    }

    /// Records steps 1–2 on the GPU: the error map of `img` (regions.rs `error_map`), its
    /// `s.quantile` (regions.rs `quantile`, exact order statistics) and, per `s.block`-pixel block
    /// (row-major, [`block_grid`]), the count of pixels with an error strictly above it, written to
    /// `block_counts[0..blocks_x·blocks_y]`. Returns (blocks_x, blocks_y). After the submission:
    /// `BlockMask::from_error_counts(width, height, s.block, &counts, s.keep_fraction)`.
    pub fn record_error_blocks(
        &self,
        rec: &mut Recorder,
        img: &ErrorImages,
        s: &RegionSettings,
        block_counts: &GpuBuffer<u32>,
    ) -> anyhow::Result<(u32, u32)> {
        let (w, h) = (img.width, img.height);
        let pixels = w as u64 * h as u64;
        anyhow::ensure!(
            pixels > 0 && pixels <= self.max_pixels as u64,
            "LPM error blocks: a {w}×{h} image, but this LpmGpu takes 1..={} pixels \
             (raise max_pixels in LpmGpu::new)",
            self.max_pixels
        );
        let pixels = pixels as u32;
        anyhow::ensure!(
            (1..=256).contains(&s.block),
            "LPM error blocks: block size {} is outside 1..=256 (the paper uses 16)",
            s.block
        );
        anyhow::ensure!(
            img.render.len() >= 3 * pixels as usize
                && img.gt.len() as u64 >= img.gt_offset as u64 + pixels as u64,
            "LPM error blocks: a {w}×{h} image needs {} render floats and ground-truth pixels \
             {}..{}, the buffers hold {} and {}",
            3 * pixels as usize,
            img.gt_offset,
            img.gt_offset as u64 + pixels as u64,
            img.render.len(),
            img.gt.len()
        );
        let (bx, by) = block_grid(w, h, s.block);
        let blocks = bx * by;
        anyhow::ensure!(
            block_counts.len() >= blocks as usize,
            "LPM error blocks: {bx}×{by} blocks, but the count buffer holds {}",
            block_counts.len()
        );
        let image_push = ImagePush {
            pixels,
            gt_offset: img.gt_offset,
            bg: img.background,
        };
        let sum_groups = pixels.div_ceil(WG * SUM_ITEMS);
        rec.barrier();
        rec.dispatch_named(
            &self.error_sums,
            &[
                ("render", img.render),
                ("gt", img.gt),
                ("partials", &self.partials),
            ],
            &image_push,
            self.ctx.groups_1d(sum_groups as u64, 1),
        );
        rec.barrier();
        rec.dispatch_named(
            &self.error_mean,
            &[("partials", &self.partials), ("scales", &self.scales)],
            &MeanPush {
                groups: sum_groups,
                pixels,
            },
            [1, 1, 1],
        );
        rec.barrier();
        rec.dispatch_named(
            &self.error_map,
            &[
                ("render", img.render),
                ("gt", img.gt),
                ("scales", &self.scales),
                ("error", &self.error),
            ],
            &image_push,
            self.ctx.groups_1d(pixels as u64, WG),
        );
        rec.barrier();
        // The ranks exactly as regions.rs `quantile` computes them.
        let q = s.quantile.clamp(0.0, 1.0) as f64;
        let pos = q * (pixels - 1) as f64;
        let lo = pos.floor();
        self.record_selection(
            rec,
            &self.error_select,
            &self.error,
            &self.no_flags,
            pixels,
            0,
            false,
            PickPush {
                pass: 0,
                mode: 0,
                n: pixels,
                rank_lo: lo as u32,
                frac: (pos - lo) as f32,
                top_num: 0,
                top_den: 1,
                ranks: 2,
            },
        );
        rec.dispatch_named(
            &self.error_blocks,
            &[
                ("error", &self.error),
                ("state", &self.error_select.state),
                ("counts", block_counts),
            ],
            &BlocksPush {
                width: w,
                height: h,
                block: s.block,
                blocks_x: bx,
                blocks,
            },
            self.ctx.groups_1d(blocks as u64, 1),
        );
        rec.barrier();
        Ok((bx, by))
    }

    /// Records the exact selection of the element of 0-based rank `rank` (ascending float-key
    /// order) among the first `count` `values` whose `flags & flag_mask` is non-zero, of which
    /// there must be more than `rank` (`taking_part`, known to the caller). Afterwards
    /// [`Self::rank_selection_state`] holds, in the layout of `glsl/lpm/select_state.glsl`, its
    /// key at `SEL_PREFIX` (4) and at `SEL_RANK` (2) its rank among the elements with exactly
    /// that key (so `SEL_RANK + 1` of those are at or below `rank`); `SEL_VALID` (1) is 0 when
    /// `taking_part` is 0. With `weighted`, element i counts `flags[i]` times (a multiset;
    /// `taking_part` is then the sum of the weights, at most 2·`count`).
    #[allow(clippy::too_many_arguments)]
    pub fn record_rank_selection(
        &self,
        rec: &mut Recorder,
        values: &GpuBuffer<f32>,
        flags: &GpuBuffer<u32>,
        flag_mask: u32,
        weighted: bool,
        count: u32,
        taking_part: u32,
        rank: u32,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            values.len() >= count as usize && flags.len() >= count as usize,
            "LPM rank selection: {count} elements, but the value buffer holds {} and the flag \
             buffer {}",
            values.len(),
            flags.len()
        );
        anyhow::ensure!(
            flag_mask != 0
                && rank < taking_part.max(1)
                && taking_part as u64 <= count as u64 * (1 + weighted as u64),
            "LPM rank selection: rank {rank} among {taking_part} of {count} elements (mask {flag_mask})"
        );
        rec.barrier();
        self.record_selection(
            rec,
            &self.rank_select,
            values,
            flags,
            count,
            flag_mask,
            weighted,
            PickPush {
                pass: 0,
                mode: 0,
                n: taking_part,
                rank_lo: rank,
                frac: 0.0,
                top_num: 0,
                top_den: 1,
                ranks: 1,
            },
        );
        Ok(())
    }

    /// The state of the last [`Self::record_rank_selection`] (bind it to a kernel that includes
    /// `select_state.glsl`).
    pub fn rank_selection_state(&self) -> &GpuBuffer<u32> {
        &self.rank_select.state
    }

    /// The error map of the last [`Self::record_error_blocks`] (its first width·height values are
    /// the image's; for tests and debugging: this reads the map back to the host).
    pub fn error_map_buffer(&self) -> &GpuBuffer<f32> {
        &self.error
    }

    /// The error threshold of the last [`Self::record_error_blocks`] (after its submission).
    pub fn read_error_threshold(&self) -> anyhow::Result<f32> {
        Ok(f32::from_bits(
            self.error_select.state.read_range(SEL_THRESHOLD, 1)?[0],
        ))
    }
}

/// CPU twin of the ground truth the kernels read: packed RGBA8 (r in the low byte) to f32 RGB,
/// composited on `background` as the GPU does (`rgb·a + bg·(1 − a)`, in f32).
pub fn unpack_ground_truth(gt: &[u32], background: [f32; 3]) -> Vec<f32> {
    let mut out = Vec::with_capacity(3 * gt.len());
    for &p in gt {
        let [r, g, b, a] = p.to_le_bytes().map(|v| v as f32 / 255.0);
        for (c, bg) in [r, g, b].into_iter().zip(background) {
            out.push(c * a + bg * (1.0 - a));
        }
    }
    out
}

/// CPU twin of the block counts: per `block`-pixel block (row-major, [`block_grid`]), the pixels
/// of `error` strictly above `threshold` (regions.rs `block_mask` counts the same way).
pub fn error_block_counts(
    error: &[f32],
    width: u32,
    height: u32,
    block: u32,
    threshold: f32,
) -> anyhow::Result<Vec<u32>> {
    anyhow::ensure!(
        error.len() == width as usize * height as usize && block > 0,
        "error block counts: {} values for a {width}×{height} map, block {block}",
        error.len()
    );
    let (bx, by) = block_grid(width, height, block);
    let mut counts = vec![0u32; (bx * by) as usize];
    for (i, &e) in error.iter().enumerate() {
        let (x, y) = (i as u32 % width, i as u32 / width);
        if e > threshold {
            counts[((y / block) * bx + x / block) as usize] += 1;
        }
    }
    Ok(counts)
}
