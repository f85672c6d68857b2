//! What a training run needs before its first iteration (the output folder) and the messages
//! that say how to resume a run that stopped. The initial model is `lpmsplat::initial`'s.

use super::args::TrainArgs;
use lpmsplat::scene::Scene;
use lpmsplat::train::trainer::Trainer;
use std::path::Path;

/// How to continue this run: its own command line with `--resume CHECKPOINT` (for messages).
pub(super) fn resume_hint(checkpoint: &Path) -> String {
    resume_hint_without(checkpoint, "--resume")
}

/// [`resume_hint`] without the valued flag `flag` as well.
fn resume_hint_without(checkpoint: &Path, flag: &str) -> String {
    let mut words = Vec::new();
    let mut args = std::env::args();
    while let Some(a) = args.next() {
        if a == "--resume" || a == flag {
            args.next();
        } else if !a.starts_with("--resume=") && !a.starts_with(&format!("{flag}=")) {
            words.push(a);
        }
    }
    words.push("--resume".into());
    words.push(checkpoint.display().to_string());
    words.join(" ")
}

/// The error of a run that ran out of device memory, after saving what can be resumed: the
/// checkpoint (the trainer's state, untouched by the allocation that failed) and, when it can
/// still be exported, the PLY.
pub(super) fn save_after_oom(
    trainer: &mut Trainer,
    scene: &Scene,
    args: &TrainArgs,
    oom: &lpmsplat::gpu::OutOfDeviceMemory,
) -> anyhow::Error {
    let checkpoint = args.out.join("checkpoint.bin");
    let (it, n) = (trainer.iteration, trainer.state.count());
    if let Err(e) = trainer.save_checkpoint(scene, &checkpoint) {
        return anyhow::anyhow!(
            "after iteration {it} ({n} Gaussians): {oom}; saving a checkpoint failed as well: \
             {e:#}. Fix: train with fewer Gaussians (a higher --densify-grad-threshold or an \
             earlier --densify-until) or on a device with more memory"
        );
    }
    let ply = args.out.join("point_cloud.ply");
    let ply_note = match trainer.export_model().and_then(|m| {
        let base = lpmsplat::models::BaseModel::of(&trainer.config);
        crate::cli::model_segment::write_model_ply(&ply, &m, base, scene)
    }) {
        Ok(()) => format!(" and {}", ply.display()),
        Err(e) => format!(" (the PLY could not be exported: {e:#})"),
    };
    anyhow::anyhow!(
        "after iteration {it} ({n} Gaussians): {oom}. Wrote {}{ply_note}: the model at \
         iteration {it}. Fix: continue on a device with more memory (or with a higher \
         --memory-limit MIB): {}; or train again with fewer Gaussians (a higher \
         --densify-grad-threshold or an earlier --densify-until, or --budget N), or as blocks \
         that each fit (lpmsplat partition SCENE --memory MIB, docs/partition.md)",
        checkpoint.display(),
        resume_hint_without(&checkpoint, "--memory-limit")
    )
}
