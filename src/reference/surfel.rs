//! CPU f64 reference of the 2D Gaussian Splatting forward pass (2DGS, Huang et al. SIGGRAPH
//! 2024; docs/algorithms/base-models.md §1.2): flat elliptic "surfels" rendered by intersecting every pixel's
//! ray with each surfel's plane. Like the 3DGS reference ([`crate::reference`]) it is plain
//! loops, no parallelism, the oracle GPU kernels will be tested against, and it keeps every
//! intermediate a backward pass needs in structs ([`SurfelProjected`], [`SurfelSample`],
//! [`SurfelPixel`]). The rules are the official code's (hbb1/diff-surfel-rasterization, commit
//! e0ed020: `cuda_rasterizer/forward.cu` `compute_transmat`, `compute_aabb`, `preprocessCUDA`,
//! `renderCUDA`; constants in `auxiliary.h`), restated in this project's camera convention.
//!
//! # Conventions
//! - Cameras as in [`crate::reference`]: [`PinholeCamera`] `K = [[fx,0,cx],[0,fy,cy],[0,0,1]]`
//!   and world-to-camera [`Pose`] `x_cam = W x + b` (x right, y down, looking down +z); the
//!   centre of pixel (i, j) is `(i + 0.5, j + 0.5)`. The official code puts pixel centres at
//!   integer coordinates with the principal point at `(W − 1)/2` (its `ndc2pix`); here `K` is
//!   used directly, as gsplat does, which is the same picture shifted by half a pixel.
//! - Surfels ([`RefSurfels`]): centre μ, two log-scales `(l_u, l_v)` (`s = exp(l)`), rotation
//!   quaternion (w, x, y, z) of any norm (`|q|² < QUAT_NORM2_MIN` reads as the identity, as in
//!   3DGS), opacity logit, 16 SH coefficients per channel. With `R = [r1 r2 r3]` (columns),
//!   the surfel is the disk `P(u, v) = μ + s_u·u·r1 + s_v·v·r2`, `r3` is its normal, and its
//!   kernel is `G(u, v) = exp(−(u² + v²)/2)`.
//! - Images are row-major, `index = j·width + i`.
//!
//! # Preprocess (per surfel, [`project`])
//! 1. Camera-space centre `t = W μ + b`. Culled ([`SurfelCull::Near`]) when `t_z ≤ near`
//!    (0.2, the official `in_frustum`), or when `t_z` is NaN.
//! 2. `R` from the normalised quaternion, `s = exp(l)`.
//! 3. The transform matrix (homography) from the surfel's `(u, v, 1)` to homogeneous pixels,
//!    `[x·z, y·z, z]ᵀ = M (u, v, 1)ᵀ`, with columns
//!    `M = [ K W (s_u r1) | K W (s_v r2) | K t ]`. Its rows `h₁, h₂, h₃` are what the
//!    rasterizer uses; `h₃·(u, v, 1)` is the camera depth of `P(u, v)`.
//! 4. Normal `n = W r3`, flipped to face the camera: with `cos = −t·n`, culled
//!    ([`SurfelCull::EdgeOn`]) when `cos == 0` exactly (the plane holds the camera centre: the
//!    surfel is seen exactly edge-on), negated when `cos < 0` (official `DUAL_VISIABLE`). The
//!    sign is kept ([`SurfelProjected::normal_sign`]) so a backward applies the same flip.
//! 5. Screen box of the image of the `k`-sigma circle `u² + v² = k²` (`k` = `cutoff` = 3): with
//!    `τ = (k², k², −1)`, `d = Σ_j τ_j h₃ⱼ²`; culled ([`SurfelCull::DegenerateBox`]) when
//!    `d == 0`; `f = τ / d`; centre `m = (Σ_j f_j h₁ⱼ h₃ⱼ, Σ_j f_j h₂ⱼ h₃ⱼ)`; half-extents
//!    `e = sqrt(max(1e-4, m² − (Σ_j f_j h₁ⱼ², Σ_j f_j h₂ⱼ²)))` per axis (the clamp keeps the
//!    square root real when rounding or a degenerate, line-like image makes the radicand ≤ 0);
//!    radius `r = ceil(max(e_x, e_y, k·filter_size))`, `filter_size = 1/sqrt(filter_inv_square)
//!    = √2/2` px (the official constant is the rounded 0.707106; after the ceil both give 3 px,
//!    the 3σ of the low-pass filter). This is the dual conic `M diag(τ) Mᵀ`: when the whole
//!    `k`-sigma disk lies in front of the camera (`d < 0`), `m` and `e` are exactly the centre
//!    and half-size of the axis-aligned box around its image (an ellipse). `m` is *not* the
//!    projection of μ in general (perspective moves the ellipse's centre) and it depends on
//!    `k`; it is also the centre of the low-pass filter. **Quirk kept from the official code
//!    (and gsplat)**: when the `k`-sigma disk crosses the camera plane (`d > 0`) its image is
//!    unbounded (a hyperbola) and these formulas give no bounding box at all; only `d == 0` is
//!    rejected, so such a surfel is drawn only inside a box the formula happens to give.
//! 6. Colour: SH at `normalise(μ − camera centre)`, `+ 0.5`, clamped at 0 per channel, as 3DGS.
//! 7. Any non-finite `M`, normal, `d`, `m`, `e`, radius, colour or opacity culls the surfel
//!    ([`SurfelCull::NonFinite`]): a NaN is never drawn. (`d` overflows to inf for
//!    astronomically large scales, where `m` and `e` would still be finite but meaningless.)
//! 8. Tile rectangle `[tile_min, tile_max)`: `floor((m − r)/tile)`, `ceil((m + r)/tile)`,
//!    clamped to `[0, tiles]` in f64 before the integer conversion, exactly as the 3DGS
//!    reference. The official `getRect` writes the upper end `trunc((m + r + 15)/16)`, which for
//!    a non-integer `m + r` can leave out the last tile the square reaches; this reference takes
//!    the conservative rectangle (a GPU kernel must copy it). No opacity-aware shrinking
//!    (the official `TIGHTBBOX` is off). A rectangle of zero area touches no tile (the official
//!    code then reports radius 0, "not visible").
//! 9. Sort key: the centre's camera depth `t_z`, per tile, ties by index (not the per-pixel hit
//!    depth: like 3DGS, one order per tile).
//!
//! # Rasterize (per pixel, [`raster`])
//! For the pixel centre `x = (x, y)`, every surfel of the tile's list in order:
//! 1. Two planes through the pixel's ray in `(u, v, 1)`-space, `a = x·h₃ − h₁`,
//!    `c = y·h₃ − h₂`; their intersection `p = a × c` is the ray's hit on the surfel's plane.
//!    Skipped ([`SurfelSkip::Parallel`]) when `p₃ == 0` exactly (the ray is parallel to the
//!    plane; the official guard, the only one before the division).
//! 2. `(u, v) = (p₁/p₃, p₂/p₃)`, hit depth `z = h₃·(u, v, 1)`. Skipped
//!    ([`SurfelSkip::NonFinite`]) when `z` is not finite: a `p₃` so small that the division
//!    overflows (or a cross product that overflowed for astronomically large scales) would
//!    otherwise put inf/NaN into the depth outputs — *this guard is not in the official code*,
//!    which would propagate them. Skipped ([`SurfelSkip::Near`]) when `z < near` (official
//!    per-pixel near cull; also removes hits behind the camera, which the homography reports
//!    with a negative depth).
//! 3. `rho3d = u² + v²` (object space), `rho2d = filter_inv_square·|m − x|²` (the low-pass
//!    filter: a screen-space Gaussian of variance 1/2 px² at the box centre `m`). The kernel is
//!    the larger of the two Gaussians, `rho = min(rho3d, rho2d)`; the object-space term wins
//!    ties (`rho3d ≤ rho2d`, the official backward's branch test), [`SurfelSample::lowpass`]
//!    says which won. Tiny and near-edge-on surfels are thin in object space; the low-pass
//!    keeps them at least a 2D blob of about one pixel around `m`.
//! 4. `G = exp(−rho/2)`, `alpha = min(alpha_max, opacity·G)`; skipped
//!    ([`SurfelSkip::Faint`]) when `alpha < alpha_min`.
//! 5. Front-to-back compositing as 3DGS: stop *before* a surfel with `T·(1 − alpha) < t_min`;
//!    else, with `w = alpha·T` and `A = 1 − T` (the weight already composited):
//!    colour `C += w·rgb`; depth `D += w·z`; normal `N += w·n` (camera space, not
//!    normalised); distortion with `m(z) = far/(far − near)·(1 − near/z)` (near 0.05, far 100):
//!    `dist += w·(m²·A + M₂ − 2·m·M₁)`, then `M₁ += w·m`, `M₂ += w·m²` (one pass for
//!    `Σ_i Σ_{j<i} w_i w_j (m_i − m_j)²`); median depth: when the transmittance *before* the
//!    surfel is `T > 0.5` (strict), `median = z` and the median contributor is this list
//!    position; then `T *= 1 − alpha`.
//! 6. Per pixel outputs ([`SurfelRasterOutput`]): `C + T·background`, alpha `1 − T`, `D`,
//!    median depth (0 when no surfel was blended while `T > 0.5`), `N`, distortion, and for the
//!    backward the final `T`, `M₁`, `M₂`, the last contributor and the median contributor (list
//!    position plus one, 0 = none; the official code stores the position plus one for the
//!    median and −1 for none).
//! 7. Host side (official `gaussian_renderer/__init__.py`, here [`SurfelRasterOutput`]'s
//!    helpers): expected depth `D / alpha` (0 where that is NaN or infinite), surface depth
//!    `(1 − depth_ratio)·expected + depth_ratio·median`, normal in world space `Wᵀ N`.
//!
//! # Smooth mode (tests only)
//! [`SurfelSettings::smooth`] removes the `alpha_min` skip, the `t_min` stop and the
//! `alpha_max` clamp, as in 3DGS, for finite differences of a future backward. The median
//! depth stays a step function of the parameters.
//!
//! # Backward ([`backward()`])
//! The branch of step 3 (object-space vs low-pass), the alpha clamp, the normal's sign, the
//! skipped (surfel, pixel) pairs, and the order are all in [`SurfelSample`] and
//! [`SurfelProjected`]; `M₁`, `M₂`, final `T` and the median contributor per pixel in
//! [`SurfelRasterOutput`]. The backward differentiates this forward exactly (its module docs
//! say where that differs from the official backward: the low-pass branch's depth gradient).

