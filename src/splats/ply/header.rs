//! The PLY header: format, elements and their properties, read and checked with errors that
//! name the line and the fix.

use std::path::Path;

use crate::error::bad_input;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Scalar {
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
    pub(super) fn parse(name: &str) -> Option<Scalar> {
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

    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Reads an unsigned list count; `None` for a negative or non-integer type.
    pub(super) fn read_count(self, b: &[u8], big: bool) -> Option<usize> {
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

pub(super) fn u16_of(b: &[u8], big: bool) -> u16 {
    let a = [b[0], b[1]];
    if big {
        u16::from_be_bytes(a)
    } else {
        u16::from_le_bytes(a)
    }
}

pub(super) fn u32_of(b: &[u8], big: bool) -> u32 {
    let a = [b[0], b[1], b[2], b[3]];
    if big {
        u32::from_be_bytes(a)
    } else {
        u32::from_le_bytes(a)
    }
}

#[derive(Debug, Clone)]
pub(super) enum PropKind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
pub(super) struct Property {
    pub(super) name: String,
    pub(super) kind: PropKind,
}

#[derive(Debug, Clone)]
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: usize,
    pub(super) props: Vec<Property>,
}

pub(super) struct Header {
    pub(super) format: Format,
    pub(super) elements: Vec<Element>,
    /// The text of every `comment` line, in order (without the keyword).
    pub(super) comments: Vec<String>,
    /// Byte offset of the body.
    pub(super) body: usize,
}

/// Headers longer than this are not PLY headers we expect (guards against scanning a huge
/// binary file line by line).
pub(super) const MAX_HEADER_BYTES: usize = 1 << 20;

pub(super) fn parse_header(path: &Path, bytes: &[u8]) -> anyhow::Result<Header> {
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
    let mut comments = Vec::new();
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
            Some("comment") => {
                let text = line.trim_start().strip_prefix("comment").unwrap_or("");
                comments.push(text.trim().to_string());
            }
            None | Some("obj_info") => {}
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
        comments,
        body: pos,
    })
}
