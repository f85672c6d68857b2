//! The forward renderer on the GPU: preprocess → depth sort → tile counts, scan and emit →
//! stable sort by tile → tile ranges → rasterize, all recorded into the caller's command buffer.
//!
//! Sorting strategy: instead of one radix sort of (tile | depth) keys over every intersection
//! (32 + tile bits, 11–12 passes over M pairs), the Gaussians are sorted once by depth (8 passes
//! over N), the pairs are emitted in that order, and a stable sort by tile id alone (only the
//! tile bits the image needs, 3–4 passes over M) keeps depth order inside each tile. Ties in depth
//! break by Gaussian index, as in the CPU reference.
//!
//! Pairing: a splat is paired only with the tiles of its rectangle where its ellipse may reach
//! `alpha_min` at a pixel centre, found per tile row in closed form (`Pairing`,
//! glsl/common/tile_rows.glsl); the rest would skip it at every pixel. Elongated and faint
//! splats have many such tiles: trained scenes at 1352×1014 lose 38–48 % of their pairs, and
//! the tile sort, the emit and the rasterizers' walks shrink with them.
//!
//! Sizes: buffers are allocated for a Gaussian capacity, an intersection capacity, a pixel and a
//! tile capacity, and grow geometrically through [`Renderer::ensure_capacity`]. The number of
//! intersections is only known on the GPU: pairs past the capacity are dropped by the emit kernel
//! and [`Renderer::last_intersections`] (after the frame's fence) tells the caller to grow and
//! render again; `counts` is copied to a host-visible buffer at the end of every frame so this
//! costs no extra wait. A frame with more pairs than one binding holds is drawn by tools in bands
//! of tile rows (`super::bands`) and refused in training.
//!
//! This file holds the renderer, its buffers and the preprocess and rasterize steps; the
//! binning steps (depth sort, pairs, tile sort, tile ranges) and the band plan are in
//! `forward/binning.rs`.

use std::sync::Arc;

use super::backward::default_pixels_per_invocation;
use super::bands::{FrameWork, TileBand};
use super::dispatch_size::DispatchSize;
use super::layout::{CameraGpu, RenderConstants};
use super::projected::ProjectedBuffers;
use super::scan::PrefixScan;
use super::sort::{RadixSort, SortedIn};
use crate::gpu::{
    Bindable, BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder, TimestampPool,
};
use crate::shaders;
use crate::splats::gpu::{GpuSplats, PARAM_BINDINGS};

mod binning;
use binning::BandTotals;

const WG: u32 = 256;
/// Slots of the `counts` buffer.
pub const COUNT_GAUSSIANS: u32 = 0;
pub const COUNT_INTERSECTIONS: u32 = 1;
pub const COUNT_STORED_PAIRS: u32 = 2;
const COUNT_SCRATCH: u32 = 3;
/// The Gaussians the depth sort kept (those pairing with a tile): what binning reads
/// (`glsl/render/gather_tile_counts.comp` and `emit_intersections.comp` name the slot too).
pub const COUNT_VISIBLE: u32 = 4;
const COUNT_SLOTS: usize = 5;
/// Slots of `Renderer::pair_groups`: the tile ranges' groups, the binning kernels' groups.
const PAIR_GROUPS: u32 = 0;
const VISIBLE_GROUPS: u32 = 1;
/// Bits of the depth keys: positive float bits, culled splats [`CULLED_DEPTH_KEY`].
const DEPTH_KEY_BITS: u32 = 31;
/// The depth key of a culled splat (`CULLED_DEPTH_KEY` in `glsl/common/projected.glsl`): the
/// depth sort drops these.
const CULLED_DEPTH_KEY: u32 = 0x7FFF_FFFF;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PreprocessPush {
    count: u32,
    camera_index: u32,
    sh_degree: u32,
    rest_coeffs: u32,
    rc: RenderConstants,
}

/// Which tiles of a splat's rectangle get a (tile, splat) pair (glsl/common/tile_rows.glsl).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PairingPush {
    alpha_min: f32,
    /// 1: only the tiles where the splat's ellipse may reach `alpha_min`; 0: the rectangle.
    ellipse: u32,
    smooth_mode: u32,
    /// The band of tile rows `[row_lo, row_hi)` paired (the whole frame but in banded frames).
    row_lo: u32,
    row_hi: u32,
    /// The band's slot of the 64-bit pair totals.
    total_slot: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct EmitPush {
    pairing: PairingPush,
    capacity: u32,
    tiles_x: u32,
}

/// How a frame's preprocess output is paired with tiles.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Pairing {
    /// Every tile of the rectangle (surfels: their footprint is not a conic's ellipse).
    Rectangle,
    /// Only the tiles where a pixel centre may get alpha ≥ `alpha_min` under these constants
    /// (3DGS's conic splats): the others would skip the splat at every pixel anyway.
    Ellipse(RenderConstants),
}