pub mod backward;
pub mod project;
pub mod raster;
pub mod regularise;

use anyhow::{ensure, Result};
use rand::Rng;

use super::linalg::{self, Vec3};
use super::sh;
use super::TileBins;
use crate::scene::{PinholeCamera, Pose};

pub use backward::SurfelProjectedGrads;
pub use backward::{backward, SurfelGradients, SurfelOutputGrads, SurfelParamGrads};
pub use project::{bounding_box, preprocess, project_surfel, transform_matrix, SurfelBox};
pub use project::{SurfelCull, SurfelProjected};
pub use raster::{bin_surfels, composite_pixel, rasterize, sample_surfel, SurfelPixel};
pub use raster::{SurfelRasterOutput, SurfelSample, SurfelSkip};

/// Surfels as plain f64 arrays, one entry per surfel in every field.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RefSurfels {
    pub positions: Vec<[f64; 3]>,
    /// Natural log of the two tangent-axis scales `(s_u, s_v)`; the normal has no extent.
    pub log_scales: Vec<[f64; 2]>,
    /// (w, x, y, z), any norm; normalised inside (see [`super::QUAT_NORM2_MIN`]).
    pub rotations: Vec<[f64; 4]>,
    /// opacity = sigmoid(logit).
    pub opacity_logits: Vec<f64>,
    /// `sh[s][k][channel]`, the layout of [`super::RefGaussians::sh`].
    pub sh: Vec<[[f64; 3]; 16]>,
}

