//! The binning half of a frame (steps 2–5 of [`super`]): the depth sort, the pairs of a band
//! of tile rows, their stable tile sort and tile ranges; the planning pass that counts every
//! tile row's pairs, and the plan of bands tools draw large frames in (`crate::render::bands`).

use std::sync::Arc;

use super::{
    max_intersections, stamp, tile_bits, EmitPush, Pairing, Renderer, COUNT_GAUSSIANS,
    COUNT_INTERSECTIONS, COUNT_SCRATCH, COUNT_SLOTS, COUNT_STORED_PAIRS, COUNT_VISIBLE,
    CULLED_DEPTH_KEY, DEPTH_KEY_BITS, PAIR_GROUPS, VISIBLE_GROUPS, WG,
};
use crate::gpu::{BufferKind, GpuBuffer, GpuContext, Recorder, TimestampPool};
use crate::render::bands::TileBand;
use crate::render::layout::CameraGpu;
use crate::render::sort::{DropKeys, SortedIn};

/// Each band's intersections as 64 bits (low word, carries: gather_tile_counts.comp), on the
/// GPU and copied for the host after the frame; room for `bands` bands.
pub(super) struct BandTotals {
    pub(super) device: GpuBuffer<u32>,
    pub(super) host: GpuBuffer<u32>,
    pub(super) bands: usize,
}

impl BandTotals {
    pub(super) fn new(ctx: &Arc<GpuContext>, bands: usize) -> anyhow::Result<Self> {
        Ok(Self {
            device: GpuBuffer::new(ctx, "band pair totals", 2 * bands, BufferKind::DeviceLocal)?,
            host: GpuBuffer::new(
                ctx,
                "band pair totals (host)",
                2 * bands,
                BufferKind::Readback,
            )?,
            bands,
        })
    }
}

impl Renderer {
    /// Step 2 of a frame whose preprocess (3DGS's or another model's) has filled
    /// `frame.projected`, the depth keys and values and `counts[0]` (its splats), and zeroed
    /// `frame.tile_ranges`: the depth sort of the Gaussians that pair with a tile (the culled
    /// ones, the largest key, are dropped by the sort's first pass; counts[COUNT_VISIBLE] are
    /// kept), and the group counts of the binning kernels over them.
    pub(in crate::render) fn record_depth_sort(
        &mut self,
        rec: &mut Recorder,
        timestamps: Option<&mut TimestampPool>,
    ) {
        let f = &self.frame;
        let depth_in = self.depth_sort.record_dropping(
            rec,
            [
                &f.depth_keys,
                &f.depth_vals,
                &f.depth_keys_tmp,
                &f.depth_vals_tmp,
            ],
            &f.counts,
            COUNT_GAUSSIANS,
            COUNT_SCRATCH,
            DEPTH_KEY_BITS,
            Some(DropKeys {
                key: CULLED_DEPTH_KEY,
                kept_index: COUNT_VISIBLE,
            }),
        );
        self.depth_sorted_in = depth_in;
        stamp(rec, timestamps, "depth sort");
        // The binning kernels run over the kept Gaussians (as many workgroups as they need: CPU
        // drivers pay for idle ones).
        self.pair_groups
            .record(rec, &f.counts, COUNT_VISIBLE, WG as u64, VISIBLE_GROUPS);
    }

    fn depth_ids(&self) -> &GpuBuffer<u32> {
        match self.depth_sorted_in {
            SortedIn::Input => &self.frame.depth_vals,
            SortedIn::Scratch => &self.frame.depth_vals_tmp,
        }
    }

    /// Zeroes the pair totals of a frame of `bands` bands (growing their buffers first), before
    /// the preprocess (whose barrier orders the fill before the binning).
    pub(in crate::render) fn prepare_bands(
        &mut self,
        rec: &mut Recorder,
        bands: usize,
    ) -> anyhow::Result<()> {
        if self.totals.bands < bands {
            self.totals = BandTotals::new(&self.ctx, bands)?;
        }
        rec.fill(&self.totals.device, 0);
        Ok(())
    }

