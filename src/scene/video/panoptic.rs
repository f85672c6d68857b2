//! The Dynamic 3D Gaussians layout of CMU Panoptic captures: `train_meta.json` and
//! `test_meta.json`, each with the image size `w`, `h` and, per frame and camera, `k` (3×3
//! intrinsics), `w2c` (4×4 world-to-camera, OpenCV axes), `fn` (the image under `ims/`) and
//! `cam_id`. Foreground masks, where present, are `seg/<fn>` with a `.png` extension. The
//! cameras do not move: every frame's `k` and `w2c` must agree with the first frame's.

use std::path::Path;

use serde_json::Value;

use super::{finish, pinhole, segment, FrameRange, VideoCamera, VideoLayout, VideoScene};
use crate::error::bad_input;
use crate::scene::{LoadOptions, Pose};

/// How far a later frame's calibration may stray from the first frame's (they are copies).
const CALIBRATION_TOLERANCE: f64 = 1e-6;

/// One camera as the meta files describe it.
struct MetaCamera {
    id: u64,
    k: [f64; 9],
    w2c: [f64; 16],
    files: Vec<String>,
}

pub fn load(root: &Path, opts: &LoadOptions, range: FrameRange) -> anyhow::Result<VideoScene> {
    let (w, h, train) = read_meta(&root.join("train_meta.json"))?;
    let test_path = root.join("test_meta.json");
    let test = if test_path.exists() {
        let (tw, th, test) = read_meta(&test_path)?;
        if (tw, th) != (w, h) {
            return bad_input(
                &test_path,
                "w, h",
                format!("{tw}x{th} differs from train_meta.json's {w}x{h}"),
                "use the meta files of one capture",
            );
        }
        test
    } else {
        Vec::new()
    };
    let available = train
        .iter()
        .chain(&test)
        .map(|c| c.files.len())
        .min()
        .unwrap_or(0);
    let (start, count) = segment(root, available, range)?;
    let test_names: Vec<String> = test.iter().map(|c| camera_name(c.id)).collect();
    let mut cameras = Vec::new();
    for c in train.into_iter().chain(test) {
        let name = camera_name(c.id);
        if cameras.iter().any(|v: &VideoCamera| v.name == name) {
            return bad_input(
                root,
                format!("cam_id {}", c.id),
                "appears twice (in train_meta.json and test_meta.json, or twice in one)",
                "list each camera once",
            );
        }
        let k = c.k;
        let (source_model, camera) = pinhole([k[0], k[4], k[2], k[5]], w, h, opts);
        let mut rotation = [[0.0; 3]; 3];
        for (r, row) in rotation.iter_mut().enumerate() {
            row.copy_from_slice(&c.w2c[4 * r..4 * r + 3]);
        }
        let pose = Pose {
            rotation,
            translation: [c.w2c[3], c.w2c[7], c.w2c[11]],
        };
        let files = &c.files[start..start + count];
        let frames: Vec<_> = files.iter().map(|f| root.join("ims").join(f)).collect();
        let masks: Vec<_> = files
            .iter()
            .map(|f| root.join("seg").join(f).with_extension("png"))
            .collect();
        let masks = masks.iter().all(|m| m.exists()).then_some(masks);
        cameras.push(VideoCamera {
            name,
            source_model,
            source_width: w,
            source_height: h,
            camera,
            pose,
            frames,
            masks,
        });
    }
    finish(
        root,
        VideoLayout::Panoptic,
        cameras,
        &test_names,
        start,
        count,
    )
}

/// `cam00`, `cam01`, …: zero-padded so that sorting by name sorts by id.
fn camera_name(id: u64) -> String {
    format!("cam{id:02}")
}