impl RefSurfels {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Checks that every field has one entry per surfel.
    pub fn validate(&self) -> Result<()> {
        let n = self.positions.len();
        for (name, len) in [
            ("log_scales", self.log_scales.len()),
            ("rotations", self.rotations.len()),
            ("opacity_logits", self.opacity_logits.len()),
            ("sh", self.sh.len()),
        ] {
            ensure!(
                len == n,
                "reference surfels: field `{name}` has {len} entries but `positions` has {n}; \
                 give every field one entry per surfel"
            );
        }
        Ok(())
    }

    /// The surfels in the engine's f32 parameter layout, in a 3DGS-shaped buffer: the two
    /// log-scales go to the first two of each Gaussian's three, the third is set to
    /// `third_log_scale` (the surfel kernels never read it; tests set it to something absurd).
    pub fn to_params(&self, sh_degree: u32, third_log_scale: f32) -> crate::splats::GaussianParams {
        let as_3d = super::RefGaussians {
            positions: self.positions.clone(),
            log_scales: self
                .log_scales
                .iter()
                .map(|l| [l[0], l[1], third_log_scale as f64])
                .collect(),
            rotations: self.rotations.clone(),
            opacity_logits: self.opacity_logits.clone(),
            sh: self.sh.clone(),
        };
        as_3d.to_params(sh_degree)
    }

