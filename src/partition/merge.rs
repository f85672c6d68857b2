//! One model from the blocks: each block's Gaussians cropped to its core (a Gaussian belongs
//! to the block whose core holds its centre; the margins only supervised the core's edges),
//! concatenated, and written like a trained model (PLY with its model and shift comments, and
//! a `.splat` for still models), with a report.
//!
//! A block whose run has not finished (no `metrics.json`, which `train` writes last) or whose
//! model cannot be read is refused by name: a merged model missing a block would render a hole
//! where the block stands, with nothing to say so.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::plan::Plan;
use crate::error::bad_input;
use crate::models::BaseModel;
use crate::scene::frame::{shift_comment, shift_from_comments, SHIFT_COMMENT};
use crate::splats::GaussianParams;

/// The files a block's finished run holds, under `runs/<block name>/`.
pub const BLOCK_MODEL: &str = "point_cloud.ply";
pub const BLOCK_DONE: &str = "metrics.json";

/// One block's line of the report.
#[derive(Debug, Clone, Serialize)]
pub struct BlockReport {
    pub name: String,
    pub run: PathBuf,
    /// Gaussians the block trained.
    pub gaussians: usize,
    /// Of those, the ones whose centre lies in its core.
    pub kept: usize,
    /// The block's own test scores on the test views that see it (its `metrics.json`).
    pub test_psnr: Option<f64>,
    pub test_ssim: Option<f64>,
    pub train_seconds: Option<f64>,
    pub device_buffers_peak_mib: Option<f64>,
}

/// What `merge` did.
#[derive(Debug, Clone, Serialize)]
pub struct MergeReport {
    pub model: String,
    pub gaussians: usize,
    pub shift: [f64; 3],
    pub blocks: Vec<BlockReport>,
}

/// The merged model as stored (positions less `shift`), the model it is, the header comments
/// it inherits from the blocks (a video model's segment), and the report.
pub struct Merged {
    pub params: GaussianParams,
    pub base: BaseModel,
    pub shift: [f64; 3],
    pub comments: Vec<String>,
    pub report: MergeReport,
}

/// The run folder of each block under `runs`.
pub fn run_folder(runs: &Path, block: &str) -> PathBuf {
    runs.join(block)
}

/// Merges the blocks of `plan` whose runs live under `runs`.
pub fn merge(plan: &Plan, runs: &Path) -> anyhow::Result<Merged> {
    let shift = plan.frame().output_shift();
    let mut merged: Option<GaussianParams> = None;
    let mut base: Option<(BaseModel, String)> = None;
    let mut inherited: Option<(Vec<String>, String)> = None;
    let mut reports = Vec::new();
    for block in &plan.blocks {
        let dir = run_folder(runs, &block.name);
        let done = dir.join(BLOCK_DONE);
        let ply = dir.join(BLOCK_MODEL);
        if !done.is_file() || !ply.is_file() {
            let missing = if ply.is_file() { &done } else { &ply };
            return bad_input(
                missing,
                format!("block {}", block.name),
                "is missing: the block's training has not finished (or failed)",
                format!(
                    "train it (its task in the Slurm array, or `lpmsplat train {} -o {} …`), \
                     then merge again",
                    block.folder.display(),
                    dir.display()
                ),
            );
        }
        let metrics: serde_json::Value = match std::fs::read_to_string(&done)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
        {
            Some(m) => m,
            None => {
                return bad_input(
                    &done,
                    format!("block {}", block.name),
                    "metrics.json is not JSON: the run was cut off while writing it",
                    "train the block again (its task resumes from its checkpoint)",
                )
            }
        };
        let model = BaseModel::for_ply(None, &ply)?;
        if model == BaseModel::SpacetimeFull {
            return bad_input(
                &ply,
                format!("block {}", block.name),
                "holds a spacetime-full model: each block's colour decoder is its own network, \
                 and one merged model has room for one",
                "train the blocks as spacetime-lite (or a still model) to merge them",
            );
        }
        match &base {
            Some((m, first)) if *m != model => {
                return bad_input(
                    &ply,
                    format!("block {}", block.name),
                    format!(
                        "holds a {} model, block {first} a {} one",
                        model.name(),
                        m.name()
                    ),
                    "train every block as the same model",
                )
            }
            None => base = Some((model, block.name.clone())),
            _ => {}
        }
        let all_comments = crate::splats::ply::ply_comments(&ply)?;
        let own_shift = shift_from_comments(&ply, &all_comments)?;
        let model_comment = format!("{} ", BaseModel::PLY_COMMENT);
        let kept_comments: Vec<String> = all_comments
            .into_iter()
            .filter(|c| !c.starts_with(SHIFT_COMMENT) && !c.starts_with(&model_comment))
            .collect();
        match &inherited {
            Some((c, first)) if *c != kept_comments => {
                return bad_input(
                    &ply,
                    format!("block {} header comments", block.name),
                    format!("{kept_comments:?} differ from block {first}'s {c:?}"),
                    "train every block on the same frames and settings",
                )
            }
            None => inherited = Some((kept_comments, block.name.clone())),
            _ => {}
        }
        let params = model
            .read_ply(&ply)
            .map_err(|e| e.context(format!("block {}: its model cannot be read", block.name)))?;
        let keep: Vec<usize> = (0..params.len())
            .filter(|&i| {
                let p = params.positions[i];
                let user = [0, 1, 2].map(|k| p[k] as f64 + own_shift[k]);
                block.core.contains(plan.ground.coordinates(user).0)
            })
            .collect();
        let mut part = params.select_rows(&keep);
        // Stored again relative to the merged model's shift, in f64.
        for (p, &i) in part.positions.iter_mut().zip(&keep) {
            let q = params.positions[i];
            *p = [0, 1, 2].map(|k| ((q[k] as f64 + own_shift[k]) - shift[k]) as f32);
        }
        let number = |k: &str| metrics[k].as_f64();
        reports.push(BlockReport {
            name: block.name.clone(),
            run: dir.clone(),
            gaussians: params.len(),
            kept: keep.len(),
            test_psnr: number("psnr"),
            test_ssim: number("ssim"),
            train_seconds: number("train_seconds"),
            device_buffers_peak_mib: number("device_buffers_peak_mib"),
        });
        merged = Some(match merged {
            None => part,
            Some(m) => concat(m, part).map_err(|e| {
                e.context(format!(
                    "block {}: cannot join the blocks before it",
                    block.name
                ))
            })?,
        });
    }
    let params = merged.expect("a plan has at least one block");
    let (base, _) = base.expect("a plan has at least one block");
    anyhow::ensure!(
        !params.is_empty(),
        "the blocks' cores hold no Gaussian: every block's Gaussians lie outside its own core \
         (the runs are not this plan's?)"
    );
    let mut comments = vec![base.ply_comment()];
    comments.extend(inherited.map(|(c, _)| c).unwrap_or_default());
    comments.extend(shift_comment(shift));
    Ok(Merged {
        report: MergeReport {
            model: base.name().into(),
            gaussians: params.len(),
            shift,
            blocks: reports,
        },
        params,
        base,
        shift,
        comments,
    })
}

