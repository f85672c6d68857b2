//! What a training run needs before its first iteration: the output folder, the initial model;
//! and the messages that say how to resume a run that stopped.

use super::args::{InitSource, TrainArgs};
use anyhow::Context;
use lpmsplat::models::BaseModel;
use lpmsplat::scene::Scene;
use lpmsplat::splats::{self, read_ply, GaussianParams};
use lpmsplat::train::trainer::Trainer;
use std::path::Path;

/// Fewer triangulated points than this fall back to random points (with a message).
const MIN_TRIANGULATED: usize = 100;

/// Initial Gaussians of `model`: a PLY, the SfM points, points triangulated from the views
/// (`--init`), or random points in the cameras' bounds; then the model's own groups. A video
/// model's triangulated points are centred in time at their frame's time.
pub fn initial_model(
    model: BaseModel,
    scene: &Scene,
    init_ply: Option<&Path>,
    source: InitSource,
    init_points: usize,
    seed: u64,
    sh_degree: u32,
) -> anyhow::Result<GaussianParams> {
    let ignored = |by: &str| {
        // Only when asked for by name: `auto` falls back silently.
        if source == InitSource::Triangulate {
            eprintln!("--init triangulate: not used, the initial points come from {by}");
        }
    };
    if let Some(p) = init_ply {
        ignored(&format!("--init-ply {}", p.display()));
        // Another trainer's model, or one of ours, in the user's frame (less its shift).
        let mut init = read_ply(p)?;
        let shift = lpmsplat::scene::frame::shift_from_comments(p, &splats::ply_comments(p)?)?;
        init.map_frame(scene.frame.stored_to_train(shift), &[], false);
        return Ok(model.initialise(init, seed));
    }
    if let Some(points) = scene.points.as_ref().filter(|p| !p.is_empty()) {
        ignored("the scene's SfM points");
        return Ok(model.initialise(splats::init::from_sfm(points, sh_degree)?, seed));
    }
    if source.triangulates(scene) {
        let t0 = std::time::Instant::now();
        let tri = lpmsplat::triangulated_init::triangulate_scene(scene, init_points, seed)?;
        eprintln!(
            "initial points: {} triangulated from {} matches in {} view pairs ({:.1} s)",
            tri.positions.len(),
            tri.matches,
            tri.pairs,
            t0.elapsed().as_secs_f64()
        );
        if tri.positions.len() >= MIN_TRIANGULATED {
            let params = lpmsplat::triangulated_init::topped_up_model(
                &tri,
                scene,
                init_points,
                seed,
                sh_degree,
            )?;
            let params = model.initialise_at_times(params, seed, &tri.times);
            return Ok(params);
        }
        eprintln!(
            "initial points: fewer than {MIN_TRIANGULATED} triangulated; {init_points} random \
             points instead"
        );
    }
    let (center, half) = scene.random_init_box();
    let params = splats::init::random_init(init_points, center, [half; 3], seed, sh_degree)?;
    Ok(model.initialise(params, seed))
}

/// Creates `out` and proves it writable before any work is done.
pub fn prepare_output(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| {
        format!(
            "{}: cannot create the output folder. Fix: choose a writable --out",
            out.display()
        )
    })?;
    let probe = out.join(".lpmsplat-write-test");
    std::fs::write(&probe, b"ok").with_context(|| {
        format!(
            "{}: the output folder is not writable. Fix: choose a writable --out",
            out.display()
        )
    })?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

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
         --densify-grad-threshold or an earlier --densify-until)",
        checkpoint.display(),
        resume_hint_without(&checkpoint, "--memory-limit")
    )
}