    /// Steps 3–5 of a frame after [`Renderer::record_depth_sort`], for the tile rows of `band`
    /// (its pair total in slot `slot`): tile counts in depth order, scan, emit, the stable tile
    /// sort and the tile ranges, pairing each splat with the tiles `pairing` says. The sorted
    /// pairs are then [`Renderer::sorted_ids`].
    pub(in crate::render) fn record_band_binning(
        &mut self,
        rec: &mut Recorder,
        camera: &CameraGpu,
        pairing: Pairing,
        band: &TileBand,
        slot: u32,
        mut timestamps: Option<&mut TimestampPool>,
    ) {
        let f = &self.frame;
        let depth_ids = self.depth_ids();
        let push = pairing.push(band, slot);
        // 3. Tile counts in depth order, scan, emit pairs, each over the kept Gaussians.
        let (visible_args, visible_at) = self.pair_groups.args(VISIBLE_GROUPS);
        rec.dispatch_indirect_named(
            &self.gather,
            &[
                ("bounds", &f.projected.bounds),
                ("depth_sorted_ids", depth_ids),
                ("touched", &f.touched),
                ("counts", &f.counts),
                ("pair_total", &self.totals.device),
                ("splats", &f.projected.splats),
            ],
            &push,
            visible_args,
            visible_at,
        );
        self.scan.record(
            rec,
            &f.touched,
            &f.counts,
            COUNT_VISIBLE,
            Some(COUNT_INTERSECTIONS),
        );
        rec.dispatch_indirect_named(
            &self.emit,
            &[
                ("bounds", &f.projected.bounds),
                ("depth_sorted_ids", depth_ids),
                ("offsets", &f.touched),
                ("keys", &f.tile_keys),
                ("vals", &f.tile_vals),
                ("counts", &f.counts),
                ("splats", &f.projected.splats),
            ],
            &EmitPush {
                pairing: push,
                capacity: self.capacity.intersections.min(u32::MAX as usize) as u32,
                tiles_x: camera.tiles_x(),
            },
            visible_args,
            visible_at,
        );
        rec.barrier();
        stamp(rec, timestamps.as_deref_mut(), "binning");

        // 4. Stable sort by tile id (only the bits this image needs).
        let bits = tile_bits(camera.tile_count());
        self.tile_sorted_in = self.tile_sort.record(
            rec,
            &f.tile_keys,
            &f.tile_vals,
            &f.tile_keys_tmp,
            &f.tile_vals_tmp,
            &f.counts,
            COUNT_STORED_PAIRS,
            COUNT_SCRATCH,
            bits,
        );
        let (keys, _) = self.sorted_pairs();
        stamp(rec, timestamps, "tile sort");

        // 5. Tile ranges, over the band's pairs (not the capacity).
        let f = &self.frame;
        self.pair_groups
            .record(rec, &f.counts, COUNT_STORED_PAIRS, WG as u64, PAIR_GROUPS);
        let (args, at) = self.pair_groups.args(PAIR_GROUPS);
        rec.dispatch_indirect_named(
            &self.ranges,
            &[
                ("keys", keys),
                ("ranges", &f.tile_ranges),
                ("counts", &f.counts),
            ],
            &(),
            args,
            at,
        );
        rec.barrier();
    }

    /// The planning pass after [`Renderer::record_depth_sort`]: every tile row's pairs into
    /// the row totals ([`Renderer::reserve_row_totals`] first).
    pub(in crate::render) fn record_row_totals(
        &mut self,
        rec: &mut Recorder,
        camera: &CameraGpu,
        pairing: Pairing,
    ) -> anyhow::Result<()> {
        let rows = self
            .row_totals
            .as_ref()
            .filter(|b| b.len() >= 2 * camera.tiles_y() as usize)
            .ok_or_else(|| anyhow::anyhow!("renderer: no row totals for this frame's rows"))?;
        rec.fill(rows, 0);
        rec.barrier();
        let (args, at) = self.pair_groups.args(VISIBLE_GROUPS);
        let f = &self.frame;
        rec.dispatch_indirect_named(
            &self.row_pairs,
            &[
                ("bounds", &f.projected.bounds),
                ("depth_sorted_ids", self.depth_ids()),
                ("counts", &f.counts),
                ("splats", &f.projected.splats),
                ("row_totals", rows),
            ],
            &pairing.push(&TileBand::whole(camera), 0),
            args,
            at,
        );
        rec.barrier();
        Ok(())
    }

