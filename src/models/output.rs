//! A trained model as its PLY is written: in the user's frame (less the shift a far-off scene is
//! written relative to, [`crate::scene::frame`]), with its base model, the video segment it was
//! trained on and that shift in the header, which `render` and `eval` read back
//! ([`BaseModel::read_ply_for_scene`], [`BaseModel::recorded_in`]). `train` and the
//! `bench trade` harness ([`crate::bench::trade`]) both write their models this way.

use std::path::Path;

use super::BaseModel;
use crate::scene::video::Segment;
use crate::scene::{frame, Scene};
use crate::splats::{write_ply_with_comments, GaussianParams};

/// Writes `model`, a `base` model in `scene`'s training frame, to `path` as a PLY in the
/// user's frame (less the shift a far-off scene is written relative to, recorded in the
/// header; [`crate::scene::frame`]), recording the scene's segment when it is a video's.
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
