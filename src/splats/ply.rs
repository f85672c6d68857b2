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

use std::io::Write;
use std::path::Path;

use anyhow::Context;
use rayon::prelude::*;

use super::model::{sh_rest_coeffs, GaussianParams, ParamField, MAX_SH_DEGREE};
use crate::error::{bad_input, write_atomic, InputError};

/// Writes `params` to `path` in the Inria layout, atomically: on any failure (including a model
/// that fails [`GaussianParams::validate`]) an existing file at `path` is left untouched.
pub fn write_ply(path: &Path, params: &GaussianParams) -> anyhow::Result<()> {
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
    let mut header = format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n");
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
    read_ply_full(path, max_degree, &[])
}

/// Reads a model with extra parameter groups (a base model's own, e.g. SpacetimeGaussians'
/// temporal groups), stored as [`extra_property_names`] writes them; a missing one is an
/// error naming the property.
pub fn read_ply_extras(
    path: &Path,
    extra: &[crate::splats::ExtraGroup],
) -> anyhow::Result<GaussianParams> {
    read_ply_full(path, MAX_SH_DEGREE, extra)
}

fn read_ply_full(
    path: &Path,
    max_degree: u32,
    extra: &[crate::splats::ExtraGroup],
) -> anyhow::Result<GaussianParams> {
    let bytes = std::fs::read(path).map_err(|e| {
        let (problem, fix) = if e.kind() == std::io::ErrorKind::NotFound {
            ("the file does not exist".to_string(), "check the path")
        } else {
            (
                format!("cannot read the file ({e})"),
                "check that the file is readable",
            )
        };
        InputError::new(path, "file", problem, fix)
    })?;
    parse_ply(path, &bytes, max_degree, extra)
}

/// An error for a model that has no Gaussians (which [`read_ply`] itself accepts).
pub fn require_nonempty(path: &Path, params: &GaussianParams) -> anyhow::Result<()> {
    if params.is_empty() {
        return bad_input(
            path,
            "element vertex",
            "the model has no Gaussians (vertex count 0)",
            "use a PLY written by a training run that produced Gaussians",
        );
    }
    Ok(())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Reads an unsigned list count; `None` for a negative or non-integer type.
    fn read_count(self, b: &[u8], big: bool) -> Option<usize> {
        let v = match self {
            Scalar::U8 => b[0] as u64,
            Scalar::I8 => u64::try_from(b[0] as i8).ok()?,
            Scalar::U16 => u16_of(b, big) as u64,
            Scalar::I16 => u64::try_from(u16_of(b, big) as i16).ok()?,
            Scalar::U32 => u32_of(b, big) as u64,
            Scalar::I32 => u64::try_from(u32_of(b, big) as i32).ok()?,
            Scalar::F32 | Scalar::F64 => return None,
        };
        usize::try_from(v).ok()
    }
}

fn u16_of(b: &[u8], big: bool) -> u16 {
    let a = [b[0], b[1]];
    if big {
        u16::from_be_bytes(a)
    } else {
        u16::from_le_bytes(a)
    }
}

fn u32_of(b: &[u8], big: bool) -> u32 {
    let a = [b[0], b[1], b[2], b[3]];
    if big {
        u32::from_be_bytes(a)
    } else {
        u32::from_le_bytes(a)
    }
}

#[derive(Debug, Clone)]
enum PropKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Property {
    name: String,
    kind: PropKind,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Byte offset of the body.
    body: usize,
}

/// Headers longer than this are not PLY headers we expect (guards against scanning a huge
/// binary file line by line).
const MAX_HEADER_BYTES: usize = 1 << 20;

