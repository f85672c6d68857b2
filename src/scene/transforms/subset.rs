//! A transforms scene cut down to some of its views, as `partition` writes each block: the
//! scene's own transforms file(s) with only those views' frames, every other field as it was,
//! so the block reads with the scene's conventions (NeRF-synthetic's white background and
//! per-file field of view, nerfstudio's shared intrinsics and distortion) and its views keep
//! their names. The frames' images are not copied: the caller links the scene's folders in.

use super::read_json;
use super::shared::{file_stem, normalize};
use crate::error::bad_input;
use serde_json::Value;
use std::collections::HashSet;
use std::path::Path;

/// The files a transforms scene keeps its cameras in (what a block writes anew; every other
/// entry of the scene folder is for the caller to link).
pub const TRANSFORMS_FILES: [&str; 4] = [
    "transforms.json",
    "transforms_train.json",
    "transforms_val.json",
    "transforms_test.json",
];

/// Writes into `out` the transforms file(s) of the scene in `root` holding only the frames of
/// the views named in `train` and `test` (view names as the loader gives them). NeRF-synthetic:
/// each split file keeps its frames among them (a file left without one is not written), so a
/// test view stays one. nerfstudio: one `transforms.json` whose `train_filenames` and
/// `test_filenames` list them (`val_filenames` and the unread `ply_file_path` dropped). A name
/// that is no frame of the scene is an error naming it.
pub fn write_subset(
    root: &Path,
    out: &Path,
    train: &[String],
    test: &[String],
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)?;
    let wanted: HashSet<&str> = train.iter().chain(test).map(String::as_str).collect();
    let mut found: HashSet<String> = HashSet::new();
    if root.join("transforms_train.json").exists() {
        for split in ["train", "val", "test"] {
            let path = root.join(format!("transforms_{split}.json"));
            if !path.exists() {
                continue;
            }
            let mut json = read_json(&path)?;
            let kept = keep_frames(&mut json, &path, |file_path| {
                let name = format!("{split}/{}", file_stem(file_path));
                wanted.contains(name.as_str()).then_some(name)
            })?;
            if kept.is_empty() {
                continue;
            }
            found.extend(kept.into_iter().map(|(name, _)| name));
            write_json(&out.join(format!("transforms_{split}.json")), &json)?;
        }
    } else {
        let path = root.join("transforms.json");
        let mut json = read_json(&path)?;
        let kept = keep_frames(&mut json, &path, |file_path| {
            let name = normalize(file_path);
            wanted.contains(name.as_str()).then_some(name)
        })?;
        let list = |names: &[String]| -> Value {
            let set: HashSet<&str> = names.iter().map(String::as_str).collect();
            Value::Array(
                kept.iter()
                    .filter(|(name, _)| set.contains(name.as_str()))
                    .map(|(_, file_path)| Value::String(file_path.clone()))
                    .collect(),
            )
        };
        if let Some(top) = json.as_object_mut() {
            top.insert("train_filenames".into(), list(train));
            top.insert("test_filenames".into(), list(test));
            top.remove("val_filenames");
            top.remove("ply_file_path");
        }
        found.extend(kept.into_iter().map(|(name, _)| name));
        write_json(&out.join("transforms.json"), &json)?;
    }
    if let Some(missing) = train.iter().chain(test).find(|n| !found.contains(*n)) {
        return bad_input(
            root,
            "frames",
            format!("no frame is the view '{missing}' the plan names"),
            "partition the scene again (the plan is not this scene's, or the scene changed)",
        );
    }
    Ok(())
}

/// Keeps the frames of `json` whose `file_path` `keep` names; returns (name, file_path) of each.
fn keep_frames(
    json: &mut Value,
    path: &Path,
    keep: impl Fn(&str) -> Option<String>,
) -> anyhow::Result<Vec<(String, String)>> {
    let Some(frames) = json.get_mut("frames").and_then(Value::as_array_mut) else {
        return bad_input(
            path,
            "frames",
            "missing or not a list",
            "point at the scene the plan was made from",
        );
    };
    let mut kept = Vec::new();
    frames.retain(|f| {
        let Some(file_path) = f.get("file_path").and_then(Value::as_str) else {
            return false;
        };
        match keep(file_path) {
            Some(name) => {
                kept.push((name, file_path.to_string()));
                true
            }
            None => false,
        }
    });
    Ok(kept)
}

fn write_json(path: &Path, json: &Value) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(json)?;
    std::fs::write(path, text + "\n")
        .map_err(|e| anyhow::anyhow!("{}: cannot be written ({e})", path.display()))
}
