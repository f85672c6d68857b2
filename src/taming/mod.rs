//! Taming-3DGS's blended score (Mallick et al. 2024) as the ranking of the exact-budget ADC
//! (`train --strategy adc-exact --budget-score blend`): which Gaussians get the budget's room is
//! decided by how much each matters to a few sampled views — its coverage, blending weight,
//! the error and edges of the pixels it covers, its opacity, size and gradient — rather than by
//! the gradient statistic alone. [`score`] is the host maths, [`strategy`] the density
//! strategy; the per-Gaussian sums come from the renderer's contributions pass
//! (`glsl/render/contributions.comp`, checked against `crate::reference::raster::contributions`).

pub mod score;
pub mod strategy;

pub use strategy::{BlendConfig, BlendEvent, BlendedScore};