fn parse_header(path: &Path, bytes: &[u8]) -> anyhow::Result<Header> {
    let not_ply = || {
        bad_input(
            path,
            "header",
            "not a PLY file (it does not start with the line `ply`)",
            "pass a Gaussian model saved as .ply (e.g. point_cloud.ply)",
        )
    };
    let mut pos = 0;
    let mut lines = 0usize;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some(nl) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            if lines == 0 {
                return not_ply();
            }
            return bad_input(
                path,
                "header",
                "the header has no `end_header` line (file truncated?)",
                "re-export the model",
            );
        };
        let raw = &bytes[pos..pos + nl];
        pos += nl + 1;
        lines += 1;
        let Ok(line) = std::str::from_utf8(raw) else {
            if lines == 1 {
                return not_ply();
            }
            return bad_input(
                path,
                format!("header line {lines}"),
                "the header line is not text",
                "re-export the model",
            );
        };
        let line = line.trim_end_matches('\r');
        if lines == 1 {
            if line.trim() != "ply" {
                return not_ply();
            }
            continue;
        }
        if pos > MAX_HEADER_BYTES {
            return bad_input(
                path,
                "header",
                format!("no `end_header` within the first {MAX_HEADER_BYTES} bytes"),
                "re-export the model",
            );
        }
        let mut tok = line.split_ascii_whitespace();
        let field = || format!("header line {lines} (`{line}`)");
        match tok.next() {
            None | Some("comment") | Some("obj_info") => {}
            Some("end_header") => break,
            Some("format") => {
                format = Some(match tok.next() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::BinaryLe,
                    Some("binary_big_endian") => Format::BinaryBe,
                    other => {
                        return bad_input(
                            path,
                            field(),
                            format!("unsupported PLY format {:?}", other.unwrap_or("")),
                            "use ascii, binary_little_endian or binary_big_endian",
                        )
                    }
                });
            }
            Some("element") => {
                let (Some(name), Some(count)) = (tok.next(), tok.next()) else {
                    return bad_input(
                        path,
                        field(),
                        "an element line needs a name and a count",
                        "fix the header",
                    );
                };
                let Ok(count) = count.parse::<usize>() else {
                    return bad_input(
                        path,
                        field(),
                        format!("element count {count:?} is not a non-negative integer"),
                        "fix the header",
                    );
                };
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let Some(element) = elements.last_mut() else {
                    return bad_input(
                        path,
                        field(),
                        "a property before any element",
                        "fix the header",
                    );
                };
                let words: Vec<&str> = tok.collect();
                let bad_type = |t: &str| {
                    bad_input(
                        path,
                        field(),
                        format!("unknown property type {t:?}"),
                        "use the PLY types char..double or int8..float64",
                    )
                };
                let prop =
                    match words.as_slice() {
                        ["list", c, i, name] => {
                            let Some(count) = Scalar::parse(c) else {
                                return bad_type(c);
                            };
                            let Some(item) = Scalar::parse(i) else {
                                return bad_type(i);
                            };
                            Property {
                                name: name.to_string(),
                                kind: PropKind::List { count, item },
                            }
                        }
                        [t, name] => {
                            let Some(s) = Scalar::parse(t) else {
                                return bad_type(t);
                            };
                            Property {
                                name: name.to_string(),
                                kind: PropKind::Scalar(s),
                            }
                        }
                        _ => return bad_input(
                            path,
                            field(),
                            "malformed property line",
                            "use `property <type> <name>` or `property list <type> <type> <name>`",
                        ),
                    };
                element.props.push(prop);
            }
            Some(other) => {
                return bad_input(
                    path,
                    field(),
                    format!("unknown header keyword {other:?}"),
                    "fix the header",
                )
            }
        }
    }
    let Some(format) = format else {
        return bad_input(
            path,
            "header format",
            "the header has no `format` line",
            "add `format binary_little_endian 1.0` (or ascii) after `ply`",
        );
    };
    Ok(Header {
        format,
        elements,
        body: pos,
    })
}

/// Where one required value sits inside a vertex row.
#[derive(Debug, Clone, Copy)]
struct Slot {
    offset: usize,
    double: bool,
    big: bool,
}

impl Slot {
    #[inline]
    fn get(self, row: &[u8]) -> f32 {
        let o = self.offset;
        if self.double {
            let mut a = [0u8; 8];
            a.copy_from_slice(&row[o..o + 8]);
            let v = if self.big {
                f64::from_be_bytes(a)
            } else {
                f64::from_le_bytes(a)
            };
            v as f32
        } else {
            let a = [row[o], row[o + 1], row[o + 2], row[o + 3]];
            if self.big {
                f32::from_be_bytes(a)
            } else {
                f32::from_le_bytes(a)
            }
        }
    }
}

/// Slots of every required property, plus the file's SH layout.
struct Layout {
    pos: [Slot; 3],
    scale: [Slot; 3],
    rot: [Slot; 4],
    opacity: Slot,
    dc: [Slot; 3],
    /// In file order: `rest[channel * file_rest + coef]`.
    rest: Vec<Slot>,
    file_rest: usize,
}

/// Names of the required properties other than `f_rest_*`, in [`Layout`] order.
const REQUIRED: [&str; 14] = [
    "x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "opacity",
    "f_dc_0", "f_dc_1", "f_dc_2",
];

