//! What both forms share: views probed for their image size and alpha, sorted by name, the
//! scene finished from them, and the JSON fields read with errors that name the file, the field
//! and the fix.

use crate::error::bad_input;
use crate::scene::{
    split, target_size, CameraModel, LoadOptions, PinholeCamera, Pose, Scene, SceneFormat, View,
};
use serde_json::Value;
use std::path::{Component, Path, PathBuf};

/// A view plus whether its image has an alpha channel (known from the header probe).
pub(super) struct ProbedView {
    pub(super) view: View,
    pub(super) has_alpha: bool,
}

impl std::ops::Deref for ProbedView {
    type Target = View;
    fn deref(&self) -> &View {
        &self.view
    }
}

#[allow(clippy::too_many_arguments)]
pub(super) fn make_view(
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
pub(super) fn sort_views(views: Vec<ProbedView>) -> (Vec<ProbedView>, Vec<usize>) {
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

pub(super) fn sorted_indices(old: &[usize], remap: &[usize]) -> Vec<usize> {
    let mut v: Vec<usize> = old.iter().map(|&o| remap[o]).collect();
    v.sort_unstable();
    v
}

pub(super) fn finish(
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
        time_base: None,
        frame: crate::scene::SceneFrame::IDENTITY,
    })
}

pub(super) fn as_object<'a>(
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

pub(super) fn frames_of<'a>(
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
pub(super) fn number(
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

pub(super) fn check_angle(a: f64, file: &Path, field: &str) -> anyhow::Result<()> {
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

pub(super) fn file_path_of(
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

pub(super) fn matrix_of(
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
    check_rotation(&mut m, file, &field)?;
    Ok(m)
}

/// How far a camera-to-world matrix's rotation may be from orthonormal, once a uniform scale
/// is taken out (`max |RᵀR − I|`): exports round to 6–9 digits, a broken pose is off by far
/// more.
const ORTHONORMAL_TOLERANCE: f64 = 1e-3;

/// Checks the upper-left 3×3 of a camera-to-world matrix: a rotation, possibly times a
/// uniform scale (some exporters fold the scene scale in), which is divided out with a
/// warning. A singular matrix (all zeros, a collapsed axis), a reflection or a shear has no
/// camera orientation and is refused, naming the frame, as is a bottom row other than
/// `0 0 0 1`.
pub(super) fn check_rotation(
    m: &mut [[f64; 4]; 4],
    file: &Path,
    field: &str,
) -> anyhow::Result<()> {
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return bad_input(
            file,
            field,
            format!("the bottom row is {:?}, not [0, 0, 0, 1]", m[3]),
            "write the camera-to-world matrix as [R | t] over [0, 0, 0, 1]",
        );
    }
    let r = |i: usize, j: usize| m[i][j];
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1))
        - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    let largest = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| m[i][j].abs())
        .fold(0.0f64, f64::max);
    // A determinant tiny against the entries' own scale is a collapsed matrix.
    if det.is_nan() || det <= 1e-9 * largest.powi(3) || largest == 0.0 {
        let problem = if det < 0.0 && det.abs() > 1e-9 * largest.powi(3) {
            format!("its rotation part has determinant {det:.3e} < 0: a reflection, not a camera orientation")
        } else {
            format!("its rotation part is singular (determinant {det:.3e}): it gives the camera no orientation")
        };
        return bad_input(
            file,
            field,
            problem,
            "export the frame's pose again (a failed registration often writes zeros); or              remove the frame",
        );
    }
    let scale = det.cbrt();
    let mut worst = 0.0f64;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| m[k][i] * m[k][j]).sum::<f64>() / (scale * scale);
            worst = worst.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    if worst > ORTHONORMAL_TOLERANCE {
        return bad_input(
            file,
            field,
            format!(
                "its rotation part is not a rotation times a uniform scale (columns off                  orthonormal by {worst:.3e}; a shear or per-axis scale)"
            ),
            "export the frame's pose again as a rigid camera-to-world matrix",
        );
    }
    if (scale - 1.0).abs() > 1e-6 {
        eprintln!(
            "warning: {}: {field}: the rotation part carries a uniform scale of {scale:.6}; \
             divided out (a camera's orientation has no scale)",
            file.display()
        );
        for row in m.iter_mut().take(3) {
            for v in row.iter_mut().take(3) {
                *v /= scale;
            }
        }
    }
    Ok(())
}

/// The image a frame names: the path as given, else with `.png` appended (NeRF-synthetic
/// frames omit the extension).
pub(super) fn resolve_image(
    root: &Path,
    file_path: &str,
    file: &Path,
    i: usize,
) -> anyhow::Result<PathBuf> {
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
pub(super) fn probe_image(path: &Path, file: &Path, i: usize) -> anyhow::Result<(u32, u32, bool)> {
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
    crate::scene::images::check_file_complete(path)?;
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
pub(super) fn normalize(p: &str) -> String {
    let parts: Vec<String> = Path::new(p)
        .components()
        .filter(|c| !matches!(c, Component::CurDir))
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    parts.join("/")
}

pub(super) fn file_stem(p: &str) -> String {
    Path::new(p)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.to_string())
}

pub(super) fn kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "an object",
    }
}

pub(super) fn short(v: &Value) -> String {
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
