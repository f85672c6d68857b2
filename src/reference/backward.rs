//! Analytic gradients of a scalar loss, given `dL/d(image)`, with respect to every parameter
//! of [`RefGaussians`]. Two stages, mirroring the GPU kernels:
//!
//! 1. [`rasterize_backward`]: per pixel, back to front over the splats that contributed (from
//!    `last_contributor − 1` down to 0, repeating the forward's skips), recovering the
//!    transmittance in front of each splat as `T / (1 − alpha)` from the stored final `T`.
//!    Produces gradients of mean2d, conic, (clamped) colour and opacity.
//! 2. [`preprocess_backward`]: through the projection, the EWA Jacobian (including its x/z, y/z
//!    clamp, which passes no gradient when active), the dilation and inverse, `Σ = R S Sᵀ Rᵀ`,
//!    the quaternion normalisation, the sigmoid, and the SH evaluation including the gradient that
//!    flows into the position through the view direction.
//!
//! Clamps and their gradients: `alpha = min(alpha_max, ·)` passes none when clamped; a colour
//! channel clamped at 0 passes none; the determinant clamp passes none through `det` when active;
//! a degenerate quaternion (read as identity) gets none.

use anyhow::{ensure, Result};

use super::linalg::{self, Mat23, Mat3, Vec3};
use super::project::{
    covariance3d, ewa_jacobian, jacobian_limits, normalize_quat, rotation_of, scaled_rotation,
    view_direction, Projected,
};
use super::raster::{sample_splat, RasterOutput, TileBins};
use super::{check_inputs, sh, RefGaussians, RenderOutput, RenderSettings};
use crate::scene::{PinholeCamera, Pose};

/// Gradients with respect to the preprocess outputs (what the rasterize-backward kernel
/// produces), one entry per Gaussian.
#[derive(Debug, Clone, PartialEq)]
pub struct ProjectedGrads {
    pub mean2d: Vec<[f64; 2]>,
    /// With respect to the conic entries `[a, b, c]` of `[[a, b], [b, c]]` (b counted once).
    pub conic: Vec<[f64; 3]>,
    /// With respect to the colour after the clamp.
    pub rgb: Vec<[f64; 3]>,
    /// With respect to the activated opacity (not the logit).
    pub opacity: Vec<f64>,
    /// Per axis, the sum over pixels of the absolute value of each pixel's term of `mean2d`
    /// (Gaussian Opacity Fields' absolute gradient, before the NDC scale).
    pub mean2d_abs: Vec<[f64; 2]>,
}

impl ProjectedGrads {
    pub fn zeros(n: usize) -> Self {
        Self {
            mean2d: vec![[0.0; 2]; n],
            conic: vec![[0.0; 3]; n],
            rgb: vec![[0.0; 3]; n],
            opacity: vec![0.0; n],
            mean2d_abs: vec![[0.0; 2]; n],
        }
    }
}

/// Gradients with respect to the stored parameters, laid out like [`RefGaussians`].
#[derive(Debug, Clone, PartialEq)]
pub struct ParamGrads {
    pub positions: Vec<[f64; 3]>,
    pub log_scales: Vec<[f64; 3]>,
    pub rotations: Vec<[f64; 4]>,
    pub opacity_logits: Vec<f64>,
    /// Zero beyond the active degree's `(degree + 1)²` coefficients.
    pub sh: Vec<[[f64; 3]; 16]>,
}

impl ParamGrads {
    pub fn zeros(n: usize) -> Self {
        Self {
            positions: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 3]; n],
            rotations: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            sh: vec![[[0.0; 3]; 16]; n],
        }
    }
}

/// Everything the backward pass produces.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradients {
    pub projected: ProjectedGrads,
    pub params: ParamGrads,
    /// Density control's statistic for this view: `|(dL/du · W/2, dL/dv · H/2)|`, the 2D-mean
    /// gradient expressed in NDC units. Zero for Gaussians that touched no pixel.
    pub ndc_mean2d_norm: Vec<f64>,
    /// The absolute-gradient statistic: `Σ|dL/du_p| · W/2 + Σ|dL/dv_p| · H/2` over the pixels.
    pub ndc_abs_grad: Vec<f64>,
}

