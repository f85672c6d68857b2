//! Analytic gradients of the 2DGS forward ([`crate::reference::surfel`]) given the gradients of
//! a scalar loss with respect to every per-pixel output: colour, accumulated alpha, the
//! expected-depth numerator `D`, the median depth, the accumulated normal `N` and the
//! distortion. Two stages, as for 3DGS ([`crate::reference::backward()`]) and as the GPU kernels
//! will be split:
//!
//! 1. [`rasterize_backward`]: per pixel, back to front over the surfels the forward blended,
//!    repeating its skips and walking the transmittance back as `T / (1 − alpha)`. Produces
//!    gradients of the preprocess outputs: the transform matrix `M`, the low-pass centre `m`,
//!    the colour, the opacity and the camera-space normal.
//! 2. [`preprocess_backward`]: through the box-centre formula (the low-pass centre is a function
//!    of `M`), the columns of `M` (`K W s_u r1`, `K W s_v r2`, `K t`), the normal's camera-facing
//!    flip, the quaternion normalisation, the sigmoid and the SH colour.
//!
//! # The weights
//! Every output is a function of the blend weights `w_i = alpha_i T_i` and of per-surfel values
//! (colour, hit depth, normal): `C = Σ w rgb`, `alpha = Σ w`, `D = Σ w z`, `N = Σ w n`, the
//! background term `(1 − Σ w)·bg`, and the distortion `Σ_i Σ_{j<i} w_i w_j (m_i − m_j)²`
//! (the forward's `A = 1 − T` *is* `Σ_{j<i} w_j`). So the backward first forms, per contributor,
//! `g_i = ∂L/∂w_i` at fixed values, then `∂L/∂alpha_k = T_k g_k − Σ_{i>k} g_i w_i / (1 − alpha_k)`
//! with the sum kept back to front. The distortion's `∂/∂w_k = m_k² A + M₂ − 2 m_k M₁` and
//! `∂/∂m_k = 2 w_k (m_k A − M₁)` use the pixel's *final* totals `A = 1 − T_final`, `M₁`, `M₂`:
//! the `j = k` terms these include cancel exactly, so this is the exact derivative (the
//! official code's form).
//!
//! # Choices (where this differs from the official backward)
//! - **Exact depth gradient on the low-pass branch.** Where the screen-space filter wins, the
//!   official code sends a hit's depth gradient to `h₃` as `∂L/∂z·(u, v, 1)` only, not through
//!   `(u, v)`'s dependence on `M`. This reference differentiates the forward exactly (the
//!   depth still goes through `(u, v)`); only the kernel value's gradient moves to `m`.
//! - **The median depth** is a step function of the parameters; its gradient goes to the hit
//!   depth of the median contributor only (as in the official code).
//!
//! # The densification statistic
//! The official code replaces ADC's 2D-mean gradient with `(∂L/∂M₁₃·M₃₃, ∂L/∂M₂₃·M₃₃)`, the
//! rasterize stage's gradient of the centre column's homogeneous `x·z`, `y·z` entries times the
//! centre's depth (for a surfel facing the camera: the gradient of its projected centre in
//! pixels), scaled by `(W/2, H/2)` to NDC units. [`SurfelGradients::ndc_center_norm`] is its
//! norm, per view; it ignores the low-pass centre's gradient, as the official code does.
//!
//! # Clamps
//! `alpha = min(alpha_max, ·)` passes nothing to the kernel or opacity when clamped; a colour
//! channel clamped at 0 passes nothing; a box half-extent whose radicand was clamped does not
//! matter (the radius is an integer, no gradient); a degenerate quaternion (read as the
//! identity) gets none; culled surfels get none.

use anyhow::{ensure, Result};

use super::project::SurfelProjected;
use super::raster::{sample_surfel, SurfelRasterOutput};
use super::{check_inputs, RefSurfels, SurfelRenderOutput, SurfelSettings};
use crate::reference::backward::{color_backward, rotation_backward};
use crate::reference::linalg::{self, Mat3, Vec3};
use crate::reference::project::normalize_quat;
use crate::reference::TileBins;
use crate::scene::{PinholeCamera, Pose};

