//! Frames whose (tile, Gaussian) pairs pass one storage binding, drawn in bands of tile rows.
//!
//! A frame's pairs live in 4-byte buffers of tile keys and Gaussian ids, each one binding: at
//! most `maxStorageBufferRange / 4` pairs (33.5 M on lavapipe's 128 MiB, 1.07 G at 4 GiB). A
//! 4K render of a multi-million-Gaussian model passes that on CPU drivers. Tools
//! ([`render_blocking`]: `render`, `eval`, `bench fps`, the orbit GIF) then draw the frame band
//! by band: the preprocess and the depth sort once, then per band of whole tile rows the
//! binning, the tile sort and the rasterizer, which writes only the band's pixels. Each band's
//! tile lists are the whole frame's lists of the same tiles, in the same order, so the image
//! is the same bit for bit (`tests/gpu_bands.rs`).
//!
//! The bands come from one planning pass that counts every tile row's pairs
//! (`glsl/render/tile_row_pairs.comp`) and packs consecutive rows greedily ([`plan_bands`]); a
//! single row past the limit is refused with its count. The plan is kept for the next frames of
//! the same size (a benchmark's loop, an evaluation's views) and redone when one of them
//! overflows. Training never draws in bands: its backward needs the whole frame's pairs at once,
//! so such a frame is refused there ([`Renderer::whole_frame`]).

use anyhow::Result;

use super::forward::{Capacity, Renderer};
use super::layout::CameraGpu;
use crate::gpu::Recorder;

/// Tile rows `[first_row, end_row)` of a frame, with their (tile, Gaussian) pairs when known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileBand {
    pub first_row: u32,
    pub end_row: u32,
    /// The band's pairs as counted by the planning pass (0 for the unplanned whole frame).
    pub pairs: u64,
}

impl TileBand {
    /// Every tile row of `camera`'s frame.
    pub fn whole(camera: &CameraGpu) -> Self {
        Self {
            first_row: 0,
            end_row: camera.tiles_y(),
            pairs: 0,
        }
    }

    /// The band's tiles in `camera`'s frame.
    pub fn tiles(&self, camera: &CameraGpu) -> u64 {
        u64::from(self.end_row - self.first_row) * u64::from(camera.tiles_x())
    }
}

/// What a frame's recording does after the preprocess and the depth sort.
#[derive(Debug, Clone)]
pub enum FrameWork {
    /// Binning, tile sort and rasterizer for each band in turn.
    Bands(Vec<TileBand>),
    /// Only counts the pairs of every tile row (the planning pass; draws nothing).
    RowTotals,
}

/// A tile row with more pairs than one band may hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowTooFull {
    pub row: u32,
    pub pairs: u64,
}

/// Cuts rows with `row_pairs[r]` pairs each into bands of consecutive rows holding at most
/// `limit` pairs each, packing greedily from the top (the fewest bands any cut into consecutive
/// rows can make). A row past `limit` cannot be drawn in any band.
pub fn plan_bands(row_pairs: &[u64], limit: u64) -> Result<Vec<TileBand>, RowTooFull> {
    let mut bands: Vec<TileBand> = Vec::new();
    for (r, &n) in row_pairs.iter().enumerate() {
        let row = r as u32;
        if n > limit {
            return Err(RowTooFull { row, pairs: n });
        }
        match bands.last_mut() {
            Some(b) if b.pairs + n <= limit => {
                b.end_row = row + 1;
                b.pairs += n;
            }
            _ => bands.push(TileBand {
                first_row: row,
                end_row: row + 1,
                pairs: n,
            }),
        }
    }
    Ok(bands)
}

/// A renderer that can be drawn in bands: the 3D-Gaussian renderer, or one built on its
/// binning (surfels).
pub trait BandedRenderer {
    /// The binning stages and buffers.
    fn base(&mut self) -> &mut Renderer;
    /// Grows every buffer the renderer sizes by `need` ([`Renderer::ensure_capacity`]).
    fn grow(&mut self, need: Capacity) -> Result<bool>;
}

