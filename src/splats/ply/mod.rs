//! Gaussian models as PLY files in the Inria 3DGS layout, so they open in existing splat viewers.
//!
//! Written files are `binary_little_endian 1.0` with one `vertex` element whose float properties
//! are, in order: `x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 .. f_rest_{3R-1} opacity scale_0
//! scale_1 scale_2 rot_0 rot_1 rot_2 rot_3`, with `R = (degree + 1)² − 1`. Opacity is stored as a
//! logit, scales as logs, the rotation as (w, x, y, z); normals are written as zeros.
//!
//! The `f_rest_*` properties are channel-major — `f_rest_{channel * R + coef}`: all red
//! coefficients, then green, then blue — while [`GaussianParams::sh_rest`] is coefficient-major;
//! reader and writer convert.
//!
//! The reader is lenient about what other tools write: properties are looked up by name in any
//! order, `ascii`, `binary_little_endian` and `binary_big_endian` bodies are accepted, required
//! properties may be `float` or `double`, unknown properties and other elements are skipped. The
//! SH degree is inferred from the number of `f_rest_*` properties (0, 9, 24, 45 → 0..3).
//! [`read_ply_two_scales`] also takes the official 2DGS code's layout, which has no `scale_2`,
//! and [`vertex_property_names`] reads only the header, to tell which base model wrote a file.

mod body;
mod header;

use body::parse_ply;
use std::io::Write;
use std::path::Path;

use anyhow::Context;
use rayon::prelude::*;

use super::model::{sh_rest_coeffs, GaussianParams, ParamField, MAX_SH_DEGREE};
use crate::error::{bad_input, write_atomic, InputError};

/// Writes `params` to `path` in the Inria layout, atomically: on any failure (including a model
/// that fails [`GaussianParams::validate`]) an existing file at `path` is left untouched.
pub fn write_ply(path: &Path, params: &GaussianParams) -> anyhow::Result<()> {
    write_ply_with_comments(path, params, &[])
}

/// [`write_ply`] with `comments` as `comment` lines of the header (one line each: a comment
/// holding a line break is refused), e.g. the segment of frames a video model was trained on.
/// Readers that do not know them skip them.
pub fn write_ply_with_comments(
    path: &Path,
    params: &GaussianParams,
    comments: &[String],
) -> anyhow::Result<()> {
    if let Some(c) = comments.iter().find(|c| c.contains(['\n', '\r'])) {
        anyhow::bail!(
            "{}: a PLY comment must be one line, not {c:?}",
            path.display()
        );
    }
    params
        .validate()
        .with_context(|| format!("{}: refusing to write an invalid model", path.display()))?;
    let n = params.len();
    let rest = params.rest_coeffs();
    let mut names = property_names(params.sh_degree);
    names.extend(
        params
            .extra
            .iter()
            .flat_map(|e| extra_property_names(&e.group)),
    );
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    for c in comments {
        header.push_str("comment ");
        header.push_str(c);
        header.push('\n');
    }
    header.push_str(&format!("element vertex {n}\n"));
    for name in &names {
        header.push_str("property float ");
        header.push_str(name);
        header.push('\n');
    }
    header.push_str("end_header\n");

    let floats_per_row = names.len();
    let row_bytes = floats_per_row * 4;
    // Rows are encoded in parallel a block at a time, so memory stays bounded for huge models.
    const BLOCK: usize = 1 << 15;
    write_atomic(path, |file| {
        let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
        out.write_all(header.as_bytes())?;
        let mut buf = vec![0u8; BLOCK.min(n) * row_bytes];
        let mut start = 0;
        while start < n {
            let count = BLOCK.min(n - start);
            let bytes = &mut buf[..count * row_bytes];
            bytes
                .par_chunks_mut(row_bytes)
                .enumerate()
                .for_each(|(j, row)| encode_row(params, start + j, rest, row));
            out.write_all(bytes)?;
            start += count;
        }
        out.flush()?;
        Ok(())
    })
    .with_context(|| format!("{}: writing the Gaussian model failed", path.display()))
}

fn encode_row(params: &GaussianParams, i: usize, rest: usize, row: &mut [u8]) {
    let mut k = 0;
    let mut put = |v: f32| {
        row[k..k + 4].copy_from_slice(&v.to_le_bytes());
        k += 4;
    };
    params.positions[i].iter().for_each(|&v| put(v));
    (0..3).for_each(|_| put(0.0));
    params.sh_dc[i].iter().for_each(|&v| put(v));
    let coeffs = &params.sh_rest[i * rest * 3..(i + 1) * rest * 3];
    for channel in 0..3 {
        for coef in 0..rest {
            put(coeffs[coef * 3 + channel]);
        }
    }
    put(params.opacity_logits[i]);
    params.log_scales[i].iter().for_each(|&v| put(v));
    params.rotations[i].iter().for_each(|&v| put(v));
    for e in &params.extra {
        let s = e.group.stride;
        e.values[i * s..(i + 1) * s].iter().for_each(|&v| put(v));
    }
}

/// The properties an extra group is written as, after the Inria ones: the group's name for a
/// one-float group (`trbf_center`), else `name_0`, `name_1`, … (`motion_0`..`motion_8`), the
/// naming of SpacetimeGaussians' PLYs.
pub fn extra_property_names(group: &crate::splats::ExtraGroup) -> Vec<String> {
    if group.stride == 1 {
        vec![group.name.clone()]
    } else {
        (0..group.stride)
            .map(|k| format!("{}_{k}", group.name))
            .collect()
    }
}

