//! The safetensors weight file: a minimal reader (F32 tensors only, which is all LPIPS needs)
//! and a writer (used by the tests to build files; `scripts/convert_lpips_weights.py` writes
//! the real one).
//!
//! Layout (<https://github.com/huggingface/safetensors>): an 8-byte little-endian header length
//! N, N bytes of JSON `{"name": {"dtype": "F32", "shape": [..], "data_offsets": [b, e]}, ...}`
//! (optionally with a `"__metadata__"` string map, possibly padded with spaces), then the raw
//! little-endian data, offsets relative to its start. The whole file is checked on open, so a
//! truncated file is reported before any tensor is used.

use crate::error::InputError;
use anyhow::{Context, Result};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

/// What to tell a user whose weight file is missing or broken.
pub const WEIGHTS_FIX: &str = "convert the official LPIPS weights (torchvision's ImageNet \
     AlexNet + lpips' v0.1 alex.pth) with `python3 scripts/convert_lpips_weights.py \
     OUT.safetensors` (see docs/lpips.md)";

/// Refuse headers larger than this: a corrupt length must not trigger a huge allocation.
const MAX_HEADER: u64 = 100 << 20;

#[derive(Debug, Clone)]
struct Entry {
    dtype: String,
    shape: Vec<usize>,
    begin: usize,
    end: usize,
}

/// A parsed safetensors file held in memory.
#[derive(Debug)]
pub struct SafeTensors {
    path: PathBuf,
    bytes: Vec<u8>,
    data_start: usize,
    entries: BTreeMap<String, Entry>,
}

fn bad(path: &Path, field: &str, problem: impl Into<String>) -> anyhow::Error {
    InputError::new(path, field, problem, WEIGHTS_FIX).into()
}

