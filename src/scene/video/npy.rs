//! A reader for the one NumPy file video scenes need: LLFF's `poses_bounds.npy`, a 2-D array
//! of little-endian floats (`<f8` or `<f4`) in C order. Version 1, 2 and 3 headers are read;
//! anything else is refused with the field that did not match.

use std::path::Path;

use crate::error::bad_input;

/// A 2-D array of f64 read from a `.npy` file, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Array2 {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f64>,
}

impl Array2 {
    pub fn row(&self, r: usize) -> &[f64] {
        &self.data[r * self.cols..(r + 1) * self.cols]
    }
}

/// Reads a 2-D float array.
pub fn read_array2(path: &Path) -> anyhow::Result<Array2> {
    let bytes = std::fs::read(path).map_err(|e| {
        crate::error::InputError::new(
            path,
            "file",
            format!("cannot be read ({e})"),
            "check the path",
        )
    })?;
    parse_array2(path, &bytes)
}

/// Parses the bytes of a `.npy` file holding a 2-D float array; `path` names it in errors.
pub fn parse_array2(path: &Path, bytes: &[u8]) -> anyhow::Result<Array2> {
    const FIX: &str = "write it with numpy.save from a 2-D float64 or float32 array";
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return bad_input(path, "magic", "is not a NumPy .npy file", FIX);
    }
    let major = bytes[6];
    let (header_len, header_start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return bad_input(path, "version", format!("{major} is not 1, 2 or 3"), FIX),
    };
    let Some(header) = bytes.get(header_start..header_start + header_len) else {
        return bad_input(path, "header", "is truncated", FIX);
    };
    let header = String::from_utf8_lossy(header);
    let descr = dict_value(&header, "descr");
    let width = match descr.as_deref() {
        Some("'<f8'") => 8,
        Some("'<f4'") => 4,
        other => {
            return bad_input(
                path,
                "header 'descr'",
                format!(
                    "is {} (little-endian float64 or float32 expected)",
                    other.unwrap_or("missing")
                ),
                FIX,
            )
        }
    };
    if dict_value(&header, "fortran_order").as_deref() != Some("False") {
        return bad_input(path, "header 'fortran_order'", "is not False", FIX);
    }
    let shape = dict_value(&header, "shape").unwrap_or_default();
    let dims: Vec<usize> = shape
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>())
        .collect::<Result<_, _>>()
        .unwrap_or_default();
    let [rows, cols] = dims[..] else {
        return bad_input(
            path,
            "header 'shape'",
            format!("is {shape} (a 2-D array expected)"),
            FIX,
        );
    };
    let body = &bytes[header_start + header_len..];
    // Checked: a shape such as (2^62, 4) must not wrap around to a size the body matches.
    let needed = rows.checked_mul(cols).and_then(|n| n.checked_mul(width));
    if needed != Some(body.len()) {
        let needed = needed.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string());
        return bad_input(
            path,
            "data",
            format!(
                "holds {} bytes where shape ({rows}, {cols}) needs {needed}",
                body.len(),
            ),
            FIX,
        );
    }
    let data = if width == 8 {
        body.chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()
    } else {
        body.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")) as f64)
            .collect()
    };
    Ok(Array2 { rows, cols, data })
}

/// The text of `key`'s value in a NumPy header dict (`{'descr': '<f8', 'shape': (3, 17), }`).
fn dict_value(header: &str, key: &str) -> Option<String> {
    let at = header.find(&format!("'{key}'"))? + key.len() + 2;
    let rest = header[at..].trim_start().strip_prefix(':')?.trim_start();
    let end = if rest.starts_with('(') {
        rest.find(')')? + 1
    } else {
        rest.find([',', '}'])?
    };
    Some(rest[..end].trim().to_string())
}

/// Writes a 2-D float64 array as a version-1 `.npy` file (for fixtures and tests).
pub fn write_array2(path: &Path, rows: usize, cols: usize, data: &[f64]) -> anyhow::Result<()> {
    anyhow::ensure!(
        data.len() == rows * cols,
        "npy data does not match its shape"
    );
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // The header is padded with spaces so the data starts on a 64-byte boundary, ending in '\n'.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    for v in data {
        out.extend(v.to_le_bytes());
    }
    std::fs::write(path, out)?;
    Ok(())
}
