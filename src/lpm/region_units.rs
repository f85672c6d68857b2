//! What one error zone is built from: a connected component of error blocks (the paper's
//! regions), a single error block, or, as the control that tells what the error map adds, as
//! many blocks drawn at random.

use super::regions::{block_regions, regions_and_owners, BlockMask, BlockOwners, Region};
use rand::seq::SliceRandom;
use rand::SeedableRng;

/// The unit a zone is built from (`--lpm-regions`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum RegionUnit {
    /// An 8-connected component of kept blocks, as its bounding box (the paper).
    #[default]
    Components,
    /// Each kept block alone ([`block_regions`]).
    Blocks,
    /// The control: as many blocks as the error map kept among those holding a match of the
    /// step's view pair, drawn uniformly among all blocks holding one, each alone. Everything
    /// after the choice (pairing, zones, weights, resets) runs as for [`RegionUnit::Blocks`], so
    /// the two differ only in where the error map says the blocks are.
    RandomBlocks,
}

impl RegionUnit {
    pub fn parse(s: &str) -> anyhow::Result<RegionUnit> {
        Ok(match s {
            "components" => RegionUnit::Components,
            "blocks" => RegionUnit::Blocks,
            "random-blocks" => RegionUnit::RandomBlocks,
            other => anyhow::bail!(
                "LPM regions {other:?} are unknown. Fix: choose components, blocks or \
                 random-blocks"
            ),
        })
    }
    pub fn name(&self) -> &'static str {
        match self {
            RegionUnit::Components => "components",
            RegionUnit::Blocks => "blocks",
            RegionUnit::RandomBlocks => "random-blocks",
        }
    }
}

/// The regions of one step and their owners: `mask` is the error map's kept blocks, `matched`
/// the step's matched keypoints in the view (pixels), `seed` the step's own draw.
pub fn step_regions(
    unit: RegionUnit,
    mask: &BlockMask,
    matched: &[[f32; 2]],
    seed: u64,
) -> (Vec<Region>, BlockOwners) {
    match unit {
        RegionUnit::Components => regions_and_owners(mask),
        RegionUnit::Blocks => block_regions(mask),
        RegionUnit::RandomBlocks => block_regions(&random_blocks_like(mask, matched, seed)),
    }
}

/// Blocks holding at least one of `points` (pixel centres at +0.5), row-major flags.
fn blocks_holding(mask: &BlockMask, points: &[[f32; 2]]) -> Vec<bool> {
    let mut has = vec![false; mask.kept.len()];
    for p in points {
        let (x, y) = (p[0] as f64, p[1] as f64);
        if !(x >= 0.0 && y >= 0.0 && x < mask.width as f64 && y < mask.height as f64) {
            continue;
        }
        let (bx, by) = (
            (x / mask.block as f64) as u32,
            (y / mask.block as f64) as u32,
        );
        if bx < mask.blocks_x && by < mask.blocks_y {
            has[(by * mask.blocks_x + bx) as usize] = true;
        }
    }
    has
}

/// A mask of the same size as `mask` with as many kept blocks as `mask` keeps among the blocks
/// holding one of `points`, drawn without replacement among all blocks holding one (seeded).
pub fn random_blocks_like(mask: &BlockMask, points: &[[f32; 2]], seed: u64) -> BlockMask {
    let has = blocks_holding(mask, points);
    let n = has.iter().zip(&mask.kept).filter(|(&h, &k)| h && k).count();
    let mut pool: Vec<usize> = (0..has.len()).filter(|&i| has[i]).collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x7261_6e64_5f62_6c6b);
    let (chosen, _) = pool.partial_shuffle(&mut rng, n);
    let mut kept = vec![false; mask.kept.len()];
    for &i in chosen.iter() {
        kept[i] = true;
    }
    BlockMask {
        kept,
        ..mask.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(w: u32, h: u32, block: u32, kept_at: &[usize]) -> BlockMask {
        let (bx, by) = (w.div_ceil(block), h.div_ceil(block));
        let mut kept = vec![false; (bx * by) as usize];
        for &i in kept_at {
            kept[i] = true;
        }
        BlockMask {
            width: w,
            height: h,
            block,
            blocks_x: bx,
            blocks_y: by,
            kept,
        }
    }

    #[test]
    fn blocks_are_regions_of_their_own_clipped_to_the_image() {
        // 10×6 image, 4-px blocks: 3×2 blocks; blocks 0, 1 (touching) and 5 (clipped corner).
        let m = mask(10, 6, 4, &[0, 1, 5]);
        let (comp, _) = step_regions(RegionUnit::Components, &m, &[], 0);
        assert_eq!(
            comp.len(),
            1,
            "8-connected: 5 touches 1 diagonally: {comp:?}"
        );
        let (r, owners) = step_regions(RegionUnit::Blocks, &m, &[], 0);
        assert_eq!(
            r,
            vec![
                Region {
                    x0: 0,
                    y0: 0,
                    x1: 4,
                    y1: 4
                },
                Region {
                    x0: 4,
                    y0: 0,
                    x1: 8,
                    y1: 4
                },
                Region {
                    x0: 8,
                    y0: 4,
                    x1: 10,
                    y1: 6
                },
            ]
        );
        assert_eq!(owners.owner(1.5, 1.5), Some(0));
        assert_eq!(owners.owner(5.5, 0.5), Some(1));
        assert_eq!(owners.owner(9.5, 5.5), Some(2));
        assert_eq!(owners.owner(1.5, 5.5), None);
    }

    #[test]
    fn random_blocks_keep_the_count_of_matched_error_blocks_and_hold_matches() {
        // 8×8 blocks of 4 px; error blocks 0..10, matches in blocks 3, 5, 20, 30, 40, 50.
        let m = mask(32, 32, 4, &(0..10).collect::<Vec<_>>());
        let at = |i: u32| [((i % 8) * 4) as f32 + 1.5, ((i / 8) * 4) as f32 + 2.5];
        let pts: Vec<[f32; 2]> = [3, 5, 20, 30, 40, 50, 50].into_iter().map(at).collect();
        for seed in 0..20 {
            let r = random_blocks_like(&m, &pts, seed);
            let kept: Vec<usize> = (0..64).filter(|&i| r.kept[i]).collect();
            assert_eq!(kept.len(), 2, "two error blocks hold a match");
            assert!(
                kept.iter().all(|i| [3, 5, 20, 30, 40, 50].contains(i)),
                "{kept:?}"
            );
            assert_eq!(r, random_blocks_like(&m, &pts, seed), "seeded");
        }
        let draws: std::collections::HashSet<Vec<bool>> = (0..20)
            .map(|s| random_blocks_like(&m, &pts, s).kept)
            .collect();
        assert!(draws.len() > 3, "the draw depends on the seed");
        // No match anywhere: nothing kept; points off the image are ignored.
        let r = random_blocks_like(&m, &[[-1.0, 3.0], [40.0, 1.0]], 1);
        assert!(r.kept.iter().all(|&k| !k));
    }

    #[test]
    fn region_units_parse_and_name_round_trip() {
        for u in [
            RegionUnit::Components,
            RegionUnit::Blocks,
            RegionUnit::RandomBlocks,
        ] {
            assert_eq!(RegionUnit::parse(u.name()).unwrap(), u);
        }
        assert!(RegionUnit::parse("pixels")
            .unwrap_err()
            .to_string()
            .contains("random-blocks"));
    }
}
