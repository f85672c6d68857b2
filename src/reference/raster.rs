//! Tile binning, per-tile depth sort, and front-to-back alpha blending per pixel.

use anyhow::{ensure, Result};

use super::project::Projected;
use super::RenderSettings;
use crate::scene::PinholeCamera;

/// Per tile, the Gaussians paired with it ([`Projected::row_tiles`]: the tiles of the
/// rectangle where the splat may reach `alpha_min` at a pixel centre), sorted by depth (ties by index):
/// exactly the order a GPU sort of (tile | depth) keys with values emitted in Gaussian order
/// and a stable sort produces.
#[derive(Debug, Clone, PartialEq)]
pub struct TileBins {
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub tile_size: u32,
    /// `lists[ty·tiles_x + tx]`: Gaussian indices, nearest first.
    pub lists: Vec<Vec<u32>>,
}

impl TileBins {
    /// The tile holding pixel (i, j).
    pub fn tile_of_pixel(&self, i: u32, j: u32) -> usize {
        (j / self.tile_size) as usize * self.tiles_x as usize + (i / self.tile_size) as usize
    }

    /// Total number of (Gaussian, tile) pairs.
    pub fn intersections(&self) -> u64 {
        self.lists.iter().map(|l| l.len() as u64).sum()
    }
}

/// Bins the projected Gaussians into tiles and sorts each tile by depth.
pub fn bin_gaussians(
    projected: &[Projected],
    camera: &PinholeCamera,
    settings: &RenderSettings,
) -> Result<TileBins> {
    ensure!(
        settings.tile_size > 0,
        "reference binning: settings.tile_size is 0; use 16"
    );
    let (tiles_x, tiles_y) = settings.tile_grid(camera.width, camera.height);
    let mut lists = vec![Vec::new(); tiles_x as usize * tiles_y as usize];
    for (g, p) in projected.iter().enumerate() {
        if p.culled {
            continue;
        }
        for ty in p.tile_min[1]..p.tile_max[1].min(tiles_y) {
            for tx in p.row_tiles(ty, settings) {
                lists[ty as usize * tiles_x as usize + tx as usize].push(g as u32);
            }
        }
    }
    for list in &mut lists {
        list.sort_by(|&a, &b| {
            projected[a as usize]
                .depth
                .total_cmp(&projected[b as usize].depth)
                .then(a.cmp(&b))
        });
    }
    Ok(TileBins {
        tiles_x,
        tiles_y,
        tile_size: settings.tile_size,
        lists,
    })
}

/// The rendered image and, per pixel, what the backward pass needs.
#[derive(Debug, Clone, PartialEq)]
pub struct RasterOutput {
    pub width: u32,
    pub height: u32,
    /// Row-major `[r, g, b]`, background included.
    pub image: Vec<[f64; 3]>,
    /// Transmittance left after the last contributing splat.
    pub final_transmittance: Vec<f64>,
    /// Position in the tile's sorted list of the last contributing splat, plus one (0 = none).
    pub last_contributor: Vec<u32>,
    /// Number of splats that contributed (not skipped) to the pixel.
    pub contributors: Vec<u32>,
    /// Per Gaussian: the pixels it contributed to (Pixel-GS's n_v(i)).
    pub pixel_count: Vec<u32>,
    /// The median depth: the view-space depth of the splat that takes the pixel's
    /// transmittance below ½ (`None` where it stays at ½ or above). SpacetimeGaussians' guided
    /// sampling reads its maximum as a view's depth (the official rasterizer's depth output,
    /// which writes 15 where there is none).
    pub median_depth: Vec<Option<f64>>,
}

/// One splat evaluated at one pixel centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplatSample {
    /// `mean2d − pixel centre`.
    pub d: [f64; 2],
    /// `exp(power)`.
    pub gauss: f64,
    /// The alpha used for blending.
    pub alpha: f64,
    /// `opacity·exp(power)` exceeded `alpha_max` and was clamped (no gradient to it).
    pub alpha_clamped: bool,
}

