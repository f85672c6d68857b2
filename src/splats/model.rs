//! The Gaussian parameters as plain host arrays, in the units the optimiser works in.
//!
//! Activations are not applied here: scales are stored as logs, opacities as logits, rotations as
//! unnormalised quaternions, colours as spherical-harmonic coefficients. This is what the PLY file
//! holds and what the GPU buffers (built elsewhere) are filled from.

use anyhow::{anyhow, bail};

/// Zeroth-order real spherical-harmonic basis constant, 1 / (2 √π).
pub const SH_C0: f64 = 0.282_094_791_773_878_14;

/// The highest SH degree the engine supports (16 coefficients per channel).
pub const MAX_SH_DEGREE: u32 = 3;

/// Probabilities given to [`inverse_sigmoid`] are clamped to `[SIGMOID_EPS, 1 - SIGMOID_EPS]`.
pub const SIGMOID_EPS: f32 = 1e-6;

/// Number of SH coefficients per colour channel beyond the DC term for `degree`:
/// `(degree + 1)² − 1`, i.e. 0, 3, 8, 15 for degrees 0..3.
pub fn sh_rest_coeffs(degree: u32) -> usize {
    let n = degree as usize + 1;
    n * n - 1
}

/// Maps a colour in [0, 1] to the SH DC coefficient that renders it (the renderer adds 0.5).
pub fn rgb_to_sh_dc(rgb: f32) -> f32 {
    ((rgb as f64 - 0.5) / SH_C0) as f32
}

/// Inverse of [`rgb_to_sh_dc`]: the colour the DC term alone renders (not clamped).
pub fn sh_dc_to_rgb(dc: f32) -> f32 {
    (dc as f64 * SH_C0 + 0.5) as f32
}

/// Logistic function. Written so that large |x| saturate to 0 or 1 rather than producing NaN.
pub fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// Logit, `ln(p / (1 − p))`. `p` is clamped to `[SIGMOID_EPS, 1 − SIGMOID_EPS]` first so that
/// opacities of exactly 0 or 1 (or slightly outside, from rounding) give a finite logit of about
/// ±13.8 instead of ±inf; NaN stays NaN.
pub fn inverse_sigmoid(p: f32) -> f32 {
    let p = p.clamp(SIGMOID_EPS, 1.0 - SIGMOID_EPS) as f64;
    (p / (1.0 - p)).ln() as f32
}

/// One parameter of one Gaussian: which array, which component.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamField {
    /// `positions[i][axis]`
    Position(usize),
    /// `log_scales[i][axis]`
    LogScale(usize),
    /// `rotations[i][k]`, k = 0 is w.
    Rotation(usize),
    /// `opacity_logits[i]`
    Opacity,
    /// `sh_dc[i][channel]`
    ShDc(usize),
    /// Rest coefficient `coef` (0-based, excluding DC) of colour channel `channel`.
    ShRest { coef: usize, channel: usize },
    /// Float `index` of the model's extra group `group` (see [`ExtraGroup`]).
    Extra { group: usize, index: usize },
}

impl std::fmt::Display for ParamField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            ParamField::Position(a) => write!(f, "positions[{a}]"),
            ParamField::LogScale(a) => write!(f, "log_scales[{a}]"),
            ParamField::Rotation(k) => write!(f, "rotations[{k}]"),
            ParamField::Opacity => write!(f, "opacity_logits"),
            ParamField::ShDc(c) => write!(f, "sh_dc[{c}]"),
            ParamField::ShRest { coef, channel } => {
                write!(f, "sh_rest[coef {coef}][channel {channel}]")
            }
            ParamField::Extra { group, index } => write!(f, "extra group {group}[{index}]"),
        }
    }
}

/// A per-Gaussian parameter group a base model adds to the 3DGS ones (SpacetimeGaussians'
/// motion, angular velocity, temporal centre and scale): its name and floats per Gaussian. Every
/// path that moves Gaussians (density control, LPM, checkpoints, Adam) carries these groups
/// like the built-in ones, so a model with extra groups needs no change there.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ExtraGroup {
    pub name: String,
    pub stride: usize,
}

impl ExtraGroup {
    pub fn new(name: &str, stride: usize) -> Self {
        Self {
            name: name.to_string(),
            stride,
        }
    }
}

/// One extra group's values for every Gaussian (Gaussian `i` at `i * stride`).
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraValues {
    pub group: ExtraGroup,
    pub values: Vec<f32>,
}

