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

mod nerf_synthetic;
mod nerfstudio;
mod shared;
pub mod subset;

use super::{LoadOptions, Scene};
use crate::error::{bad_input, InputError};
use nerf_synthetic::load_nerf_synthetic;
use nerfstudio::load_nerfstudio;
use serde_json::Value;
use std::path::Path;

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
    let text = std::fs::read_to_string(path).map_err(|e| {
        let (problem, fix) = match e.kind() {
            std::io::ErrorKind::InvalidData => (
                "is not UTF-8 text".to_string(),
                "write the file as UTF-8 JSON (it may be truncated or another file under this \
                 name)",
            ),
            std::io::ErrorKind::NotFound => (
                "does not exist".to_string(),
                "check the path, or point at the scene's top folder",
            ),
            _ => (
                format!("cannot be read ({e})"),
                "check that the file is readable",
            ),
        };
        InputError::new(path, "file", problem, fix)
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
