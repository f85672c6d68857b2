//! SpacetimeGaussians' temporal step (the lite and full models share it), in f64: what a
//! Gaussian is at time `t`, as the still 3D Gaussian the projection and rasterizer then draw, and
//! the chain rule back to the temporal parameters. The GPU's `glsl/spacetime/` kernels copy it.
//!
//! Per Gaussian, with `Δ = t − c` (`c` the temporal centre, `s` the temporal log-scale):
//! - position `μ(t) = μ + m₁Δ + m₂Δ² + m₃Δ³` (the official cubic motion);
//! - rotation `q(t) = q + ωΔ`, left unnormalised: the projection normalises it, as it does every
//!   quaternion, so the chain rule through the normalisation is the projection's;
//! - opacity `α(t) = σ(o)·g` with the temporal weight `g = exp(−u²)`, `u = Δ·e^{−s}` (no ½ in
//!   the exponent: the official radial basis);
//! - scales and colour do not depend on time.
//!
//! **Δ is detached in the motion and the rotation**, as in the official code (it computes
//! the polynomial from a detached time difference): the temporal centre `c` learns only through
//! the opacity. The gradients below are those of that computation, not of the full
//! function of `c`.
//!
//! The projection takes an opacity *logit*, so the temporal step hands it
//! `o(t) = logit(σ(o)·g) = log σ(o) − u² − log(1 − σ(o)·g)`, written so that nothing overflows
//! or divides by zero: `log σ(o) = −softplus(−o)`, and `1 − σ(o)·g = σ(−o) + σ(o)·(1 − g)` is a
//! sum of non-negative terms whose first is never 0 for a finite `o` (the naive form
//! rounds to 0 for `o` > 17 in f32). A Gaussian far from its time gets a very negative logit
//! (`−u²`), which the projection reads as opacity 0: no clamp is needed, and the gradients
//! `∂o(t)/∂c = 2u·e^{−s}/(1 − σg)`, `∂o(t)/∂s = 2u²/(1 − σg)`, `∂o(t)/∂o = σ(−o)/(1 − σg)`
//! stay finite (the first two grow with `u`; a Gaussian that far away is invisible and its
//! logit gradient from the projection is 0).

/// The temporal parameters of one Gaussian (the time-independent ones are not needed here).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Temporal {
    pub position: [f64; 3],
    /// `m₁, m₂, m₃`, each an xyz triple.
    pub motion: [f64; 9],
    /// Quaternion (w, x, y, z), unnormalised.
    pub rotation: [f64; 4],
    /// Angular velocity: added to the quaternion per unit time.
    pub omega: [f64; 4],
    pub opacity_logit: f64,
    /// Temporal centre `c`.
    pub t_center: f64,
    /// Temporal log-scale `s`.
    pub t_log_scale: f64,
}

/// The still Gaussian at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Instant {
    pub position: [f64; 3],
    pub rotation: [f64; 4],
    pub opacity_logit: f64,
}

/// Gradients of the temporal parameters.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TemporalGrads {
    pub position: [f64; 3],
    pub motion: [f64; 9],
    pub rotation: [f64; 4],
    pub omega: [f64; 4],
    pub opacity_logit: f64,
    pub t_center: f64,
    pub t_log_scale: f64,
}

/// `log(1 + e^x)` without overflow.
pub fn softplus(x: f64) -> f64 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// `1 − e^{−x}` for `x ≥ 0`, accurate for small `x` (f32 has no `expm1`: the GPU uses the series
/// below `EXPM1_SERIES_BELOW`, and so does this reference, to match it).
pub fn one_minus_exp_neg(x: f64) -> f64 {
    if x < EXPM1_SERIES_BELOW {
        x * (1.0 - 0.5 * x * (1.0 - x / 3.0))
    } else {
        1.0 - (-x).exp()
    }
}

/// Floor of `1 − σ(o)·g`: it only acts when `σ(−o)` < 1e-30 (a logit above 69, opacity 1 to 30
/// digits) and the Gaussian is at its temporal centre, where f32 would otherwise divide by 0.
pub const ONE_MINUS_MIN: f64 = 1e-30;

/// Below this `u²`, `1 − e^{−u²}` is evaluated by its series (error < x⁴/24 ≈ 4e-14 relative).
pub const EXPM1_SERIES_BELOW: f64 = 1e-3;

/// The temporal weight `g = exp(−((t − c)·e^{−s})²)`.
pub fn temporal_weight(p: &Temporal, t: f64) -> f64 {
    let u = (t - p.t_center) * (-p.t_log_scale).exp();
    (-u * u).exp()
}

/// The still Gaussian at time `t`.
pub fn instant(p: &Temporal, t: f64) -> Instant {
    instant_detached(p, t, t - p.t_center)
}

