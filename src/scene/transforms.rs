//! transforms.json scenes, in the two forms found in the wild:
//!
//! - **NeRF-synthetic**: `transforms_train.json`, `transforms_val.json`, `transforms_test.json`,
//!   each with one `camera_angle_x` and frames `{file_path, transform_matrix}`; `file_path` usually
//!   has no extension (`.png` is meant), images are RGBA and composited on white by convention.
//! - **nerfstudio / instant-ngp**: one `transforms.json` with `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`
//!   and optional OpenCV distortion `k1 k2 p1 p2`, any of which a frame may override; the split
//!   comes from `train_filenames` / `test_filenames` when present.
//!
//! In both, `transform_matrix` is camera-to-world with OpenGL camera axes (x right, y up, looking
//! down −z); it is converted to the engine's world-to-camera OpenCV pose here.
//!
//! Not read: `ply_file_path` (nerfstudio's optional SfM point cloud); such scenes start from
//! random points like NeRF-synthetic ones.

use super::{
    split, target_size, CameraModel, LoadOptions, NerfTestSplit, PinholeCamera, Pose, Scene,
    SceneFormat, View,
};
use crate::error::{bad_input, InputError};
use anyhow::Context;
use rayon::prelude::*;
use serde_json::Value;
use std::collections::{HashMap, HashSet};
use std::path::{Component, Path, PathBuf};

/// Loads a transforms.json scene from `root`: the NeRF-synthetic form when
/// `transforms_train.json` exists, else the single-file nerfstudio form.
pub fn load_scene(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
    if root.join("transforms_train.json").exists() {
        load_nerf_synthetic(root, opts)
    } else if root.join("transforms.json").exists() {
        load_nerfstudio(root, opts)
    } else {
        bad_input(
            root,
            "transforms*.json",
            "neither transforms_train.json nor transforms.json is in this folder",
            "point at the folder that holds the transforms file(s)",
        )
    }
}

/// Reads and parses a JSON file; a syntax error names its line and column. Bare `NaN` and
/// `Infinity` (which Python's json module writes) are read as the strings "NaN" / "Infinity" so
/// that the field holding them can be named in the error.
pub fn read_json(path: &Path) -> anyhow::Result<Value> {
    let text = std::fs::read_to_string(path).with_context(|| {
        format!(
            "{}: cannot read the file (does it exist and is it UTF-8 text?)",
            path.display()
        )
    })?;
    serde_json::from_str(&text).or_else(|e| {
        if let Ok(v) = serde_json::from_str(&quote_non_finite(&text)) {
            return Ok(v);
        }
        Err(InputError::new(
            path,
            format!("line {}, column {}", e.line(), e.column()),
            format!("malformed JSON ({e})"),
            "fix the JSON syntax at that place (a validator such as `python3 -m json.tool` shows it too)",
        )
        .into())
    })
}

