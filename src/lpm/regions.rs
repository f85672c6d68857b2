//! Error map → error regions (docs/algorithms/lpm.md steps 1–2).
//!
//! Split in three so each step can be replaced by a GPU pass without touching the rest:
//! [`error_map`] (render + ground truth → per-pixel error), [`block_mask`] (error → kept 16×16
//! blocks; or [`BlockMask::from_error_counts`] when a GPU pass already counted error pixels per
//! block) and [`regions_from_blocks`] (kept blocks → 8-connected components → pixel boxes).

/// Settings of steps 1–2 (the paper's numbers by default).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionSettings {
    /// A pixel is an error pixel when its error is strictly above this quantile of the map.
    pub quantile: f32,
    /// Block side in pixels; 0: follow the image size ([`RegionSettings::resolved`]).
    pub block: u32,
    /// A block is kept when strictly more than this fraction of its pixels are error pixels.
    pub keep_fraction: f32,
}

impl Default for RegionSettings {
    fn default() -> Self {
        Self {
            quantile: 0.4,
            block: 0,
            keep_fraction: 0.85,
        }
    }
}

/// The block side the paper uses (16 px) at the resolution it works at (about 1 megapixel).
pub const REFERENCE_BLOCK: u32 = 16;
pub const REFERENCE_PIXELS: f64 = 1.0e6;
/// The smallest automatic block side: below 4×4 a block is a handful of noisy pixels.
pub const MIN_AUTO_BLOCK: u32 = 4;

impl RegionSettings {
    /// The settings for a `width`×`height` image: an explicit `block` as it is; `block` 0 follows
    /// the image size, 16 px at one megapixel scaled with the diagonal (so a block covers the
    /// same share of the image at every resolution), at least 4 px. An 85 % error block of 16 px
    /// is a small region at 1 MP but a sixth of the height at 162×242, where it almost never
    /// occurs.
    pub fn resolved(&self, width: u32, height: u32) -> RegionSettings {
        let block = if self.block > 0 {
            self.block
        } else {
            let scale = (width as f64 * height as f64 / REFERENCE_PIXELS).sqrt();
            ((REFERENCE_BLOCK as f64 * scale).round() as u32).clamp(MIN_AUTO_BLOCK, 256)
        };
        RegionSettings { block, ..*self }
    }
}

/// A pixel box, right/bottom exclusive, clipped to the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Region {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Region {
    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }
    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }
    /// True when the continuous point (x, y) (pixel centres at +0.5) lies in the box.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0 as f64 && x < self.x1 as f64 && y >= self.y0 as f64 && y < self.y1 as f64
    }
}

/// Which blocks of a (padded) image are kept.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BlockMask {
    /// The image size (unpadded).
    pub width: u32,
    pub height: u32,
    pub block: u32,
    /// Blocks per row and per column: `ceil(width / block)`, `ceil(height / block)`.
    pub blocks_x: u32,
    pub blocks_y: u32,
    /// Row-major, `blocks_x * blocks_y`.
    pub kept: Vec<bool>,
}

impl BlockMask {
    /// From per-block counts of error pixels (row-major, `ceil(w/block) * ceil(h/block)`), as a
    /// GPU pass would produce them. Padding pixels count as non-error pixels, so the threshold is
    /// always against the full `block²` (as when the mask is zero-padded to a multiple of 16).
    pub fn from_error_counts(
        width: u32,
        height: u32,
        block: u32,
        counts: &[u32],
        keep_fraction: f32,
    ) -> anyhow::Result<BlockMask> {
        anyhow::ensure!(block > 0, "block size must be positive");
        let blocks_x = width.div_ceil(block);
        let blocks_y = height.div_ceil(block);
        anyhow::ensure!(
            counts.len() == (blocks_x * blocks_y) as usize,
            "block counts: got {}, expected {} ({}×{} blocks of {} px for a {}×{} image)",
            counts.len(),
            blocks_x * blocks_y,
            blocks_x,
            blocks_y,
            block,
            width,
            height
        );
        let need = keep_fraction as f64 * (block * block) as f64;
        let kept = counts.iter().map(|&c| c as f64 > need).collect();
        Ok(BlockMask {
            width,
            height,
            block,
            blocks_x,
            blocks_y,
            kept,
        })
    }

