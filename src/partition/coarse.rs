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

use super::grid::Rect;
use super::ground::GroundFrame;
use super::plan::{Block, CoarseStart, Plan};
use crate::models::BaseModel;
use crate::scene::frame::shift_from_comments;
use crate::splats::GaussianParams;

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
        let (params, shift) = read_with_shift(path)?;
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

/// The model in `path` and the shift its header records.
fn read_with_shift(path: &Path) -> anyhow::Result<(GaussianParams, [f64; 3])> {
    let model = BaseModel::for_ply(None, path)?;
    let params = model.read_ply(path)?;
    let shift = shift_from_comments(path, &crate::splats::ply::ply_comments(path)?)?;
    Ok((params, shift))
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

/// Where a block's start lies, relative to the plan's folder.
pub fn block_start_path(block: &Block) -> PathBuf {
    block.folder.join(BLOCK_START_FILE)
}

/// Writes every block's start (`<block folder>/coarse.ply`: the rows of
/// [`CoarseModel::rows_for`], with the coarse file's header comments, so it is read in the
/// same frame as the same model) under the plan's folder `out`; each file holds as many
/// Gaussians as its block's `start_gaussians` in the plan.
pub fn write_block_starts(out: &Path, plan: &Plan, coarse: &CoarseModel) -> anyhow::Result<()> {
    let path = &coarse.start.ply;
    let model = BaseModel::for_ply(None, path)?;
    let params = model.read_ply(path)?;
    let comments = crate::splats::ply::ply_comments(path)?;
    for block in &plan.blocks {
        let rows = coarse.rows_for(&plan.ground, &block.region);
        anyhow::ensure!(
            Some(rows.len() as u64) == block.start_gaussians,
            "block {}: its start holds {} Gaussians, the plan counted {:?} (the coarse model \
             changed while partitioning?)",
            block.name,
            rows.len(),
            block.start_gaussians
        );
        crate::splats::write_ply_with_comments(
            &out.join(block_start_path(block)),
            &params.select_rows(&rows),
            &comments,
        )?;
    }
    Ok(())
}