/// Puts quotes around bare `NaN`, `Infinity` and `-Infinity` outside strings.
fn quote_non_finite(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 16);
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if in_string {
            if escaped {
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == '"' {
                in_string = false;
            }
        } else if c == '"' {
            in_string = true;
        } else if let Some(tok) = ["NaN", "Infinity", "-Infinity"]
            .into_iter()
            .find(|t| rest.starts_with(t))
        {
            out.push('"');
            out.push_str(tok);
            out.push('"');
            rest = &rest[tok.len()..];
            continue;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    out
}

// ---------------------------------------------------------------------------------------------
// NeRF-synthetic

fn load_nerf_synthetic(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
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

// ---------------------------------------------------------------------------------------------
// nerfstudio / instant-ngp

/// Keys a frame may override; the rest of the frame is `file_path`, `transform_matrix` and
/// whatever else writers put there (ignored).
const DISTORTION_KEYS: [&str; 4] = ["k1", "k2", "p1", "p2"];

fn load_nerfstudio(root: &Path, opts: &LoadOptions) -> anyhow::Result<Scene> {
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

// ---------------------------------------------------------------------------------------------
// Shared pieces

/// A view plus whether its image has an alpha channel (known from the header probe).
struct ProbedView {
    view: View,
    has_alpha: bool,
}

impl std::ops::Deref for ProbedView {
    type Target = View;
    fn deref(&self) -> &View {
        &self.view
    }
}

#[allow(clippy::too_many_arguments)]
fn make_view(
    name: String,
    stem: String,
    image_path: PathBuf,
    model: CameraModel,
    w: u32,
    h: u32,
    pose: Pose,
    has_alpha: bool,
    opts: &LoadOptions,
) -> ProbedView {
    let (fx, fy, cx, cy) = model.pinhole_part();
    let (tw, th) = target_size(w, h, opts);
    let camera = PinholeCamera {
        fx,
        fy,
        cx,
        cy,
        width: w,
        height: h,
    }
    .resized(tw, th);
    ProbedView {
        view: View {
            name,
            stem,
            image_path,
            source_model: model,
            source_width: w,
            source_height: h,
            camera,
            pose,
            colmap_image_id: None,
            keypoints: None,
        },
        has_alpha,
    }
}

/// Sorts views by name; `remap[old] = new`.
fn sort_views(views: Vec<ProbedView>) -> (Vec<ProbedView>, Vec<usize>) {
    let mut order: Vec<usize> = (0..views.len()).collect();
    order.sort_by(|&a, &b| views[a].name.cmp(&views[b].name));
    let mut remap = vec![0; views.len()];
    for (new, &old) in order.iter().enumerate() {
        remap[old] = new;
    }
    let mut slots: Vec<Option<ProbedView>> = views.into_iter().map(Some).collect();
    let sorted = order
        .iter()
        .map(|&old| slots[old].take().expect("each index once"))
        .collect();
    (sorted, remap)
}

fn sorted_indices(old: &[usize], remap: &[usize]) -> Vec<usize> {
    let mut v: Vec<usize> = old.iter().map(|&o| remap[o]).collect();
    v.sort_unstable();
    v
}

fn finish(
    root: &Path,
    format: SceneFormat,
    views: Vec<View>,
    train: Vec<usize>,
    test: Vec<usize>,
    background: Option<[f32; 3]>,
    has_alpha: bool,
) -> anyhow::Result<Scene> {
    if train.is_empty() {
        return bad_input(
            root,
            "train split",
            "has no views",
            "list at least one training image (train_filenames, or transforms_train.json frames)",
        );
    }
    let (center, extent) = split::camera_extent(&views, &train);
    Ok(Scene {
        root: root.to_path_buf(),
        format,
        views,
        train,
        test,
        points: None,
        center,
        extent,
        background,
        has_alpha,
        view_times: None,
    })
}

fn as_object<'a>(
    v: &'a Value,
    file: &Path,
    field: &str,
) -> anyhow::Result<&'a serde_json::Map<String, Value>> {
    match v.as_object() {
        Some(o) => Ok(o),
        None => bad_input(
            file,
            field,
            format!("is {} where an object {{...}} was expected", kind(v)),
            "make it a JSON object",
        ),
    }
}

fn frames_of<'a>(
    top: &'a serde_json::Map<String, Value>,
    file: &Path,
) -> anyhow::Result<&'a Vec<Value>> {
    match top.get("frames") {
        None => bad_input(
            file,
            "frames",
            "missing",
            "add a \"frames\" list with one entry per image",
        ),
        Some(Value::Array(a)) if a.is_empty() => bad_input(
            file,
            "frames",
            "is empty: the scene has no images",
            "add one entry per image",
        ),
        Some(Value::Array(a)) => Ok(a),
        Some(v) => bad_input(
            file,
            "frames",
            format!("is {} where a list was expected", kind(v)),
            "make \"frames\" a list",
        ),
    }
}

/// A finite number under `key`, or `None` when absent (or JSON null).
fn number(
    obj: &serde_json::Map<String, Value>,
    key: &str,
    file: &Path,
    field: &str,
) -> anyhow::Result<Option<f64>> {
    match obj.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(v) => match v.as_f64() {
            Some(x) if x.is_finite() => Ok(Some(x)),
            _ => bad_input(
                file,
                field,
                format!("{v} is not a finite number"),
                format!("give \"{key}\" as a number"),
            ),
        },
    }
}

fn check_angle(a: f64, file: &Path, field: &str) -> anyhow::Result<()> {
    if a > 0.0 && a < std::f64::consts::PI {
        Ok(())
    } else {
        bad_input(
            file,
            field,
            format!("field of view {a} is not in (0, π) radians"),
            "give the full field of view in radians",
        )
    }
}

