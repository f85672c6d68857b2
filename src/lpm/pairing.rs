//! Region pairing (docs/algorithms/lpm.md step 5): an error box in V → the box of its matched keypoints in V
//! (R_e) and the box of their matches in the referred view V' (R_e').

use super::regions::{BlockOwners, Region};

/// A continuous pixel box `[x0, x1] × [y0, y1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelBox {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl From<Region> for PixelBox {
    /// The region's pixel box (its pixels' edges).
    fn from(r: Region) -> PixelBox {
        PixelBox {
            x0: r.x0 as f64,
            y0: r.y0 as f64,
            x1: r.x1 as f64,
            y1: r.y1 as f64,
        }
    }
}

impl PixelBox {
    pub fn center(&self) -> [f64; 2] {
        [0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1)]
    }
    /// Radius of the circumscribed circle (half the diagonal).
    pub fn circumradius(&self) -> f64 {
        0.5 * (self.x1 - self.x0).hypot(self.y1 - self.y0)
    }
    pub fn area(&self) -> f64 {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }
    /// The bounding box of `pts`; `None` when empty or not finite.
    pub fn bounding(pts: impl IntoIterator<Item = [f64; 2]>) -> Option<PixelBox> {
        let mut b = PixelBox {
            x0: f64::INFINITY,
            y0: f64::INFINITY,
            x1: f64::NEG_INFINITY,
            y1: f64::NEG_INFINITY,
        };
        for p in pts {
            b.x0 = b.x0.min(p[0]);
            b.y0 = b.y0.min(p[1]);
            b.x1 = b.x1.max(p[0]);
            b.y1 = b.y1.max(p[1]);
        }
        (b.x0.is_finite() && b.x1.is_finite() && b.y0.is_finite() && b.y1.is_finite()).then_some(b)
    }
}

/// An error region with its paired boxes.
#[derive(Debug, Clone, PartialEq)]
pub struct RegionPair {
    /// The error box in V.
    pub region: Region,
    /// R_e: bounding box of the matched keypoints of `region` (inside its box, or on its own
    /// error blocks: [`RegionKeypoints`]), in V.
    pub in_view: PixelBox,
    /// R_e': bounding box of their matches, in V'.
    pub in_reference: PixelBox,
    pub matches: usize,
    /// Indices (into the step's `xy_view` / `xy_ref`) of the matches inside `region`: the
    /// correspondences the triangulated zone is built from.
    pub matched: Vec<u32>,
}

/// What happened to the regions of one step (for the summary).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PairingStats {
    pub regions: usize,
    pub paired: usize,
    /// Regions holding no matched keypoint.
    pub no_matches: usize,
    /// Regions whose R_e or R_e' has zero area (e.g. one match, or matches on a line).
    pub zero_area: usize,
}

/// Which matched keypoints speak for an error region.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum RegionKeypoints {
    /// Only those on the region's own error blocks. A region is an 8-connected set of error
    /// blocks, and its box also covers what lies between them; on Truck at `-r 4` one region of
    /// background trees had a box reaching over the truck's hood, whose keypoints (many,
    /// textured) outnumbered the trees' and put the zone on the hood, where there was no error.
    /// Not the default: measured (docs/results/lpm.md), the zones grew instead
    /// (0.29 of the scene extent against 0.21), since a region's own blocks often span depths
    /// (trees behind a fence) and one sphere encloses them all, and the gain was smaller.
    ErrorBlocks,
    /// The paper and the authors' code (default): every match inside the region's box.
    #[default]
    Box,
}

impl RegionKeypoints {
    pub fn name(self) -> &'static str {
        match self {
            RegionKeypoints::ErrorBlocks => "error-blocks",
            RegionKeypoints::Box => "box",
        }
    }

    pub fn parse(name: &str) -> anyhow::Result<RegionKeypoints> {
        Ok(match name {
            "error-blocks" => RegionKeypoints::ErrorBlocks,
            "box" => RegionKeypoints::Box,
            other => anyhow::bail!(
                "LPM region keypoints {other:?} are unknown. Fix: choose error-blocks or box"
            ),
        })
    }
}

/// Pairs every region with the matches inside its box. `xy_view[i]` (in V) matches
/// `xy_ref[i]` (in V').
pub fn pair_regions(
    regions: &[Region],
    xy_view: &[[f32; 2]],
    xy_ref: &[[f32; 2]],
) -> (Vec<RegionPair>, PairingStats) {
    pair_regions_on(regions, None, xy_view, xy_ref)
}

/// [`pair_regions`], counting for each region only the matches on its own error blocks when
/// `owners` is given ([`RegionKeypoints::ErrorBlocks`]).
pub fn pair_regions_on(
    regions: &[Region],
    owners: Option<&BlockOwners>,
    xy_view: &[[f32; 2]],
    xy_ref: &[[f32; 2]],
) -> (Vec<RegionPair>, PairingStats) {
    pair(regions, owners, xy_view, xy_ref, false)
}

/// [`pair_regions_on`] for zones built from the region itself
/// ([`crate::lpm::ZoneGeometry::Local`]): R_e is the region's own box (the pixels that had the
/// error), and one match is enough (a single error block often holds one keypoint); R_e' is the
/// box of the matches in V', of zero area for one match.
pub fn pair_regions_whole(
    regions: &[Region],
    owners: Option<&BlockOwners>,
    xy_view: &[[f32; 2]],
    xy_ref: &[[f32; 2]],
) -> (Vec<RegionPair>, PairingStats) {
    pair(regions, owners, xy_view, xy_ref, true)
}

fn pair(
    regions: &[Region],
    owners: Option<&BlockOwners>,
    xy_view: &[[f32; 2]],
    xy_ref: &[[f32; 2]],
    whole: bool,
) -> (Vec<RegionPair>, PairingStats) {
    let mut stats = PairingStats {
        regions: regions.len(),
        ..Default::default()
    };
    let mut out = Vec::new();
    for (k, r) in regions.iter().enumerate() {
        let inside: Vec<usize> = (0..xy_view.len().min(xy_ref.len()))
            .filter(|&i| {
                let (x, y) = (xy_view[i][0] as f64, xy_view[i][1] as f64);
                r.contains(x, y) && owners.is_none_or(|o| o.owner(x, y) == Some(k))
            })
            .collect();
        if inside.is_empty() {
            stats.no_matches += 1;
            continue;
        }
        let to64 = |p: [f32; 2]| [p[0] as f64, p[1] as f64];
        let bv = match whole {
            true => Some(PixelBox::from(*r)),
            false => PixelBox::bounding(inside.iter().map(|&i| to64(xy_view[i]))),
        };
        let br = PixelBox::bounding(inside.iter().map(|&i| to64(xy_ref[i])));
        match (bv, br) {
            (Some(bv), Some(br)) if whole || (bv.area() > 0.0 && br.area() > 0.0) => {
                stats.paired += 1;
                out.push(RegionPair {
                    region: *r,
                    in_view: bv,
                    in_reference: br,
                    matches: inside.len(),
                    matched: inside.iter().map(|&i| i as u32).collect(),
                });
            }
            _ => stats.zero_area += 1,
        }
    }
    (out, stats)
}
