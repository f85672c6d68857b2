//! The PLY body: the required vertex properties found by name, the rows read from binary
//! (either byte order, float or double) or ASCII, other elements skipped, and the model
//! gathered from the rows.

use std::path::Path;

use rayon::prelude::*;

use super::header::{parse_header, Element, Format, PropKind, Scalar};
use super::{extra_property_names, property_name};
use crate::error::bad_input;
use crate::splats::model::{sh_rest_coeffs, GaussianParams, ParamField};

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

/// Resolves the required properties of `vertex` to indices into its property list. With
/// `two_scales`, a file without `scale_2` (the official 2DGS layout) reads `scale_1` in its
/// place, for the caller to overwrite; the returned flag says it did.
fn required_indices(
    path: &Path,
    vertex: &Element,
    two_scales: bool,
) -> anyhow::Result<(Vec<usize>, u32, bool)> {
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
    let mut stood_in = false;
    for name in REQUIRED.iter().map(|s| s.to_string()).chain(rest_names) {
        let found = by_name.get(name.as_str()).copied();
        let found = match (found, name.as_str()) {
            (None, "scale_2") if two_scales => {
                stood_in = true;
                by_name.get("scale_1").copied()
            }
            _ => found,
        };
        let Some(i) = found else {
            let fix = if by_name.contains_key("packed_position") {
                "this is a compressed splat PLY (packed_position, the PlayCanvas / SuperSplat \
                 layout): convert it to an uncompressed Inria-layout PLY first"
            } else if name == "scale_2" && by_name.contains_key("scale_1") {
                "a PLY with two scales is a 2DGS model (the official 2DGS layout): read it with \
                 --model 2dgs; a 3D Gaussian model needs scale_0..2"
            } else {
                "a Gaussian model needs x y z f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3 \
                 (the Inria 3DGS layout); re-export it in that layout"
            };
            return bad_input(
                path,
                format!("property {name}"),
                "the vertex element has no such property",
                fix,
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
    Ok((indices, degree, stood_in))
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

/// Parses a whole PLY file. `third_log_scale`: a file without `scale_2` is read as a 2DGS
/// model whose third log-scale is this value (None: `scale_2` is required).
pub(super) fn parse_ply(
    path: &Path,
    bytes: &[u8],
    max_degree: u32,
    extra: &[crate::splats::ExtraGroup],
    third_log_scale: Option<f32>,
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
    let (mut indices, file_degree, scale_2_stood_in) =
        required_indices(path, vertex, third_log_scale.is_some())?;
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
            // The elements after the vertex rows, then nothing: a body longer than the header
            // declares means a wrong count (e.g. `element vertex 1` over 11,384 rows), and
            // reading only the declared rows would silently drop the rest of the model.
            let mut end = start + needed;
            for e in &header.elements[vi + 1..] {
                end = skip_binary_element(path, body, end, e, big)?;
            }
            if end < body.len() {
                return Err(excess_error(
                    path,
                    vertex,
                    body.len() - end,
                    (vi + 1 == header.elements.len()).then_some(stride),
                ));
            }
        }
        Format::Ascii => {
            owned = ascii_to_rows(
                path,
                body,
                (&header.elements[..vi], &header.elements[vi + 1..]),
                vertex,
                &indices,
            )?;
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
    if let (true, Some(v)) = (scale_2_stood_in, third_log_scale) {
        params.log_scales.iter_mut().for_each(|l| l[2] = v);
    }
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

/// The error for a body that holds `extra` bytes more than the header's elements need;
/// `vertex_stride` is the row size when the vertex element is the last one (the extra bytes are
/// then most likely undeclared vertex rows).
fn excess_error(
    path: &Path,
    vertex: &Element,
    extra: usize,
    vertex_stride: Option<usize>,
) -> anyhow::Error {
    let n = vertex.count;
    let rows = match vertex_stride {
        Some(s) if extra.is_multiple_of(s) => format!(" ({} vertex rows)", extra / s),
        Some(s) => format!(" ({} vertex rows and {} bytes)", extra / s, extra % s),
        None => String::new(),
    };
    crate::error::InputError::new(
        path,
        format!("element vertex {n}"),
        format!(
            "the file holds {extra} bytes{rows} more than the header declares (`element vertex \
             {n}` and the other elements' counts and property types)"
        ),
        "the header's count is wrong: write the true count, or re-export the model",
    )
    .into()
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
    (before, after): (&[Element], &[Element]),
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
    skip_ascii_elements(path, &mut tok, before)?;
    let out = ascii_vertex_rows(path, body.len(), &mut tok, vertex, indices)?;
    skip_ascii_elements(path, &mut tok, after)?;
    // Whitespace after the last row is fine (most writers end with a newline); anything else
    // is content the header does not declare.
    if let Some(t) = tok.next() {
        let more = 1 + tok.count();
        let per_row = vertex.props.len();
        let rows = if after.is_empty() && more.is_multiple_of(per_row) {
            format!(" ({} vertex rows)", more / per_row)
        } else {
            String::new()
        };
        return bad_input(
            path,
            format!("element vertex {}", vertex.count),
            format!(
                "the file holds {more} values{rows} more than the header declares, from {t:?} \
                 on (`element vertex {}` and the other elements' counts)",
                vertex.count
            ),
            "the header's count is wrong: write the true count, or re-export the model",
        );
    }
    Ok(out)
}

/// Consumes the tokens of ASCII elements `elements`.
fn skip_ascii_elements(
    path: &Path,
    tok: &mut std::str::SplitAsciiWhitespace<'_>,
    elements: &[Element],
) -> anyhow::Result<()> {
    for e in elements {
        // An element without properties has no tokens, whatever its (untrusted) count: no
        // loop over a count of 2^40 that reads nothing.
        if e.props.is_empty() {
            continue;
        }
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
    Ok(())
}

/// Parses the vertex rows of an ASCII body (`body_len` bytes) into little-endian f32 rows of the
/// `indices` properties.
fn ascii_vertex_rows(
    path: &Path,
    body_len: usize,
    tok: &mut std::str::SplitAsciiWhitespace<'_>,
    vertex: &Element,
    indices: &[usize],
) -> anyhow::Result<Vec<u8>> {
    // Where each vertex property goes in the output row, if anywhere (twice for a property
    // that stands in for a missing one).
    let mut dest = vec![Vec::new(); vertex.props.len()];
    for (k, &i) in indices.iter().enumerate() {
        dest[i].push(k);
    }
    let row_bytes = indices.len() * 4;
    // Capacity from the body length, not the claimed count, so a lying header cannot make us
    // allocate more than the file could hold.
    let cap = vertex
        .count
        .min(body_len / (2 * vertex.props.len()).max(1) + 1);
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
            if d.is_empty() {
                continue;
            }
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
            for &k in d {
                row[k * 4..k * 4 + 4].copy_from_slice(&value.to_le_bytes());
            }
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
