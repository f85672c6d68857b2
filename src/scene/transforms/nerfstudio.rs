//! The nerfstudio / instant-ngp form: one `transforms.json` with shared intrinsics and
//! distortion that frames may override, and the split from its file lists.

use super::read_json;
use super::shared::{
    as_object, check_angle, file_path_of, file_stem, finish, frames_of, make_view, matrix_of,
    normalize, number, probe_image, resolve_image, sort_views,
};
use crate::error::bad_input;
use crate::scene::{split, CameraModel, LoadOptions, Pose, Scene, SceneFormat, View};
use rayon::prelude::*;
use serde_json::Value;
use std::collections::{HashMap, HashSet};
use std::path::Path;

/// Keys a frame may override; the rest of the frame is `file_path`, `transform_matrix` and
/// whatever else writers put there (ignored).
const DISTORTION_KEYS: [&str; 4] = ["k1", "k2", "p1", "p2"];

pub(super) fn load_nerfstudio(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
    let path = root.join("transforms.json");
    let json = read_json(&path)?;
    let top = as_object(&json, &path, "top level")?;
    let frames = frames_of(top, &path)?;

    let mut specs = Vec::with_capacity(frames.len());
    for (i, frame) in frames.iter().enumerate() {
        let f = as_object(frame, &path, &format!("frames[{i}]"))?;
        let file_path = file_path_of(f, &path, i)?;
        let m = matrix_of(f, &path, i)?;
        specs.push((i, f, file_path, m));
    }
    let probed = specs
        .par_iter()
        .map(|(i, _, file_path, _)| {
            let image_path = resolve_image(root, file_path, &path, *i)?;
            let dims = probe_image(&image_path, &path, *i)?;
            Ok((image_path, dims))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;

    let mut views = Vec::with_capacity(specs.len());
    let mut seen: HashMap<String, usize> = HashMap::new();
    for ((i, frame, file_path, m), (image_path, (w, h, alpha))) in specs.into_iter().zip(probed) {
        let model = frame_model(top, frame, &path, i, w, h, &image_path)?;
        let name = normalize(&file_path);
        if let Some(j) = seen.insert(name.clone(), i) {
            return bad_input(
                &path,
                format!("frames[{i}].file_path"),
                format!("\"{file_path}\" names the same image as frames[{j}]"),
                "remove the duplicate frame",
            );
        }
        let stem = file_stem(&file_path);
        views.push(make_view(
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

    let (views, _) = sort_views(views);
    let has_alpha = views.iter().any(|v| v.has_alpha);
    let views: Vec<View> = views.into_iter().map(|p| p.view).collect();
    let (train, test) = nerfstudio_split(root, top, &path, &views, opts)?;
    finish(
        root,
        SceneFormat::Nerfstudio,
        views,
        train,
        test,
        None,
        has_alpha,
    )
}

/// The lens model of frame `i` from its own keys, else the file's, in source pixels.
fn frame_model(
    top: &serde_json::Map<String, Value>,
    frame: &serde_json::Map<String, Value>,
    file: &Path,
    i: usize,
    w: u32,
    h: u32,
    image_path: &Path,
) -> anyhow::Result<CameraModel> {
    // A frame's own key wins; the field named in errors says which one was read.
    let lookup = |key: &str| -> anyhow::Result<Option<f64>> {
        if let Some(v) = number(frame, key, file, &format!("frames[{i}].{key}"))? {
            return Ok(Some(v));
        }
        number(top, key, file, key)
    };
    let where_is = |key: &str| {
        if frame.contains_key(key) {
            format!("frames[{i}].{key}")
        } else {
            key.to_string()
        }
    };

    for (key, size, axis) in [("w", w, "width"), ("h", h, "height")] {
        if let Some(declared) = lookup(key)? {
            if declared <= 0.0 {
                return bad_input(
                    file,
                    where_is(key),
                    format!("declares a zero-area image ({key} = {declared})"),
                    format!("set {key} to the image's {axis} in pixels"),
                );
            }
            if declared != size as f64 {
                return bad_input(
                    file,
                    where_is(key),
                    format!(
                        "declares {axis} {declared} but frames[{i}]'s image {} is {w}x{h}",
                        image_path.display()
                    ),
                    format!("set {key} to {size} (per frame if the images differ in size), or replace the image"),
                );
            }
        }
    }

    if let Some(name) = frame
        .get("camera_model")
        .or_else(|| top.get("camera_model"))
    {
        let field = where_is("camera_model");
        match name.as_str() {
            Some("OPENCV") | Some("PINHOLE") | Some("SIMPLE_PINHOLE") => {}
            _ => {
                return bad_input(
                    file,
                    field,
                    format!("camera model {name} is not supported (OPENCV, PINHOLE and SIMPLE_PINHOLE are)"),
                    "undistort the images to a pinhole model first (e.g. `ns-process-data` or COLMAP's image_undistorter)",
                )
            }
        }
    }
    if frame
        .get("is_fisheye")
        .or_else(|| top.get("is_fisheye"))
        .and_then(Value::as_bool)
        == Some(true)
    {
        return bad_input(
            file,
            where_is("is_fisheye"),
            "fisheye cameras are not supported",
            "undistort the images to a pinhole model first",
        );
    }
    for key in ["k3", "k4"] {
        if let Some(v) = lookup(key)? {
            if v != 0.0 {
                return bad_input(
                    file,
                    where_is(key),
                    format!("{key} = {v}: only the OpenCV model k1 k2 p1 p2 is supported"),
                    "undistort the images first, or refit the camera with k1 k2 p1 p2 only",
                );
            }
        }
    }

    let focal = |fl_key: &str, angle_key: &str, size: u32| -> anyhow::Result<Option<f64>> {
        // Per level, an explicit focal length beats a field of view.
        for (obj, prefix) in [(frame, format!("frames[{i}].")), (top, String::new())] {
            if let Some(f) = number(obj, fl_key, file, &format!("{prefix}{fl_key}"))? {
                if f <= 0.0 {
                    return bad_input(
                        file,
                        format!("{prefix}{fl_key}"),
                        format!("focal length {f} is not positive"),
                        "give the focal length in pixels",
                    );
                }
                return Ok(Some(f));
            }
            if let Some(a) = number(obj, angle_key, file, &format!("{prefix}{angle_key}"))? {
                check_angle(a, file, &format!("{prefix}{angle_key}"))?;
                return Ok(Some(0.5 * size as f64 / (0.5 * a).tan()));
            }
        }
        Ok(None)
    };
    let Some(fx) = focal("fl_x", "camera_angle_x", w)? else {
        return bad_input(
            file,
            format!("frames[{i}].fl_x"),
            "missing: neither the frame nor the top level has fl_x or camera_angle_x",
            "add \"fl_x\" (focal length in pixels) at the top level or to the frame",
        );
    };
    let fy = focal("fl_y", "camera_angle_y", h)?.unwrap_or(fx);
    let cx = lookup("cx")?.unwrap_or(0.5 * w as f64);
    let cy = lookup("cy")?.unwrap_or(0.5 * h as f64);
    let mut k = [0.0; 4];
    for (slot, key) in k.iter_mut().zip(DISTORTION_KEYS) {
        *slot = lookup(key)?.unwrap_or(0.0);
    }
    Ok(if k.iter().any(|&v| v != 0.0) {
        CameraModel::OpenCv {
            fx,
            fy,
            cx,
            cy,
            k1: k[0],
            k2: k[1],
            p1: k[2],
            p2: k[3],
        }
    } else {
        CameraModel::Pinhole { fx, fy, cx, cy }
    })
}

/// Train/test from `train_filenames` / `test_filenames` (or `val_filenames`) when present,
/// else every `holdout_every`-th view.
fn nerfstudio_split(
    root: &Path,
    top: &serde_json::Map<String, Value>,
    file: &Path,
    views: &[View],
    opts: &LoadOptions,
) -> anyhow::Result<(Vec<usize>, Vec<usize>)> {
    let train_list = filename_list(top, "train_filenames", file)?;
    let test_list = match filename_list(top, "test_filenames", file)? {
        Some(l) => Some(("test_filenames", l)),
        None => filename_list(top, "val_filenames", file)?.map(|l| ("val_filenames", l)),
    };
    if train_list.is_none() && test_list.is_none() {
        return Ok(split::holdout_split(
            views,
            opts.holdout_every,
            opts.eval_split,
        ));
    }

    // A list entry may be written like file_path or relative to the scene folder.
    let mut index_of: HashMap<String, usize> = HashMap::new();
    for (k, v) in views.iter().enumerate() {
        index_of.insert(v.name.clone(), k);
        if let Ok(rel) = v.image_path.strip_prefix(root) {
            index_of.insert(normalize(&rel.to_string_lossy()), k);
        }
    }
    let resolve = |key: &str, list: &[String]| -> anyhow::Result<Vec<usize>> {
        let mut out = Vec::with_capacity(list.len());
        let mut seen = HashSet::new();
        for (j, name) in list.iter().enumerate() {
            let Some(&k) = index_of.get(&normalize(name)) else {
                return bad_input(
                    file,
                    format!("{key}[{j}]"),
                    format!("\"{name}\" is not the file_path of any frame"),
                    "list file paths exactly as the frames give them, or remove the entry",
                );
            };
            if seen.insert(k) {
                out.push(k);
            }
        }
        Ok(out)
    };
    let train = train_list
        .as_deref()
        .map(|l| resolve("train_filenames", l))
        .transpose()?;
    let test = test_list
        .as_ref()
        .map(|(key, l)| resolve(key, l))
        .transpose()?;
    let rest = |taken: &[usize]| -> Vec<usize> {
        let taken: HashSet<usize> = taken.iter().copied().collect();
        (0..views.len()).filter(|k| !taken.contains(k)).collect()
    };
    let (mut train, mut test) = match (train, test) {
        (Some(tr), Some(te)) => (tr, te),
        (Some(tr), None) => {
            let te = rest(&tr);
            (tr, te)
        }
        (None, Some(te)) => (rest(&te), te),
        (None, None) => unreachable!("handled above"),
    };
    if let Some(k) = train.iter().find(|k| test.contains(k)) {
        return bad_input(
            file,
            "train_filenames / test_filenames",
            format!("\"{}\" is in both lists", views[*k].name),
            "list each image in one split only",
        );
    }
    if !opts.eval_split {
        train.append(&mut test);
    }
    train.sort_unstable();
    test.sort_unstable();
    Ok((train, test))
}

fn filename_list(
    top: &serde_json::Map<String, Value>,
    key: &str,
    file: &Path,
) -> anyhow::Result<Option<Vec<String>>> {
    let Some(v) = top.get(key) else {
        return Ok(None);
    };
    let Some(arr) = v.as_array() else {
        return bad_input(
            file,
            key,
            "is not a list of file names",
            format!("make \"{key}\" a list of strings"),
        );
    };
    arr.iter()
        .enumerate()
        .map(|(j, e)| match e.as_str() {
            Some(s) => Ok(s.to_string()),
            None => bad_input(
                file,
                format!("{key}[{j}]"),
                format!("{e} is not a string"),
                "list file paths as strings",
            ),
        })
        .collect::<anyhow::Result<Vec<_>>>()
        .map(Some)
}
