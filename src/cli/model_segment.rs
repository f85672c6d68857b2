//! A video model and the frames it was trained on: the training writes its segment into the
//! PLY's header ([`lpmsplat::models::output`], re-exported here for the commands that write
//! models), and `render` and `eval` read it back, so that a model is drawn at the times it was
//! trained at whatever `--frames` asks for (a part of the segment, or by default all of it).

use std::path::Path;

use lpmsplat::scene::video::Segment;
use lpmsplat::scene::Scene;
use lpmsplat::splats::ply_comments;

use super::SceneArgs;

pub use lpmsplat::models::output::{in_output_frame, write_model_ply, write_stored_ply};

/// Loads the scene of `args` for the model in `ply`: when the PLY records the segment it was
/// trained on, that segment is loaded unless `--frames` names another (which must lie inside
/// it), and every frame gets the time it had in training.
pub fn load_scene_for_model(args: &SceneArgs, ply: &Path) -> anyhow::Result<Scene> {
    let mut opts = args.load_options()?;
    // A file that cannot be read is reported by the model's reader with its own message.
    let comments = ply_comments(ply).unwrap_or_default();
    if let Some(trained) = Segment::from_comments(ply, &comments)? {
        if args.frames.is_none() {
            opts.frames = trained.range();
        }
        opts.time_base = Some(trained);
    }
    Scene::load(&args.scene, &opts)
}