/// [`instant`] with the motion's and rotation's `Δ` given: finite differences of the temporal
/// centre hold it fixed, as the detached official computation does.
pub fn instant_detached(p: &Temporal, t: f64, motion_delta: f64) -> Instant {
    let d = motion_delta;
    let position = [0, 1, 2].map(|k| {
        p.position[k] + p.motion[k] * d + p.motion[3 + k] * d * d + p.motion[6 + k] * d * d * d
    });
    let rotation = [0, 1, 2, 3].map(|k| p.rotation[k] + p.omega[k] * d);
    let u = (t - p.t_center) * (-p.t_log_scale).exp();
    let u2 = u * u;
    let sig = 1.0 / (1.0 + (-p.opacity_logit).exp());
    let sig_neg = 1.0 / (1.0 + p.opacity_logit.exp());
    let one_minus = (sig_neg + sig * one_minus_exp_neg(u2)).max(ONE_MINUS_MIN);
    let opacity_logit = -softplus(-p.opacity_logit) - u2 - one_minus.ln();
    Instant {
        position,
        rotation,
        opacity_logit,
    }
}

/// The temporal parameters' gradients from the still Gaussian's.
pub fn instant_backward(p: &Temporal, t: f64, d: &Instant) -> TemporalGrads {
    let delta = t - p.t_center;
    let mut g = TemporalGrads::default();
    let mut power = 1.0;
    for j in 0..3 {
        power *= delta;
        for k in 0..3 {
            g.motion[3 * j + k] = power * d.position[k];
        }
    }
    g.position = d.position;
    g.rotation = d.rotation;
    g.omega = d.rotation.map(|x| x * delta);
    let inv_scale = (-p.t_log_scale).exp();
    let u = delta * inv_scale;
    let u2 = u * u;
    let sig = 1.0 / (1.0 + (-p.opacity_logit).exp());
    let sig_neg = 1.0 / (1.0 + p.opacity_logit.exp());
    let one_minus = (sig_neg + sig * one_minus_exp_neg(u2)).max(ONE_MINUS_MIN);
    let dl = d.opacity_logit / one_minus;
    g.opacity_logit = dl * sig_neg;
    g.t_center = dl * 2.0 * u * inv_scale;
    g.t_log_scale = dl * 2.0 * u2;
    g
}

pub use crate::settings::spacetime::PRESENT_MIN_WEIGHT;

/// The centre of a Gaussian at time `t` when its temporal weight there is at least
/// `min_weight` (`glsl/spacetime/positions_at_time.comp`, which writes NaN for `None`).
pub fn frame_position(p: &Temporal, t: f64, min_weight: f64) -> Option<[f64; 3]> {
    (temporal_weight(p, t) >= min_weight).then(|| instant(p, t).position)
}

/// The temporal parameters of Gaussian `i` of a model with SpacetimeGaussians' extra groups
/// (`motion`, `omega`, `trbf_center`, `trbf_scale`); `None` when the model lacks them.
pub fn temporal_of(p: &crate::splats::GaussianParams, i: usize) -> Option<Temporal> {
    let (m, w) = (p.extra_values("motion")?, p.extra_values("omega")?);
    let (c, s) = (
        p.extra_values("trbf_center")?,
        p.extra_values("trbf_scale")?,
    );
    let d = |v: f32| v as f64;
    Some(Temporal {
        position: p.positions[i].map(d),
        motion: std::array::from_fn(|k| d(m[9 * i + k])),
        rotation: p.rotations[i].map(d),
        omega: std::array::from_fn(|k| d(w[4 * i + k])),
        opacity_logit: d(p.opacity_logits[i]),
        t_center: d(c[i]),
        t_log_scale: d(s[i]),
    })
}

/// The still model a video model is at time `t` (no extra groups): what the temporal step
/// hands the projection. `None` when the model has no temporal groups.
pub fn still_at(
    p: &crate::splats::GaussianParams,
    t: f64,
) -> Option<crate::splats::GaussianParams> {
    let mut s = p.clone();
    s.extra.clear();
    for i in 0..p.len() {
        let x = instant(&temporal_of(p, i)?, t);
        s.positions[i] = x.position.map(|v| v as f32);
        s.rotations[i] = x.rotation.map(|v| v as f32);
        s.opacity_logits[i] = x.opacity_logit as f32;
    }
    Some(s)
}

/// SpacetimeGaussians' angular-velocity split (`train::passes::spacetime_settings::OmegaFreeze`'s thresholds):
/// whether a Gaussian keeps its angular velocity at the selection — it moves
/// (Σ|m₁| > `motion_above`), its largest scale lies strictly inside `scale_between`, and
/// σ(o) > `opacity_above` (`glsl/spacetime/omega_select.comp`).
pub fn omega_marked(
    p: &Temporal,
    log_scales: [f64; 3],
    motion_above: f64,
    scale_between: [f64; 2],
    opacity_above: f64,
) -> bool {
    let m1: f64 = p.motion[..3].iter().map(|v| v.abs()).sum();
    let s = log_scales
        .iter()
        .fold(f64::NEG_INFINITY, |a, &b| a.max(b))
        .exp();
    let opacity = 1.0 / (1.0 + (-p.opacity_logit).exp());
    m1 > motion_above && s > scale_between[0] && s < scale_between[1] && opacity > opacity_above
}