impl Pairing {
    fn push(self, band: &TileBand, total_slot: u32) -> PairingPush {
        let (alpha_min, ellipse, smooth_mode) = match self {
            Pairing::Rectangle => (0.0, 0, 0),
            Pairing::Ellipse(rc) => (
                rc.alpha_min,
                1,
                u32::from(rc.flags & RenderConstants::SMOOTH != 0),
            ),
        };
        PairingPush {
            alpha_min,
            ellipse,
            smooth_mode,
            row_lo: band.first_row,
            row_hi: band.end_row,
            total_slot,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RasterPush {
    rc: RenderConstants,
    camera_index: u32,
    background: [f32; 3],
    /// The band's first tile (`glsl/render/rasterize.glsl`).
    tile_offset: u32,
}

/// The median-depth pass (`glsl/render/median_depth.comp`) and its output.
struct MedianDepth {
    pipe: ComputePipeline,
    /// One float a pixel (allocated by the first frame, regrown with the capacity).
    depth: Option<GpuBuffer<f32>>,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MedianPush {
    rc: RenderConstants,
    camera_index: u32,
    /// The band's first tile.
    tile_offset: u32,
}

/// The contributions pass (`glsl/render/contributions.comp`): its input, one weight a pixel,
/// and its per-Gaussian sums (allocated by the first frame, regrown with the capacity).
struct ContributionPass {
    pipe: ComputePipeline,
    buffers: Option<ContributionBuffers>,
}

struct ContributionBuffers {
    pixel_weights: GpuBuffer<f32>,
    /// weight, pixel count, T·alpha, distance: one buffer each, so that each binding holds one
    /// float a Gaussian.
    sums: [GpuBuffer<f32>; 4],
}

/// What each Gaussian gave the last frame of a renderer made
/// [`Renderer::with_contributions`], summed over the pixels it was blended into.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Contributions {
    /// The pixels' weights ([`Renderer::pixel_weights_buffer`]).
    pub weight: Vec<f32>,
    /// The pixels (a float: the kernel adds 1.0 a pixel).
    pub pixels: Vec<f32>,
    /// Its blending weights `T·alpha`.
    pub blend: Vec<f32>,
    /// Its 2D mean's distance to the pixel centres (pixels).
    pub distance: Vec<f32>,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ContributionPush {
    rc: RenderConstants,
    camera_index: u32,
    tile_offset: u32,
}

/// What a frame needs besides the splats and the camera buffer.
#[derive(Clone, Copy)]
pub struct FrameSettings<'a> {
    pub sh_degree: u32,
    pub background: [f32; 3],
    pub constants: RenderConstants,
    /// Mip-Splatting's 3D smoothing filter, one standard deviation per Gaussian (world units):
    /// rendered with scales sqrt(s² + f²) and opacity × sqrt(Π s² / Π (s² + f²)).
    pub filter3d: Option<&'a GpuBuffer<f32>>,
    /// Feature channels blended beside the colour with the same weights over a zero
    /// background (SpacetimeGaussians' full model), into [`Renderer::feature_image`].
    pub features: Option<FeatureChannels<'a>>,
}

impl FrameSettings<'_> {
    /// 3DGS's frame: the default constants, no filter, no feature channels.
    pub fn plain(sh_degree: u32, background: [f32; 3]) -> Self {
        FrameSettings {
            sh_degree,
            background,
            constants: RenderConstants::default(),
            filter3d: None,
            features: None,
        }
    }
}

/// Per-Gaussian feature channels: `values[g·channels + c]`.
#[derive(Clone, Copy)]
pub struct FeatureChannels<'a> {
    pub values: &'a GpuBuffer<f32>,
    pub channels: u32,
    /// SpacetimeGaussians' decoder weights ([`crate::reference::decoder::WEIGHTS`] floats;
    /// the channels must then be its [`crate::reference::decoder::FEATURE_CHANNELS`]): the
    /// rasterizer decodes each pixel in its epilogue and [`FrameBuffers::image`] is the decoded
    /// RGB; no feature image is written (frames that are displayed, not trained on).
    pub decoded_by: Option<&'a GpuBuffer<f32>>,
}

/// Capacities the renderer's buffers are sized for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Capacity {
    pub gaussians: usize,
    pub intersections: usize,
    pub pixels: usize,
    pub tiles: usize,
}

impl Capacity {
    /// One of everything: what buffers are shrunk to before a regrowth frees them.
    pub fn single() -> Self {
        Self {
            gaussians: 1,
            intersections: 1,
            pixels: 1,
            tiles: 1,
        }
    }

    /// What a frame of `gaussians` at `camera`'s size needs, intersections aside (known only
    /// after the frame).
    pub fn for_frame(gaussians: usize, camera: &CameraGpu) -> Self {
        Self {
            gaussians,
            intersections: 0,
            pixels: (camera.width() as usize) * (camera.height() as usize),
            tiles: camera.tile_count() as usize,
        }
    }
}