/// Resolves the required properties of `vertex` to indices into its property list.
fn required_indices(path: &Path, vertex: &Element) -> anyhow::Result<(Vec<usize>, u32)> {
    let mut by_name = std::collections::HashMap::new();
    for (i, p) in vertex.props.iter().enumerate() {
        if by_name.insert(p.name.as_str(), i).is_some() {
            return bad_input(
                path,
                format!("property {}", p.name),
                "the vertex element lists this property twice",
                "remove the duplicate from the header",
            );
        }
    }
    let n_rest = vertex
        .props
        .iter()
        .filter(|p| p.name.starts_with("f_rest_"))
        .count();
    let degree = match n_rest {
        0 => 0,
        9 => 1,
        24 => 2,
        45 => 3,
        _ => {
            return bad_input(
                path,
                "property f_rest_*",
                format!("{n_rest} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0..3)"),
                "re-export the model with a complete set of SH coefficients",
            )
        }
    };
    let rest_names = (0..n_rest).map(|k| format!("f_rest_{k}"));
    let mut indices = Vec::with_capacity(REQUIRED.len() + n_rest);
    for name in REQUIRED.iter().map(|s| s.to_string()).chain(rest_names) {
        let Some(&i) = by_name.get(name.as_str()) else {
            return bad_input(
                path,
                format!("property {name}"),
                "the vertex element has no such property",
                "a Gaussian model needs x y z f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3 \
                 (the Inria 3DGS layout); re-export it in that layout",
            );
        };
        match vertex.props[i].kind {
            PropKind::Scalar(Scalar::F32) | PropKind::Scalar(Scalar::F64) => {}
            PropKind::Scalar(s) => {
                return bad_input(
                    path,
                    format!("property {name}"),
                    format!("has integer type {s:?}"),
                    "store Gaussian parameters as float or double",
                )
            }
            PropKind::List { .. } => {
                return bad_input(
                    path,
                    format!("property {name}"),
                    "is a list property",
                    "store Gaussian parameters as scalar float or double properties",
                )
            }
        }
        indices.push(i);
    }
    Ok((indices, degree))
}

fn layout_from_slots(slots: &[Slot], degree: u32) -> Layout {
    let s = |i: usize| slots[i];
    Layout {
        pos: [s(0), s(1), s(2)],
        scale: [s(3), s(4), s(5)],
        rot: [s(6), s(7), s(8), s(9)],
        opacity: s(10),
        dc: [s(11), s(12), s(13)],
        rest: slots[REQUIRED.len()..].to_vec(),
        file_rest: sh_rest_coeffs(degree),
    }
}

