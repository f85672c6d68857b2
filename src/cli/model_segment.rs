//! A video model and the frames it was trained on: the training writes its segment into the
//! PLY's header, and `render` and `eval` read it back, so that a model is drawn at the times it
//! was trained at whatever `--frames` asks for (a part of the segment, or by default all of it).

use std::path::Path;

use lpmsplat::models::BaseModel;
use lpmsplat::scene::video::Segment;
use lpmsplat::scene::{frame, Scene};
use lpmsplat::splats::{ply_comments, write_ply_with_comments, GaussianParams};

use super::SceneArgs;

/// Writes `model`, a `base` model in `scene`'s training frame, to `path` as a PLY in the
/// user's frame (less the shift a far-off scene is written relative to, recorded in the
/// header; [`lpmsplat::scene::frame`]), recording the scene's segment when it is a video's.
pub fn write_model_ply(
    path: &Path,
    model: &GaussianParams,
    base: BaseModel,
    scene: &Scene,
) -> anyhow::Result<()> {
    let (stored, shift) = in_output_frame(model, base, scene);
    write_stored_ply(path, &stored, shift, base, scene)
}

/// `model`, a `base` model in `scene`'s training frame, in the frame its outputs are written
/// in, and that frame's shift.
pub fn in_output_frame(
    model: &GaussianParams,
    base: BaseModel,
    scene: &Scene,
) -> (GaussianParams, [f64; 3]) {
    let shift = scene.frame.output_shift();
    let mut stored = model.clone();
    base.map_frame(&mut stored, scene.frame.train_to_stored(shift));
    (stored, shift)
}

/// Writes a `base` model already in its output frame ([`in_output_frame`]), with the model,
/// its shift and the scene's segment in the header.
pub fn write_stored_ply(
    path: &Path,
    stored: &GaussianParams,
    shift: [f64; 3],
    base: BaseModel,
    scene: &Scene,
) -> anyhow::Result<()> {
    let mut comments = vec![base.ply_comment()];
    comments.extend(scene.time_base.iter().map(Segment::comment));
    comments.extend(frame::shift_comment(shift));
    write_ply_with_comments(path, stored, &comments)
}

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