/// The per-frame buffers (kept after the frame: the backward pass reads them).
pub struct FrameBuffers {
    pub projected: ProjectedBuffers,
    pub(super) depth_keys: GpuBuffer<u32>,
    pub(super) depth_vals: GpuBuffer<u32>,
    depth_keys_tmp: GpuBuffer<u32>,
    depth_vals_tmp: GpuBuffer<u32>,
    touched: GpuBuffer<u32>,
    tile_keys: GpuBuffer<u32>,
    tile_vals: GpuBuffer<u32>,
    tile_keys_tmp: GpuBuffer<u32>,
    tile_vals_tmp: GpuBuffer<u32>,
    pub tile_ranges: GpuBuffer<[u32; 2]>,
    pub image: GpuBuffer<f32>,
    pub final_t: GpuBuffer<f32>,
    pub last_index: GpuBuffer<u32>,
    /// `COUNT_*` slots.
    pub counts: GpuBuffer<u32>,
    /// `counts` after the frame.
    counts_host: GpuBuffer<u32>,
}

pub struct Renderer {
    ctx: Arc<GpuContext>,
    preprocess: ComputePipeline,
    /// Bound in place of an absent 3D filter (never read).
    no_filter: GpuBuffer<f32>,
    gather: ComputePipeline,
    emit: ComputePipeline,
    ranges: ComputePipeline,
    raster: ComputePipeline,
    /// Pixels per invocation of `raster` and `raster_features`.
    raster_pixels: u32,
    /// The rasterizer with feature channels (built on first use, per channel count and
    /// whether it decodes).
    raster_features: Option<((u32, bool), ComputePipeline)>,
    /// The last frame's feature channels, `[pix·channels + c]` (when it had some).
    feature_image: Option<GpuBuffer<f32>>,
    /// The median-depth pass and its per-pixel output, when asked for
    /// ([`Renderer::with_median_depth`]).
    median: Option<MedianDepth>,
    /// The contributions pass, when asked for ([`Renderer::with_contributions`]).
    contributions: Option<ContributionPass>,
    depth_sort: RadixSort,
    tile_sort: RadixSort,
    /// The group counts of the tile-ranges pass and the binning kernels, from the frame's pair
    /// and visible counts on the GPU ([`PAIR_GROUPS`], [`VISIBLE_GROUPS`]).
    pair_groups: DispatchSize,
    scan: PrefixScan,
    /// Counts every tile row's pairs (`glsl/render/tile_row_pairs.comp`) to plan bands.
    row_pairs: ComputePipeline,
    /// Its output, 64 bits a tile row (allocated by the first planning pass).
    row_totals: Option<GpuBuffer<u32>>,
    /// The most pairs one frame (or band) may have: one binding's worth, or less
    /// ([`Renderer::limit_pairs`]).
    pair_limit: u64,
    /// The bands of tile rows tools draw frames of `plan.0` tile rows in (empty: whole frames).
    plan: (u32, Vec<TileBand>),
    totals: BandTotals,
    /// The bands of the last recorded frame.
    last_bands: usize,
    capacity: Capacity,
    pub frame: FrameBuffers,
    tile_sorted_in: SortedIn,
    depth_sorted_in: SortedIn,
    last_camera: Option<CameraGpu>,
}

fn stamp(rec: &mut Recorder, pool: Option<&mut TimestampPool>, label: &str) {
    if let Some(p) = pool {
        rec.timestamp(p, label);
    }
}

/// The most (tile, Gaussian) pairs a frame may have on this device: what one binding of the
/// 4-byte tile keys (or Gaussian ids) holds, and what the 32-bit pair offsets address.
pub fn max_intersections(ctx: &GpuContext) -> u64 {
    (ctx.info.max_storage_buffer_range / 4).min(u32::MAX as u64)
}

/// Bits needed to hold every tile id of a grid with `tiles` tiles.
pub fn tile_bits(tiles: u32) -> u32 {
    32 - tiles.saturating_sub(1).leading_zeros()
}

impl FrameBuffers {
    fn new(ctx: &Arc<GpuContext>, cap: &Capacity) -> anyhow::Result<Self> {
        let dl = BufferKind::DeviceLocal;
        let n = cap.gaussians.max(1);
        let m = cap.intersections.max(1);
        Ok(Self {
            projected: ProjectedBuffers::new(ctx, "projected", n, dl)?,
            depth_keys: GpuBuffer::new(ctx, "depth keys", n, dl)?,
            depth_vals: GpuBuffer::new(ctx, "depth ids", n, dl)?,
            depth_keys_tmp: GpuBuffer::new(ctx, "depth keys (scratch)", n, dl)?,
            depth_vals_tmp: GpuBuffer::new(ctx, "depth ids (scratch)", n, dl)?,
            touched: GpuBuffer::new(ctx, "tiles touched", n, dl)?,
            tile_keys: GpuBuffer::new(ctx, "tile keys", m, dl)?,
            tile_vals: GpuBuffer::new(ctx, "tile ids", m, dl)?,
            tile_keys_tmp: GpuBuffer::new(ctx, "tile keys (scratch)", m, dl)?,
            tile_vals_tmp: GpuBuffer::new(ctx, "tile ids (scratch)", m, dl)?,
            tile_ranges: GpuBuffer::new(ctx, "tile ranges", cap.tiles.max(1), dl)?,
            image: GpuBuffer::new(ctx, "image", cap.pixels.max(1) * 3, dl)?,
            final_t: GpuBuffer::new(ctx, "final T", cap.pixels.max(1), dl)?,
            last_index: GpuBuffer::new(ctx, "last index", cap.pixels.max(1), dl)?,
            counts: GpuBuffer::new(ctx, "render counts", COUNT_SLOTS, dl)?,
            counts_host: GpuBuffer::new(
                ctx,
                "render counts (host)",
                COUNT_SLOTS,
                BufferKind::Readback,
            )?,
        })
    }