    /// The inverse of [`RefSurfels::to_params`] (the third log-scale dropped): f32 values
    /// widened exactly, so a reference render of the result sees what the GPU sees.
    pub fn from_params(p: &crate::splats::GaussianParams) -> Self {
        let g = super::RefGaussians::from_params(p);
        Self {
            positions: g.positions,
            log_scales: g.log_scales.iter().map(|l| [l[0], l[1]]).collect(),
            rotations: g.rotations,
            opacity_logits: g.opacity_logits,
            sh: g.sh,
        }
    }

    /// Appends one surfel with only the DC colour set.
    pub fn push(
        &mut self,
        position: [f64; 3],
        log_scale: [f64; 2],
        rotation: [f64; 4],
        opacity_logit: f64,
        dc: [f64; 3],
    ) {
        let mut sh = [[0.0; 3]; 16];
        sh[0] = dc;
        self.positions.push(position);
        self.log_scales.push(log_scale);
        self.rotations.push(rotation);
        self.opacity_logits.push(opacity_logit);
        self.sh.push(sh);
    }
}

/// `n` random surfels for tests, drawn like [`super::scenes::random_gaussians`]: centres in a
/// ball of radius 1.2 around the origin, log-scales uniform in `[ln 0.03, ln 0.3]` per axis,
/// quaternions of norm 0.5–2 (not normalised), opacity logits in `[−2, 2]`, SH DC in
/// `[−2.5, 2]` (some channels clamp at 0) and higher bands in `[−0.3, 0.3]`.
pub fn random_surfels(rng: &mut impl Rng, n: usize) -> RefSurfels {
    let mut s = RefSurfels::default();
    for _ in 0..n {
        let p = loop {
            let p: Vec3 = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
            if linalg::dot(p, p) <= 1.0 {
                break linalg::scale(p, 1.2);
            }
        };
        s.positions.push(p);
        s.log_scales
            .push([0; 2].map(|_| rng.gen_range(0.03f64.ln()..0.3f64.ln())));
        let q: [f64; 4] = [0; 4].map(|_| rng.gen_range(-1.0..1.0));
        let qn = q.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-3);
        let norm = rng.gen_range(0.5..2.0);
        s.rotations.push(q.map(|v| v / qn * norm));
        s.opacity_logits.push(rng.gen_range(-2.0..2.0));
        let mut sh = [[0.0; 3]; 16];
        sh[0] = [0; 3].map(|_| rng.gen_range(-2.5..2.0));
        for coeff in sh.iter_mut().skip(1) {
            *coeff = [0; 3].map(|_| rng.gen_range(-0.3..0.3));
        }
        s.sh.push(sh);
    }
    s
}

