//! Frames whose (tile, Gaussian) pairs pass one storage binding, drawn in bands of tile rows.
//!
//! A frame's pairs live in 4-byte buffers of tile keys and Gaussian ids, each one binding: at
//! most `maxStorageBufferRange / 4` pairs (33.5 M on lavapipe's 128 MiB, 1.07 G at 4 GiB). A
//! 4K render of a multi-million-Gaussian model passes that on CPU drivers. Tools (`render`,
//! `eval`, `bench fps`, the orbit GIF, through `super::blocking`) then draw the frame band by
//! band: the preprocess and the depth sort once, then per band of whole tile rows the binning,
//! the tile sort and the rasterizer, which writes only the band's pixels. Each band's tile
//! lists are the whole frame's lists of the same tiles, in the same order, so the image is the
//! same bit for bit (`tests/gpu/bands.rs`).
//!
//! The bands come from one planning pass that counts every tile row's pairs
//! (`glsl/render/tile_row_pairs.comp`) and packs consecutive rows greedily ([`plan_bands`]); a
//! single row past the limit is refused with its count. The plan is kept for the next frames
//! of the same tile rows (a benchmark's loop, an evaluation's views), made again when one of
//! them overflows, and dropped after a banded frame whose pairs would have fit whole. Training
//! never draws in bands: its backward needs the whole frame's pairs at once, so such a frame is
//! refused there (`Renderer::whole_frame`). This module holds the bands and their planning;
//! `super::blocking` draws frames with them.

use super::layout::CameraGpu;

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