    /// Total bytes of the frame buffers (for memory reports).
    pub fn bytes(&self) -> u64 {
        self.projected.byte_len()
            + 4 * self.depth_keys.byte_len()
            + self.touched.byte_len()
            + 2 * (self.tile_keys.byte_len() + self.tile_vals.byte_len())
            + self.tile_ranges.byte_len()
            + self.image.byte_len()
            + self.final_t.byte_len()
            + self.last_index.byte_len()
    }
}

impl Renderer {
    pub fn new(ctx: &Arc<GpuContext>, capacity: Capacity) -> anyhow::Result<Self> {
        let pipe = |name: &str, spirv: &[u8], buffers: u32, push: usize| {
            ComputePipeline::new(ctx, name, spirv, buffers, push as u32, WG, &[])
        };
        Ok(Self {
            ctx: ctx.clone(),
            no_filter: GpuBuffer::new(ctx, "no 3D filter", 1, BufferKind::DeviceLocal)?,
            preprocess: pipe(
                "render/preprocess",
                shaders::RENDER_PREPROCESS,
                17,
                std::mem::size_of::<PreprocessPush>(),
            )?,
            gather: pipe(
                "render/gather_tile_counts",
                shaders::RENDER_GATHER_TILE_COUNTS,
                6,
                std::mem::size_of::<PairingPush>(),
            )?,
            emit: pipe(
                "render/emit_intersections",
                shaders::RENDER_EMIT_INTERSECTIONS,
                7,
                std::mem::size_of::<EmitPush>(),
            )?,
            ranges: pipe("render/tile_ranges", shaders::RENDER_TILE_RANGES, 3, 0)?,
            row_pairs: pipe(
                "render/tile_row_pairs",
                shaders::RENDER_TILE_ROW_PAIRS,
                5,
                std::mem::size_of::<PairingPush>(),
            )?,
            row_totals: None,
            pair_limit: max_intersections(ctx),
            plan: (0, Vec::new()),
            totals: BandTotals::new(ctx, 1)?,
            last_bands: 1,
            // Same pixels-per-invocation choice as the backward (CPU drivers: 8).
            raster_pixels: default_pixels_per_invocation(&ctx.info),
            raster: Self::raster_pipeline(ctx, default_pixels_per_invocation(&ctx.info), 0, false)?,
            raster_features: None,
            feature_image: None,
            median: None,
            contributions: None,
            depth_sort: RadixSort::dropping(ctx, capacity.gaussians as u64)?,
            tile_sort: RadixSort::new(ctx, capacity.intersections as u64)?,
            pair_groups: DispatchSize::new(ctx, 2)?,
            scan: PrefixScan::new(ctx, capacity.gaussians as u64)?,
            frame: FrameBuffers::new(ctx, &capacity)?,
            capacity,
            tile_sorted_in: SortedIn::Input,
            depth_sorted_in: SortedIn::Input,
            last_camera: None,
        })
    }

    /// The rasterizer with `pixels` (1, 2, 4 or 8) pixels per invocation instead of the device's
    /// default: tests run the GPU layout (1) on a CPU driver this way.
    pub fn with_raster_pixels(mut self, pixels: u32) -> anyhow::Result<Self> {
        super::backward::raster_workgroup(&self.ctx.info, pixels, 8, "renderer")?;
        self.raster = Self::raster_pipeline(&self.ctx, pixels, 0, false)?;
        self.raster_pixels = pixels;
        self.raster_features = None;
        Ok(self)
    }

    /// A renderer that also writes every frame's median depth per pixel
    /// (`glsl/render/median_depth.comp`: the camera depth of the splat that takes the pixel's
    /// transmittance below ½, 0 where none does), read by [`Renderer::read_median_depth`].
    pub fn with_median_depth(mut self) -> anyhow::Result<Self> {
        self.median = Some(MedianDepth {
            pipe: ComputePipeline::new(
                &self.ctx,
                "render/median_depth",
                shaders::RENDER_MEDIAN_DEPTH,
                6,
                std::mem::size_of::<MedianPush>() as u32,
                256,
                &[],
            )?,
            depth: None,
        });
        Ok(self)
    }

    /// The median-depth output (`None` before the first frame or without
    /// [`Renderer::with_median_depth`]); tests poison it.
    pub fn median_depth_buffer(&self) -> Option<&GpuBuffer<f32>> {
        self.median.as_ref().and_then(|m| m.depth.as_ref())
    }

    /// The last frame's median depth per pixel, row-major (0 where the transmittance stayed at
    /// ½ or above); refused for a renderer made without [`Renderer::with_median_depth`].
    pub fn read_median_depth(&self) -> anyhow::Result<Vec<f32>> {
        let cam = self
            .last_camera
            .ok_or_else(|| anyhow::anyhow!("no frame rendered yet"))?;
        let depth = self
            .median
            .as_ref()
            .and_then(|m| m.depth.as_ref())
            .ok_or_else(|| {
                anyhow::anyhow!("this renderer writes no median depth (with_median_depth)")
            })?;
        depth.read_range(0, (cam.width() * cam.height()) as usize)
    }