    pub fn is_kept(&self, bx: u32, by: u32) -> bool {
        self.kept[(by * self.blocks_x + bx) as usize]
    }
}

/// Mean-normalised absolute error summed over RGB, one value per pixel. `render` and `gt` hold 3
/// floats per pixel, row-major. Each image is divided by `mean + 0.01` (mean over all pixels and
/// channels) first, so a global exposure difference is not read as error.
pub fn error_map(render: &[f32], gt: &[f32], width: u32, height: u32) -> anyhow::Result<Vec<f32>> {
    let n = width as usize * height as usize;
    anyhow::ensure!(
        render.len() == 3 * n && gt.len() == 3 * n,
        "error map: render has {} floats, ground truth {}, expected {} (3 per pixel of {}×{})",
        render.len(),
        gt.len(),
        3 * n,
        width,
        height
    );
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64;
    let sr = 1.0 / (mean(render) + 0.01);
    let sg = 1.0 / (mean(gt) + 0.01);
    Ok((0..n)
        .map(|i| {
            let mut e = 0.0f64;
            for c in 0..3 {
                e += (render[3 * i + c] as f64 * sr - gt[3 * i + c] as f64 * sg).abs();
            }
            e as f32
        })
        .collect())
}

/// The `q`-quantile of `values` with linear interpolation between order statistics (the default
/// of `torch.quantile` and `numpy.quantile`). NaNs sort last. Empty input gives 0.
pub fn quantile(values: &[f32], q: f32) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    let mut v = values.to_vec();
    let q = q.clamp(0.0, 1.0) as f64;
    let pos = q * (v.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let frac = pos - lo as f64;
    let (_, &mut a, rest) = v.select_nth_unstable_by(lo, |x, y| x.total_cmp(y));
    if frac == 0.0 || rest.is_empty() {
        return a;
    }
    let b = rest
        .iter()
        .copied()
        .min_by(|x, y| x.total_cmp(y))
        .unwrap_or(a);
    (a as f64 + frac * (b as f64 - a as f64)) as f32
}

/// Error pixels (error strictly above the `quantile` of the map) counted per block, then blocks
/// kept above `keep_fraction`. The image is treated as zero-padded to a multiple of `block`.
pub fn block_mask(
    error: &[f32],
    width: u32,
    height: u32,
    quantile_q: f32,
    block: u32,
    keep_fraction: f32,
) -> anyhow::Result<BlockMask> {
    anyhow::ensure!(
        error.len() == width as usize * height as usize,
        "block mask: error map has {} values, expected {}×{}",
        error.len(),
        width,
        height
    );
    anyhow::ensure!(block > 0, "block size must be positive");
    let threshold = quantile(error, quantile_q);
    let blocks_x = width.div_ceil(block);
    let blocks_y = height.div_ceil(block);
    let mut counts = vec![0u32; (blocks_x * blocks_y) as usize];
    for y in 0..height {
        let row = &error[(y * width) as usize..((y + 1) * width) as usize];
        let by = y / block;
        for (x, &e) in row.iter().enumerate() {
            if e > threshold {
                counts[(by * blocks_x + x as u32 / block) as usize] += 1;
            }
        }
    }
    BlockMask::from_error_counts(width, height, block, &counts, keep_fraction)
}

/// 8-connected components of kept blocks, each as its pixel bounding box (right/bottom exclusive,
/// clipped to the image). Ordered by the first block met in row-major order.
pub fn regions_from_blocks(mask: &BlockMask) -> Vec<Region> {
    regions_and_owners(mask).0
}

/// Which region owns each kept block: the 8-connected component it belongs to, as an index into
/// the regions [`regions_and_owners`] returns with it. A region's box can hold blocks of other
/// components and blocks that are not error blocks at all; this says which are its own.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BlockOwners {
    block: u32,
    blocks_x: u32,
    blocks_y: u32,
    /// Per block (row-major): region index + 1, 0 for a block that is not kept.
    label: Vec<u32>,
}