/// The full backward pass for a forward pass `forward` made with the same arguments.
#[allow(clippy::too_many_arguments)]
pub fn backward(
    gaussians: &RefGaussians,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    background: [f64; 3],
    settings: &RenderSettings,
    forward: &RenderOutput,
    dl_dimage: &[[f64; 3]],
) -> Result<Gradients> {
    let projected = rasterize_backward(
        &forward.projected,
        &forward.bins,
        &forward.raster,
        background,
        settings,
        dl_dimage,
    )?;
    let params = preprocess_backward(
        gaussians,
        &forward.projected,
        camera,
        pose,
        sh_degree,
        settings,
        &projected,
    )?;
    let ndc_mean2d_norm = ndc_mean2d_norm(&projected, camera);
    let (hw, hh) = (0.5 * camera.width as f64, 0.5 * camera.height as f64);
    let ndc_abs_grad = projected
        .mean2d_abs
        .iter()
        .map(|a| a[0] * hw + a[1] * hh)
        .collect();
    Ok(Gradients {
        projected,
        params,
        ndc_mean2d_norm,
        ndc_abs_grad,
    })
}

/// `|(dL/du · W/2, dL/dv · H/2)|` per Gaussian.
pub fn ndc_mean2d_norm(grads: &ProjectedGrads, camera: &PinholeCamera) -> Vec<f64> {
    let (hw, hh) = (0.5 * camera.width as f64, 0.5 * camera.height as f64);
    grads
        .mean2d
        .iter()
        .map(|g| (g[0] * hw).hypot(g[1] * hh))
        .collect()
}

/// Gradients of mean2d, conic, colour and opacity from `dL/d(image)`.
pub fn rasterize_backward(
    projected: &[Projected],
    bins: &TileBins,
    raster: &RasterOutput,
    background: [f64; 3],
    settings: &RenderSettings,
    dl_dimage: &[[f64; 3]],
) -> Result<ProjectedGrads> {
    let n_pix = raster.width as usize * raster.height as usize;
    ensure!(
        dl_dimage.len() == n_pix,
        "reference backward: dL/dimage has {} pixels but the image has {}×{}; pass one gradient \
         per pixel",
        dl_dimage.len(),
        raster.width,
        raster.height
    );
    let mut grads = ProjectedGrads::zeros(projected.len());
    for j in 0..raster.height {
        for i in 0..raster.width {
            let pix = j as usize * raster.width as usize + i as usize;
            let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
            let dl_dc = dl_dimage[pix];
            let t_final = raster.final_transmittance[pix];
            let bg_dot = linalg::dot(background, dl_dc);
            let list = &bins.lists[bins.tile_of_pixel(i, j)];
            let last = raster.last_contributor[pix] as usize;

            let mut t = t_final;
            // Colour of everything behind the current splat, per unit of transmittance in front
            // of that splat (background excluded: it is handled through t_final).
            let mut behind = [0.0; 3];
            let mut next_alpha = 0.0;
            let mut next_rgb = [0.0; 3];
            for k in (0..last).rev() {
                let g = list[k] as usize;
                let p = &projected[g];
                let Some(s) = sample_splat(p, px, py, settings) else {
                    continue;
                };
                // Transmittance in front of this splat.
                t /= 1.0 - s.alpha;
                for ch in 0..3 {
                    behind[ch] = next_alpha * next_rgb[ch] + (1.0 - next_alpha) * behind[ch];
                    grads.rgb[g][ch] += s.alpha * t * dl_dc[ch];
                }
                let mut dl_dalpha = 0.0;
                for ch in 0..3 {
                    dl_dalpha += (p.rgb[ch] - behind[ch]) * t * dl_dc[ch];
                }
                dl_dalpha -= t_final / (1.0 - s.alpha) * bg_dot;
                next_alpha = s.alpha;
                next_rgb = p.rgb;

                if s.alpha_clamped {
                    continue;
                }
                grads.opacity[g] += s.gauss * dl_dalpha;
                // power = −½(a dx² + c dy²) − b dx dy, alpha = opacity·exp(power).
                let dl_dpower = p.opacity * s.gauss * dl_dalpha;
                let [a, b, c] = p.conic;
                let [dx, dy] = s.d;
                let du = dl_dpower * (-a * dx - b * dy);
                let dv = dl_dpower * (-c * dy - b * dx);
                grads.mean2d[g][0] += du;
                grads.mean2d[g][1] += dv;
                grads.mean2d_abs[g][0] += du.abs();
                grads.mean2d_abs[g][1] += dv.abs();
                grads.conic[g][0] += dl_dpower * (-0.5 * dx * dx);
                grads.conic[g][1] += dl_dpower * (-dx * dy);
                grads.conic[g][2] += dl_dpower * (-0.5 * dy * dy);
            }
        }
    }
    Ok(grads)
}