/// The trainable parameters of a set of 3D Gaussians, one entry per Gaussian in every array.
///
/// `sh_rest` holds the higher-order SH coefficients of all Gaussians back to back; Gaussian `i`
/// owns `sh_rest[i * R * 3 .. (i + 1) * R * 3]` with `R = sh_rest_coeffs(sh_degree)`, laid out
/// coefficient-major: element `coef * 3 + channel`. (So each coefficient is an RGB triple, the
/// order the shaders read; the Inria PLY stores them channel-major, see `ply.rs`.)
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GaussianParams {
    /// 0..=3.
    pub sh_degree: u32,
    pub positions: Vec<[f32; 3]>,
    /// Natural log of the per-axis standard deviations.
    pub log_scales: Vec<[f32; 3]>,
    /// Quaternions (w, x, y, z); need not be normalised.
    pub rotations: Vec<[f32; 4]>,
    /// Opacity before the sigmoid.
    pub opacity_logits: Vec<f32>,
    /// SH DC coefficient per channel (R, G, B).
    pub sh_dc: Vec<[f32; 3]>,
    /// Higher-order SH coefficients, layout described on the struct.
    pub sh_rest: Vec<f32>,
    /// The model's extra groups (none for 3DGS, 2DGS, Pixel-GS, Mip-Splatting).
    pub extra: Vec<ExtraValues>,
}

impl GaussianParams {
    /// The Gaussians `rows` of the model, in that order, every array and extra group alike.
    pub fn select_rows(&self, rows: &[usize]) -> GaussianParams {
        let stride = self.rest_stride();
        let pick = |values: &[f32], s: usize| -> Vec<f32> {
            rows.iter()
                .flat_map(|&i| values[i * s..(i + 1) * s].iter().copied())
                .collect()
        };
        GaussianParams {
            sh_degree: self.sh_degree,
            positions: rows.iter().map(|&i| self.positions[i]).collect(),
            log_scales: rows.iter().map(|&i| self.log_scales[i]).collect(),
            rotations: rows.iter().map(|&i| self.rotations[i]).collect(),
            opacity_logits: rows.iter().map(|&i| self.opacity_logits[i]).collect(),
            sh_dc: rows.iter().map(|&i| self.sh_dc[i]).collect(),
            sh_rest: pick(&self.sh_rest, stride),
            extra: self
                .extra
                .iter()
                .map(|e| ExtraValues {
                    group: e.group.clone(),
                    values: pick(&e.values, e.group.stride),
                })
                .collect(),
        }
    }

    /// Maps the model through a change of frame `x ↦ k·x + b` (uniform `k > 0`, no rotation;
    /// [`crate::scene::frame`]), in f64: positions, log-scales (`+ ln k`; all three, or the
    /// first two when `keep_third_scale`, a surfel's unused axis) and the extra groups named
    /// in `length_groups` (`× k`: lengths, or lengths per unit time such as a motion
    /// polynomial's coefficients). Rotations, opacities, colours and the other groups have no
    /// length and stay.
    pub fn map_frame(
        &mut self,
        (k, b): (f64, [f64; 3]),
        length_groups: &[&str],
        keep_third_scale: bool,
    ) {
        if k == 1.0 && b == [0.0; 3] {
            return;
        }
        for p in &mut self.positions {
            *p = [0, 1, 2].map(|a| (p[a] as f64 * k + b[a]) as f32);
        }
        let ln_k = k.ln();
        let axes = if keep_third_scale { 2 } else { 3 };
        for l in &mut self.log_scales {
            for v in &mut l[..axes] {
                *v = (*v as f64 + ln_k) as f32;
            }
        }
        for e in &mut self.extra {
            if length_groups.contains(&e.group.name.as_str()) {
                for v in &mut e.values {
                    *v = (*v as f64 * k) as f32;
                }
            }
        }
    }

    /// The values of the extra group called `name` (every Gaussian's, row after row).
    pub fn extra_values(&self, name: &str) -> Option<&[f32]> {
        self.extra
            .iter()
            .find(|e| e.group.name == name)
            .map(|e| e.values.as_slice())
    }

    /// An empty model of the given SH degree.
    pub fn empty(sh_degree: u32) -> Self {
        Self {
            sh_degree,
            ..Default::default()
        }
    }

    /// Number of Gaussians (the length of `positions`).
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Rest coefficients per channel for this model's degree.
    pub fn rest_coeffs(&self) -> usize {
        sh_rest_coeffs(self.sh_degree)
    }

    /// Floats of `sh_rest` per Gaussian (`rest_coeffs() * 3`).
    pub fn rest_stride(&self) -> usize {
        self.rest_coeffs() * 3
    }

    /// The rest coefficients of Gaussian `i` (coefficient-major), or `None` if out of range.
    pub fn sh_rest_of(&self, i: usize) -> Option<&[f32]> {
        let s = self.rest_stride();
        self.sh_rest.get(i * s..(i + 1) * s)
    }