impl BandedRenderer for Renderer {
    fn base(&mut self) -> &mut Renderer {
        self
    }
    fn grow(&mut self, need: Capacity) -> Result<bool> {
        self.ensure_capacity(need)
    }
}

/// Renders one frame and waits: `record` records the frame's work into the given command
/// buffer. The frame is redrawn after growing the pair buffers when they were too small, and in
/// bands of tile rows (planned by one counting pass) when its pairs pass what one binding holds.
pub fn render_blocking<R: BandedRenderer>(
    r: &mut R,
    camera: &CameraGpu,
    mut record: impl FnMut(&mut R, &mut Recorder, &FrameWork) -> Result<()>,
) -> Result<()> {
    let ctx = r.base().context().clone();
    let mut planned = false;
    loop {
        let bands = r.base().bands_for(camera);
        let mut rec = Recorder::new(&ctx)?;
        record(r, &mut rec, &FrameWork::Bands(bands))?;
        rec.submit_and_wait()?;
        let totals = r.base().last_band_totals()?;
        let most = totals.iter().copied().max().unwrap_or(0);
        let base = r.base();
        let capacity = base.capacity();
        if most <= capacity.intersections as u64 {
            return Ok(());
        }
        let limit = base.pair_limit();
        if most <= limit {
            r.grow(Capacity {
                intersections: most as usize,
                ..capacity
            })?;
            continue;
        }
        // The planned bands were counted exactly: one past the limit would mean the count and
        // the binning disagree.
        anyhow::ensure!(
            !planned,
            "a band of tile rows has {most} (tile, Gaussian) pairs after planning for at most \
             {limit}: the planning pass and the binning disagree (a bug; please report it)"
        );
        let total: u64 = totals.iter().sum();
        let mut rec = Recorder::new(&ctx)?;
        r.base().reserve_row_totals(camera)?;
        record(r, &mut rec, &FrameWork::RowTotals)?;
        rec.submit_and_wait()?;
        let base = r.base();
        let rows = base.last_row_totals(camera)?;
        let plan = plan_bands(&rows, limit).map_err(|full| {
            anyhow::anyhow!(
                "a frame has {total} (tile, Gaussian) intersections, and its row {} of 16-px \
                 tiles alone has {}, more than the {limit} one storage binding holds on this \
                 device ({} MiB maxStorageBufferRange, 4 bytes a pair): it cannot be drawn even \
                 in bands of tile rows. Fix: render at a lower resolution (-r, \
                 --width/--height) or with fewer Gaussians",
                full.row,
                full.pairs,
                base.context().info.max_storage_buffer_range >> 20
            )
        })?;
        let most = plan.iter().map(|b| b.pairs).max().unwrap_or(0);
        base.set_plan(camera, plan)?;
        let capacity = base.capacity();
        r.grow(Capacity {
            intersections: most as usize,
            ..capacity
        })?;
        planned = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(plan: &[TileBand]) -> Vec<(u32, u32, u64)> {
        plan.iter()
            .map(|b| (b.first_row, b.end_row, b.pairs))
            .collect()
    }

    #[test]
    fn rows_pack_greedily_into_bands_that_fit() {
        let plan = plan_bands(&[3, 4, 0, 5, 5, 1, 10], 10).unwrap();
        assert_eq!(
            rows(&plan),
            vec![(0, 3, 7), (3, 5, 10), (5, 6, 1), (6, 7, 10)]
        );
        // Every row in exactly one band, in order.
        assert_eq!(plan_bands(&[1; 6], 100).unwrap().len(), 1);
        assert!(plan_bands(&[], 10).unwrap().is_empty());
        assert_eq!(
            plan_bands(&[2, 11, 3], 10),
            Err(RowTooFull { row: 1, pairs: 11 })
        );
        // Totals past 2^32 per band.
        let big = 3u64 << 31;
        assert_eq!(
            rows(&plan_bands(&[big, big, big], 2 * big).unwrap()),
            vec![(0, 2, 2 * big), (2, 3, big)]
        );
    }
}
