//! Mip-Splatting's 3D smoothing filter (docs/algorithms/base-models.md §2.2), in f64.
//!
//! Every Gaussian gets a filter standard deviation `f = √0.2 · d_min / f_max`: `d_min` is the
//! smallest camera depth of its centre over the training cameras that see it (depth > 0.2 and
//! the projection within 15 % of the image past each edge), `f_max` the largest focal length
//! over all training cameras, i.e. the finest world-space sampling interval any training view
//! has at that point. The filter is a change of parameters, with no gradient of its own:
//! scales `s'_k = sqrt(s_k² + f²)` (the covariance `Σ + f²·I`: R is orthonormal) and opacity
//! `σ(o)' = σ(o) · sqrt(Π s_k² / Π (s_k² + f²))`, so the filtered Gaussian keeps its integral.
//! [`fuse`] applies it to the stored parameters (what the renderer sees, and what a PLY for an
//! ordinary 3DGS viewer must hold); [`fuse_backward`] takes gradients of the fused parameters
//! back to the stored ones.

use anyhow::{ensure, Result};

use super::backward::ParamGrads;
use super::project::sigmoid;
use super::RefGaussians;
use crate::scene::{PinholeCamera, Pose};

pub use crate::settings::mip::{FILTER_SCALE, FRUSTUM_MARGIN, MIN_DEPTH};

/// The filter standard deviation of every centre in `positions` over `cameras`. Centres no
/// camera sees get the largest value of the others (as the official code); when no centre is
/// seen at all, every filter is 0 (no smoothing). The principal point is the camera's own
/// (`cx`, `cy`); the official code assumes the image centre.
pub fn filter3d(positions: &[[f64; 3]], cameras: &[(PinholeCamera, Pose)]) -> Result<Vec<f64>> {
    ensure!(
        !cameras.is_empty(),
        "Mip-Splatting 3D filter: no training cameras; the filter needs at least one"
    );
    let f_max = cameras.iter().map(|(c, _)| c.fx).fold(0.0, f64::max);
    ensure!(
        f_max.is_finite() && f_max > 0.0,
        "Mip-Splatting 3D filter: the largest focal length is {f_max}; cameras need finite \
         positive focal lengths"
    );
    let depths: Vec<Option<f64>> = positions
        .iter()
        .map(|&p| {
            cameras
                .iter()
                .filter_map(|(c, pose)| {
                    let [x, y, z] = pose.transform(p);
                    if z.is_nan() || z <= MIN_DEPTH {
                        return None;
                    }
                    let (w, h) = (c.width as f64, c.height as f64);
                    let u = c.fx * x / z + c.cx;
                    let v = c.fy * y / z + c.cy;
                    let inside = (-FRUSTUM_MARGIN * w..=(1.0 + FRUSTUM_MARGIN) * w).contains(&u)
                        && (-FRUSTUM_MARGIN * h..=(1.0 + FRUSTUM_MARGIN) * h).contains(&v);
                    inside.then_some(z)
                })
                .reduce(f64::min)
        })
        .collect();
    let unseen = depths.iter().flatten().copied().fold(0.0, f64::max);
    Ok(depths
        .iter()
        .map(|d| d.unwrap_or(unseen) / f_max * FILTER_SCALE.sqrt())
        .collect())
}

fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// The parameters with the 3D filter `filter` (one standard deviation per Gaussian) folded in.
pub fn fuse(g: &RefGaussians, filter: &[f64]) -> Result<RefGaussians> {
    ensure!(
        filter.len() == g.len(),
        "Mip-Splatting 3D filter: {} filter values for {} Gaussians",
        filter.len(),
        g.len()
    );
    let mut out = g.clone();
    for (i, &f) in filter.iter().enumerate() {
        let phi = f * f;
        let mut log_ratio = 0.0;
        for k in 0..3 {
            let s2 = (2.0 * g.log_scales[i][k]).exp();
            out.log_scales[i][k] = 0.5 * (s2 + phi).ln();
            log_ratio += (s2 / (s2 + phi)).ln();
        }
        out.opacity_logits[i] = logit(sigmoid(g.opacity_logits[i]) * (0.5 * log_ratio).exp());
    }
    Ok(out)
}

/// Gradients of the fused parameters (`fuse(g, filter)`) → gradients of `g`'s. Positions,
/// rotations and SH pass through; the filter itself is a constant.
pub fn fuse_backward(g: &RefGaussians, filter: &[f64], fused: &ParamGrads) -> Result<ParamGrads> {
    ensure!(
        filter.len() == g.len() && fused.log_scales.len() == g.len(),
        "Mip-Splatting 3D filter backward: {} filter values and {} gradients for {} Gaussians",
        filter.len(),
        fused.log_scales.len(),
        g.len()
    );
    let mut out = fused.clone();
    for (i, &f) in filter.iter().enumerate() {
        let phi = f * f;
        let s2 = g.log_scales[i].map(|l| (2.0 * l).exp());
        let rho = s2.iter().map(|&s| (s / (s + phi)).sqrt()).product::<f64>();
        let o = sigmoid(g.opacity_logits[i]);
        let fo = o * rho;
        // Fused logit = logit(o·ρ): dL/d(o·ρ) = dL/dlogit' / (o·ρ·(1 − o·ρ)).
        let dl_dfo = fused.opacity_logits[i] / (fo * (1.0 - fo));
        out.opacity_logits[i] = dl_dfo * rho * o * (1.0 - o);
        for (k, &s2k) in s2.iter().enumerate() {
            // l'_k = ½ ln(s_k² + φ): dl'_k/dl_k = s_k² / (s_k² + φ); ∂ ln ρ / ∂l_k = φ / (s_k² + φ).
            let w = s2k / (s2k + phi);
            out.log_scales[i][k] = fused.log_scales[i][k] * w + dl_dfo * fo * (1.0 - w);
        }
    }
    Ok(out)
}