/// Gradients of the stored parameters from the gradients of the preprocess outputs.
pub fn preprocess_backward(
    gaussians: &RefGaussians,
    projected: &[Projected],
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    settings: &RenderSettings,
    grads: &ProjectedGrads,
) -> Result<ParamGrads> {
    check_inputs(gaussians, camera, sh_degree, settings)?;
    let n = gaussians.len();
    ensure!(
        projected.len() == n && grads.mean2d.len() == n,
        "reference backward: {} projected Gaussians and {} gradients for {n} Gaussians; pass the \
         forward pass of the same scene",
        projected.len(),
        grads.mean2d.len()
    );
    let limits = jacobian_limits(camera, settings);
    let center = pose.center();
    let w = pose.rotation;
    let wt = linalg::transpose(&w);
    let mut out = ParamGrads::zeros(n);
    for (i, p) in projected.iter().enumerate() {
        if p.culled {
            continue;
        }
        // p.opacity = sigmoid(logit) · ρ (ρ = 1 without the 2D Mip filter).
        let o = p.opacity / p.compensation;
        out.opacity_logits[i] = grads.opacity[i] * p.compensation * o * (1.0 - o);

        // Colour: SH coefficients and the view direction.
        let mut dl_dpos = color_backward(
            gaussians.positions[i],
            &gaussians.sh[i],
            p.rgb_clamped,
            center,
            sh_degree,
            grads.rgb[i],
            &mut out.sh[i],
        );

        // Conic → dilated 2D covariance [a, b, c].
        let mut dl_dcov2d = conic_backward(p.cov2d, grads.conic[i], settings.det_min);
        if settings.mip_2d && !p.compensation_floored {
            // ρ = sqrt(det0 / det1): dρ/dΣ = ρ/2 · (∇det0 / det0 − ∇det1 / det1), with
            // ∇det = (c, −2b, a) of the undilated (det0) and dilated (det1) covariance; the
            // dilation is a constant, so gradients of either are gradients of the other.
            let [a1, b, c1] = p.cov2d;
            let (a0, c0) = (a1 - settings.eps2d, c1 - settings.eps2d);
            let det0 = a0 * c0 - b * b;
            let det1 = a1 * c1 - b * b;
            let k = grads.opacity[i] * o * 0.5 * p.compensation;
            dl_dcov2d[0] += k * (c0 / det0 - c1 / det1);
            dl_dcov2d[1] += k * (-2.0 * b / det0 + 2.0 * b / det1);
            dl_dcov2d[2] += k * (a0 / det0 - a1 / det1);
        }

        // 2D covariance → camera-space mean (through J) and the 3D covariance.
        let t = p.cam_mean;
        let sigma = covariance3d(gaussians.log_scales[i], gaussians.rotations[i]);
        let (jac, clamped) = ewa_jacobian(camera, t, &limits);
        let jw = linalg::mul23(&jac, &w);
        let (dl_dsigma, dl_djw) = cov2d_backward(&jw, &sigma, dl_dcov2d);
        let dl_djac = mul23_t(&dl_djw, &w);
        let mut dl_dt = jacobian_backward(camera, t, &limits, clamped, &dl_djac);

        // Projected mean → camera-space mean.
        let [x, y, z] = t;
        let [du, dv] = grads.mean2d[i];
        dl_dt[0] += du * camera.fx / z;
        dl_dt[1] += dv * camera.fy / z;
        dl_dt[2] += -du * camera.fx * x / (z * z) - dv * camera.fy * y / (z * z);

        // Camera space → world: t = W p + T.
        linalg::add_assign(&mut dl_dpos, linalg::mat_vec(&wt, dl_dt));
        out.positions[i] = dl_dpos;

        // 3D covariance → log-scales and quaternion.
        let (dl_dlog_scale, dl_dq) =
            sigma_backward(gaussians.log_scales[i], gaussians.rotations[i], &dl_dsigma);
        out.log_scales[i] = dl_dlog_scale;
        out.rotations[i] = dl_dq;
    }
    Ok(out)
}