    /// Room for the row totals of `camera`'s frame.
    pub(in crate::render) fn reserve_row_totals(
        &mut self,
        camera: &CameraGpu,
    ) -> anyhow::Result<()> {
        let need = 2 * camera.tiles_y() as usize;
        if self.row_totals.as_ref().is_none_or(|b| b.len() < need) {
            self.row_totals = None;
            self.row_totals = Some(GpuBuffer::new(
                &self.ctx,
                "tile row pairs",
                need,
                BufferKind::DeviceLocal,
            )?);
        }
        Ok(())
    }

    /// The pairs of every tile row of the last planning pass (call after its fence).
    pub(in crate::render) fn last_row_totals(
        &self,
        camera: &CameraGpu,
    ) -> anyhow::Result<Vec<u64>> {
        let rows = camera.tiles_y() as usize;
        let raw = self
            .row_totals
            .as_ref()
            .ok_or_else(|| anyhow::anyhow!("renderer: no planning pass recorded"))?
            .read_range(0, 2 * rows)?;
        Ok(raw
            .chunks_exact(2)
            .map(|w| ((w[1] as u64) << 32) | w[0] as u64)
            .collect())
    }

    /// The end of every frame of `bands` bands: the counts and the bands' pair totals go to the
    /// host buffers (read after the frame's fence) and the camera is remembered for the
    /// readbacks.
    pub(in crate::render) fn finish_frame(
        &mut self,
        rec: &mut Recorder,
        camera: &CameraGpu,
        bands: usize,
    ) {
        rec.copy(&self.frame.counts, &self.frame.counts_host, COUNT_SLOTS);
        if bands > 0 {
            rec.copy(&self.totals.device, &self.totals.host, 2 * bands);
        }
        self.last_bands = bands;
        self.last_camera = Some(*camera);
    }

    /// The bands tools draw `camera`'s frames in: the plan made for frames of its tile rows,
    /// or the whole frame.
    pub fn bands_for(&self, camera: &CameraGpu) -> Vec<TileBand> {
        match &self.plan {
            (rows, bands) if *rows == camera.tiles_y() && !bands.is_empty() => bands.clone(),
            _ => vec![TileBand::whole(camera)],
        }
    }

    /// Draws frames of `camera`'s tile rows in `bands` from now on (tools; see
    /// [`super::bands`]).
    pub(in crate::render) fn set_plan(
        &mut self,
        camera: &CameraGpu,
        bands: Vec<TileBand>,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            bands.first().map(|b| b.first_row) == Some(0)
                && bands.last().map(|b| b.end_row) == Some(camera.tiles_y())
                && bands.windows(2).all(|w| w[0].end_row == w[1].first_row),
            "renderer: bands {bands:?} do not cover the {} tile rows in order",
            camera.tiles_y()
        );
        self.plan = (camera.tiles_y(), bands);
        Ok(())
    }

    /// Draws every frame whole again (tools; see [`super::bands`]).
    pub(in crate::render) fn clear_plan(&mut self) {
        self.plan = (0, Vec::new());
    }

    /// Caps the pairs a frame (or a band of a frame drawn in bands) may have below what one
    /// binding holds: to rehearse a device with a smaller `maxStorageBufferRange`, and for
    /// tests of banded frames.
    pub fn limit_pairs(&mut self, limit: u64) {
        self.pair_limit = limit.clamp(1, max_intersections(&self.ctx));
    }

    /// The most pairs a frame (or band) may have ([`max_intersections`] unless lowered).
    pub fn pair_limit(&self) -> u64 {
        self.pair_limit
    }

    pub(in crate::render) fn sorted_pairs(&self) -> (&GpuBuffer<u32>, &GpuBuffer<u32>) {
        let f = &self.frame;
        match self.tile_sorted_in {
            SortedIn::Input => (&f.tile_keys, &f.tile_vals),
            SortedIn::Scratch => (&f.tile_keys_tmp, &f.tile_vals_tmp),
        }
    }
}