/// The vertex property names of the Inria layout for `sh_degree`, in file order.
pub fn property_names(sh_degree: u32) -> Vec<String> {
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    names.extend((0..3 * sh_rest_coeffs(sh_degree)).map(|k| format!("f_rest_{k}")));
    names.push("opacity".into());
    names.extend((0..3).map(|k| format!("scale_{k}")));
    names.extend((0..4).map(|k| format!("rot_{k}")));
    names
}

/// The PLY property that stores `field`, for a file with `rest_coeffs` rest coefficients per
/// channel.
pub fn property_name(field: ParamField, rest_coeffs: usize) -> String {
    match field {
        ParamField::Position(a) => ["x", "y", "z"][a].to_string(),
        ParamField::LogScale(a) => format!("scale_{a}"),
        ParamField::Rotation(k) => format!("rot_{k}"),
        ParamField::Opacity => "opacity".to_string(),
        ParamField::ShDc(c) => format!("f_dc_{c}"),
        ParamField::ShRest { coef, channel } => format!("f_rest_{}", channel * rest_coeffs + coef),
        ParamField::Extra { group, index } => format!("extra_{group}_{index}"),
    }
}

/// Reads a Gaussian model at the SH degree stored in the file. A file with zero vertices gives
/// an empty model; see [`require_nonempty`].
pub fn read_ply(path: &Path) -> anyhow::Result<GaussianParams> {
    read_ply_with_degree(path, MAX_SH_DEGREE)
}

/// Reads a Gaussian model, keeping SH coefficients up to `max_degree` (lower than the file's
/// degree drops the higher bands; higher keeps the file's degree). Coefficients dropped this way
/// are not checked for NaN.
pub fn read_ply_with_degree(path: &Path, max_degree: u32) -> anyhow::Result<GaussianParams> {
    read_ply_full(path, max_degree, &[], None)
}

/// Reads a 2DGS model: the Inria layout (our 2DGS PLYs, whose `scale_2` is unused), or the
/// official 2DGS code's, which stores two scales; there the third log-scale is
/// `third_log_scale` (the value the surfel model keeps in it).
pub fn read_ply_two_scales(path: &Path, third_log_scale: f32) -> anyhow::Result<GaussianParams> {
    read_ply_full(path, MAX_SH_DEGREE, &[], Some(third_log_scale))
}

/// The names of a PLY's vertex properties, from its header alone: which base model wrote a
/// file can be told before reading it as one. Empty when the file has no vertex element (the
/// readers then say so).
pub fn vertex_property_names(path: &Path) -> anyhow::Result<Vec<String>> {
    let header = read_header(path)?;
    Ok(header
        .elements
        .iter()
        .find(|e| e.name == "vertex")
        .map(|e| e.props.iter().map(|p| p.name.clone()).collect())
        .unwrap_or_default())
}

/// The text of a PLY's `comment` lines, in order, from its header alone.
pub fn ply_comments(path: &Path) -> anyhow::Result<Vec<String>> {
    Ok(read_header(path)?.comments)
}

/// Reads and parses the header of the PLY at `path` without reading its body.
fn read_header(path: &Path) -> anyhow::Result<header::Header> {
    use std::io::Read;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .and_then(|f| {
            f.take(header::MAX_HEADER_BYTES as u64 + 1)
                .read_to_end(&mut head)
        })
        .map_err(|e| open_error(path, e))?;
    header::parse_header(path, &head)
}

/// The error for a model file that cannot be opened or read.
fn open_error(path: &Path, e: std::io::Error) -> anyhow::Error {
    let (problem, fix) = if e.kind() == std::io::ErrorKind::NotFound {
        ("the file does not exist".to_string(), "check the path")
    } else {
        (
            format!("cannot read the file ({e})"),
            "check that the file is readable",
        )
    };
    InputError::new(path, "file", problem, fix).into()
}

/// Reads a model with extra parameter groups (a base model's own, e.g. SpacetimeGaussians'
/// temporal groups), stored as [`extra_property_names`] writes them; a missing one is an
/// error naming the property.
pub fn read_ply_extras(
    path: &Path,
    extra: &[crate::splats::ExtraGroup],
) -> anyhow::Result<GaussianParams> {
    read_ply_full(path, MAX_SH_DEGREE, extra, None)
}

fn read_ply_full(
    path: &Path,
    max_degree: u32,
    extra: &[crate::splats::ExtraGroup],
    third_log_scale: Option<f32>,
) -> anyhow::Result<GaussianParams> {
    let bytes = std::fs::read(path).map_err(|e| open_error(path, e))?;
    parse_ply(path, &bytes, max_degree, extra, third_log_scale)
}

/// An error for a model that has no Gaussians (which [`read_ply`] itself accepts).
pub fn require_nonempty(path: &Path, params: &GaussianParams) -> anyhow::Result<()> {
    if params.is_empty() {
        return bad_input(
            path,
            "element vertex",
            "the model has no Gaussians (vertex count 0)",
            "use a model that has Gaussians (a training run whose density control pruned them \
             all says so in its last lines)",
        );
    }
    Ok(())
}