    /// A renderer that also sums, per Gaussian, what it gave every frame
    /// (`glsl/render/contributions.comp`: the weights of the pixels it was blended into, their
    /// number, its blending weights and its distances to them), read by
    /// [`Renderer::read_contributions`]. The pixel weights are the caller's: upload them into
    /// [`Renderer::pixel_weights_buffer`] (sized by a first frame) before the frame.
    pub fn with_contributions(mut self) -> anyhow::Result<Self> {
        self.contributions = Some(ContributionPass {
            pipe: ComputePipeline::new(
                &self.ctx,
                "render/contributions",
                shaders::RENDER_CONTRIBUTIONS,
                9,
                std::mem::size_of::<ContributionPush>() as u32,
                256,
                &[],
            )?,
            buffers: None,
        });
        Ok(self)
    }

    /// The pixel weights the contributions pass reads, row-major, one a pixel of the frame
    /// (`None` before the first frame or without [`Renderer::with_contributions`]).
    pub fn pixel_weights_buffer(&self) -> Option<&GpuBuffer<f32>> {
        let b = self.contributions.as_ref()?.buffers.as_ref()?;
        Some(&b.pixel_weights)
    }

    /// The contributions pass's four per-Gaussian sums (weight, pixels, blend, distance);
    /// tests poison them.
    pub fn contribution_buffers(&self) -> Option<&[GpuBuffer<f32>; 4]> {
        let b = self.contributions.as_ref()?.buffers.as_ref()?;
        Some(&b.sums)
    }

    /// What each of the first `count` Gaussians gave the last frame; refused for a renderer
    /// made without [`Renderer::with_contributions`].
    pub fn read_contributions(&self, count: usize) -> anyhow::Result<Contributions> {
        anyhow::ensure!(self.last_camera.is_some(), "no frame rendered yet");
        let b = self
            .contributions
            .as_ref()
            .and_then(|c| c.buffers.as_ref())
            .ok_or_else(|| {
                anyhow::anyhow!("this renderer sums no contributions (with_contributions)")
            })?;
        anyhow::ensure!(
            count <= self.capacity.gaussians,
            "renderer: {count} contributions asked of a renderer sized for {} Gaussians",
            self.capacity.gaussians
        );
        let [w, p, t, d] = &b.sums;
        Ok(Contributions {
            weight: w.read_range(0, count)?,
            pixels: p.read_range(0, count)?,
            blend: t.read_range(0, count)?,
            distance: d.read_range(0, count)?,
        })
    }

    /// The rasterizer with `extra` feature channels (0: colour only), decoding them in its
    /// epilogue with `decode`.
    fn raster_pipeline(
        ctx: &Arc<GpuContext>,
        pixels: u32,
        extra: u32,
        decode: bool,
    ) -> anyhow::Result<ComputePipeline> {
        // A device without subgroup shuffles gets SPIR-V that does not declare them.
        let (name, spirv) = if ctx.info.subgroup_shuffle {
            ("render/rasterize", shaders::RENDER_RASTERIZE)
        } else {
            ("render/rasterize_plain", shaders::RENDER_RASTERIZE_PLAIN)
        };
        ComputePipeline::new(
            ctx,
            name,
            spirv,
            10,
            std::mem::size_of::<RasterPush>() as u32,
            WG / pixels,
            &[pixels, extra, decode as u32],
        )
    }

    /// The last frame's feature channels (`[pix·channels + c]`), when it rendered some and did
    /// not decode them.
    pub fn feature_image(&self) -> Option<&GpuBuffer<f32>> {
        self.feature_image.as_ref()
    }

    /// A renderer sized for `gaussians` and one camera, with a first guess of 8 intersections
    /// per Gaussian (regrown on demand).
    pub fn for_camera(
        ctx: &Arc<GpuContext>,
        gaussians: usize,
        camera: &CameraGpu,
    ) -> anyhow::Result<Self> {
        Self::new(
            ctx,
            Capacity {
                gaussians,
                intersections: (gaussians * 8)
                    .max(1 << 16)
                    .min(max_intersections(ctx) as usize),
                pixels: (camera.width() * camera.height()) as usize,
                tiles: camera.tile_count() as usize,
            },
        )
    }

    pub fn capacity(&self) -> Capacity {
        self.capacity
    }