fn file_path_of(
    frame: &serde_json::Map<String, Value>,
    file: &Path,
    i: usize,
) -> anyhow::Result<String> {
    match frame.get("file_path") {
        Some(Value::String(s)) if !s.is_empty() => Ok(s.clone()),
        None => bad_input(
            file,
            format!("frames[{i}].file_path"),
            "missing",
            "add the image's path relative to the scene folder",
        ),
        Some(v) => bad_input(
            file,
            format!("frames[{i}].file_path"),
            format!("{v} is not a file path"),
            "give the image's path relative to the scene folder as a string",
        ),
    }
}

fn matrix_of(
    frame: &serde_json::Map<String, Value>,
    file: &Path,
    i: usize,
) -> anyhow::Result<[[f64; 4]; 4]> {
    let field = format!("frames[{i}].transform_matrix");
    let Some(v) = frame.get("transform_matrix") else {
        return bad_input(file, field, "missing", "add the 4x4 camera-to-world matrix");
    };
    let not_4x4 = |what: String| {
        bad_input(
            file,
            &field,
            what,
            "give a 4x4 list of rows of finite numbers",
        )
    };
    let Some(rows) = v.as_array().filter(|r| r.len() == 4) else {
        return not_4x4(format!("is not a list of 4 rows: {}", short(v)));
    };
    let mut m = [[0.0; 4]; 4];
    for (r, row) in rows.iter().enumerate() {
        let Some(cols) = row.as_array().filter(|c| c.len() == 4) else {
            return not_4x4(format!(
                "row {r} is not a list of 4 numbers: {}",
                short(row)
            ));
        };
        for (c, x) in cols.iter().enumerate() {
            match x.as_f64() {
                Some(val) if val.is_finite() => m[r][c] = val,
                _ => return not_4x4(format!("element [{r}][{c}] = {x} is not a finite number")),
            }
        }
    }
    Ok(m)
}

/// The image a frame names: the path as given, else with `.png` appended (NeRF-synthetic
/// frames omit the extension).
fn resolve_image(root: &Path, file_path: &str, file: &Path, i: usize) -> anyhow::Result<PathBuf> {
    let given = root.join(file_path);
    if given.is_file() {
        return Ok(given);
    }
    let with_png = root.join(format!("{file_path}.png"));
    if with_png.is_file() {
        return Ok(with_png);
    }
    bad_input(
        file,
        format!("frames[{i}].file_path"),
        format!(
            "image \"{file_path}\" not found (tried {} and {})",
            given.display(),
            with_png.display()
        ),
        "put the image there or correct file_path (relative to the scene folder)",
    )
}

/// Width, height and whether the image has alpha, from its header alone.
fn probe_image(path: &Path, file: &Path, i: usize) -> anyhow::Result<(u32, u32, bool)> {
    use image::ImageDecoder;
    let field = format!("frames[{i}].file_path");
    let unreadable = |e: &dyn std::fmt::Display| {
        bad_input::<(u32, u32, bool)>(
            file,
            &field,
            format!("image {} cannot be read: {e}", path.display()),
            "replace it with a valid PNG or JPEG",
        )
    };
    let reader = match image::ImageReader::open(path).and_then(|r| r.with_guessed_format()) {
        Ok(r) => r,
        Err(e) => return unreadable(&e),
    };
    let decoder = match reader.into_decoder() {
        Ok(d) => d,
        Err(e) => return unreadable(&e),
    };
    let (w, h) = decoder.dimensions();
    if w == 0 || h == 0 {
        return bad_input(
            file,
            field,
            format!("image {} has zero area ({w}x{h})", path.display()),
            "replace it with a real image",
        );
    }
    Ok((w, h, decoder.color_type().has_alpha()))
}

/// `./train/r_0` → `train/r_0`: the form names and split lists are compared in.
fn normalize(p: &str) -> String {
    let parts: Vec<String> = Path::new(p)
        .components()
        .filter(|c| !matches!(c, Component::CurDir))
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    parts.join("/")
}

fn file_stem(p: &str) -> String {
    Path::new(p)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.to_string())
}

fn kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "an object",
    }
}

fn short(v: &Value) -> String {
    let s = v.to_string();
    if s.len() > 80 {
        format!(
            "{}…",
            &s[..s.char_indices().nth(77).map_or(s.len(), |(k, _)| k)]
        )
    } else {
        s
    }
}
