//! CPU f64 reference implementation of the 3D Gaussian Splatting forward and backward passes:
//! the oracle every GPU kernel is tested against. Plain loops, no parallelism, no cleverness: it
//! documents the math, and the GPU kernels copy its choices exactly.
//!
//! # Conventions
//! - Cameras: [`PinholeCamera`] + world-to-camera [`Pose`] (COLMAP/OpenCV: x right, y down, the
//!   camera looks down +z). A camera-space point (x, y, z) lands at pixel
//!   `u = fx·x/z + cx`, `v = fy·y/z + cy`; the centre of pixel (i, j) is (i + 0.5, j + 0.5).
//! - Images are row-major, `index = j·width + i`, one `[r, g, b]` per pixel.
//! - Gaussians ([`RefGaussians`]): position, log-scale (scale = exp), rotation quaternion
//!   (w, x, y, z) normalised inside, opacity logit (opacity = sigmoid), 16 SH coefficients per
//!   channel of which the first `(degree + 1)²` are used.
//!
//! # Preprocess (per Gaussian, [`project`])
//! 1. Camera-space mean `t = R p + T`. Culled when `z ≤ near` (or z is NaN). `near` defaults
//!    to 0.01 (gsplat's; the Inria code uses 0.2).
//! 2. Rotation from the normalised quaternion. A quaternion with `|q|² < QUAT_NORM2_MIN`
//!    (zero, denormal, …) is read as the identity and gets no gradient.
//! 3. `Σ = R S Sᵀ Rᵀ`, `S = diag(exp(log_scale))`, rotated into the camera: `W Σ Wᵀ`.
//! 4. EWA: `J = [[fx/z, 0, −fx·tx/z], [0, fy/z, −fy·ty/z]]` where `tx = x/z` clamped to
//!    `[−fov_clamp·cx/fx, fov_clamp·(width − cx)/fx]` and `ty = y/z` to
//!    `[−fov_clamp·cy/fy, fov_clamp·(height − cy)/fy]`: 1.3× the tangent of the half field of
//!    view on each side, measured from the principal point (for a centred principal point
//!    this is Inria's `1.3·tan(fov/2)`). The clamp is written `min(max(t, lo), hi)` so an
//!    inverted interval (principal point outside the image) still gives a number.
//!    The projected mean itself is not clamped.
//! 5. `Σ2D = J W Σ Wᵀ Jᵀ + eps2d·I` (eps2d = 0.3 px², the low-pass dilation). With
//!    `mip_2d` (Mip-Splatting's 2D Mip filter, eps2d = 0.1) the opacity is also multiplied by
//!    `ρ = sqrt(max(ρ_min², det(Σ2D − eps2d·I) / det(Σ2D)))`, `ρ_min = 0.005` (gsplat's
//!    floor; the official code adds 1e-6 terms instead), so the filter widens a splat without
//!    adding energy; the floor passes no gradient. The 3D smoothing filter is a change of the
//!    parameters themselves: [`mip`].
//! 6. `det = a·c − b²` of `Σ2D = [[a, b], [b, c]]`: culled when `det ≤ 0`; otherwise clamped to
//!    `max(det, det_min)` (`det_min = 1e-6`; mathematically det ≥ eps2d² = 0.09, so the clamp
//!    only catches rounding in low precision). Conic = inverse = `[c, −b, a] / det`.
//! 7. Radius (px) = `ceil(3·sqrt(λmax))`, `λmax = m + sqrt(max(m² − det, 0))`, `m = (a + c)/2`,
//!    kept as an f64 so huge Gaussians do not overflow an integer before the tile clamp.
//! 8. Tile rectangle `[min, max)`: `min = floor((mean2d − e) / tile)`,
//!    `max = ceil((mean2d + e) / tile)`, both clamped to `[0, tiles]` before any integer
//!    conversion, with the extent `e = min(r, ceil(sqrt(2·ln(opacity/alpha_min)·λmax)))`:
//!    beyond that distance alpha < alpha_min in every direction, so the image is the same as
//!    with the 3σ square, faint Gaussians just touch fewer tiles (`e = r` in smooth mode; a
//!    Gaussian with opacity ≤ alpha_min touches none). Culled or zero-area rectangles touch
//!    no tile.
//! 9. Colour: SH at `dir = normalise(p − camera centre)`, `+ 0.5`, clamped at 0 per channel;
//!    a clamped channel passes no gradient.
//! 10. Any non-finite mean2d, conic, radius, SH colour or opacity culls the Gaussian (it is
//!     never drawn as NaN).
//!
//! # Rasterize (per pixel, [`raster`])
//! The Gaussians whose tile rectangle holds the pixel's tile, sorted by camera z ascending
//! (ties by index). For each: `d = mean2d − pixel centre`,
//! `power = −½(a·dx² + c·dy²) − b·dx·dy`; skip if `power > 0`;
//! `alpha = min(alpha_max, opacity·exp(power))`; skip if `alpha < alpha_min`;
//! stop *before* a splat with `T·(1 − alpha) < t_min`; else `C += rgb·alpha·T`, `T *= 1 − alpha`.
//! Output `C + T·background`. Per pixel we keep the final `T` and `last_contributor`: the
//! position in the tile's sorted list of the last splat that contributed, plus one (0 = none).
//!
//! # Backward ([`backward()`], module [`mod@backward`])
//! Given `dL/d(image)`: the rasterizer backward walks each pixel's list back to front from
//! `last_contributor`, recovering `T` in front of each splat by dividing by `1 − alpha`, and
//! produces gradients of mean2d, conic, colour and opacity; the preprocess backward carries
//! them to position (including through the SH view direction), log-scale, quaternion (through
//! the normalisation), opacity logit and every SH coefficient. Clamps pass no gradient where
//! they are active (alpha at `alpha_max`, colour at 0, the Jacobian's x/z and y/z, the
//! determinant). It also returns density control's per-view statistic
//! `|(dL/du · W/2, dL/dv · H/2)|`.
//!
//! # Smooth mode (tests only)
//! [`RenderSettings::smooth`] removes the `alpha_min` skip, the `t_min` stop and the
//! `alpha_max` clamp so the image is a smooth function of the parameters and central finite
//! differences are meaningful. The 3σ tile culling stays, so a finite-difference step that moves
//! a Gaussian across a tile boundary is a discontinuity: the tests detect and skip those.
//! The backward divides by `1 − alpha`, so smooth mode needs opacities below 1.