/// Gradients of a loss with respect to the per-pixel outputs of the forward, row-major, one
/// entry per pixel in every field (zeros where an output is not in the loss).
#[derive(Debug, Clone, PartialEq)]
pub struct SurfelOutputGrads {
    /// With respect to the final image (background included).
    pub image: Vec<[f64; 3]>,
    /// With respect to the accumulated alpha `1 − T`.
    pub alpha: Vec<f64>,
    /// With respect to the expected-depth numerator `Σ w·z`.
    pub depth: Vec<f64>,
    /// With respect to the median depth.
    pub median_depth: Vec<f64>,
    /// With respect to `Σ w·n` (camera space).
    pub normal: Vec<Vec3>,
    /// With respect to the distortion.
    pub distortion: Vec<f64>,
}

impl SurfelOutputGrads {
    pub fn zeros(pixels: usize) -> Self {
        Self {
            image: vec![[0.0; 3]; pixels],
            alpha: vec![0.0; pixels],
            depth: vec![0.0; pixels],
            median_depth: vec![0.0; pixels],
            normal: vec![[0.0; 3]; pixels],
            distortion: vec![0.0; pixels],
        }
    }

    fn check(&self, raster: &SurfelRasterOutput) -> Result<()> {
        let n = raster.width as usize * raster.height as usize;
        for (name, len) in [
            ("image", self.image.len()),
            ("alpha", self.alpha.len()),
            ("depth", self.depth.len()),
            ("median_depth", self.median_depth.len()),
            ("normal", self.normal.len()),
            ("distortion", self.distortion.len()),
        ] {
            ensure!(
                len == n,
                "reference surfel backward: the `{name}` gradient has {len} pixels but the image \
                 has {}×{}; pass one gradient per pixel in every field (zeros for outputs not in \
                 the loss)",
                raster.width,
                raster.height
            );
        }
        Ok(())
    }
}

/// Gradients with respect to the preprocess outputs, one entry per surfel.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfelProjectedGrads {
    /// With respect to `M` (row-major, as [`SurfelProjected::transform`]) from the ray–splat
    /// intersection and the hit depth; the low-pass centre's share is in `center2d`.
    pub transform: Vec<Mat3>,
    /// With respect to the low-pass centre `m`.
    pub center2d: Vec<[f64; 2]>,
    /// With respect to the colour after the clamp.
    pub rgb: Vec<[f64; 3]>,
    /// With respect to the activated opacity.
    pub opacity: Vec<f64>,
    /// With respect to the camera-facing camera-space normal.
    pub normal: Vec<Vec3>,
}

impl SurfelProjectedGrads {
    pub fn zeros(n: usize) -> Self {
        Self {
            transform: vec![[[0.0; 3]; 3]; n],
            center2d: vec![[0.0; 2]; n],
            rgb: vec![[0.0; 3]; n],
            opacity: vec![0.0; n],
            normal: vec![[0.0; 3]; n],
        }
    }
}

/// Gradients with respect to the stored parameters, laid out like [`RefSurfels`].
#[derive(Debug, Clone, PartialEq)]
pub struct SurfelParamGrads {
    pub positions: Vec<[f64; 3]>,
    pub log_scales: Vec<[f64; 2]>,
    pub rotations: Vec<[f64; 4]>,
    pub opacity_logits: Vec<f64>,
    /// Zero beyond the active degree's `(degree + 1)²` coefficients.
    pub sh: Vec<[[f64; 3]; 16]>,
}

impl SurfelParamGrads {
    pub fn zeros(n: usize) -> Self {
        Self {
            positions: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 2]; n],
            rotations: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            sh: vec![[[0.0; 3]; 16]; n],
        }
    }
}