impl SafeTensors {
    /// Reads and checks the header of `path`: every tensor's data must lie inside the file.
    pub fn open(path: &Path) -> Result<SafeTensors> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(bad(path, "file", "does not exist"))
            }
            Err(e) => {
                return Err(e).with_context(|| format!("{}: cannot read", path.display()));
            }
        };
        if bytes.len() < 8 {
            return Err(bad(
                path,
                "header length",
                format!(
                    "the file is {} bytes, too short for a safetensors file (truncated?)",
                    bytes.len()
                ),
            ));
        }
        let n = u64::from_le_bytes(bytes[..8].try_into().unwrap());
        let avail = bytes.len() as u64 - 8;
        if n > MAX_HEADER || n > avail {
            return Err(bad(
                path,
                "header length",
                format!(
                    "the header claims {n} bytes of JSON but {avail} bytes follow \
                     (truncated, or not a safetensors file)"
                ),
            ));
        }
        let data_start = 8 + n as usize;
        let header: serde_json::Value = serde_json::from_slice(&bytes[8..data_start])
            .map_err(|e| bad(path, "header", format!("is not valid JSON ({e})")))?;
        let obj = header
            .as_object()
            .ok_or_else(|| bad(path, "header", "is not a JSON object"))?;
        let data_len = bytes.len() - data_start;
        let mut entries = BTreeMap::new();
        for (name, v) in obj {
            if name == "__metadata__" {
                continue;
            }
            let field = |what: &str| format!("tensor {name:?}: {what}");
            let dtype = v
                .get("dtype")
                .and_then(|d| d.as_str())
                .ok_or_else(|| bad(path, &field("dtype"), "missing or not a string"))?
                .to_string();
            let shape = v
                .get("shape")
                .and_then(|s| s.as_array())
                .and_then(|a| {
                    a.iter()
                        .map(|x| x.as_u64().map(|x| x as usize))
                        .collect::<Option<Vec<_>>>()
                })
                .ok_or_else(|| bad(path, &field("shape"), "missing or not a list of integers"))?;
            let offs = v
                .get("data_offsets")
                .and_then(|s| s.as_array())
                .and_then(|a| {
                    a.iter()
                        .map(|x| x.as_u64().map(|x| x as usize))
                        .collect::<Option<Vec<_>>>()
                })
                .filter(|o| o.len() == 2 && o[0] <= o[1])
                .ok_or_else(|| {
                    bad(
                        path,
                        &field("data_offsets"),
                        "missing or not [begin, end] with begin ≤ end",
                    )
                })?;
            let (begin, end) = (offs[0], offs[1]);
            if end > data_len {
                return Err(bad(
                    path,
                    &field("data_offsets"),
                    format!(
                        "its data ends at byte {end} but the file holds only {data_len} bytes \
                         of data: the file is truncated"
                    ),
                ));
            }
            entries.insert(
                name.clone(),
                Entry {
                    dtype,
                    shape,
                    begin,
                    end,
                },
            );
        }
        Ok(SafeTensors {
            path: path.to_path_buf(),
            bytes,
            data_start,
            entries,
        })
    }

    /// The file this was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Tensor names, sorted.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.entries.keys().map(|s| s.as_str())
    }

    /// The shape of a tensor, if present.
    pub fn shape(&self, name: &str) -> Option<&[usize]> {
        self.entries.get(name).map(|e| e.shape.as_slice())
    }

    /// The F32 tensor `name`, which must have exactly the shape `expected`.
    pub fn f32(&self, name: &str, expected: &[usize]) -> Result<Vec<f32>> {
        let e = self.entries.get(name).ok_or_else(|| {
            bad(
                &self.path,
                &format!("tensor {name:?}"),
                format!("is missing (expected shape {expected:?})"),
            )
        })?;
        if e.shape != expected {
            return Err(bad(
                &self.path,
                &format!("tensor {name:?}"),
                format!("has shape {:?}, expected {expected:?}", e.shape),
            ));
        }
        self.read(name, e)
    }

    /// The F32 tensor `name` with whatever shape it has.
    pub fn f32_any_shape(&self, name: &str) -> Result<(Vec<usize>, Vec<f32>)> {
        let e = self
            .entries
            .get(name)
            .ok_or_else(|| bad(&self.path, &format!("tensor {name:?}"), "is missing"))?;
        Ok((e.shape.clone(), self.read(name, e)?))
    }

    fn read(&self, name: &str, e: &Entry) -> Result<Vec<f32>> {
        let field = format!("tensor {name:?}");
        if e.dtype != "F32" {
            return Err(bad(
                &self.path,
                &field,
                format!("has dtype {}, expected F32 (float32)", e.dtype),
            ));
        }
        // Checked: a shape such as [2^62, 4] must not wrap around to a size the data matches
        // (the caller would then index past the values it got).
        let needed = e.shape.iter().try_fold(4usize, |n, &d| n.checked_mul(d));
        if needed != Some(e.end - e.begin) {
            let needed = needed.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string());
            return Err(bad(
                &self.path,
                &field,
                format!(
                    "holds {} bytes but shape {:?} of F32 needs {needed}",
                    e.end - e.begin,
                    e.shape,
                ),
            ));
        }
        let raw = &self.bytes[self.data_start + e.begin..self.data_start + e.end];
        Ok(raw
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect())
    }
}

/// Writes F32 tensors `(name, shape, values)` as a safetensors file (atomically), in the order
/// given, each 4-byte aligned (the header is padded with spaces to a multiple of 8 bytes, as the
/// reference implementation does).
pub fn write_f32(path: &Path, tensors: &[(&str, &[usize], &[f32])]) -> Result<()> {
    let mut header = serde_json::Map::new();
    let mut offset = 0usize;
    for (name, shape, values) in tensors {
        let count: usize = shape.iter().product();
        anyhow::ensure!(
            count == values.len(),
            "tensor {name:?}: shape {shape:?} needs {count} values, got {}",
            values.len()
        );
        header.insert(
            name.to_string(),
            serde_json::json!({
                "dtype": "F32",
                "shape": shape,
                "data_offsets": [offset, offset + 4 * count],
            }),
        );
        offset += 4 * count;
    }
    let mut json = serde_json::to_vec(&serde_json::Value::Object(header))?;
    while json.len() % 8 != 0 {
        json.push(b' ');
    }
    crate::error::write_atomic(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        w.write_all(&(json.len() as u64).to_le_bytes())?;
        w.write_all(&json)?;
        for (_, _, values) in tensors {
            for v in values.iter() {
                w.write_all(&v.to_le_bytes())?;
            }
        }
        w.flush()?;
        Ok(())
    })
    .with_context(|| format!("{}: cannot write the safetensors file", path.display()))
}