    /// Grows the buffers (geometrically: 1.5× what is asked) when `need` exceeds the current
    /// capacity in any dimension. Returns true when it reallocated (recorded frames that used
    /// the old buffers must have completed).
    pub fn ensure_capacity(&mut self, need: Capacity) -> anyhow::Result<bool> {
        let cur = self.capacity;
        let max_pairs = self.pair_limit;
        if need.intersections as u64 > max_pairs {
            anyhow::bail!(
                "a frame has {} (tile, Gaussian) intersections, more than the {max_pairs} one \
                 storage binding holds on this device ({} MiB maxStorageBufferRange, 4 bytes a \
                 pair); training needs all of a frame's pairs at once (render, eval and bench \
                 fps draw such frames in bands of tile rows). Fix: train at a lower resolution \
                 (-r, --width/--height) or with fewer Gaussians",
                need.intersections,
                self.ctx.info.max_storage_buffer_range >> 20
            );
        }
        let grow = |have: usize, want: usize| {
            if want > have {
                want + want / 2
            } else {
                have
            }
        };
        let next = Capacity {
            gaussians: grow(cur.gaussians, need.gaussians),
            intersections: grow(cur.intersections, need.intersections).min(max_pairs as usize),
            pixels: grow(cur.pixels, need.pixels),
            tiles: grow(cur.tiles, need.tiles),
        };
        if next == cur {
            return Ok(false);
        }
        // Free the old buffers first so peak memory does not double.
        self.frame = FrameBuffers::new(&self.ctx, &Capacity::single())?;
        if next.gaussians != cur.gaussians {
            self.depth_sort = RadixSort::dropping(&self.ctx, next.gaussians as u64)?;
            self.scan = PrefixScan::new(&self.ctx, next.gaussians as u64)?;
        }
        if next.intersections != cur.intersections {
            self.tile_sort = RadixSort::new(&self.ctx, next.intersections as u64)?;
        }
        self.frame = FrameBuffers::new(&self.ctx, &next)?;
        self.capacity = next;
        Ok(true)
    }

    /// Grows the pixel and tile buffers to fit `camera`'s frame (see
    /// [`Renderer::ensure_capacity`]).
    pub fn fit_camera(&mut self, camera: &CameraGpu) -> anyhow::Result<bool> {
        let c = self.capacity;
        self.ensure_capacity(Capacity {
            pixels: c.pixels.max((camera.width() * camera.height()) as usize),
            tiles: c.tiles.max(camera.tile_count() as usize),
            ..c
        })
    }