fn parse_ply(
    path: &Path,
    bytes: &[u8],
    max_degree: u32,
    extra: &[crate::splats::ExtraGroup],
) -> anyhow::Result<GaussianParams> {
    let header = parse_header(path, bytes)?;
    let Some(vi) = header.elements.iter().position(|e| e.name == "vertex") else {
        return bad_input(
            path,
            "element vertex",
            "the file has no vertex element",
            "pass a Gaussian model PLY (one vertex per Gaussian)",
        );
    };
    let vertex = &header.elements[vi];
    if let Some(p) = vertex
        .props
        .iter()
        .find(|p| matches!(p.kind, PropKind::List { .. }))
    {
        return bad_input(
            path,
            format!("property {}", p.name),
            "list properties in the vertex element are not supported",
            "export the Gaussians with scalar properties only",
        );
    }
    let (mut indices, file_degree) = required_indices(path, vertex)?;
    let base_len = indices.len();
    for g in extra {
        for name in extra_property_names(g) {
            match vertex.props.iter().position(|p| p.name == name) {
                Some(i) => indices.push(i),
                None => {
                    return bad_input(
                        path,
                        format!("property {name}"),
                        format!("is missing: the model needs the '{}' group", g.name),
                        "pass a PLY written by a training run of this model",
                    )
                }
            }
        }
    }
    let n = vertex.count;
    let body = &bytes[header.body..];

    let (rows, stride, layout, extra_slots): (&[u8], usize, Layout, Vec<Slot>);
    let owned: Vec<u8>;
    match header.format {
        Format::BinaryLe | Format::BinaryBe => {
            let big = header.format == Format::BinaryBe;
            let mut start = 0;
            for e in &header.elements[..vi] {
                start = skip_binary_element(path, body, start, e, big)?;
            }
            let mut offsets = Vec::with_capacity(vertex.props.len());
            let mut off = 0;
            for p in &vertex.props {
                offsets.push(off);
                if let PropKind::Scalar(s) = p.kind {
                    off += s.size();
                }
            }
            stride = off;
            let slots: Vec<Slot> = indices
                .iter()
                .map(|&i| Slot {
                    offset: offsets[i],
                    double: matches!(vertex.props[i].kind, PropKind::Scalar(Scalar::F64)),
                    big,
                })
                .collect();
            layout = layout_from_slots(&slots[..base_len], file_degree);
            extra_slots = slots[base_len..].to_vec();
            let data = &body[start..];
            let needed = n.saturating_mul(stride);
            if data.len() < needed {
                let k = data.len() / stride;
                return bad_input(
                    path,
                    format!("vertex {k}"),
                    format!(
                        "truncated: the data ends inside vertex {k} of {n} ({} bytes of vertex \
                         data, {needed} needed)",
                        data.len()
                    ),
                    "the file is incomplete; re-export or re-download it",
                );
            }
            rows = &data[..needed];
        }
        Format::Ascii => {
            owned = ascii_to_rows(path, body, &header.elements[..vi], vertex, &indices)?;
            stride = indices.len() * 4;
            let slots: Vec<Slot> = (0..indices.len())
                .map(|k| Slot {
                    offset: k * 4,
                    double: false,
                    big: false,
                })
                .collect();
            layout = layout_from_slots(&slots[..base_len], file_degree);
            extra_slots = slots[base_len..].to_vec();
            rows = &owned;
        }
    }
    let degree = file_degree.min(max_degree);
    let mut params = gather(rows, stride, n, &layout, degree);
    let mut at = 0;
    for g in extra {
        let slots = &extra_slots[at..at + g.stride];
        at += g.stride;
        let values = (0..n)
            .flat_map(|i| {
                let r = &rows[i * stride..(i + 1) * stride];
                slots.iter().map(move |s| s.get(r))
            })
            .collect();
        params.extra.push(crate::splats::ExtraValues {
            group: g.clone(),
            values,
        });
    }
    if let Some((i, field)) = params.find_non_finite() {
        let name = match field {
            ParamField::Extra { group, index } => {
                extra_property_names(&params.extra[group].group)[index].clone()
            }
            _ => property_name(field, layout.file_rest),
        };
        return bad_input(
            path,
            format!("vertex {i}, property {name}"),
            format!(
                "value {} is NaN or infinite (or beyond the float range)",
                params.value(i, field)
            ),
            "the model is corrupt (a diverged training run?); re-train or re-export it",
        );
    }
    Ok(params)
}

/// Returns the body offset just past element `e`, which starts at `start`.
fn skip_binary_element(
    path: &Path,
    body: &[u8],
    start: usize,
    e: &Element,
    big: bool,
) -> anyhow::Result<usize> {
    let truncated = |row: usize| {
        bad_input(
            path,
            format!("element {} row {row}", e.name),
            "truncated: the data ends inside this element",
            "the file is incomplete; re-export or re-download it",
        )
    };
    if e.props
        .iter()
        .all(|p| matches!(p.kind, PropKind::Scalar(_)))
    {
        let row: usize = e
            .props
            .iter()
            .map(|p| match p.kind {
                PropKind::Scalar(s) => s.size(),
                PropKind::List { .. } => 0,
            })
            .sum();
        let end = e
            .count
            .checked_mul(row)
            .and_then(|b| b.checked_add(start))
            .unwrap_or(usize::MAX);
        if end > body.len() {
            return truncated((body.len() - start) / row.max(1));
        }
        return Ok(end);
    }
    let mut pos = start;
    for r in 0..e.count {
        for p in &e.props {
            match p.kind {
                PropKind::Scalar(s) => pos += s.size(),
                PropKind::List { count, item } => {
                    if pos + count.size() > body.len() {
                        return truncated(r);
                    }
                    let Some(c) = count.read_count(&body[pos..], big) else {
                        return bad_input(
                            path,
                            format!("element {} row {r}, property {}", e.name, p.name),
                            "invalid list count",
                            "the file is corrupt; re-export it",
                        );
                    };
                    pos = c
                        .checked_mul(item.size())
                        .and_then(|b| b.checked_add(pos + count.size()))
                        .unwrap_or(usize::MAX);
                }
            }
            if pos > body.len() {
                return truncated(r);
            }
        }
    }
    Ok(pos)
}