/// Everything the surfel backward produces.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfelGradients {
    pub projected: SurfelProjectedGrads,
    pub params: SurfelParamGrads,
    /// The official densification statistic for this view (module docs), per surfel.
    pub ndc_center_norm: Vec<f64>,
}

/// The full backward for a forward `forward` made with the same arguments.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    surfels: &RefSurfels,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    background: [f64; 3],
    settings: &SurfelSettings,
    forward: &SurfelRenderOutput,
    grads: &SurfelOutputGrads,
) -> Result<SurfelGradients> {
    let projected = rasterize_backward(
        &forward.projected,
        &forward.bins,
        &forward.raster,
        background,
        settings,
        grads,
    )?;
    let ndc_center_norm = ndc_center_norm(&forward.projected, &projected, camera);
    let params = preprocess_backward(
        surfels,
        &forward.projected,
        camera,
        pose,
        sh_degree,
        settings,
        &projected,
    )?;
    Ok(SurfelGradients {
        projected,
        params,
        ndc_center_norm,
    })
}

/// `|(∂L/∂M₁₃·M₃₃·W/2, ∂L/∂M₂₃·M₃₃·H/2)|` per surfel (0 for culled ones).
pub fn ndc_center_norm(
    projected: &[SurfelProjected],
    grads: &SurfelProjectedGrads,
    camera: &PinholeCamera,
) -> Vec<f64> {
    let (hw, hh) = (0.5 * camera.width as f64, 0.5 * camera.height as f64);
    projected
        .iter()
        .zip(&grads.transform)
        .map(|(p, g)| {
            if p.culled() {
                return 0.0;
            }
            let depth = p.transform[2][2];
            (g[0][2] * depth * hw).hypot(g[1][2] * depth * hh)
        })
        .collect()
}

/// Per-surfel gradients of the preprocess outputs from the per-pixel output gradients.
pub fn rasterize_backward(
    projected: &[SurfelProjected],
    bins: &TileBins,
    raster: &SurfelRasterOutput,
    background: [f64; 3],
    settings: &SurfelSettings,
    grads: &SurfelOutputGrads,
) -> Result<SurfelProjectedGrads> {
    grads.check(raster)?;
    let mut out = SurfelProjectedGrads::zeros(projected.len());
    for j in 0..raster.height {
        for i in 0..raster.width {
            let pix = j as usize * raster.width as usize + i as usize;
            let list = &bins.lists[bins.tile_of_pixel(i, j)];
            pixel_backward(
                projected,
                list,
                raster,
                pix,
                (i as f64 + 0.5, j as f64 + 0.5),
                background,
                settings,
                grads,
                &mut out,
            );
        }
    }
    Ok(out)
}

