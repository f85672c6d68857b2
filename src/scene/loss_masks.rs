//! Which pixels of each training view a run learns from.
//!
//! A block of a partitioned scene trains on views that also see what other blocks own: left
//! alone, it explains that content with Gaussians inside its own region (floaters in front of
//! the rest of the scene), and the merge keeps them. `partition --loss-masks` writes
//! `loss_masks.json` into each block folder: per view, a grid of image cells, `1` where the
//! block learns the pixels and `0` where the content belongs to another block. `train` reads
//! the file in any scene folder and zeroes the loss gradient at a view's `0` cells
//! (`glsl/train/mask_grads.comp`), so those pixels pull on no Gaussian. The cells are relative
//! to the image (cell `(cx, cy)` of a `cols × rows` grid holds pixel `(x, y)` with
//! `cx = ⌊x·cols/W⌋`, `cy = ⌊y·rows/H⌋`), so one file serves every `-r`.
//!
//! The file: `{"cols": C, "rows": R, "views": {"<view name>": ["0110…", …R rows of C]}}`. A view
//! it does not list learns from every pixel.

use std::collections::HashMap;
use std::path::Path;

use crate::error::bad_input;

pub const LOSS_MASKS_FILE: &str = "loss_masks.json";

/// The largest grid side the reader accepts: a mask finer than this is an image, not cells, and
/// 256 × 256 bits (8 KiB a view) keep thousands of views' masks in one storage binding.
pub const MAX_CELLS: u32 = 256;

/// Per-view cell masks of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct LossMasks {
    pub cols: u32,
    pub rows: u32,
    /// Per view of the scene (its index in `Scene::views`): row-major cells, `true` where the
    /// view's pixels are learned; `None`: every pixel.
    pub views: Vec<Option<Vec<bool>>>,
}

impl LossMasks {
    /// The share of view `view`'s cells that are learned (1 without a mask).
    pub fn learned_share(&self, view: usize) -> f64 {
        match self.views.get(view).and_then(Option::as_ref) {
            Some(m) if !m.is_empty() => m.iter().filter(|&&b| b).count() as f64 / m.len() as f64,
            _ => 1.0,
        }
    }

    /// Whether any view has a cell it does not learn.
    pub fn masks_anything(&self) -> bool {
        self.views.iter().flatten().any(|m| m.iter().any(|&b| !b))
    }
}

/// The file's JSON for `cols × rows` cells and `(view name, cells)` pairs.
pub fn to_json(cols: u32, rows: u32, views: &[(String, Vec<bool>)]) -> serde_json::Value {
    let mut map = serde_json::Map::new();
    for (name, cells) in views {
        let lines: Vec<String> = cells
            .chunks(cols as usize)
            .map(|r| r.iter().map(|&b| if b { '1' } else { '0' }).collect())
            .collect();
        map.insert(name.clone(), serde_json::json!(lines));
    }
    serde_json::json!({"cols": cols, "rows": rows, "views": map})
}