/// SH colour backward for one splat at `position` with coefficients `coeffs` (3DGS and
/// surfels alike): writes the SH coefficient gradients into `dl_dsh` and returns the position
/// gradient that flows through the view direction. `rgb_clamped` are the channels the forward
/// clamped at 0.
pub(crate) fn color_backward(
    position: Vec3,
    coeffs: &[[f64; 3]; 16],
    rgb_clamped: [bool; 3],
    camera_center: Vec3,
    sh_degree: usize,
    dl_drgb: [f64; 3],
    dl_dsh: &mut [[f64; 3]; 16],
) -> Vec3 {
    // The clamp at 0 kills the gradient of a clamped channel.
    let mut dl_draw = dl_drgb;
    for (d, &clamped) in dl_draw.iter_mut().zip(&rgb_clamped) {
        if clamped {
            *d = 0.0;
        }
    }
    let (dir, len) = view_direction(position, camera_center);
    let basis = sh::basis(sh_degree, dir);
    let basis_grad = sh::basis_gradient(sh_degree, dir);
    let mut dl_ddir = [0.0; 3];
    for k in 0..sh::num_coeffs(sh_degree) {
        let mut weight = 0.0;
        for ch in 0..3 {
            dl_dsh[k][ch] = basis[k] * dl_draw[ch];
            weight += coeffs[k][ch] * dl_draw[ch];
        }
        linalg::add_assign(&mut dl_ddir, linalg::scale(basis_grad[k], weight));
    }
    // dir = v / |v|: d dir / d v = (I − dir dirᵀ) / |v|.
    let radial = linalg::dot(dir, dl_ddir);
    linalg::scale(linalg::sub(dl_ddir, linalg::scale(dir, radial)), 1.0 / len)
}

/// Conic `[c, −b, a] / max(det, det_min)` → gradient of the covariance entries `[a, b, c]`.
fn conic_backward(cov2d: [f64; 3], dl_dconic: [f64; 3], det_min: f64) -> [f64; 3] {
    let [a, b, c] = cov2d;
    let [ga, gb, gc] = dl_dconic;
    let det_raw = a * c - b * b;
    let det = det_raw.max(det_min);
    let mut out = [gc / det, -gb / det, ga / det];
    if det_raw >= det_min {
        let dl_ddet = -(ga * c - gb * b + gc * a) / (det * det);
        out[0] += dl_ddet * c;
        out[1] += dl_ddet * (-2.0 * b);
        out[2] += dl_ddet * a;
    }
    out
}

/// `cov2d = T Σ Tᵀ (+ eps2d·I)` with `T = J W` → (dL/dΣ, dL/dT).
fn cov2d_backward(t: &Mat23, sigma: &Mat3, dl_dcov2d: [f64; 3]) -> (Mat3, Mat23) {
    // The symmetric 2×2 gradient; b appears twice in the matrix, so each copy gets half.
    let g2 = [
        [dl_dcov2d[0], 0.5 * dl_dcov2d[1]],
        [0.5 * dl_dcov2d[1], dl_dcov2d[2]],
    ];
    // dL/dΣ = Tᵀ G T.
    let mut dl_dsigma = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            let mut v = 0.0;
            for m in 0..2 {
                for n in 0..2 {
                    v += t[m][r] * g2[m][n] * t[n][c];
                }
            }
            dl_dsigma[r][c] = v;
        }
    }
    // dL/dT = 2 G T Σ.
    let ts = linalg::mul23(t, sigma);
    let mut dl_dt = [[0.0; 3]; 2];
    for m in 0..2 {
        for c in 0..3 {
            dl_dt[m][c] = 2.0 * (g2[m][0] * ts[0][c] + g2[m][1] * ts[1][c]);
        }
    }
    (dl_dsigma, dl_dt)
}

/// `a · bᵀ` for a 2×3 `a` and a 3×3 `b`.
fn mul23_t(a: &Mat23, b: &Mat3) -> Mat23 {
    let mut c = [[0.0; 3]; 2];
    for i in 0..2 {
        for j in 0..3 {
            c[i][j] = linalg::dot(a[i], b[j]);
        }
    }
    c
}

