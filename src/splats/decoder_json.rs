//! The full SpacetimeGaussians model's decoder weights beside its PLY: `NAME.decoder.json` for
//! `NAME.ply` (`point_cloud.decoder.json` from `train`, `adc+lpm.decoder.json` from
//! `bench trade`). `w1` is 6 rows of 12, `w2` 3 rows of 6 ([`crate::reference::decoder`]).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// The decoder's shape. Inputs: specular feature 3, time feature 3, ray origin 3, ray
/// direction 3.
pub const INPUTS: usize = 12;
pub const HIDDEN: usize = 6;
pub const OUTPUTS: usize = 3;
/// `W₁` (HIDDEN × INPUTS) then `W₂` (OUTPUTS × HIDDEN).
pub const WEIGHTS: usize = HIDDEN * INPUTS + OUTPUTS * HIDDEN;
/// Feature channels per Gaussian besides the base colour (`f_spec`, `Δ·f_t`).
pub const FEATURE_CHANNELS: usize = 6;

/// The decoder file that goes with `ply`.
pub fn path_for(ply: &Path) -> PathBuf {
    ply.with_extension("decoder.json")
}

/// The weights (`W₁` row-major, then `W₂`) as the file's JSON.
pub fn to_json(weights: &[f32]) -> Result<String> {
    anyhow::ensure!(
        weights.len() == WEIGHTS,
        "decoder: {} weights, not {WEIGHTS}",
        weights.len()
    );
    let (w1, w2) = weights.split_at(HIDDEN * INPUTS);
    let rows =
        |m: &[f32], cols: usize| -> Vec<Vec<f32>> { m.chunks(cols).map(|r| r.to_vec()).collect() };
    let doc = serde_json::json!({
        "model": "spacetime-full",
        "inputs": ["f_spec_0", "f_spec_1", "f_spec_2", "f_t_0·dt", "f_t_1·dt", "f_t_2·dt",
                   "camera_x", "camera_y", "camera_z", "ray_x", "ray_y", "ray_z"],
        "rgb": "sigmoid(base + w2 · relu(w1 · inputs)); base = the blended f_dc_0..2, dt = t − trbf_center, ray = unit world direction through the pixel centre",
        "w1": rows(w1, INPUTS),
        "w2": rows(w2, HIDDEN),
    });
    Ok(serde_json::to_string_pretty(&doc)?)
}

/// Reads the decoder file that goes with `ply`, naming the file and the field on bad input.
pub fn read_for(ply: &Path) -> Result<Vec<f32>> {
    let path = path_for(ply);
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!(
            "{}: cannot read the decoder of the full model {}. Fix: keep the .decoder.json \
             that training wrote beside the PLY",
            path.display(),
            ply.display()
        )
    })?;
    let doc: serde_json::Value = serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: not JSON. Fix: restore the file training wrote",
            path.display()
        )
    })?;
    let matrix = |key: &str, rows: usize, cols: usize| -> Result<Vec<f32>> {
        let m: Vec<Vec<f32>> = doc
            .get(key)
            .and_then(|v| serde_json::from_value(v.clone()).ok())
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: field '{key}' missing or not a matrix of numbers. Fix: restore the \
                     file training wrote",
                    path.display()
                )
            })?;
        anyhow::ensure!(
            m.len() == rows
                && m.iter()
                    .all(|r| r.len() == cols && r.iter().all(|v| v.is_finite())),
            "{}: field '{key}' must be {rows} rows of {cols} finite numbers. Fix: restore the \
             file training wrote",
            path.display()
        );
        Ok(m.concat())
    };
    let mut w = matrix("w1", HIDDEN, INPUTS)?;
    w.extend(matrix("w2", OUTPUTS, HIDDEN)?);
    Ok(w)
}
