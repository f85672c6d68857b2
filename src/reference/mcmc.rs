//! f64 oracle of the MCMC strategy's pieces (`crate::mcmc`): the relocation's scale factor by
//! quadrature of the integral the peers' binomial sum stands for, a plan applied to host
//! parameters, the position noise, and the opacity and scale regularisers' gradients.

use crate::mcmc::plan::{sigmoid, Plan};
use crate::reference::project::{normalize_quat, quat_to_rotation};
use crate::splats::GaussianParams;

/// `o / D` with `D = ∫ 1 − (1 − o'·g(x))^n dx / √(2π)`, `g(x) = exp(−x²/2)`: the profile of `n`
/// stacked copies of opacity `o'` composited along a ray, integrated across it, against the
/// original's `o·∫ g / √(2π) = o` (composite Simpson on [−14, 14], 20 000 intervals).
pub fn scale_factor_by_quadrature(o: f64, o_new: f64, n: u32) -> f64 {
    let (a, b, m) = (-14.0f64, 14.0f64, 20_000usize);
    let h = (b - a) / m as f64;
    let f = |x: f64| 1.0 - (1.0 - o_new * (-0.5 * x * x).exp()).powi(n as i32);
    let mut s = f(a) + f(b);
    for k in 1..m {
        s += f(a + k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 };
    }
    let d = s * h / 3.0 / (2.0 * std::f64::consts::PI).sqrt();
    o / d
}

/// What the GPU does with a plan, on host parameters and moments: every copy's destination row
/// takes its source's parameters; moments of destinations and sources zeroed; every update
/// sets the row's logit and adds its change to the first `scaled_axes` log-scales (f32 adds,
/// as the kernel).
pub fn apply_plan(
    params: &mut GaussianParams,
    moments: &mut [&mut GaussianParams],
    plan: &Plan,
    scaled_axes: usize,
) {
    for &(d, s) in &plan.copies {
        let (d, s) = (d as usize, s as usize);
        copy_row(params, d, s);
        for m in moments.iter_mut() {
            zero_row(m, d);
            zero_row(m, s);
        }
    }
    for &(row, l, delta) in &plan.updates {
        let r = row as usize;
        params.opacity_logits[r] = l;
        for k in 0..scaled_axes {
            params.log_scales[r][k] += delta;
        }
    }
}

fn copy_row(p: &mut GaussianParams, d: usize, s: usize) {
    p.positions[d] = p.positions[s];
    p.log_scales[d] = p.log_scales[s];
    p.rotations[d] = p.rotations[s];
    p.opacity_logits[d] = p.opacity_logits[s];
    p.sh_dc[d] = p.sh_dc[s];
    let r = p.rest_stride();
    for k in 0..r {
        p.sh_rest[d * r + k] = p.sh_rest[s * r + k];
    }
    for g in p.extra.iter_mut() {
        let w = g.group.stride;
        for k in 0..w {
            g.values[d * w + k] = g.values[s * w + k];
        }
    }
}

fn zero_row(p: &mut GaussianParams, d: usize) {
    p.positions[d] = [0.0; 3];
    p.log_scales[d] = [0.0; 3];
    p.rotations[d] = [0.0; 4];
    p.opacity_logits[d] = 0.0;
    p.sh_dc[d] = [0.0; 3];
    let r = p.rest_stride();
    for k in 0..r {
        p.sh_rest[d * r + k] = 0.0;
    }
    for g in p.extra.iter_mut() {
        let w = g.group.stride;
        for k in 0..w {
            g.values[d * w + k] = 0.0;
        }
    }
}

/// The gate that keeps noise to the faint: `1 / (1 + exp(k·(o − t)))`.
pub fn noise_gate(opacity: f64, k: f64, t: f64) -> f64 {
    1.0 / (1.0 + (k * (opacity - t)).exp())
}

/// Gaussian `i`'s displacement: `amount · gate(σ(logit)) · Σ ε` with `Σ = R diag(s²) Rᵀ` from its
/// normalised rotation and scales, `ε` the three standard normals given.
pub fn noise_displacement(
    p: &GaussianParams,
    i: usize,
    eps: [f64; 3],
    amount: f64,
    k: f64,
    t: f64,
) -> [f64; 3] {
    // A quaternion too small to normalise reads as the identity (as the kernel does).
    let r = match normalize_quat(p.rotations[i].map(|v| v as f64)) {
        Some((u, _)) => quat_to_rotation(u),
        None => quat_to_rotation([1.0, 0.0, 0.0, 0.0]),
    };
    let s2 = p.log_scales[i].map(|l| (2.0 * l as f64).exp());
    let gate = noise_gate(sigmoid(p.opacity_logits[i] as f64), k, t);
    // Σ ε = R (s² ⊙ (Rᵀ ε)).
    let mut rt_e = [0.0; 3];
    for a in 0..3 {
        rt_e[a] = (0..3).map(|b| r[b][a] * eps[b]).sum::<f64>() * s2[a];
    }
    let mut out = [0.0; 3];
    for a in 0..3 {
        out[a] = amount * gate * (0..3).map(|b| r[a][b] * rt_e[b]).sum::<f64>();
    }
    out
}

/// The regularisers `λ_o · mean σ(logit) + λ_s · mean exp(log-scale)` (the mean over the first
/// `scaled_axes` scales of every Gaussian) and their gradients with respect to the logits and
/// log-scales.
pub fn regulariser(
    p: &GaussianParams,
    opacity_weight: f64,
    scale_weight: f64,
    scaled_axes: usize,
) -> (f64, Vec<f64>, Vec<[f64; 3]>) {
    let n = p.len() as f64;
    let mut loss = 0.0;
    let mut g_logit = Vec::with_capacity(p.len());
    let mut g_scale = Vec::with_capacity(p.len());
    for i in 0..p.len() {
        let o = sigmoid(p.opacity_logits[i] as f64);
        loss += opacity_weight * o / n;
        g_logit.push(opacity_weight * o * (1.0 - o) / n);
        let mut g = [0.0; 3];
        for (k, gk) in g.iter_mut().enumerate().take(scaled_axes) {
            let s = (p.log_scales[i][k] as f64).exp();
            loss += scale_weight * s / (n * scaled_axes as f64);
            *gk = scale_weight * s / (n * scaled_axes as f64);
        }
        g_scale.push(g);
    }
    (loss, g_logit, g_scale)
}