/// The backward of one pixel (module docs, "The weights").
#[allow(clippy::too_many_arguments)]
fn pixel_backward(
    projected: &[SurfelProjected],
    list: &[u32],
    raster: &SurfelRasterOutput,
    pix: usize,
    (px, py): (f64, f64),
    background: [f64; 3],
    settings: &SurfelSettings,
    grads: &SurfelOutputGrads,
    out: &mut SurfelProjectedGrads,
) {
    let dl_dc = grads.image[pix];
    let dl_dn = grads.normal[pix];
    let (dl_dalpha_map, dl_dd, dl_dmedian, dl_ddist) = (
        grads.alpha[pix],
        grads.depth[pix],
        grads.median_depth[pix],
        grads.distortion[pix],
    );
    // Totals of the pixel: Σw = 1 − T_final, M₁, M₂.
    let total_w = raster.alpha[pix];
    let (m1, m2) = (raster.m1[pix], raster.m2[pix]);
    // The background adds (1 − Σw)·bg: −bg·dL/dC per unit of weight.
    let bg_per_w = -linalg::dot(background, dl_dc);
    let last = raster.last_contributor[pix] as usize;
    let median = raster.median_contributor[pix] as usize;

    let mut t = raster.final_transmittance[pix];
    // Σ_{i behind} g_i w_i.
    let mut behind = 0.0;
    for k in (0..last).rev() {
        let g = list[k] as usize;
        let p = &projected[g];
        let Ok(s) = sample_surfel(p, px, py, settings) else {
            continue;
        };
        // Transmittance in front of this surfel and its weight.
        t /= 1.0 - s.alpha;
        let w = s.alpha * t;
        let m = settings.mapped_depth(s.z);

        // g_k = ∂L/∂w_k at fixed values.
        let dist_dw = m * m * total_w + m2 - 2.0 * m * m1;
        let g_w = linalg::dot(dl_dc, p.rgb)
            + dl_dalpha_map
            + bg_per_w
            + dl_dd * s.z
            + linalg::dot(dl_dn, p.normal)
            + dl_ddist * dist_dw;
        let dl_dalpha = t * g_w - behind / (1.0 - s.alpha);
        behind += g_w * w;

        // Values at fixed weights.
        for ch in 0..3 {
            out.rgb[g][ch] += w * dl_dc[ch];
            out.normal[g][ch] += w * dl_dn[ch];
        }
        let dm_dz = settings.far * settings.near / ((settings.far - settings.near) * s.z * s.z);
        let mut dl_dz = w * dl_dd + dl_ddist * 2.0 * w * (m * total_w - m1) * dm_dz;
        if k + 1 == median {
            dl_dz += dl_dmedian;
        }

        // alpha → opacity and the kernel (nothing when clamped).
        let mut dl_duv = [0.0; 2];
        if !s.alpha_clamped {
            out.opacity[g] += s.gauss * dl_dalpha;
            // rho → G = exp(−rho/2).
            let dl_drho = -0.5 * s.gauss * p.opacity * dl_dalpha;
            if s.lowpass {
                // rho2d = fis·|m − x|²; `s.d = m − x`.
                for a in 0..2 {
                    out.center2d[g][a] += dl_drho * 2.0 * settings.filter_inv_square * s.d[a];
                }
            } else {
                dl_duv = [2.0 * s.uv[0] * dl_drho, 2.0 * s.uv[1] * dl_drho];
            }
        }

        // z = u h₃₁ + v h₃₂ + h₃₃.
        let h3 = p.transform[2];
        dl_duv[0] += dl_dz * h3[0];
        dl_duv[1] += dl_dz * h3[1];
        let mut dl_dh3 = [dl_dz * s.uv[0], dl_dz * s.uv[1], dl_dz];

        // (u, v) = (p₁, p₂)/p₃, p = a × c, a = x h₃ − h₁, c = y h₃ − h₂.
        let p3 = s.p[2];
        let dl_dp = [
            dl_duv[0] / p3,
            dl_duv[1] / p3,
            -(dl_duv[0] * s.uv[0] + dl_duv[1] * s.uv[1]) / p3,
        ];
        let dl_da = cross(s.c, dl_dp);
        let dl_dcc = cross(dl_dp, s.a);
        for col in 0..3 {
            dl_dh3[col] += px * dl_da[col] + py * dl_dcc[col];
        }
        let tm = &mut out.transform[g];
        for col in 0..3 {
            tm[0][col] -= dl_da[col];
            tm[1][col] -= dl_dcc[col];
            tm[2][col] += dl_dh3[col];
        }
    }
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Adds the gradient of the box centre `m = (Σ τ_j h₁ⱼ h₃ⱼ, Σ τ_j h₂ⱼ h₃ⱼ) / d`,
/// `d = Σ τ_j h₃ⱼ²`, to `dl_dm` (the transform's gradient).
pub fn box_center_backward(
    transform: &Mat3,
    center: [f64; 2],
    cutoff: f64,
    dl_dcenter: [f64; 2],
    dl_dm: &mut Mat3,
) {
    let tau = [cutoff * cutoff, cutoff * cutoff, -1.0];
    let [h1, h2, h3] = *transform;
    let d: f64 = (0..3).map(|j| tau[j] * h3[j] * h3[j]).sum();
    let [gx, gy] = dl_dcenter;
    let along = gx * center[0] + gy * center[1];
    for j in 0..3 {
        dl_dm[0][j] += gx * tau[j] * h3[j] / d;
        dl_dm[1][j] += gy * tau[j] * h3[j] / d;
        dl_dm[2][j] +=
            (gx * tau[j] * h1[j] + gy * tau[j] * h2[j]) / d - 2.0 * tau[j] * h3[j] * along / d;
    }
}

/// `Kᵀ g`: the gradient of a camera-space vector `v` from that of `K v`.
fn apply_k_transpose(camera: &PinholeCamera, g: Vec3) -> Vec3 {
    [
        camera.fx * g[0],
        camera.fy * g[1],
        camera.cx * g[0] + camera.cy * g[1] + g[2],
    ]
}

/// Gradients of the stored parameters from those of the preprocess outputs.
pub fn preprocess_backward(
    surfels: &RefSurfels,
    projected: &[SurfelProjected],
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    settings: &SurfelSettings,
    grads: &SurfelProjectedGrads,
) -> Result<SurfelParamGrads> {
    check_inputs(surfels, camera, sh_degree, settings)?;
    let n = surfels.len();
    ensure!(
        projected.len() == n && grads.transform.len() == n,
        "reference surfel backward: {} projected surfels and {} gradients for {n} surfels; pass \
         the forward pass of the same scene",
        projected.len(),
        grads.transform.len()
    );
    let center = pose.center();
    let wt = linalg::transpose(&pose.rotation);
    let mut out = SurfelParamGrads::zeros(n);
    for (i, p) in projected.iter().enumerate() {
        if p.culled() {
            continue;
        }
        let o = p.opacity;
        out.opacity_logits[i] = grads.opacity[i] * o * (1.0 - o);

        let mut dl_dpos = color_backward(
            surfels.positions[i],
            &surfels.sh[i],
            p.rgb_clamped,
            center,
            sh_degree,
            grads.rgb[i],
            &mut out.sh[i],
        );

        // The low-pass centre is a function of M.
        let mut dl_dm = grads.transform[i];
        box_center_backward(
            &p.transform,
            p.center2d,
            settings.cutoff,
            grads.center2d[i],
            &mut dl_dm,
        );

        // Columns of M: K W (s_u r1), K W (s_v r2), K t.
        let column = |k: usize| [dl_dm[0][k], dl_dm[1][k], dl_dm[2][k]];
        let dl_dt = apply_k_transpose(camera, column(2));
        linalg::add_assign(&mut dl_dpos, linalg::mat_vec(&wt, dl_dt));
        out.positions[i] = dl_dpos;

        let r = p.rotation;
        let mut dl_dr = [[0.0; 3]; 3];
        for (k, scale) in p.scale.iter().enumerate() {
            // ∂L/∂(s r_k) in world space.
            let g = linalg::mat_vec(&wt, apply_k_transpose(camera, column(k)));
            let r_k = [r[0][k], r[1][k], r[2][k]];
            out.log_scales[i][k] = linalg::dot(r_k, g) * scale;
            for row in 0..3 {
                dl_dr[row][k] = g[row] * scale;
            }
        }
        // n = sign · W r3.
        let dl_dr3 = linalg::scale(linalg::mat_vec(&wt, grads.normal[i]), p.normal_sign);
        for row in 0..3 {
            dl_dr[row][2] = dl_dr3[row];
        }

        let Some((unit, norm)) = normalize_quat(surfels.rotations[i]) else {
            continue;
        };
        let dl_dunit = rotation_backward(unit, &dl_dr);
        let radial: f64 = (0..4).map(|k| unit[k] * dl_dunit[k]).sum();
        out.rotations[i] = [0, 1, 2, 3].map(|k| (dl_dunit[k] - unit[k] * radial) / norm);
    }
    Ok(out)
}