impl BlockOwners {
    /// The owners of `mask`'s blocks from their labels (region index + 1, 0: not kept).
    fn of(mask: &BlockMask, label: Vec<u32>) -> BlockOwners {
        BlockOwners {
            block: mask.block,
            blocks_x: mask.blocks_x,
            blocks_y: mask.blocks_y,
            label,
        }
    }

    /// The region owning the block containing pixel point (x, y) (pixel centres at +0.5);
    /// `None` outside the image or on a block that is not kept.
    pub fn owner(&self, x: f64, y: f64) -> Option<usize> {
        if !(x >= 0.0 && y >= 0.0) || self.block == 0 {
            return None;
        }
        let (bx, by) = (
            (x / self.block as f64) as u64,
            (y / self.block as f64) as u64,
        );
        if bx >= self.blocks_x as u64 || by >= self.blocks_y as u64 {
            return None;
        }
        let l = self.label[(by * self.blocks_x as u64 + bx) as usize];
        (l > 0).then(|| l as usize - 1)
    }
}

/// [`regions_from_blocks`] with the owner of every kept block.
pub fn regions_and_owners(mask: &BlockMask) -> (Vec<Region>, BlockOwners) {
    let (bw, bh) = (mask.blocks_x as i64, mask.blocks_y as i64);
    let mut label = vec![0u32; mask.kept.len()];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for start in 0..mask.kept.len() {
        if !mask.kept[start] || label[start] > 0 {
            continue;
        }
        let id = out.len() as u32 + 1;
        label[start] = id;
        stack.push(start);
        let (mut bx0, mut by0, mut bx1, mut by1) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
        while let Some(i) = stack.pop() {
            let (bx, by) = (i as i64 % bw, i as i64 / bw);
            bx0 = bx0.min(bx);
            by0 = by0.min(by);
            bx1 = bx1.max(bx);
            by1 = by1.max(by);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (bx + dx, by + dy);
                    if nx < 0 || ny < 0 || nx >= bw || ny >= bh {
                        continue;
                    }
                    let j = (ny * bw + nx) as usize;
                    if mask.kept[j] && label[j] == 0 {
                        label[j] = id;
                        stack.push(j);
                    }
                }
            }
        }
        let b = mask.block as i64;
        out.push(Region {
            x0: (bx0 * b) as u32,
            y0: (by0 * b) as u32,
            x1: (((bx1 + 1) * b) as u32).min(mask.width),
            y1: (((by1 + 1) * b) as u32).min(mask.height),
        });
    }
    (out, BlockOwners::of(mask, label))
}

/// Every kept block as a region of its own (its pixel box, clipped to the image), in row-major
/// order, with the owners that say so: the unit of [`RegionUnit::Blocks`]. A connected component
/// of error blocks can run across the image (the ground under a truck, a sky line), and its box,
/// and the zone of its matches, then spans near and far surfaces; a block is as local as the
/// error map is.
///
/// [`RegionUnit::Blocks`]: crate::lpm::region_units::RegionUnit::Blocks
pub fn block_regions(mask: &BlockMask) -> (Vec<Region>, BlockOwners) {
    let mut label = vec![0u32; mask.kept.len()];
    let mut out = Vec::new();
    let b = mask.block;
    for (i, _) in mask.kept.iter().enumerate().filter(|(_, &k)| k) {
        let (bx, by) = (i as u32 % mask.blocks_x, i as u32 / mask.blocks_x);
        out.push(Region {
            x0: bx * b,
            y0: by * b,
            x1: ((bx + 1) * b).min(mask.width),
            y1: ((by + 1) * b).min(mask.height),
        });
        label[i] = out.len() as u32;
    }
    (out, BlockOwners::of(mask, label))
}

/// Steps 1–2 in one call: render and ground truth (3 floats per pixel) → error regions.
pub fn error_regions(
    render: &[f32],
    gt: &[f32],
    width: u32,
    height: u32,
    s: &RegionSettings,
) -> anyhow::Result<Vec<Region>> {
    let e = error_map(render, gt, width, height)?;
    let m = block_mask(&e, width, height, s.quantile, s.block, s.keep_fraction)?;
    Ok(regions_from_blocks(&m))
}
