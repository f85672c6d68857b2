//! The compact `.splat` format web viewers load (antimatter15/splat and the viewers that
//! followed it): 32 bytes per Gaussian, no header, little-endian, SH degree 0.
//!
//! | bytes  | field                                                                 |
//! |--------|-----------------------------------------------------------------------|
//! | 0..12  | position x, y, z (`f32`)                                              |
//! | 12..24 | scale x, y, z: standard deviations, i.e. `exp(log_scale)` (`f32`)     |
//! | 24..28 | colour R, G, B, A (`u8`): `0.5 + C0·f_dc` and `sigmoid(opacity)`, ×255  |
//! | 28..32 | rotation w, x, y, z (`u8`): the unit quaternion as `q·128 + 128`        |
//!
//! Rows are sorted by decreasing `exp(Σ log_scale) · sigmoid(opacity)` (the large, opaque
//! Gaussians first), as those viewers' converters do, so a viewer that streams the file shows
//! the bulk of the scene before the details. View-dependent colour (the `f_rest` coefficients)
//! is dropped: the format has no room for it.

use std::io::Write;
use std::path::Path;

use anyhow::Context;

use super::model::{GaussianParams, SH_C0};
use crate::error::write_atomic;

/// Bytes per Gaussian.
pub const SPLAT_ROW_BYTES: usize = 32;

/// One Gaussian as a `.splat` row. The arithmetic is done in f64 and bytes are rounded half to
/// even after clamping, as the viewers' own PLY converters do in JavaScript (`Uint8ClampedArray`
/// stores), so converting our PLY in a viewer and loading our `.splat` give the same bytes.
pub fn encode_splat_row(params: &GaussianParams, i: usize) -> [u8; SPLAT_ROW_BYTES] {
    let mut row = [0u8; SPLAT_ROW_BYTES];
    let mut k = 0;
    let mut put = |v: f32| {
        row[k..k + 4].copy_from_slice(&v.to_le_bytes());
        k += 4;
    };
    params.positions[i].iter().for_each(|&v| put(v));
    params.log_scales[i]
        .iter()
        .for_each(|&v| put(f64::from(v).exp() as f32));
    for c in 0..3 {
        row[24 + c] = clamped_byte((0.5 + SH_C0 * f64::from(params.sh_dc[i][c])) * 255.0);
    }
    row[27] = clamped_byte(sigmoid(f64::from(params.opacity_logits[i])) * 255.0);
    let q = params.rotations[i].map(f64::from);
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    for (c, v) in q.iter().enumerate() {
        // A zero quaternion (never produced by training) encodes as the identity.
        let unit = if norm > 0.0 {
            v / norm
        } else if c == 0 {
            1.0
        } else {
            0.0
        };
        row[28 + c] = clamped_byte(unit * 128.0 + 128.0);
    }
    row
}

/// JavaScript's `ToUint8Clamp`: NaN → 0, clamp to [0, 255], round half to even.
fn clamped_byte(v: f64) -> u8 {
    if v.is_nan() {
        0
    } else {
        v.clamp(0.0, 255.0).round_ties_even() as u8
    }
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// The row order of a `.splat` file: decreasing `exp(Σ log_scale) / (1 + exp(−opacity))`
/// (computed in f64 like the viewers' converters), ties by index (a stable sort, as theirs).
pub fn splat_order(params: &GaussianParams) -> Vec<usize> {
    let key: Vec<f64> = (0..params.len())
        .map(|i| {
            let s = params.log_scales[i].map(f64::from);
            (s[0] + s[1] + s[2]).exp() / (1.0 + (-f64::from(params.opacity_logits[i])).exp())
        })
        .collect();
    let mut order: Vec<usize> = (0..params.len()).collect();
    order.sort_by(|&a, &b| key[b].total_cmp(&key[a]));
    order
}

/// Writes `params` as a `.splat` file, atomically (an existing file is left untouched on
/// failure).
pub fn write_splat(path: &Path, params: &GaussianParams) -> anyhow::Result<()> {
    params
        .validate()
        .with_context(|| format!("{}: refusing to write an invalid model", path.display()))?;
    let order = splat_order(params);
    write_atomic(path, |file| {
        let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
        for &i in &order {
            out.write_all(&encode_splat_row(params, i))?;
        }
        out.flush()?;
        Ok(())
    })
    .with_context(|| format!("{}: writing the .splat file failed", path.display()))
}