/// Evaluates splat `p` at the pixel centre `(px, py)`; `None` when the splat is skipped there
/// (`power > 0`, or alpha below `alpha_min` outside smooth mode).
pub fn sample_splat(
    p: &Projected,
    px: f64,
    py: f64,
    settings: &RenderSettings,
) -> Option<SplatSample> {
    let d = [p.mean2d[0] - px, p.mean2d[1] - py];
    let [a, b, c] = p.conic;
    let power = -0.5 * (a * d[0] * d[0] + c * d[1] * d[1]) - b * d[0] * d[1];
    // power > 0 is impossible for a positive definite conic; it only guards rounding.
    if power > 0.0 {
        return None;
    }
    let gauss = power.exp();
    let raw = p.opacity * gauss;
    if settings.smooth {
        return Some(SplatSample {
            d,
            gauss,
            alpha: raw,
            alpha_clamped: false,
        });
    }
    let alpha_clamped = raw > settings.alpha_max;
    let alpha = if alpha_clamped {
        settings.alpha_max
    } else {
        raw
    };
    if alpha < settings.alpha_min {
        return None;
    }
    Some(SplatSample {
        d,
        gauss,
        alpha,
        alpha_clamped,
    })
}

/// Blends every pixel front to back over its tile's sorted list.
pub fn rasterize(
    projected: &[Projected],
    bins: &TileBins,
    camera: &PinholeCamera,
    background: [f64; 3],
    settings: &RenderSettings,
) -> Result<RasterOutput> {
    let (tiles_x, tiles_y) = settings.tile_grid(camera.width, camera.height);
    ensure!(
        bins.tiles_x == tiles_x && bins.tiles_y == tiles_y && bins.tile_size == settings.tile_size,
        "reference rasterize: the tile bins ({}×{} tiles of {} px) were not made for this camera \
         and settings ({tiles_x}×{tiles_y} tiles of {} px); bin with the same camera and settings",
        bins.tiles_x,
        bins.tiles_y,
        bins.tile_size,
        settings.tile_size
    );
    let n = camera.width as usize * camera.height as usize;
    let mut out = RasterOutput {
        width: camera.width,
        height: camera.height,
        image: vec![[0.0; 3]; n],
        final_transmittance: vec![1.0; n],
        last_contributor: vec![0; n],
        contributors: vec![0; n],
        pixel_count: vec![0; projected.len()],
        median_depth: vec![None; n],
    };
    for j in 0..camera.height {
        for i in 0..camera.width {
            let pix = j as usize * camera.width as usize + i as usize;
            let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
            let list = &bins.lists[bins.tile_of_pixel(i, j)];
            let mut t = 1.0;
            let mut color = [0.0; 3];
            for (k, &g) in list.iter().enumerate() {
                let p = &projected[g as usize];
                let Some(s) = sample_splat(p, px, py, settings) else {
                    continue;
                };
                let next_t = t * (1.0 - s.alpha);
                // Stop before the splat that would make the pixel (almost) opaque: the
                // backward divides by 1 − alpha to walk back, and this bounds that.
                if !settings.smooth && next_t < settings.t_min {
                    break;
                }
                for (c, rgb) in color.iter_mut().zip(p.rgb) {
                    *c += rgb * s.alpha * t;
                }
                if t >= 0.5 && next_t < 0.5 {
                    out.median_depth[pix] = Some(p.depth);
                }
                t = next_t;
                out.last_contributor[pix] = k as u32 + 1;
                out.contributors[pix] += 1;
                out.pixel_count[g as usize] += 1;
            }
            for ch in 0..3 {
                out.image[pix][ch] = color[ch] + t * background[ch];
            }
            out.final_transmittance[pix] = t;
        }
    }
    Ok(out)
}

/// What each Gaussian gave a frame, summed over the pixels it was blended into
/// ([`contributions`]; `glsl/render/contributions.comp` on the GPU).
#[derive(Debug, Clone, PartialEq)]
pub struct ContributionSums {
    /// The weights of those pixels.
    pub weight: Vec<f64>,
    /// Their number.
    pub pixels: Vec<f64>,
    /// Its blending weights `T·alpha` there.
    pub blend: Vec<f64>,
    /// Its 2D mean's distance to their centres.
    pub distance: Vec<f64>,
}