/// Parses an ASCII body into little-endian f32 rows holding only the required properties, in
/// `indices` order.
fn ascii_to_rows(
    path: &Path,
    body: &[u8],
    before: &[Element],
    vertex: &Element,
    indices: &[usize],
) -> anyhow::Result<Vec<u8>> {
    let Ok(text) = std::str::from_utf8(body) else {
        return bad_input(
            path,
            "body",
            "the ascii body is not text",
            "check the header's format line",
        );
    };
    let mut tok = text.split_ascii_whitespace();
    for e in before {
        for r in 0..e.count {
            for p in &e.props {
                let field = || format!("element {} row {r}, property {}", e.name, p.name);
                let Some(t) = tok.next() else {
                    return bad_input(
                        path,
                        field(),
                        "truncated: the file ends here",
                        "re-export the model",
                    );
                };
                if let PropKind::List { .. } = p.kind {
                    let Ok(c) = t.parse::<usize>() else {
                        return bad_input(
                            path,
                            field(),
                            format!("list count {t:?} is not a count"),
                            "re-export the model",
                        );
                    };
                    for _ in 0..c {
                        if tok.next().is_none() {
                            return bad_input(
                                path,
                                field(),
                                "truncated: the file ends inside this list",
                                "re-export the model",
                            );
                        }
                    }
                }
            }
        }
    }
    // Where each vertex property goes in the output row, if anywhere.
    let mut dest = vec![None; vertex.props.len()];
    for (k, &i) in indices.iter().enumerate() {
        dest[i] = Some(k);
    }
    let row_bytes = indices.len() * 4;
    // Capacity from the body length, not the claimed count, so a lying header cannot make us
    // allocate more than the file could hold.
    let cap = vertex
        .count
        .min(body.len() / (2 * vertex.props.len()).max(1) + 1);
    let mut out = Vec::with_capacity(cap * row_bytes);
    let mut row = vec![0u8; row_bytes];
    for v in 0..vertex.count {
        for (p, d) in vertex.props.iter().zip(&dest) {
            let Some(t) = tok.next() else {
                return bad_input(
                    path,
                    format!("vertex {v}, property {}", p.name),
                    format!(
                        "truncated: the file ends inside vertex {v} of {}",
                        vertex.count
                    ),
                    "the file is incomplete; re-export it",
                );
            };
            let Some(k) = *d else { continue };
            let value = match p.kind {
                PropKind::Scalar(Scalar::F64) => t.parse::<f64>().map(|x| x as f32).ok(),
                _ => t.parse::<f32>().ok(),
            };
            let Some(value) = value else {
                return bad_input(
                    path,
                    format!("vertex {v}, property {}", p.name),
                    format!("{t:?} is not a number"),
                    "fix the value or re-export the model",
                );
            };
            row[k * 4..k * 4 + 4].copy_from_slice(&value.to_le_bytes());
        }
        out.extend_from_slice(&row);
    }
    Ok(out)
}

/// Builds the model from `n` rows of `stride` bytes, keeping SH bands up to `degree`.
fn gather(rows: &[u8], stride: usize, n: usize, l: &Layout, degree: u32) -> GaussianParams {
    let row = |i: usize| &rows[i * stride..(i + 1) * stride];
    const MIN: usize = 4096;
    let positions = (0..n)
        .into_par_iter()
        .with_min_len(MIN)
        .map(|i| {
            let r = row(i);
            l.pos.map(|s| s.get(r))
        })
        .collect();
    let log_scales = (0..n)
        .into_par_iter()
        .with_min_len(MIN)
        .map(|i| {
            let r = row(i);
            l.scale.map(|s| s.get(r))
        })
        .collect();
    let rotations = (0..n)
        .into_par_iter()
        .with_min_len(MIN)
        .map(|i| {
            let r = row(i);
            l.rot.map(|s| s.get(r))
        })
        .collect();
    let opacity_logits = (0..n)
        .into_par_iter()
        .with_min_len(MIN)
        .map(|i| l.opacity.get(row(i)))
        .collect();
    let sh_dc = (0..n)
        .into_par_iter()
        .with_min_len(MIN)
        .map(|i| {
            let r = row(i);
            l.dc.map(|s| s.get(r))
        })
        .collect();
    let rest = sh_rest_coeffs(degree);
    let mut sh_rest = vec![0.0f32; n * rest * 3];
    if rest > 0 {
        sh_rest
            .par_chunks_mut(rest * 3)
            .with_min_len(MIN)
            .enumerate()
            .for_each(|(i, out)| {
                let r = row(i);
                for channel in 0..3 {
                    for coef in 0..rest {
                        out[coef * 3 + channel] = l.rest[channel * l.file_rest + coef].get(r);
                    }
                }
            });
    }
    GaussianParams {
        sh_degree: degree,
        positions,
        log_scales,
        rotations,
        opacity_logits,
        sh_dc,
        sh_rest,
        extra: Vec::new(),
    }
}