pub mod backward;
pub mod decoder;
pub mod density;
pub mod linalg;
pub mod loss_mask;
pub mod lpm_membership;
pub mod mcmc;
pub mod mip;
pub mod project;
pub mod raster;
pub mod scenes;
pub mod sh;
pub mod spacetime;
pub mod surfel;

use anyhow::{ensure, Result};

use crate::scene::{PinholeCamera, Pose};

pub use backward::{backward, Gradients, ParamGrads, ProjectedGrads};
pub use project::{preprocess, Projected};
pub use raster::{
    alpha_min_edges, bin_gaussians, rasterize, sample_splat, Footprint, RasterOutput, SplatSample,
    TileBins,
};

/// Below this squared norm a rotation quaternion is read as the identity (no NaN from 0/0).
pub const QUAT_NORM2_MIN: f64 = 1e-24;

/// Gaussians as plain f64 arrays, one entry per Gaussian in every field.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RefGaussians {
    pub positions: Vec<[f64; 3]>,
    /// Natural log of the three axis scales.
    pub log_scales: Vec<[f64; 3]>,
    /// (w, x, y, z), any norm; normalised inside (see [`QUAT_NORM2_MIN`]).
    pub rotations: Vec<[f64; 4]>,
    /// opacity = sigmoid(logit).
    pub opacity_logits: Vec<f64>,
    /// `sh[g][k][channel]`: coefficient k (0 = DC) of Gaussian g. Only the first
    /// `(degree + 1)²` are read at a given active degree.
    pub sh: Vec<[[f64; 3]; 16]>,
}

impl RefGaussians {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Checks that every field has one entry per Gaussian.
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
                "reference Gaussians: field `{name}` has {len} entries but `positions` has {n}; \
                 give every field one entry per Gaussian"
            );
        }
        Ok(())
    }
}