/// Walks every pixel's list as [`rasterize`] blends it and sums, per Gaussian blended there,
/// the pixel's weight (`pixel_weights`, row-major), 1, `T·alpha` and the distance from its 2D
/// mean to the pixel centre.
pub fn contributions(
    projected: &[Projected],
    bins: &TileBins,
    camera: &PinholeCamera,
    settings: &RenderSettings,
    pixel_weights: &[f64],
) -> Result<ContributionSums> {
    let n = camera.width as usize * camera.height as usize;
    ensure!(
        pixel_weights.len() == n,
        "reference contributions: {} pixel weights for a {}×{} frame",
        pixel_weights.len(),
        camera.width,
        camera.height
    );
    let zeros = vec![0.0; projected.len()];
    let mut out = ContributionSums {
        weight: zeros.clone(),
        pixels: zeros.clone(),
        blend: zeros.clone(),
        distance: zeros,
    };
    for j in 0..camera.height {
        for i in 0..camera.width {
            let pix = j as usize * camera.width as usize + i as usize;
            let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
            let mut t = 1.0;
            for &g in &bins.lists[bins.tile_of_pixel(i, j)] {
                let Some(s) = sample_splat(&projected[g as usize], px, py, settings) else {
                    continue;
                };
                let next_t = t * (1.0 - s.alpha);
                if !settings.smooth && next_t < settings.t_min {
                    break;
                }
                let g = g as usize;
                out.weight[g] += pixel_weights[pix];
                out.pixels[g] += 1.0;
                out.blend[g] += t * s.alpha;
                out.distance[g] += s.d[0].hypot(s.d[1]);
                t = next_t;
            }
        }
    }
    Ok(out)
}

/// A splat's footprint as another renderer computed it: 2D mean, conic and opacity (for
/// [`alpha_min_edges`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    pub mean2d: [f64; 2],
    pub conic: [f64; 3],
    pub opacity: f64,
}

impl Footprint {
    pub fn of(p: &Projected) -> Self {
        Footprint {
            mean2d: p.mean2d,
            conic: p.conic,
            opacity: p.opacity,
        }
    }

    /// The footprint the GPU's preprocess wrote (f32, widened).
    pub fn of_gpu(p: &crate::render::layout::ProjectedGpu) -> Self {
        Footprint {
            mean2d: [p.mean_x as f64, p.mean_y as f64],
            conic: [p.conic_a as f64, p.conic_b as f64, p.conic_c as f64],
            opacity: p.opacity as f64,
        }
    }

    /// `opacity·exp(power)` at the pixel centre (px, py), before any clamp or threshold
    /// (power above 0, possible only by rounding, counts as 0).
    pub fn raw_alpha(&self, px: f64, py: f64) -> f64 {
        let d = [self.mean2d[0] - px, self.mean2d[1] - py];
        let [a, b, c] = self.conic;
        let power = -0.5 * (a * d[0] * d[0] + c * d[1] * d[1]) - b * d[0] * d[1];
        self.opacity * power.min(0.0).exp()
    }
}

/// Per pixel, how many splats of its tile list may be blended by one renderer and skipped by
/// the other at the `alpha_min` test: those whose raw alpha there, evaluated from this
/// reference's footprint and from `other`'s (another renderer's projection of the same
/// splats, e.g. a GPU's in f32; index for index), reaches into `alpha_min·(1 ± band)` or
/// straddles it (`band` covers the other renderer's own per-pixel rounding). Each such
/// decision changes the pixel by up to alpha_min of its transmittance, so comparisons bound
/// those pixels by their count instead of the exact tolerance. 0 everywhere in smooth mode
/// (no alpha_min test).
pub fn alpha_min_edges(
    projected: &[Projected],
    other: &[Footprint],
    bins: &TileBins,
    camera: &PinholeCamera,
    settings: &RenderSettings,
    band: f64,
) -> Vec<u32> {
    let n = camera.width as usize * camera.height as usize;
    let mut edges = vec![0u32; n];
    if settings.smooth {
        return edges;
    }
    let (lo, hi) = (
        settings.alpha_min * (1.0 - band),
        settings.alpha_min * (1.0 + band),
    );
    for j in 0..camera.height {
        for i in 0..camera.width {
            let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
            let list = &bins.lists[bins.tile_of_pixel(i, j)];
            edges[j as usize * camera.width as usize + i as usize] =
                list.iter()
                    .filter(|&&g| {
                        let a = Footprint::of(&projected[g as usize]).raw_alpha(px, py);
                        let b = other[g as usize].raw_alpha(px, py);
                        a.min(b) <= hi && a.max(b) >= lo
                    })
                    .count() as u32;
        }
    }
    edges
}