/// Reads one meta file: the image size and its cameras, checked to be fixed over the frames.
fn read_meta(path: &Path) -> anyhow::Result<(u32, u32, Vec<MetaCamera>)> {
    let json = crate::scene::transforms::read_json(path)?;
    let size = |key: &str| -> anyhow::Result<u32> {
        match json.get(key).and_then(Value::as_u64) {
            Some(v) if v > 0 && v <= u32::MAX as u64 => Ok(v as u32),
            _ => bad_input(
                path,
                key,
                "is missing or not a positive integer",
                "give the image size in pixels",
            ),
        }
    };
    let (w, h) = (size("w")?, size("h")?);
    let frames = |key: &str| -> anyhow::Result<&Vec<Value>> {
        match json.get(key).and_then(Value::as_array) {
            Some(a) if !a.is_empty() => Ok(a),
            _ => bad_input(
                path,
                key,
                "is missing or empty (a list per frame, each with one entry per camera)",
                "use the meta file of the Dynamic 3D Gaussians data release",
            ),
        }
    };
    let (ks, w2cs, fns, ids) = (
        frames("k")?,
        frames("w2c")?,
        frames("fn")?,
        frames("cam_id")?,
    );
    if [w2cs.len(), fns.len(), ids.len()]
        .iter()
        .any(|&n| n != ks.len())
    {
        return bad_input(
            path,
            "k, w2c, fn, cam_id",
            format!(
                "list {}, {}, {} and {} frames: they must agree",
                ks.len(),
                w2cs.len(),
                fns.len(),
                ids.len()
            ),
            "use an unedited meta file",
        );
    }
    let mut cameras: Vec<MetaCamera> = Vec::new();
    for f in 0..ks.len() {
        let row = |v: &Value, key: &str| -> anyhow::Result<Vec<Value>> {
            match v.as_array() {
                Some(a) => Ok(a.clone()),
                None => bad_input(
                    path,
                    format!("{key}[{f}]"),
                    "is not a list",
                    "use an unedited meta file",
                ),
            }
        };
        let (k, w2c, fname, id) = (
            row(&ks[f], "k")?,
            row(&w2cs[f], "w2c")?,
            row(&fns[f], "fn")?,
            row(&ids[f], "cam_id")?,
        );
        if f == 0 {
            for (c, idv) in id.iter().enumerate() {
                let Some(id) = idv.as_u64() else {
                    return bad_input(
                        path,
                        format!("cam_id[0][{c}]"),
                        "is not a camera number",
                        "use an unedited meta file",
                    );
                };
                cameras.push(MetaCamera {
                    id,
                    k: matrix(path, &format!("k[0][{c}]"), k.get(c))?,
                    w2c: matrix(path, &format!("w2c[0][{c}]"), w2c.get(c))?,
                    files: Vec::new(),
                });
            }
        }
        if id.len() != cameras.len() || k.len() != cameras.len() || w2c.len() != cameras.len() {
            return bad_input(
                path,
                format!("frame {f}"),
                format!(
                    "lists {} cameras where frame 0 lists {}",
                    id.len(),
                    cameras.len()
                ),
                "every frame must list the same cameras",
            );
        }
        for (c, cam) in cameras.iter_mut().enumerate() {
            if id[c].as_u64() != Some(cam.id) {
                return bad_input(
                    path,
                    format!("cam_id[{f}][{c}]"),
                    format!("is {} where frame 0 has {}", id[c], cam.id),
                    "keep one camera order for every frame",
                );
            }
            let kf: [f64; 9] = matrix(path, &format!("k[{f}][{c}]"), k.get(c))?;
            let wf: [f64; 16] = matrix(path, &format!("w2c[{f}][{c}]"), w2c.get(c))?;
            let moved = kf
                .iter()
                .zip(&cam.k)
                .chain(wf.iter().zip(&cam.w2c))
                .any(|(a, b)| (a - b).abs() > CALIBRATION_TOLERANCE * (1.0 + b.abs()));
            if moved {
                return bad_input(
                    path,
                    format!("k/w2c[{f}][{c}] (camera {})", cam.id),
                    "differs from frame 0: this engine's video scenes have fixed cameras",
                    "use a capture with static, calibrated cameras",
                );
            }
            let Some(name) = fname.get(c).and_then(Value::as_str) else {
                return bad_input(
                    path,
                    format!("fn[{f}][{c}]"),
                    "is not a file name",
                    "use an unedited meta file",
                );
            };
            cam.files.push(name.to_string());
        }
    }
    Ok((w, h, cameras))
}

/// A row-major matrix of `N` numbers from nested JSON lists.
fn matrix<const N: usize>(path: &Path, field: &str, v: Option<&Value>) -> anyhow::Result<[f64; N]> {
    let flat: Vec<f64> = v
        .and_then(Value::as_array)
        .map(|rows| {
            rows.iter()
                .filter_map(Value::as_array)
                .flatten()
                .filter_map(Value::as_f64)
                .collect()
        })
        .unwrap_or_default();
    match <[f64; N]>::try_from(flat) {
        Ok(m) if m.iter().all(|x| x.is_finite()) => Ok(m),
        _ => bad_input(
            path,
            field,
            format!(
                "is not a {}x{} matrix of finite numbers",
                (N as f64).sqrt(),
                (N as f64).sqrt()
            ),
            "use an unedited meta file",
        ),
    }
}
