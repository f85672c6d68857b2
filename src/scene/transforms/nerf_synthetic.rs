//! The NeRF-synthetic form: `transforms_{train,val,test}.json`, one `camera_angle_x` each,
//! RGBA images composited on white.

use super::read_json;
use super::shared::{
    as_object, check_angle, file_path_of, file_stem, finish, frames_of, make_view, matrix_of,
    number, probe_image, resolve_image, sort_views, sorted_indices, ProbedView,
};
use crate::error::bad_input;
use crate::scene::{CameraModel, LoadOptions, NerfTestSplit, Pose, Scene, SceneFormat, View};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::Path;

pub(super) fn load_nerf_synthetic(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
    let mut views = Vec::new();
    // (split name, view indices before sorting)
    let mut by_split: HashMap<&str, Vec<usize>> = HashMap::new();
    for split_name in ["train", "val", "test"] {
        let path = root.join(format!("transforms_{split_name}.json"));
        if !path.exists() {
            continue;
        }
        let first = views.len();
        views.extend(read_nerf_synthetic_file(root, &path, split_name, opts)?);
        by_split.insert(split_name, (first..views.len()).collect());
    }

    let test_split = match opts.nerf_test_split {
        NerfTestSplit::TestOrVal if by_split.contains_key("test") => Some("test"),
        NerfTestSplit::TestOrVal if by_split.contains_key("val") => Some("val"),
        NerfTestSplit::TestOrVal => None,
        NerfTestSplit::Val => Some("val"),
        NerfTestSplit::Test => Some("test"),
    };
    if let Some(s) = test_split {
        if !by_split.contains_key(s) {
            return bad_input(
                root.join(format!("transforms_{s}.json")),
                "file",
                format!("the {s} split was asked for as the test set but this file does not exist"),
                "choose the split that exists (test or val), or add the file",
            );
        }
    }

    let mut train_old = by_split.get("train").cloned().unwrap_or_default();
    let mut test_old = test_split
        .and_then(|s| by_split.get(s).cloned())
        .unwrap_or_default();
    if !opts.eval_split {
        // As in the Inria reference: without evaluation the test views are trained on too.
        train_old.append(&mut test_old);
    }

    let (views, remap) = sort_views(views);
    let train: Vec<usize> = sorted_indices(&train_old, &remap);
    let test: Vec<usize> = sorted_indices(&test_old, &remap);
    let has_alpha = views.iter().any(|v| v.has_alpha);
    let views: Vec<View> = views.into_iter().map(|p| p.view).collect();
    finish(
        root,
        SceneFormat::NerfSynthetic,
        views,
        train,
        test,
        Some([1.0, 1.0, 1.0]),
        has_alpha,
    )
}

fn read_nerf_synthetic_file(
    root: &Path,
    path: &Path,
    split_name: &str,
    opts: &LoadOptions,
) -> anyhow::Result<Vec<ProbedView>> {
    let json = read_json(path)?;
    let top = as_object(&json, path, "top level")?;
    let angle = match number(top, "camera_angle_x", path, "camera_angle_x")? {
        Some(a) => a,
        None => {
            return bad_input(
                path,
                "camera_angle_x",
                "missing (the horizontal field of view in radians)",
                "add \"camera_angle_x\" to the file",
            )
        }
    };
    check_angle(angle, path, "camera_angle_x")?;
    let frames = frames_of(top, path)?;

    let mut specs = Vec::with_capacity(frames.len());
    for (i, frame) in frames.iter().enumerate() {
        let f = as_object(frame, path, &format!("frames[{i}]"))?;
        let file_path = file_path_of(f, path, i)?;
        let m = matrix_of(f, path, i)?;
        specs.push((i, file_path, m));
    }
    let probed = specs
        .par_iter()
        .map(|(i, file_path, _)| {
            let image_path = resolve_image(root, file_path, path, *i)?;
            let dims = probe_image(&image_path, path, *i)?;
            Ok((image_path, dims))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;

    let mut seen = HashMap::new();
    let mut out = Vec::with_capacity(specs.len());
    for ((i, file_path, m), (image_path, (w, h, alpha))) in specs.into_iter().zip(probed) {
        let stem = file_stem(&file_path);
        let name = format!("{split_name}/{stem}");
        if let Some(j) = seen.insert(name.clone(), i) {
            return bad_input(
                path,
                format!("frames[{i}].file_path"),
                format!("\"{file_path}\" names the same image as frames[{j}]"),
                "remove the duplicate frame",
            );
        }
        // Square pixels: the vertical focal length equals the horizontal one, as the Inria
        // reference derives it; camera_angle_y, where present, is redundant with it.
        let f = 0.5 * w as f64 / (0.5 * angle).tan();
        let model = CameraModel::Pinhole {
            fx: f,
            fy: f,
            cx: 0.5 * w as f64,
            cy: 0.5 * h as f64,
        };
        out.push(make_view(
            name,
            stem,
            image_path,
            model,
            w,
            h,
            Pose::from_opengl_camera_to_world(m),
            alpha,
            opts,
        ));
    }
    Ok(out)
}
