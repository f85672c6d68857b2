//! Surfel tile binning, per-tile depth sort, ray–surfel intersection through the transform
//! matrix, and front-to-back compositing of colour, depth, normal, median depth and distortion.
//! The numbered steps are those of the module docs of [`crate::reference::surfel`].

use anyhow::{ensure, Result};

use super::project::SurfelProjected;
use super::SurfelSettings;
use crate::reference::linalg::{self, Vec3};
use crate::reference::TileBins;
use crate::scene::{PinholeCamera, Pose};

/// Bins the projected surfels into tiles and sorts each tile by the centre's camera depth, ties
/// by index (the order of [`crate::reference::bin_gaussians`]).
pub fn bin_surfels(
    projected: &[SurfelProjected],
    camera: &PinholeCamera,
    settings: &SurfelSettings,
) -> Result<TileBins> {
    ensure!(
        settings.tile_size > 0,
        "reference surfel binning: settings.tile_size is 0; use 16"
    );
    let (tiles_x, tiles_y) = settings.tile_grid(camera.width, camera.height);
    let mut lists = vec![Vec::new(); tiles_x as usize * tiles_y as usize];
    for (g, p) in projected.iter().enumerate() {
        if p.culled() {
            continue;
        }
        for ty in p.tile_min[1]..p.tile_max[1].min(tiles_y) {
            for tx in p.tile_min[0]..p.tile_max[0].min(tiles_x) {
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

/// Why a surfel is skipped at a pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfelSkip {
    /// Step 1: `p₃ == 0`, the ray is parallel to the surfel's plane (official guard).
    Parallel,
    /// Step 2: the hit depth is not finite (overflow in the division by a tiny `p₃`, or in the
    /// cross product); not in the official code.
    NonFinite,
    /// Step 2: the hit depth is below `near` (or behind the camera).
    Near,
    /// Step 4: alpha below `alpha_min` (never in smooth mode).
    Faint,
}

/// One surfel evaluated at one pixel centre: every intermediate of steps 1–4.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfelSample {
    /// The plane `x·h₃ − h₁`.
    pub a: Vec3,
    /// The plane `y·h₃ − h₂`.
    pub c: Vec3,
    /// `a × c`, the homogeneous hit in the surfel's `(u, v, 1)` plane.
    pub p: Vec3,
    /// `(p₁/p₃, p₂/p₃)`.
    pub uv: [f64; 2],
    /// Hit depth `h₃·(u, v, 1)`.
    pub z: f64,
    /// `u² + v²`.
    pub rho3d: f64,
    /// `m − x` (box centre minus pixel centre).
    pub d: [f64; 2],
    /// `filter_inv_square·|d|²`.
    pub rho2d: f64,
    /// The low-pass term won (`rho3d > rho2d`): `rho = rho2d`.
    pub lowpass: bool,
    /// `exp(−rho/2)`.
    pub gauss: f64,
    /// The alpha used for blending.
    pub alpha: f64,
    /// `opacity·gauss` exceeded `alpha_max` and was clamped (no gradient to it).
    pub alpha_clamped: bool,
}

impl SurfelSample {
    /// `min(rho3d, rho2d)` with ties to the object-space term.
    pub fn rho(&self) -> f64 {
        if self.lowpass {
            self.rho2d
        } else {
            self.rho3d
        }
    }
}

/// Evaluates surfel `p` at the pixel centre `(px, py)` (steps 1–4), or says why it is skipped
/// there.
pub fn sample_surfel(
    p: &SurfelProjected,
    px: f64,
    py: f64,
    settings: &SurfelSettings,
) -> Result<SurfelSample, SurfelSkip> {
    let [h1, h2, h3] = p.transform;
    // Step 1: the two planes through the ray and their intersection.
    let a = linalg::sub(linalg::scale(h3, px), h1);
    let c = linalg::sub(linalg::scale(h3, py), h2);
    let hit = cross(a, c);
    if hit[2] == 0.0 {
        return Err(SurfelSkip::Parallel);
    }
    // Step 2: the division by p₃ and the hit depth. The finiteness guard is ours (see the
    // module docs): `p₃` passed the exact-zero test but can still be small enough for the
    // quotient to overflow.
    let uv = [hit[0] / hit[2], hit[1] / hit[2]];
    let z = uv[0] * h3[0] + uv[1] * h3[1] + h3[2];
    if !z.is_finite() {
        return Err(SurfelSkip::NonFinite);
    }
    if z < settings.near {
        return Err(SurfelSkip::Near);
    }
    // Step 3: object-space falloff vs the screen-space low-pass filter.
    let rho3d = uv[0] * uv[0] + uv[1] * uv[1];
    let d = [p.center2d[0] - px, p.center2d[1] - py];
    let rho2d = settings.filter_inv_square * (d[0] * d[0] + d[1] * d[1]);
    // `z` finite implies finite (u, v), so `rho3d` is never NaN here (it can be +inf when
    // u² overflows); ties go to the object-space term.
    let lowpass = rho3d > rho2d;
    let rho = if lowpass { rho2d } else { rho3d };
    // Step 4: alpha.
    let gauss = (-0.5 * rho).exp();
    let raw = p.opacity * gauss;
    let (alpha, alpha_clamped) = if settings.smooth {
        (raw, false)
    } else if raw > settings.alpha_max {
        (settings.alpha_max, true)
    } else {
        (raw, false)
    };
    if !settings.smooth && alpha < settings.alpha_min {
        return Err(SurfelSkip::Faint);
    }
    Ok(SurfelSample {
        a,
        c,
        p: hit,
        uv,
        z,
        rho3d,
        d,
        rho2d,
        lowpass,
        gauss,
        alpha,
        alpha_clamped,
    })
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// One pixel after compositing its tile's list (step 5), before the background.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfelPixel {
    /// `Σ w·rgb`.
    pub color: [f64; 3],
    /// Transmittance left after the last contributor.
    pub transmittance: f64,
    /// `Σ w·z`.
    pub depth: f64,
    /// `Σ w·n` (camera space).
    pub normal: Vec3,
    /// Hit depth of the last surfel blended while `T > 0.5` (0 if none).
    pub median_depth: f64,
    /// Its list position plus one (0 = none).
    pub median_contributor: u32,
    /// `Σ_i w_i (m_i² A_i + M₂ − 2 m_i M₁)`.
    pub distortion: f64,
    /// `Σ w·m(z)`.
    pub m1: f64,
    /// `Σ w·m(z)²`.
    pub m2: f64,
    /// List position plus one of the last contributor (0 = none).
    pub last_contributor: u32,
    /// Number of surfels blended.
    pub contributors: u32,
}

/// Composites the sorted `list` at the pixel centre `(px, py)` (step 5).
pub fn composite_pixel(
    projected: &[SurfelProjected],
    list: &[u32],
    px: f64,
    py: f64,
    settings: &SurfelSettings,
) -> SurfelPixel {
    let mut out = SurfelPixel {
        color: [0.0; 3],
        transmittance: 1.0,
        depth: 0.0,
        normal: [0.0; 3],
        median_depth: 0.0,
        median_contributor: 0,
        distortion: 0.0,
        m1: 0.0,
        m2: 0.0,
        last_contributor: 0,
        contributors: 0,
    };
    for (k, &g) in list.iter().enumerate() {
        let p = &projected[g as usize];
        let Ok(s) = sample_surfel(p, px, py, settings) else {
            continue;
        };
        let t = out.transmittance;
        let next_t = t * (1.0 - s.alpha);
        // Stop before the surfel that would make the pixel (almost) opaque (a backward divides
        // by 1 − alpha to walk back).
        if !settings.smooth && next_t < settings.t_min {
            break;
        }
        let w = s.alpha * t;
        // Distortion: `A` is the weight already composited in front, `1 − T` as the official
        // code writes it.
        let acc = 1.0 - t;
        let m = settings.mapped_depth(s.z);
        out.distortion += (m * m * acc + out.m2 - 2.0 * m * out.m1) * w;
        out.depth += w * s.z;
        out.m1 += w * m;
        out.m2 += w * m * m;
        if t > 0.5 {
            out.median_depth = s.z;
            out.median_contributor = k as u32 + 1;
        }
        for ch in 0..3 {
            out.normal[ch] += w * p.normal[ch];
            out.color[ch] += w * p.rgb[ch];
        }
        out.transmittance = next_t;
        out.last_contributor = k as u32 + 1;
        out.contributors += 1;
    }
    out
}

/// Per-pixel maps of the 2DGS forward (step 6), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfelRasterOutput {
    pub width: u32,
    pub height: u32,
    /// `C + T·background`.
    pub image: Vec<[f64; 3]>,
    /// Accumulated alpha `1 − T`.
    pub alpha: Vec<f64>,
    /// Expected-depth numerator `Σ w·z` (divide by `alpha`: [`Self::expected_depth`]).
    pub depth: Vec<f64>,
    /// Median depth (0 where no surfel was blended while `T > 0.5`).
    pub median_depth: Vec<f64>,
    /// `Σ w·n`, camera space, not normalised ([`Self::world_normals`] for world space).
    pub normal: Vec<Vec3>,
    /// Depth distortion.
    pub distortion: Vec<f64>,
    /// Final transmittance `T`.
    pub final_transmittance: Vec<f64>,
    /// `Σ w·m(z)` and `Σ w·m(z)²` (the distortion backward's totals).
    pub m1: Vec<f64>,
    pub m2: Vec<f64>,
    /// List position plus one of the last contributor (0 = none).
    pub last_contributor: Vec<u32>,
    /// List position plus one of the median contributor (0 = none).
    pub median_contributor: Vec<u32>,
    /// Number of surfels blended.
    pub contributors: Vec<u32>,
}

impl SurfelRasterOutput {
    /// `D / alpha`, 0 where that is not finite (the official host code's `nan_to_num`).
    pub fn expected_depth(&self) -> Vec<f64> {
        self.depth
            .iter()
            .zip(&self.alpha)
            .map(|(&d, &a)| {
                let v = d / a;
                if v.is_finite() {
                    v
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// `(1 − depth_ratio)·expected + depth_ratio·median` (official default 0; 1 for meshing
    /// bounded scenes).
    pub fn surface_depth(&self, depth_ratio: f64) -> Vec<f64> {
        self.expected_depth()
            .iter()
            .zip(&self.median_depth)
            .map(|(&e, &m)| (1.0 - depth_ratio) * e + depth_ratio * m)
            .collect()
    }

    /// The accumulated normals rotated to world space, `Wᵀ N`.
    pub fn world_normals(&self, pose: &Pose) -> Vec<Vec3> {
        let wt = linalg::transpose(&pose.rotation);
        self.normal
            .iter()
            .map(|&n| linalg::mat_vec(&wt, n))
            .collect()
    }
}

/// Composites every pixel over its tile's sorted list.
pub fn rasterize(
    projected: &[SurfelProjected],
    bins: &TileBins,
    camera: &PinholeCamera,
    background: [f64; 3],
    settings: &SurfelSettings,
) -> Result<SurfelRasterOutput> {
    let (tiles_x, tiles_y) = settings.tile_grid(camera.width, camera.height);
    ensure!(
        bins.tiles_x == tiles_x && bins.tiles_y == tiles_y && bins.tile_size == settings.tile_size,
        "reference surfel rasterize: the tile bins ({}×{} tiles of {} px) were not made for this \
         camera and settings ({tiles_x}×{tiles_y} tiles of {} px); bin with the same camera and \
         settings",
        bins.tiles_x,
        bins.tiles_y,
        bins.tile_size,
        settings.tile_size
    );
    let n = camera.width as usize * camera.height as usize;
    let mut out = SurfelRasterOutput {
        width: camera.width,
        height: camera.height,
        image: Vec::with_capacity(n),
        alpha: Vec::with_capacity(n),
        depth: Vec::with_capacity(n),
        median_depth: Vec::with_capacity(n),
        normal: Vec::with_capacity(n),
        distortion: Vec::with_capacity(n),
        final_transmittance: Vec::with_capacity(n),
        m1: Vec::with_capacity(n),
        m2: Vec::with_capacity(n),
        last_contributor: Vec::with_capacity(n),
        median_contributor: Vec::with_capacity(n),
        contributors: Vec::with_capacity(n),
    };
    for j in 0..camera.height {
        for i in 0..camera.width {
            let list = &bins.lists[bins.tile_of_pixel(i, j)];
            let px = composite_pixel(projected, list, i as f64 + 0.5, j as f64 + 0.5, settings);
            let t = px.transmittance;
            out.image
                .push([0, 1, 2].map(|ch| px.color[ch] + t * background[ch]));
            out.alpha.push(1.0 - t);
            out.depth.push(px.depth);
            out.median_depth.push(px.median_depth);
            out.normal.push(px.normal);
            out.distortion.push(px.distortion);
            out.final_transmittance.push(t);
            out.m1.push(px.m1);
            out.m2.push(px.m2);
            out.last_contributor.push(px.last_contributor);
            out.median_contributor.push(px.median_contributor);
            out.contributors.push(px.contributors);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A projected surfel with a hand-written transform (a fronto-parallel unit disk at depth 2
    /// seen by `fx = fy = 10`, principal point (5, 5)).
    fn disk() -> SurfelProjected {
        SurfelProjected {
            transform: [[10.0, 0.0, 10.0], [0.0, 10.0, 10.0], [0.0, 0.0, 2.0]],
            center2d: [5.0, 5.0],
            opacity: 0.8,
            normal: [0.0, 0.0, -1.0],
            rgb: [1.0, 0.5, 0.25],
            ..SurfelProjected::default()
        }
    }

    #[test]
    fn sample_at_the_centre_is_the_centre() {
        let s = sample_surfel(&disk(), 5.0, 5.0, &SurfelSettings::default()).unwrap();
        assert_eq!(s.uv, [0.0, 0.0]);
        assert_eq!(s.z, 2.0);
        assert_eq!(s.gauss, 1.0);
        assert_eq!(s.alpha, 0.8);
        assert!(!s.lowpass);
        // One pixel right: x = 6 → u = (6 − 5)·2/10 = 0.2.
        let s = sample_surfel(&disk(), 6.0, 5.0, &SurfelSettings::default()).unwrap();
        assert!((s.uv[0] - 0.2).abs() < 1e-15 && s.uv[1] == 0.0);
        assert!((s.rho3d - 0.04).abs() < 1e-15 && s.rho2d == 2.0 && !s.lowpass);
    }

    #[test]
    fn skip_reasons() {
        let st = SurfelSettings::default();
        // Along the row y = 5 the ray is parallel to this plane: `c = 5·h₃ − h₂ = (0, 0, 1)`
        // has no (u, v) part, so `p₃ = a₁c₂ − a₂c₁ = 0` exactly.
        let mut edge = disk();
        edge.transform = [[10.0, 0.0, 10.0], [0.0, 5.0, 9.0], [0.0, 1.0, 2.0]];
        assert_eq!(
            sample_surfel(&edge, 5.0, 5.0, &st).unwrap_err(),
            SurfelSkip::Parallel
        );
        // p₃ = −9e-300 and p₁ ≈ 7e10: u overflows to −inf and z = u·0 + … is NaN.
        let mut tiny = disk();
        tiny.transform = [[1e-300, 0.0, 10.0], [0.0, 1e-300, -1e10], [0.0, 1.0, 2.0]];
        let err = sample_surfel(&tiny, 7.0, 9.0, &st).unwrap_err();
        assert_eq!(err, SurfelSkip::NonFinite);
        let mut near = disk();
        near.transform[2][2] = 0.5 * st.near;
        assert_eq!(
            sample_surfel(&near, 0.5, 0.5, &st).unwrap_err(),
            SurfelSkip::Near
        );
        assert_eq!(
            sample_surfel(&disk(), 30.0, 30.0, &st).unwrap_err(),
            SurfelSkip::Faint
        );
        assert!(sample_surfel(&disk(), 30.0, 30.0, &SurfelSettings::smooth()).is_ok());
    }

    #[test]
    fn distortion_of_two_hits_is_the_pairwise_sum() {
        let st = SurfelSettings::default();
        let mut back = disk();
        back.transform = [[10.0, 0.0, 20.0], [0.0, 10.0, 20.0], [0.0, 0.0, 4.0]];
        back.opacity = 0.5;
        let px = composite_pixel(&[disk(), back], &[0, 1], 5.0, 5.0, &st);
        let (w1, w2) = (0.8, 0.2 * 0.5);
        let (m1, m2) = (st.mapped_depth(2.0), st.mapped_depth(4.0));
        assert!((px.distortion - w1 * w2 * (m1 - m2).powi(2)).abs() < 1e-15);
        assert!((px.depth - (w1 * 2.0 + w2 * 4.0)).abs() < 1e-15);
        assert_eq!((px.median_depth, px.median_contributor), (2.0, 1));
        assert_eq!((px.last_contributor, px.contributors), (2, 2));
    }
}
