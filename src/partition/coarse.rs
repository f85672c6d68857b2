//! Each block's start from a coarse model of the whole scene (`partition --coarse PLY`): the
//! coarse Gaussians that stand in the block's region, which the block refines, and a share of
//! the others as its backdrop (`--coarse-backdrop`), the most opaque and largest first.
//!
//! Why a backdrop and why only a share: a block's views also see the rest of the scene, in
//! front of and behind its region; with the whole coarse model present the block learns its
//! region against it instead of explaining the other blocks' content with floaters (on Truck
//! 2×2 that closes a 3.3 dB gap, docs/partition.md). But the whole coarse model in every block
//! makes every block nearly as large as the whole scene. What occludes and frames a block's
//! pixels is mostly the backdrop's opaque, large Gaussians; the small ones fill in detail that
//! only the blocks that own it need. So each block keeps the rest ranked by opacity × surface
//! area (σ(o)·(s₀s₁ + s₀s₂ + s₁s₂), a Gaussian's footprint at a given distance, weighted by how
//! much it hides) and takes the top share.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::grid::Rect;
use super::ground::GroundFrame;
use crate::models::BaseModel;
use crate::scene::frame::shift_from_comments;
use crate::splats::GaussianParams;

/// A coarse model of the whole scene (a short `train` of it) that every block starts from,
/// as CityGaussian's prior: in each view a block then finds the rest of the scene already
/// there, in front of and behind its own region, and learns its region against it instead of
/// explaining the other blocks' content with Gaussians of its own (floaters the merge would
/// keep). A block starts from the coarse Gaussians in its region and the `backdrop` share of
/// the others (this module; written as `coarse.ply` in its folder), which adds to its
/// Gaussians; the merge keeps only what lies in each core. The block runs get `--init-ply` on
/// a fresh start only (a resumed run continues from its checkpoint).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CoarseStart {
    /// The model's PLY, absolute.
    pub ply: PathBuf,
    /// Its Gaussians.
    pub gaussians: u64,
    /// The share of its Gaussians outside a block's region that the block keeps (plans from
    /// before the share existed kept all of them).
    #[serde(default = "whole_backdrop")]
    pub backdrop: f64,
}

fn whole_backdrop() -> f64 {
    1.0
}

/// The name of a block's start in its folder.
pub const BLOCK_START_FILE: &str = "coarse.ply";

/// A coarse model as the plan needs it: where each Gaussian stands (the user's frame) and how
/// much of a view it can hide.
#[derive(Debug, Clone, PartialEq)]
pub struct CoarseModel {
    pub start: CoarseStart,
    /// Each Gaussian's centre in the user's frame (the file's positions plus its shift).
    pub positions: Vec<[f64; 3]>,
    /// Each Gaussian's rank score as a backdrop: σ(opacity) × its surface-area proxy.
    pub importance: Vec<f64>,
    /// The model as read (the rows the blocks' starts are cut from) and its header comments
    /// (its model and shift, which every start keeps).
    pub params: GaussianParams,
    pub comments: Vec<String>,
}

impl CoarseModel {
    /// Reads the coarse model at `path` (as the model its header records), keeping `backdrop`
    /// (in [0, 1]) of the Gaussians outside each block's region.
    pub fn read(path: &Path, backdrop: f64) -> anyhow::Result<CoarseModel> {
        anyhow::ensure!(
            (0.0..=1.0).contains(&backdrop),
            "--coarse-backdrop {backdrop}: the share of the coarse model outside a block's \
             region that the block keeps lies in [0, 1] (1: all of it, 0: none). Fix: pass a \
             share such as 0.25"
        );
        let model = BaseModel::for_ply(None, path)?;
        let params = model.read_ply(path)?;
        let comments = crate::splats::ply::ply_comments(path)?;
        let shift = shift_from_comments(path, &comments)?;
        let positions = params
            .positions
            .iter()
            .map(|p| [0, 1, 2].map(|k| p[k] as f64 + shift[k]))
            .collect();
        Ok(CoarseModel {
            start: CoarseStart {
                ply: std::path::absolute(path)?,
                gaussians: params.len() as u64,
                backdrop,
            },
            positions,
            importance: importance(&params),
            params,
            comments,
        })
    }

    /// The rows (ascending) a block with `region` starts from: every Gaussian whose centre the
    /// region holds, and the top `backdrop` share (rounded up) of the others by importance
    /// (ties by row, so the choice is reproducible).
    pub fn rows_for(&self, ground: &GroundFrame, region: &Rect) -> Vec<usize> {
        rows_for(
            &self.positions,
            &self.importance,
            self.start.backdrop,
            ground,
            region,
        )
    }
}

/// σ(opacity) × (s₀s₁ + s₀s₂ + s₁s₂) of every Gaussian.
pub fn importance(params: &GaussianParams) -> Vec<f64> {
    params
        .opacity_logits
        .iter()
        .zip(&params.log_scales)
        .map(|(&o, l)| {
            let s = l.map(|v| (v as f64).exp());
            let opacity = 1.0 / (1.0 + (-(o as f64)).exp());
            opacity * (s[0] * s[1] + s[0] * s[2] + s[1] * s[2])
        })
        .collect()
}

/// [`CoarseModel::rows_for`] on plain arrays.
pub fn rows_for(
    positions: &[[f64; 3]],
    importance: &[f64],
    backdrop: f64,
    ground: &GroundFrame,
    region: &Rect,
) -> Vec<usize> {
    let (mut inside, mut outside): (Vec<usize>, Vec<usize>) =
        (0..positions.len()).partition(|&i| region.contains(ground.coordinates(positions[i]).0));
    outside.sort_by(|&a, &b| importance[b].total_cmp(&importance[a]).then(a.cmp(&b)));
    let keep = (backdrop * outside.len() as f64).ceil() as usize;
    inside.extend_from_slice(&outside[..keep.min(outside.len())]);
    inside.sort_unstable();
    inside
}