    /// Records one whole frame of `splats` seen from `cameras[camera_index]` (whose host copy
    /// is `camera`), as training does. With a timestamp pool, writes one timestamp per stage
    /// (the caller starts the pool). The frame's outputs stay in [`Renderer::frame`] until the
    /// next record.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        settings: &FrameSettings,
        timestamps: Option<&mut TimestampPool>,
    ) -> anyhow::Result<()> {
        let work = FrameWork::Bands(vec![TileBand::whole(camera)]);
        self.record_work(
            rec,
            splats,
            cameras,
            camera_index,
            camera,
            settings,
            &work,
            timestamps,
        )
    }

    /// Records a frame's preprocess and depth sort, then `work`: with
    /// `FrameWork::Bands(renderer.bands_for(camera))`, a frame in the bands of tile rows
    /// [`Renderer::render_blocking`] planned for frames of this size (a benchmark's repeated
    /// frames; the whole frame when none were needed), whose per-band stages are timed once per
    /// band under the same labels.
    #[allow(clippy::too_many_arguments)]
    pub fn record_work(
        &mut self,
        rec: &mut Recorder,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        settings: &FrameSettings,
        work: &FrameWork,
        mut timestamps: Option<&mut TimestampPool>,
    ) -> anyhow::Result<()> {
        self.check_frame(splats.count, camera)?;
        if let FrameWork::Bands(bands) = work {
            self.prepare_bands(rec, bands.len())?;
        }
        let ctx = self.ctx.clone();
        let f = &self.frame;
        let n = splats.count as u64;

        // 1. Preprocess.
        let mut rc = settings.constants;
        if let Some(filter) = settings.filter3d {
            anyhow::ensure!(
                filter.len() >= splats.count,
                "renderer: {} 3D filter values for {} Gaussians",
                filter.len(),
                splats.count
            );
            rc.flags |= RenderConstants::FILTER_3D;
        }
        rec.fill(&f.tile_ranges, 0);
        let own: [(&str, &dyn Bindable); 7] = [
            ("cameras", cameras),
            ("projected_splats", &f.projected.splats),
            ("depth_keys", &f.depth_keys),
            ("depth_vals", &f.depth_vals),
            ("counts", &f.counts),
            ("filter3d", settings.filter3d.unwrap_or(&self.no_filter)),
            ("projected_bounds_out", &f.projected.bounds),
        ];
        let buffers: Vec<(&str, &dyn Bindable)> = own
            .into_iter()
            .chain(splats.bindings(&PARAM_BINDINGS))
            .collect();
        rec.dispatch_named(
            &self.preprocess,
            &buffers,
            &PreprocessPush {
                count: splats.count as u32,
                camera_index,
                sh_degree: settings.sh_degree.min(splats.sh_degree),
                rest_coeffs: ((splats.sh_degree + 1) * (splats.sh_degree + 1) - 1),
                rc,
            },
            // At least one invocation so counts[0] is written for an empty scene.
            ctx.groups_1d(n.max(1), WG),
        );
        rec.barrier();
        stamp(rec, timestamps.as_deref_mut(), "preprocess");

        // 2. Depth sort.
        self.record_depth_sort(rec, timestamps.as_deref_mut());
        let bands = match work {
            FrameWork::RowTotals => {
                self.record_row_totals(rec, camera, Pairing::Ellipse(rc))?;
                self.finish_frame(rec, camera, 0);
                return Ok(());
            }
            FrameWork::Bands(bands) => bands,
        };

        // The rasterizer's feature channels.
        if let Some(fc) = settings.features {
            anyhow::ensure!(
                fc.channels > 0 && fc.values.len() >= splats.count * fc.channels as usize,
                "renderer: {} feature values for {} Gaussians of {} channels",
                fc.values.len(),
                splats.count,
                fc.channels
            );
            let decode = fc.decoded_by.is_some();
            if let Some(w) = fc.decoded_by {
                use crate::splats::decoder_json::{FEATURE_CHANNELS, WEIGHTS};
                anyhow::ensure!(
                    fc.channels as usize == FEATURE_CHANNELS && w.len() >= WEIGHTS,
                    "renderer: the decoder takes {FEATURE_CHANNELS} feature channels and \
                     {WEIGHTS} weights, not {} and {}",
                    fc.channels,
                    w.len()
                );
            }
            let key = (fc.channels, decode);
            if self.raster_features.as_ref().map(|r| r.0) != Some(key) {
                let pipe = Self::raster_pipeline(&ctx, self.raster_pixels, fc.channels, decode)?;
                self.raster_features = Some((key, pipe));
            }
            let need = self.capacity.pixels.max(1) * fc.channels as usize;
            if decode {
                // A decoded frame writes no feature image: none is kept.
                self.feature_image = None;
            } else if self.feature_image.as_ref().is_none_or(|b| b.len() < need) {
                self.feature_image = None;
                self.feature_image = Some(GpuBuffer::new(
                    &ctx,
                    "feature image",
                    need,
                    BufferKind::DeviceLocal,
                )?);
            }
        }
        if let Some(m) = self.median.as_mut() {
            let need = self.capacity.pixels.max(1);
            if m.depth.as_ref().is_none_or(|b| b.len() < need) {
                m.depth = None;
                m.depth = Some(GpuBuffer::new(
                    &ctx,
                    "median depth",
                    need,
                    BufferKind::DeviceLocal,
                )?);
            }
        }
        if let Some(c) = self.contributions.as_mut() {
            let (pixels, gaussians) = (self.capacity.pixels.max(1), self.capacity.gaussians.max(1));
            let small = c
                .buffers
                .as_ref()
                .is_none_or(|b| b.pixel_weights.len() < pixels || b.sums[0].len() < gaussians);
            if small {
                c.buffers = None;
                let sum =
                    |name: &str| GpuBuffer::new(&ctx, name, gaussians, BufferKind::DeviceLocal);
                c.buffers = Some(ContributionBuffers {
                    pixel_weights: GpuBuffer::new(
                        &ctx,
                        "pixel weights",
                        pixels,
                        BufferKind::DeviceLocal,
                    )?,
                    sums: [
                        sum("contribution weight")?,
                        sum("contribution pixels")?,
                        sum("contribution blend")?,
                        sum("contribution distance")?,
                    ],
                });
            }
            let b = c.buffers.as_ref().expect("allocated above");
            for s in &b.sums {
                rec.fill_range(s, splats.count.max(1), 0);
            }
            rec.barrier();
        }
        // A decoding rasterizer's stage holds the decoder too.
        let decoded = settings.features.is_some_and(|f| f.decoded_by.is_some());
        let label = if decoded {
            "rasterize + decode"
        } else {
            "rasterize"
        };

        for (slot, band) in bands.iter().enumerate() {
            // 3–5. Binning, tile sort and tile ranges of the band's rows.
            self.record_band_binning(
                rec,
                camera,
                Pairing::Ellipse(rc),
                band,
                slot as u32,
                timestamps.as_deref_mut(),
            );
            // 6. Rasterize one workgroup per tile of the band.
            let f = &self.frame;
            let (_, ids) = self.sorted_pairs();
            let (raster, features, feature_image, weights) = match settings.features {
                Some(fc) => (
                    &self.raster_features.as_ref().expect("built above").1,
                    fc.values,
                    match fc.decoded_by {
                        // Bound, never written.
                        Some(_) => &self.no_filter,
                        None => self.feature_image.as_ref().expect("allocated above"),
                    },
                    fc.decoded_by.unwrap_or(&self.no_filter),
                ),
                None => (
                    &self.raster,
                    &self.no_filter,
                    &self.no_filter,
                    &self.no_filter,
                ),
            };
            rec.dispatch_named(
                raster,
                &[
                    ("splats", &f.projected.splats),
                    ("sorted_ids", ids),
                    ("ranges", &f.tile_ranges),
                    ("cameras", cameras),
                    ("image", &f.image),
                    ("final_t", &f.final_t),
                    ("last_index", &f.last_index),
                    ("features", features),
                    ("feature_image", feature_image),
                    ("dec_w", weights),
                ],
                &RasterPush {
                    rc: settings.constants,
                    camera_index,
                    background: settings.background,
                    tile_offset: band.first_row * camera.tiles_x(),
                },
                ctx.groups_1d(band.tiles(camera), 1),
            );
            rec.barrier();
            stamp(rec, timestamps.as_deref_mut(), label);
            if let Some(m) = &self.median {
                rec.dispatch_named(
                    &m.pipe,
                    &[
                        ("splats", &f.projected.splats),
                        ("bounds", &f.projected.bounds),
                        ("sorted_ids", ids),
                        ("ranges", &f.tile_ranges),
                        ("cameras", cameras),
                        ("median_depth", m.depth.as_ref().expect("allocated above")),
                    ],
                    &MedianPush {
                        rc: settings.constants,
                        camera_index,
                        tile_offset: band.first_row * camera.tiles_x(),
                    },
                    ctx.groups_1d(band.tiles(camera), 1),
                );
                rec.barrier();
                stamp(rec, timestamps.as_deref_mut(), "median depth");
            }
            if let Some(c) = &self.contributions {
                let b = c.buffers.as_ref().expect("allocated above");
                rec.dispatch_named(
                    &c.pipe,
                    &[
                        ("splats", &f.projected.splats),
                        ("sorted_ids", ids),
                        ("ranges", &f.tile_ranges),
                        ("cameras", cameras),
                        ("pixel_weights", &b.pixel_weights),
                        ("weight_sum", &b.sums[0]),
                        ("pixel_count", &b.sums[1]),
                        ("blend_sum", &b.sums[2]),
                        ("distance_sum", &b.sums[3]),
                    ],
                    &ContributionPush {
                        rc: settings.constants,
                        camera_index,
                        tile_offset: band.first_row * camera.tiles_x(),
                    },
                    ctx.groups_1d(band.tiles(camera), 1),
                );
                rec.barrier();
                stamp(rec, timestamps.as_deref_mut(), "contributions");
            }
        }
        self.finish_frame(rec, camera, bands.len());
        Ok(())
    }

    /// Checks that a frame of `count` splats at `camera`'s size fits the buffers.
    pub(super) fn check_frame(&self, count: usize, camera: &CameraGpu) -> anyhow::Result<()> {
        let pixels = (camera.width() as usize) * (camera.height() as usize);
        anyhow::ensure!(
            count <= self.capacity.gaussians
                && pixels <= self.capacity.pixels
                && camera.tile_count() as usize <= self.capacity.tiles,
            "renderer sized for {:?} cannot draw {} Gaussians at {}×{}; call ensure_capacity first",
            self.capacity,
            count,
            camera.width(),
            camera.height()
        );
        Ok(())
    }

    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// How many bands of tile rows the last frame was drawn in (1: whole).
    pub fn last_frame_bands(&self) -> usize {
        self.last_bands
    }

    /// Fails unless the last frame was drawn whole: the backward passes read the whole frame's
    /// sorted pairs and tile ranges.
    pub fn whole_frame(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.last_bands == 1,
            "this frame was drawn in {} bands of tile rows (its pairs pass what one storage \
             binding holds), and training needs all of a frame's pairs at once. Fix: train at a \
             lower resolution (-r, --width/--height) or with fewer Gaussians",
            self.last_bands
        );
        Ok(())
    }

    /// The digits of the renderer's two radix sorts ([`super::sort::Digits::for_device`]).
    pub fn sort_digits(&self) -> super::sort::Digits {
        self.tile_sort.digits()
    }

    /// The Gaussian index of every intersection, tile-major, front to back within a tile (the
    /// contract's `sorted_ids`) of the last recorded frame.
    pub fn sorted_ids(&self) -> &GpuBuffer<u32> {
        self.sorted_pairs().1
    }

    /// The intersection count of the last completed frame (call after its fence). When it is
    /// above the capacity the frame dropped pairs: grow and render again.
    pub fn last_intersections(&self) -> anyhow::Result<u64> {
        Ok(self.last_band_totals()?.iter().sum())
    }

    /// Each band's intersection count of the last completed frame (one for a whole frame;
    /// call after its fence). A band above the capacity dropped pairs.
    pub fn last_band_totals(&self) -> anyhow::Result<Vec<u64>> {
        let raw = self.totals.host.read_range(0, 2 * self.last_bands)?;
        Ok(raw
            .chunks_exact(2)
            .map(|w| ((w[1] as u64) << 32) | w[0] as u64)
            .collect())
    }

    /// How many Gaussians of the last completed frame paired with a tile (the depth sort kept
    /// them; call after its fence).
    pub fn last_visible(&self) -> anyhow::Result<u64> {
        Ok(self.frame.counts_host.read()?[COUNT_VISIBLE as usize] as u64)
    }

    /// True when the last completed frame (every band of it) had room for every intersection.
    pub fn last_frame_complete(&self) -> anyhow::Result<bool> {
        let cap = self.capacity.intersections as u64;
        Ok(self.last_band_totals()?.iter().all(|&t| t <= cap))
    }

    /// Reads the last frame's image (RGB interleaved, `width × height × 3`).
    pub fn read_image(&self) -> anyhow::Result<Vec<f32>> {
        let cam = self
            .last_camera
            .ok_or_else(|| anyhow::anyhow!("no frame rendered yet"))?;
        self.frame
            .image
            .read_range(0, (cam.width() * cam.height()) as usize * 3)
    }
}