pub use crate::settings::raster::{RenderSettings, MIP_EPS2D, MIP_MIN_COMPENSATION};

/// Everything the forward pass produced: the per-Gaussian intermediates, the per-tile sorted
/// lists and the image with what the backward needs.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOutput {
    pub projected: Vec<Projected>,
    pub bins: TileBins,
    pub raster: RasterOutput,
}

/// Checks the arguments shared by the forward and backward entry points.
pub(crate) fn check_inputs(
    gaussians: &RefGaussians,
    camera: &PinholeCamera,
    sh_degree: usize,
    settings: &RenderSettings,
) -> Result<()> {
    gaussians.validate()?;
    ensure!(
        sh_degree <= sh::MAX_SH_DEGREE,
        "reference render: sh_degree {sh_degree} is above the supported {}; pass 0..=3",
        sh::MAX_SH_DEGREE
    );
    ensure!(
        camera.width > 0 && camera.height > 0,
        "reference render: camera size {}×{} is empty; give a camera at least 1×1 pixel",
        camera.width,
        camera.height
    );
    ensure!(
        settings.tile_size > 0,
        "reference render: settings.tile_size is 0; use 16"
    );
    ensure!(
        camera.fx.is_finite() && camera.fy.is_finite() && camera.fx > 0.0 && camera.fy > 0.0,
        "reference render: focal lengths fx = {}, fy = {} must be finite and positive",
        camera.fx,
        camera.fy
    );
    Ok(())
}

/// The full forward pass: preprocess, bin and sort, rasterize.
pub fn render(
    gaussians: &RefGaussians,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    background: [f64; 3],
    settings: &RenderSettings,
) -> Result<RenderOutput> {
    check_inputs(gaussians, camera, sh_degree, settings)?;
    let projected = preprocess(gaussians, camera, pose, sh_degree, settings)?;
    let bins = bin_gaussians(&projected, camera, settings)?;
    let raster = rasterize(&projected, &bins, camera, background, settings)?;
    Ok(RenderOutput {
        projected,
        bins,
        raster,
    })
}

impl RefGaussians {
    /// The engine's f32 parameters widened to f64 (every value exactly representable), so the
    /// reference renders exactly the model the GPU sees.
    pub fn from_params(p: &crate::splats::GaussianParams) -> Self {
        let w3 = |v: &[f32; 3]| v.map(|x| x as f64);
        let rc = p.rest_coeffs();
        Self {
            positions: p.positions.iter().map(w3).collect(),
            log_scales: p.log_scales.iter().map(w3).collect(),
            rotations: p.rotations.iter().map(|q| q.map(|x| x as f64)).collect(),
            opacity_logits: p.opacity_logits.iter().map(|&x| x as f64).collect(),
            sh: (0..p.len())
                .map(|i| {
                    let mut sh = [[0.0; 3]; 16];
                    sh[0] = w3(&p.sh_dc[i]);
                    for (k, coeff) in sh.iter_mut().skip(1).take(rc).enumerate() {
                        for (c, v) in coeff.iter_mut().enumerate() {
                            *v = p.sh_rest[(i * rc + k) * 3 + c] as f64;
                        }
                    }
                    sh
                })
                .collect(),
        }
    }

    /// Rounds to the engine's f32 parameters, keeping SH coefficients up to `sh_degree`.
    pub fn to_params(&self, sh_degree: u32) -> crate::splats::GaussianParams {
        let n3 = |v: &[f64; 3]| v.map(|x| x as f32);
        let mut p = crate::splats::GaussianParams::empty(sh_degree);
        let rc = p.rest_coeffs();
        p.positions = self.positions.iter().map(n3).collect();
        p.log_scales = self.log_scales.iter().map(n3).collect();
        p.rotations = self.rotations.iter().map(|q| q.map(|x| x as f32)).collect();
        p.opacity_logits = self.opacity_logits.iter().map(|&x| x as f32).collect();
        p.sh_dc = self.sh.iter().map(|s| n3(&s[0])).collect();
        p.sh_rest = self
            .sh
            .iter()
            .flat_map(|s| (1..=rc).flat_map(move |k| s[k].map(|x| x as f32)))
            .collect();
        p
    }
}