pub use crate::settings::surfel::SurfelSettings;

/// Everything the forward pass produced.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfelRenderOutput {
    pub projected: Vec<SurfelProjected>,
    pub bins: TileBins,
    pub raster: SurfelRasterOutput,
}

/// Checks the arguments of the entry points.
pub(crate) fn check_inputs(
    surfels: &RefSurfels,
    camera: &PinholeCamera,
    sh_degree: usize,
    settings: &SurfelSettings,
) -> Result<()> {
    surfels.validate()?;
    ensure!(
        sh_degree <= sh::MAX_SH_DEGREE,
        "reference surfel render: sh_degree {sh_degree} is above the supported {}; pass 0..=3",
        sh::MAX_SH_DEGREE
    );
    ensure!(
        camera.width > 0 && camera.height > 0,
        "reference surfel render: camera size {}×{} is empty; give a camera at least 1×1 pixel",
        camera.width,
        camera.height
    );
    ensure!(
        settings.tile_size > 0,
        "reference surfel render: settings.tile_size is 0; use 16"
    );
    ensure!(
        camera.fx.is_finite() && camera.fy.is_finite() && camera.fx > 0.0 && camera.fy > 0.0,
        "reference surfel render: focal lengths fx = {}, fy = {} must be finite and positive",
        camera.fx,
        camera.fy
    );
    ensure!(
        settings.near > 0.0 && settings.far > settings.near,
        "reference surfel render: near = {} and far = {} must satisfy 0 < near < far",
        settings.near,
        settings.far
    );
    Ok(())
}

/// The full forward pass: preprocess, bin and sort, rasterize.
pub fn render(
    surfels: &RefSurfels,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    background: [f64; 3],
    settings: &SurfelSettings,
) -> Result<SurfelRenderOutput> {
    let projected = preprocess(surfels, camera, pose, sh_degree, settings)?;
    let bins = bin_surfels(&projected, camera, settings)?;
    let raster = rasterize(&projected, &bins, camera, background, settings)?;
    Ok(SurfelRenderOutput {
        projected,
        bins,
        raster,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64;

    fn camera() -> PinholeCamera {
        PinholeCamera {
            fx: 40.0,
            fy: 44.0,
            cx: 17.3,
            cy: 16.1,
            width: 36,
            height: 28,
        }
    }

    #[test]
    fn mapped_depth_spans_zero_to_one() {
        let s = SurfelSettings::default();
        assert_eq!(s.mapped_depth(s.near), 0.0);
        assert!((s.mapped_depth(s.far) - 1.0).abs() < 1e-15);
        assert!((s.min_radius() - 3.0 / 2f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn validate_names_the_short_field() {
        let mut s = random_surfels(&mut Pcg64::seed_from_u64(1), 3);
        s.log_scales.pop();
        let err = s.validate().unwrap_err().to_string();
        assert!(err.contains("log_scales"), "{err}");
    }

    #[test]
    fn render_is_finite_and_alpha_is_one_minus_t() {
        let mut rng = Pcg64::seed_from_u64(7);
        let s = random_surfels(&mut rng, 30);
        let pose = super::super::scenes::look_at([0.3, -0.2, -4.0], [0.0; 3], [0.0, -1.0, 0.0]);
        let out = render(
            &s,
            &camera(),
            &pose,
            3,
            [0.1, 0.2, 0.3],
            &SurfelSettings::default(),
        )
        .unwrap();
        let r = &out.raster;
        assert!(r.alpha.iter().any(|&a| a > 0.5));
        for pix in 0..r.image.len() {
            assert!(r.image[pix].iter().all(|v| v.is_finite()));
            assert_eq!(r.alpha[pix], 1.0 - r.final_transmittance[pix]);
            assert!(r.distortion[pix] >= -1e-15 && r.depth[pix] >= 0.0);
            assert!(r.median_contributor[pix] <= r.last_contributor[pix]);
        }
    }
}