/// The masks `root/loss_masks.json` holds for the views named `names` (a scene's views, in
/// its order), if the file exists. Every defect is an
/// error naming the file and the field: a grid side outside 1..=[`MAX_CELLS`], a view that is
/// not the scene's, a row count or row length that is not the grid's, a character other than
/// `0` and `1`.
pub fn read(root: &Path, names: &[&str]) -> anyhow::Result<Option<LossMasks>> {
    let path = root.join(LOSS_MASKS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let fix_file =
        "write it as partition --loss-masks does, or remove it to learn from every pixel";
    let text = crate::error::read_text(&path, fix_file)?;
    let json: serde_json::Value = match serde_json::from_str(&text) {
        Ok(j) => j,
        Err(e) => return bad_input(&path, "file", format!("is not JSON: {e}"), fix_file),
    };
    let side = |key: &str| -> anyhow::Result<u32> {
        match json.get(key).and_then(serde_json::Value::as_u64) {
            Some(n) if (1..=MAX_CELLS as u64).contains(&n) => Ok(n as u32),
            other => bad_input(
                &path,
                key,
                format!(
                    "is {}, not a whole number of cells from 1 to {MAX_CELLS}",
                    other.map_or_else(
                        || json.get(key).map_or("missing".into(), |v| v.to_string()),
                        |n| n.to_string()
                    )
                ),
                "give the grid's cells along that side of the image (e.g. 32)",
            ),
        }
    };
    let (cols, rows) = (side("cols")?, side("rows")?);
    let Some(listed) = json.get("views").and_then(serde_json::Value::as_object) else {
        return bad_input(
            &path,
            "views",
            "is missing or not an object of view name → rows",
            fix_file,
        );
    };
    let index: HashMap<&str, usize> = names.iter().enumerate().map(|(i, n)| (*n, i)).collect();
    let mut masks = vec![None; names.len()];
    for (name, lines) in listed {
        let field = format!("views.{name}");
        let Some(&i) = index.get(name.as_str()) else {
            return bad_input(
                &path,
                field,
                format!("'{name}' is not a view of the scene"),
                "name views as the scene lists them (e.g. images.txt's NAME column), or drop the entry",
            );
        };
        let Some(lines) = lines.as_array().filter(|l| l.len() == rows as usize) else {
            return bad_input(
                &path,
                field,
                format!("is not a list of {rows} rows (the file's \"rows\")"),
                "give one string of cols '0'/'1' characters a row",
            );
        };
        let mut cells = Vec::with_capacity((cols * rows) as usize);
        for (r, line) in lines.iter().enumerate() {
            let ok = line
                .as_str()
                .filter(|s| s.len() == cols as usize && s.bytes().all(|b| b == b'0' || b == b'1'));
            let Some(s) = ok else {
                return bad_input(
                    &path,
                    format!("{field}[{r}]"),
                    format!("is {line}, not {cols} characters of '0' and '1'"),
                    "give each row as a string of the grid's cols cells, 1 to learn, 0 to ignore",
                );
            };
            cells.extend(s.bytes().map(|b| b == b'1'));
        }
        masks[i] = Some(cells);
    }
    Ok(Some(LossMasks {
        cols,
        rows,
        views: masks,
    }))
}

/// The masks of `scene`'s folder ([`read`] with its views), and the mean share of its training
/// views' cells that are learned; `None` without a file or where it masks nothing.
pub fn for_scene(scene: &super::Scene) -> anyhow::Result<Option<(LossMasks, f64)>> {
    let names: Vec<&str> = scene.views.iter().map(|v| v.name.as_str()).collect();
    let Some(masks) = read(&scene.root, &names)? else {
        return Ok(None);
    };
    if !masks.masks_anything() {
        return Ok(None);
    }
    let share = scene
        .train
        .iter()
        .map(|&v| masks.learned_share(v))
        .sum::<f64>()
        / scene.train.len().max(1) as f64;
    Ok(Some((masks, share)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn views<'a>(names: &[&'a str]) -> Vec<&'a str> {
        names.to_vec()
    }

    fn dir_with(text: &str) -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join(LOSS_MASKS_FILE), text).unwrap();
        d
    }

    #[test]
    fn a_written_file_reads_back_per_view() {
        let v = views(&["a.jpg", "b.jpg", "c.jpg"]);
        let cells = vec![true, false, true, true, true, false];
        let json = to_json(3, 2, &[("b.jpg".into(), cells.clone())]);
        let d = dir_with(&json.to_string());
        let m = read(d.path(), &v).unwrap().unwrap();
        assert_eq!((m.cols, m.rows), (3, 2));
        assert_eq!(m.views, vec![None, Some(cells), None]);
        assert!((m.learned_share(1) - 4.0 / 6.0).abs() < 1e-12);
        assert_eq!(m.learned_share(0), 1.0);
        assert!(m.masks_anything());
        assert!(read(tempfile::tempdir().unwrap().path(), &v)
            .unwrap()
            .is_none());
    }

    #[test]
    fn every_defect_names_the_file_and_field() {
        let v = views(&["a.jpg"]);
        let cases = [
            ("{", "file"),
            ("[]", "cols"),
            (r#"{"cols": 0, "rows": 1, "views": {}}"#, "cols"),
            (r#"{"cols": 2, "rows": 257, "views": {}}"#, "rows"),
            (r#"{"cols": 2.5, "rows": 1, "views": {}}"#, "cols"),
            (r#"{"cols": 2, "rows": 1}"#, "views"),
            (
                r#"{"cols": 2, "rows": 1, "views": {"z.jpg": ["11"]}}"#,
                "views.z.jpg",
            ),
            (
                r#"{"cols": 2, "rows": 1, "views": {"a.jpg": ["11", "00"]}}"#,
                "views.a.jpg",
            ),
            (
                r#"{"cols": 2, "rows": 1, "views": {"a.jpg": "11"}}"#,
                "views.a.jpg",
            ),
            (
                r#"{"cols": 2, "rows": 1, "views": {"a.jpg": ["1"]}}"#,
                "views.a.jpg[0]",
            ),
            (
                r#"{"cols": 2, "rows": 1, "views": {"a.jpg": ["12"]}}"#,
                "views.a.jpg[0]",
            ),
            (
                r#"{"cols": 2, "rows": 1, "views": {"a.jpg": [11]}}"#,
                "views.a.jpg[0]",
            ),
        ];
        for (text, field) in cases {
            let d = dir_with(text);
            let e = format!("{:#}", read(d.path(), &v).unwrap_err());
            assert!(e.contains(LOSS_MASKS_FILE), "{text}: {e}");
            assert!(e.contains(field), "{text}: wanted field {field}: {e}");
        }
    }

    #[test]
    fn random_bytes_never_panic() {
        use rand::{Rng, SeedableRng};
        let v = views(&["a.jpg"]);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let good = to_json(4, 2, &[("a.jpg".into(), vec![true; 8])]).to_string();
        for _ in 0..300 {
            let mut bytes = good.clone().into_bytes();
            for _ in 0..rng.gen_range(1..4) {
                let i = rng.gen_range(0..bytes.len());
                bytes[i] = rng.gen();
            }
            let d = tempfile::tempdir().unwrap();
            std::fs::write(d.path().join(LOSS_MASKS_FILE), &bytes).unwrap();
            if let Ok(Some(m)) = read(d.path(), &v) {
                for cells in m.views.iter().flatten() {
                    assert_eq!(cells.len(), (m.cols * m.rows) as usize);
                }
            }
        }
    }
}