    /// Checks that the degree is supported, every array has one entry per Gaussian, and every
    /// value is finite. The error names the first offending Gaussian index and field.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.sh_degree > MAX_SH_DEGREE {
            bail!(
                "Gaussian model: sh_degree is {}, the engine supports 0..={MAX_SH_DEGREE}",
                self.sh_degree
            );
        }
        let n = self.len();
        let lens = [
            ("log_scales", self.log_scales.len(), n),
            ("rotations", self.rotations.len(), n),
            ("opacity_logits", self.opacity_logits.len(), n),
            ("sh_dc", self.sh_dc.len(), n),
            ("sh_rest", self.sh_rest.len(), n * self.rest_stride()),
        ];
        let extra = self
            .extra
            .iter()
            .map(|e| (e.group.name.as_str(), e.values.len(), n * e.group.stride));
        for (name, got, want) in lens.into_iter().chain(extra) {
            if got != want {
                bail!(
                    "Gaussian model: {name} has {got} entries, expected {want} for {n} Gaussians \
                     of SH degree {}",
                    self.sh_degree
                );
            }
        }
        if let Some((i, field)) = self.find_non_finite() {
            return Err(anyhow!(
                "Gaussian model: Gaussian {i}: {field} is not finite ({})",
                self.value(i, field)
            ));
        }
        Ok(())
    }

    /// The value of one field of Gaussian `i`. Panics if out of range: callers pass indices that
    /// come from this model.
    pub fn value(&self, i: usize, field: ParamField) -> f32 {
        match field {
            ParamField::Position(a) => self.positions[i][a],
            ParamField::LogScale(a) => self.log_scales[i][a],
            ParamField::Rotation(k) => self.rotations[i][k],
            ParamField::Opacity => self.opacity_logits[i],
            ParamField::ShDc(c) => self.sh_dc[i][c],
            ParamField::ShRest { coef, channel } => {
                self.sh_rest[i * self.rest_stride() + coef * 3 + channel]
            }
            ParamField::Extra { group, index } => {
                let e = &self.extra[group];
                e.values[i * e.group.stride + index]
            }
        }
    }

    /// The lowest-indexed Gaussian holding a NaN or infinite value, with the first such field
    /// (in the order positions, log_scales, rotations, opacity, sh_dc, sh_rest). Assumes the
    /// array lengths are consistent (checked by [`validate`](Self::validate) first).
    pub fn find_non_finite(&self) -> Option<(usize, ParamField)> {
        use rayon::prelude::*;
        let stride = self.rest_stride();
        let bad = |i: usize| -> Option<ParamField> {
            let p = &self.positions[i];
            if let Some(a) = p.iter().position(|v| !v.is_finite()) {
                return Some(ParamField::Position(a));
            }
            if let Some(a) = self.log_scales[i].iter().position(|v| !v.is_finite()) {
                return Some(ParamField::LogScale(a));
            }
            if let Some(k) = self.rotations[i].iter().position(|v| !v.is_finite()) {
                return Some(ParamField::Rotation(k));
            }
            if !self.opacity_logits[i].is_finite() {
                return Some(ParamField::Opacity);
            }
            if let Some(c) = self.sh_dc[i].iter().position(|v| !v.is_finite()) {
                return Some(ParamField::ShDc(c));
            }
            let rest = &self.sh_rest[i * stride..(i + 1) * stride];
            if let Some(j) = rest.iter().position(|v| !v.is_finite()) {
                return Some(ParamField::ShRest {
                    coef: j / 3,
                    channel: j % 3,
                });
            }
            self.extra.iter().enumerate().find_map(|(group, e)| {
                let s = e.group.stride;
                e.values[i * s..(i + 1) * s]
                    .iter()
                    .position(|v| !v.is_finite())
                    .map(|index| ParamField::Extra { group, index })
            })
        };
        let i = (0..self.len())
            .into_par_iter()
            .with_min_len(4096)
            .position_first(|i| bad(i).is_some())?;
        bad(i).map(|f| (i, f))
    }

    /// The same model at SH degree `degree`: higher coefficients are dropped, missing ones are
    /// zero. Fails for a degree above [`MAX_SH_DEGREE`].
    pub fn with_sh_degree(mut self, degree: u32) -> anyhow::Result<Self> {
        if degree > MAX_SH_DEGREE {
            bail!("SH degree {degree} requested; the engine supports 0..={MAX_SH_DEGREE}");
        }
        if degree == self.sh_degree {
            return Ok(self);
        }
        let old = self.rest_stride();
        let new = sh_rest_coeffs(degree) * 3;
        let n = self.len();
        if self.sh_rest.len() != n * old {
            bail!(
                "Gaussian model: sh_rest has {} entries, expected {} for {n} Gaussians of SH \
                 degree {}",
                self.sh_rest.len(),
                n * old,
                self.sh_degree
            );
        }
        // Coefficient-major layout: the first `min(old, new)` floats of each Gaussian are exactly
        // the coefficients both degrees share.
        let keep = old.min(new);
        let mut rest = vec![0.0f32; n * new];
        if keep > 0 {
            for (dst, src) in rest
                .chunks_exact_mut(new)
                .zip(self.sh_rest.chunks_exact(old))
            {
                dst[..keep].copy_from_slice(&src[..keep]);
            }
        }
        self.sh_rest = rest;
        self.sh_degree = degree;
        Ok(self)
    }
}