/// EWA Jacobian → camera-space mean. `J = [[fx/z, 0, −fx·tx/z], [0, fy/z, −fy·ty/z]]` where
/// `tx = x/z` unless clamped (then a constant).
fn jacobian_backward(
    camera: &PinholeCamera,
    t: Vec3,
    limits: &[[f64; 2]; 2],
    clamped: [bool; 2],
    dl_dj: &Mat23,
) -> Vec3 {
    let [x, y, z] = t;
    let tx = (x / z).max(limits[0][0]).min(limits[0][1]);
    let ty = (y / z).max(limits[1][0]).min(limits[1][1]);
    let (fx, fy) = (camera.fx, camera.fy);
    let z2 = z * z;
    let mut out = [0.0; 3];
    out[2] += dl_dj[0][0] * (-fx / z2) + dl_dj[1][1] * (-fy / z2);
    // ∂J02/∂z at fixed tx, and likewise J12.
    out[2] += dl_dj[0][2] * (fx * tx / z2) + dl_dj[1][2] * (fy * ty / z2);
    if !clamped[0] {
        // ∂J02/∂tx = −fx/z; ∂tx/∂x = 1/z, ∂tx/∂z = −x/z².
        let dl_dtx = dl_dj[0][2] * (-fx / z);
        out[0] += dl_dtx / z;
        out[2] += dl_dtx * (-x / z2);
    }
    if !clamped[1] {
        let dl_dty = dl_dj[1][2] * (-fy / z);
        out[1] += dl_dty / z;
        out[2] += dl_dty * (-y / z2);
    }
    out
}

/// `Σ = M Mᵀ`, `M = R(q̂) diag(exp(log_scale))`, `q̂ = q / |q|` → (dL/dlog_scale, dL/dq).
fn sigma_backward(log_scale: [f64; 3], q: [f64; 4], dl_dsigma: &Mat3) -> ([f64; 3], [f64; 4]) {
    let m = scaled_rotation(log_scale, q);
    let r = rotation_of(q);
    let s = log_scale.map(f64::exp);
    // dL/dM = 2 dL/dΣ M (dL/dΣ is symmetric).
    let dl_dm = linalg::mul(dl_dsigma, &m);
    let mut dl_dlog_scale = [0.0; 3];
    let mut dl_dr = [[0.0; 3]; 3];
    for row in 0..3 {
        for col in 0..3 {
            let g = 2.0 * dl_dm[row][col];
            dl_dlog_scale[col] += g * r[row][col] * s[col];
            dl_dr[row][col] = g * s[col];
        }
    }
    let Some((unit, norm)) = normalize_quat(q) else {
        return (dl_dlog_scale, [0.0; 4]);
    };
    let dl_dunit = rotation_backward(unit, &dl_dr);
    // q̂ = q/|q|: dL/dq = (dL/dq̂ − q̂ (q̂·dL/dq̂)) / |q|.
    let radial: f64 = (0..4).map(|k| unit[k] * dl_dunit[k]).sum();
    let dl_dq = [0, 1, 2, 3].map(|k| (dl_dunit[k] - unit[k] * radial) / norm);
    (dl_dlog_scale, dl_dq)
}

/// Gradient of `quat_to_rotation` with respect to the (unit) quaternion (w, x, y, z).
pub(crate) fn rotation_backward(q: [f64; 4], g: &Mat3) -> [f64; 4] {
    let [w, x, y, z] = q;
    [
        2.0 * (-z * g[0][1] + y * g[0][2] + z * g[1][0] - x * g[1][2] - y * g[2][0] + x * g[2][1]),
        2.0 * (y * g[0][1] + z * g[0][2] + y * g[1][0] - 2.0 * x * g[1][1] - w * g[1][2]
            + z * g[2][0]
            + w * g[2][1]
            - 2.0 * x * g[2][2]),
        2.0 * (-2.0 * y * g[0][0] + x * g[0][1] + w * g[0][2] + x * g[1][0] + z * g[1][2]
            - w * g[2][0]
            + z * g[2][1]
            - 2.0 * y * g[2][2]),
        2.0 * (-2.0 * z * g[0][0] - w * g[0][1] + x * g[0][2] + w * g[1][0] - 2.0 * z * g[1][1]
            + y * g[1][2]
            + x * g[2][0]
            + y * g[2][1]),
    ]
}