/// `a` followed by `b`: same SH degree and extra groups, or an error saying which differs.
pub fn concat(mut a: GaussianParams, b: GaussianParams) -> anyhow::Result<GaussianParams> {
    anyhow::ensure!(
        a.sh_degree == b.sh_degree,
        "SH degree {} against {}",
        b.sh_degree,
        a.sh_degree
    );
    let groups = |p: &GaussianParams| {
        p.extra
            .iter()
            .map(|e| (e.group.name.clone(), e.group.stride))
            .collect::<Vec<_>>()
    };
    anyhow::ensure!(
        groups(&a) == groups(&b),
        "extra groups {:?} against {:?}",
        groups(&b),
        groups(&a)
    );
    a.positions.extend(b.positions);
    a.log_scales.extend(b.log_scales);
    a.rotations.extend(b.rotations);
    a.opacity_logits.extend(b.opacity_logits);
    a.sh_dc.extend(b.sh_dc);
    a.sh_rest.extend(b.sh_rest);
    for (x, y) in a.extra.iter_mut().zip(b.extra) {
        x.values.extend(y.values);
    }
    Ok(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model(n: usize, degree: u32, offset: f32) -> GaussianParams {
        let r = crate::splats::model::sh_rest_coeffs(degree) * 3;
        GaussianParams {
            sh_degree: degree,
            positions: (0..n).map(|i| [i as f32 + offset, 0.0, 0.0]).collect(),
            log_scales: vec![[-2.0; 3]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: (0..n).map(|i| i as f32).collect(),
            sh_dc: vec![[0.1, 0.2, 0.3]; n],
            sh_rest: (0..n * r).map(|i| i as f32).collect(),
            extra: vec![],
        }
    }

    #[test]
    fn select_then_concat_keeps_every_row_whole() {
        let a = model(5, 2, 0.0);
        let b = model(4, 2, 100.0);
        let s = a.select_rows(&[4, 1]);
        let stride = a.rest_stride();
        assert_eq!(s.positions, vec![[4.0, 0.0, 0.0], [1.0, 0.0, 0.0]]);
        assert_eq!(&s.sh_rest[..stride], &a.sh_rest[4 * stride..5 * stride]);
        let c = concat(s, b.clone()).unwrap();
        assert_eq!(c.len(), 6);
        c.validate().unwrap();
        assert_eq!(&c.sh_rest[2 * stride..], &b.sh_rest[..]);
        assert!(concat(model(1, 1, 0.0), model(1, 2, 0.0)).is_err());
    }
}
