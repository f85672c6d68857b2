//! A fuzz corpus for every input format the library reads: valid files written by the library's
//! own writers, then cut, byte-edited and mutated where the structure matters (header counts,
//! property types and order, declared byte order, non-finite numbers in every numeric field,
//! duplicated and removed lines, empty files). Every case must end in a clear error that names
//! the file (and says `Fix:` for the readers that follow the `InputError` convention) or in a
//! valid load; a panic, a case slower than [`CASE_LIMIT`], a corpus that does not
//! finish (a hang) or an abort for a huge allocation fails the test with the case's name and
//! seed. Cases with huge counts (2^40, u64::MAX) stay in: the run finishing without running out
//! of memory is what shows the readers bound their allocations by the file's size.
//!
//! A small sample runs through the `lpmsplat` binary as well, which must fail cleanly and leave
//! an existing output file untouched.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::fuzz_support::*;
use lpmsplat::error::InputError;
use lpmsplat::scene::colmap::{self, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint};
use lpmsplat::scene::video::npy;
use lpmsplat::scene::{LoadOptions, Scene};
use lpmsplat::splats::model::sh_rest_coeffs;
use lpmsplat::splats::ply::{read_ply_extras, read_ply_two_scales, vertex_property_names};
use lpmsplat::splats::{
    ply_comments, read_ply, write_ply, ExtraGroup, ExtraValues, GaussianParams,
};
use rand::Rng;
use rand_pcg::Pcg64;
use serde_json::{json, Value};

/// The longest a whole corpus may take before it counts as hung (each is a second or two).
const CORPUS_LIMIT: Duration = Duration::from_secs(50);

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// The cases of a corpus with (`known` = true) or without a known issue in code outside the
/// readers this corpus owns (huge finite coordinates, non-UTF-8 JSON): those run in tests of
/// their own that name the issue (`colmap_huge_coordinates_are_refused`,
/// `transforms_known_issues`, …), fixed in the loaders and kept as regressions.
fn partition(cases: Vec<Case>, known: bool, issue: impl Fn(&Case) -> bool) -> Vec<Case> {
    cases.into_iter().filter(|c| issue(c) == known).collect()
}

/// A scene file that is not UTF-8: `scene::transforms::read_json` (used by both transforms
/// forms and the Panoptic meta files) names the file but gives no `Fix:`.
fn not_utf8(c: &Case) -> bool {
    std::str::from_utf8(&c.bytes).is_err()
}

/// A finite but huge coordinate (1e300 and beyond): the scene loaders accept it and the scene
/// comes out with an infinite extent or non-finite recentred points.
fn huge_coordinate(c: &Case) -> bool {
    ["= 1e300", "= 1e308", "= -1e308"]
        .iter()
        .any(|t| c.name.contains(t))
}

/// What a case must end in, beyond "no panic, a clear error or a valid load".
#[derive(Clone)]
enum Expect {
    Any,
    /// An error whose text holds this.
    Fail(String),
    Load,
    /// A value only the extra-group reader reads: `read_ply` loads, `read_ply_extras` fails
    /// with an error holding this.
    FailExtras(String),
}

// ---------------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------------

fn ply_model(n: usize, degree: u32, extra: bool, seed: u64) -> GaussianParams {
    let mut r = rng(seed);
    let mut v = |lo: f32, hi: f32| r.gen_range(lo..hi);
    let mut m = GaussianParams {
        sh_degree: degree,
        positions: (0..n)
            .map(|_| [v(-2.0, 2.0), v(-2.0, 2.0), v(-2.0, 2.0)])
            .collect(),
        log_scales: (0..n)
            .map(|_| [v(-5.0, 0.0), v(-5.0, 0.0), v(-5.0, 0.0)])
            .collect(),
        rotations: (0..n)
            .map(|_| [v(0.5, 1.0), v(-0.5, 0.5), v(-0.5, 0.5), v(-0.5, 0.5)])
            .collect(),
        opacity_logits: (0..n).map(|_| v(-3.0, 3.0)).collect(),
        sh_dc: (0..n)
            .map(|_| [v(-1.0, 1.0), v(-1.0, 1.0), v(-1.0, 1.0)])
            .collect(),
        sh_rest: (0..n * sh_rest_coeffs(degree) * 3)
            .map(|_| v(-0.1, 0.1))
            .collect(),
        extra: Vec::new(),
    };
    if extra {
        for g in ply_extras() {
            let values = (0..n * g.stride).map(|_| v(-1.0, 1.0)).collect();
            m.extra.push(ExtraValues { group: g, values });
        }
    }
    m
}

fn ply_extras() -> Vec<ExtraGroup> {
    vec![
        ExtraGroup {
            name: "trbf_center".into(),
            stride: 1,
        },
        ExtraGroup {
            name: "motion".into(),
            stride: 3,
        },
    ]
}

/// A PLY split at the end of its header.
struct Ply {
    name: String,
    header: String,
    body: Vec<u8>,
    /// Vertex count and row size (binary), for row boundaries.
    n: usize,
    row: usize,
    ascii: bool,
}

impl Ply {
    fn bytes(&self) -> Vec<u8> {
        [self.header.as_bytes(), &self.body].concat()
    }
    fn case(&self, what: &str, header: &str, body: &[u8]) -> Case {
        Case::new(
            format!("{} {what}", self.name),
            [header.as_bytes(), body].concat(),
        )
    }
}

fn split_ply(name: &str, bytes: Vec<u8>, n: usize, ascii: bool) -> Ply {
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = String::from_utf8(bytes[..end].to_vec()).unwrap();
    let props = header.matches("\nproperty ").count();
    let row = if header.contains("property double") {
        props * 8
    } else {
        props * 4
    };
    Ply {
        name: name.into(),
        header,
        body: bytes[end..].to_vec(),
        n,
        row,
        ascii,
    }
}

/// The valid PLYs the corpus starts from: binary little-endian (degrees 0 and 1, with extra
/// groups), big-endian, double-typed and ASCII forms of them.
fn ply_bases(dir: &Path) -> Vec<Ply> {
    let mut out = Vec::new();
    let written = |m: &GaussianParams, name: &str| {
        let p = dir.join(format!("{name}.ply"));
        write_ply(&p, m).unwrap();
        std::fs::read(&p).unwrap()
    };
    let m1 = ply_model(3, 1, false, 1);
    let le = split_ply("le_deg1", written(&m1, "le_deg1"), 3, false);
    let m0 = ply_model(2, 0, true, 2);
    let ex = split_ply("le_extra", written(&m0, "le_extra"), 2, false);
    // Big-endian: the same header with the other byte order and every float swapped.
    let be = Ply {
        name: "be_deg1".into(),
        header: le
            .header
            .replace("binary_little_endian", "binary_big_endian"),
        body: le
            .body
            .chunks_exact(4)
            .flat_map(|c| [c[3], c[2], c[1], c[0]])
            .collect(),
        n: 3,
        row: le.row,
        ascii: false,
    };
    // Doubles: every property declared `double`, every value widened.
    let dbl = Ply {
        name: "le_double".into(),
        header: ex.header.replace("property float", "property double"),
        body: ex
            .body
            .chunks_exact(4)
            .flat_map(|c| (f32::from_le_bytes(c.try_into().unwrap()) as f64).to_le_bytes())
            .collect(),
        n: 2,
        row: ex.row * 2,
        ascii: false,
    };
    // ASCII: one line per vertex.
    let props = ex.header.matches("\nproperty ").count();
    let text: String = ex
        .body
        .chunks_exact(4 * props)
        .map(|r| {
            r.chunks_exact(4)
                .map(|c| format!("{}", f32::from_le_bytes(c.try_into().unwrap())))
                .collect::<Vec<_>>()
                .join(" ")
                + "\n"
        })
        .collect();
    let asc = Ply {
        name: "ascii".into(),
        header: ex.header.replace("binary_little_endian", "ascii"),
        body: text.into_bytes(),
        n: 2,
        row: 0,
        ascii: true,
    };
    out.extend([le, ex, be, dbl, asc]);
    out
}

/// Whether an ASCII body cut to `k` bytes lost anything but whitespace.
fn ascii_cut_loses_data(body: &[u8], k: usize) -> bool {
    body[k.min(body.len())..]
        .iter()
        .any(|b| !b.is_ascii_whitespace())
}

fn ply_cases(dir: &Path, seed: u64) -> Vec<(Case, Expect)> {
    let mut r = rng(seed);
    let mut out: Vec<(Case, Expect)> = Vec::new();
    for base in ply_bases(dir) {
        let h = &base.header;
        let b = &base.body;
        out.push((base.case("valid", h, b), Expect::Load));
        // Truncations: the whole header byte by byte, every row boundary, random points.
        let whole = Case::new(base.name.clone(), base.bytes());
        let rows: Vec<usize> = (0..=base.n).map(|i| h.len() + i * base.row).collect();
        for c in truncations(&whole, &rows, h.len() + 8, 40, &mut r) {
            let k = c.bytes.len();
            let expect = if k <= h.len() || !base.ascii || ascii_cut_loses_data(b, k - h.len()) {
                Expect::Fail(String::new())
            } else {
                Expect::Any
            };
            out.push((c, expect));
        }
        // Random byte edits, in the header and in the body.
        for c in byte_edits(&whole, 0, 60, &mut r) {
            out.push((c, Expect::Any));
        }
        for c in byte_edits(&whole, h.len(), 60, &mut r) {
            out.push((c, Expect::Any));
        }
        // Bytes past the declared rows (the `element vertex 1` over 11,384 rows bug).
        for extra in [1usize, 3, 4, 8, base.row.max(1), 2 * base.row.max(1) + 5] {
            let tail: Vec<u8> = if base.ascii {
                b" 1".repeat(extra)
            } else {
                vec![0u8; extra]
            };
            out.push((
                base.case(
                    &format!("{extra} extra body bytes"),
                    h,
                    &[b, &tail[..]].concat(),
                ),
                Expect::Fail("more than the header declares".into()),
            ));
        }
        if base.ascii {
            out.push((
                base.case("trailing whitespace", h, &[b, &b"\n \t\r\n"[..]].concat()),
                Expect::Load,
            ));
        }
        // Header lines: each removed, duplicated, swapped with the next.
        let lines: Vec<&str> = h.lines().collect();
        let join = |ls: &[String]| ls.iter().map(|l| format!("{l}\n")).collect::<String>();
        for i in 0..lines.len() {
            let mut ls: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
            ls.remove(i);
            out.push((
                base.case(&format!("header line {i} removed"), &join(&ls), b),
                Expect::Any,
            ));
            let mut ls: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
            ls.insert(i, lines[i].to_string());
            // A duplicated property or element line changes the row layout: always an error.
            let expect = if lines[i].starts_with("property") || lines[i].starts_with("element") {
                Expect::Fail(String::new())
            } else {
                Expect::Any
            };
            out.push((
                base.case(&format!("header line {i} duplicated"), &join(&ls), b),
                expect,
            ));
            if i + 1 < lines.len() {
                let mut ls: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
                ls.swap(i, i + 1);
                out.push((
                    base.case(
                        &format!("header lines {i}, {} swapped", i + 1),
                        &join(&ls),
                        b,
                    ),
                    Expect::Any,
                ));
            }
        }
        // The vertex count: too small, too large, huge, negative, not a number.
        let count_line = format!("element vertex {}\n", base.n);
        for c in BAD_COUNTS {
            if c == base.n.to_string() {
                continue;
            }
            out.push((
                base.case(
                    &format!("element vertex {c}"),
                    &h.replace(&count_line, &format!("element vertex {c}\n")),
                    b,
                ),
                Expect::Fail(String::new()),
            ));
        }
        // Property types: every scalar type, a list, an unknown one, on a sample of properties.
        let props: Vec<&str> = lines
            .iter()
            .copied()
            .filter(|l| l.starts_with("property "))
            .collect();
        for (k, p) in props.iter().enumerate() {
            if k % 3 != 0 && k + 1 != props.len() {
                continue;
            }
            let name = p.rsplit(' ').next().unwrap();
            for t in [
                "char",
                "uchar",
                "short",
                "ushort",
                "int",
                "uint",
                "float",
                "double",
                "int8",
                "float64",
                "list uchar float",
                "list float int",
                "list uint double",
                "quad",
            ] {
                let new = format!("property {t} {name}");
                if new == *p {
                    continue;
                }
                out.push((
                    base.case(
                        &format!("{name} as {t}"),
                        &h.replacen(&format!("{p}\n"), &format!("{new}\n"), 1),
                        b,
                    ),
                    Expect::Any,
                ));
            }
        }
        // The declared format: each other byte order, ASCII over binary and back, unknown.
        for f in [
            "ascii 1.0",
            "binary_little_endian 1.0",
            "binary_big_endian 1.0",
            "binary_middle_endian 1.0",
            "binary_little_endian",
            "",
        ] {
            let line = lines.iter().find(|l| l.starts_with("format")).unwrap();
            out.push((
                base.case(
                    &format!("format {f:?}"),
                    &h.replace(&format!("{line}\n"), &format!("format {f}\n")),
                    b,
                ),
                Expect::Any,
            ));
        }
        // Elements before and after the vertices with untrusted counts and no, scalar or list
        // properties: a count of 2^40 rows of nothing must not loop 2^40 times.
        for (what, el) in [
            ("empty 2^40", "element face 1099511627776\n"),
            ("empty u64::MAX", "element face 18446744073709551615\n"),
            (
                "scalar 2^40",
                "element face 1099511627776\nproperty float q\n",
            ),
            (
                "list 2^40",
                "element face 1099511627776\nproperty list uchar int vertex_indices\n",
            ),
            (
                "list u64::MAX",
                "element face 18446744073709551615\nproperty list uint uint idx\n",
            ),
        ] {
            let before = h.replacen("element vertex", &format!("{el}element vertex"), 1);
            out.push((
                base.case(&format!("{what} element before"), &before, b),
                Expect::Any,
            ));
            let after = h.replace("end_header\n", &format!("{el}end_header\n"));
            out.push((
                base.case(&format!("{what} element after"), &after, b),
                Expect::Any,
            ));
        }
        // Other header shapes: CRLF lines, non-text, comments, no vertex element, empty file.
        out.push((
            base.case("crlf header", &h.replace('\n', "\r\n"), b),
            Expect::Any,
        ));
        let mut bad = h.as_bytes().to_vec();
        bad.splice(4..4, [0xFFu8, 0xFE, b'\n']);
        out.push((
            Case::new(
                format!("{} non-text header line", base.name),
                [&bad[..], b].concat(),
            ),
            Expect::Fail(String::new()),
        ));
        out.push((
            base.case(
                "comments",
                &h.replacen(
                    "format",
                    "comment a\ncomment \ncomment \u{e9}\u{0}\nformat",
                    1,
                ),
                b,
            ),
            Expect::Load,
        ));
        out.push((
            base.case(
                "no vertex element",
                &h.replace("element vertex", "element point"),
                b,
            ),
            Expect::Fail("vertex".into()),
        ));
        // Non-finite values in every field of every row: an error naming the vertex and the
        // property for the ones the model reads (normals are not read).
        let names: Vec<String> = props
            .iter()
            .map(|p| p.rsplit(' ').next().unwrap().to_string())
            .collect();
        for v in 0..base.n {
            for (k, name) in names.iter().enumerate() {
                let read = !name.starts_with('n');
                for (j, x) in NON_FINITE_F64.iter().enumerate() {
                    let body = if base.ascii {
                        let text = String::from_utf8(b.clone()).unwrap();
                        let mut rows: Vec<Vec<String>> = text
                            .lines()
                            .map(|l| l.split(' ').map(str::to_string).collect())
                            .collect();
                        rows[v][k] = ["nan", "inf", "-inf"][j].into();
                        rows.iter()
                            .map(|r| r.join(" ") + "\n")
                            .collect::<String>()
                            .into_bytes()
                    } else {
                        let mut body = b.clone();
                        let width = base.row / names.len();
                        let o = v * base.row + k * width;
                        let bytes = match (width, base.header.contains("big_endian")) {
                            (8, _) => x.to_le_bytes().to_vec(),
                            (_, true) => (*x as f32).to_be_bytes().to_vec(),
                            _ => (*x as f32).to_le_bytes().to_vec(),
                        };
                        body[o..o + width].copy_from_slice(&bytes);
                        body
                    };
                    let field = format!("vertex {v}, property {name}");
                    let extra = name == "trbf_center" || name.starts_with("motion_");
                    let expect = if extra {
                        Expect::FailExtras(field)
                    } else if read {
                        Expect::Fail(field)
                    } else {
                        Expect::Load
                    };
                    out.push((
                        base.case(&format!("vertex {v} {name} = {x}"), h, &body),
                        expect,
                    ));
                }
            }
        }
        // ASCII tokens replaced by words that are not finite floats, or not numbers.
        if base.ascii {
            let text = String::from_utf8(b.clone()).unwrap();
            for (k, t) in BAD_TOKENS.iter().enumerate() {
                let at = (k * 7) % names.len();
                let mut rows: Vec<Vec<String>> = text
                    .lines()
                    .map(|l| l.split(' ').map(str::to_string).collect())
                    .collect();
                rows[k % base.n][at] = t.to_string();
                let body = rows.iter().map(|r| r.join(" ") + "\n").collect::<String>();
                out.push((
                    base.case(&format!("token {at} = {t:?}"), h, body.as_bytes()),
                    Expect::Any,
                ));
            }
        }
    }
    out.push((
        Case::new("empty file", Vec::new()),
        Expect::Fail("header".into()),
    ));
    out.push((
        Case::new("only ply", b"ply\n".to_vec()),
        Expect::Fail("header".into()),
    ));
    out.push((
        Case::new("png bytes", b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR".to_vec()),
        Expect::Fail("not a PLY".into()),
    ));
    out
}

/// A read model must be what a model is: consistent lengths, finite values.
fn valid_model(p: &GaussianParams) -> Result<(), String> {
    p.validate()
        .map_err(|e| format!("loaded an invalid model: {e:#}"))
}

fn check_ply(path: &Path, expect: &Expect) -> Result<(), String> {
    let results: [(&str, anyhow::Result<()>); 5] = [
        (
            "read_ply",
            read_ply(path).map(|p| {
                if let Err(e) = valid_model(&p) {
                    panic!("{e}")
                }
            }),
        ),
        (
            "read_ply_two_scales",
            read_ply_two_scales(path, -4.0).map(|p| {
                if let Err(e) = valid_model(&p) {
                    panic!("{e}")
                }
            }),
        ),
        (
            "read_ply_extras",
            read_ply_extras(path, &ply_extras()).map(|p| {
                if let Err(e) = valid_model(&p) {
                    panic!("{e}")
                }
                for e in &p.extra {
                    assert_eq!(e.values.len(), p.len() * e.group.stride);
                    assert!(e.values.iter().all(|v| v.is_finite()), "non-finite extra");
                }
            }),
        ),
        (
            "vertex_property_names",
            vertex_property_names(path).map(drop),
        ),
        ("ply_comments", ply_comments(path).map(drop)),
    ];
    for (reader, r) in &results {
        if let Err(e) = r {
            names_file(e, path, true).map_err(|w| format!("{reader}: {w}"))?;
            if e.downcast_ref::<InputError>().is_none() {
                return Err(format!("{reader}: not an InputError: {e:#}"));
            }
        }
    }
    // The expectation is about reading the model (read_ply); the other readers may refuse a
    // file read_ply takes (no extra groups) or take one it refuses (headers only).
    match (expect, &results[0].1) {
        (Expect::Fail(want), Ok(())) => Err(format!("read_ply accepted it (expected {want:?})")),
        (Expect::Fail(want), Err(e)) if !format!("{e:#}").contains(want.as_str()) => {
            Err(format!("read_ply's error lacks {want:?}: {e:#}"))
        }
        (Expect::Load, Err(e)) => Err(format!("read_ply refused a valid file: {e:#}")),
        (Expect::FailExtras(want), r) => match (r, &results[2].1) {
            (Err(e), _) => Err(format!("read_ply refused a value it does not read: {e:#}")),
            (_, Ok(())) => Err(format!("read_ply_extras accepted it (expected {want:?})")),
            (_, Err(e)) if !format!("{e:#}").contains(want.as_str()) => {
                Err(format!("read_ply_extras' error lacks {want:?}: {e:#}"))
            }
            _ => Ok(()),
        },
        _ => Ok(()),
    }
}

#[test]
fn ply_corpus() {
    let seed = 0x9_1A;
    let dir = tmp();
    let cases = ply_cases(dir.path(), seed);
    let work = dir.path().join("cases");
    std::fs::create_dir_all(&work).unwrap();
    let expects: Vec<Expect> = cases.iter().map(|c| c.1.clone()).collect();
    let cases: Vec<Case> = cases
        .into_iter()
        .enumerate()
        .map(|(i, (mut c, _))| {
            c.name = format!("#{i} {}", c.name);
            c
        })
        .collect();
    let index = |c: &Case| -> usize { c.name[1..].split(' ').next().unwrap().parse().unwrap() };
    let _keep = dir;
    run_corpus("ply", seed, cases, CORPUS_LIMIT, move |c| {
        let i = index(c);
        let path = case_path(&work, i, "ply");
        std::fs::write(&path, &c.bytes).unwrap();
        let r = check_ply(&path, &expects[i]);
        std::fs::remove_file(&path).ok();
        r
    });
}

// ---------------------------------------------------------------------------------------------
// COLMAP
// ---------------------------------------------------------------------------------------------

const CW: u64 = 16;
const CH: u64 = 12;

/// A small consistent model: two cameras (PINHOLE, OPENCV), three images with keypoints, four
/// points whose tracks point at them.
fn colmap_model() -> ColmapModel {
    let cameras = vec![
        ColmapCamera {
            id: 1,
            model_id: 1,
            width: CW,
            height: CH,
            params: vec![14.0, 15.0, 8.0, 6.0],
        },
        ColmapCamera {
            id: 2,
            model_id: 4,
            width: CW,
            height: CH,
            params: vec![14.0, 14.0, 8.0, 6.0, 0.01, -0.002, 0.0005, 0.0001],
        },
    ];
    let q = |a: f64| [(a / 2.0).cos(), 0.0, (a / 2.0).sin(), 0.0];
    let images = (0..3u32)
        .map(|i| ColmapImage {
            id: i + 1,
            qvec: q(0.1 * i as f64),
            tvec: [0.1 * i as f64, 0.0, 4.0],
            camera_id: 1 + i % 2,
            name: format!("im{i}.png"),
            points2d: vec![[3.5, 4.5], [10.0, 7.25]],
            point3d_ids: vec![(i as i64 % 4) + 1, -1],
        })
        .collect();
    let points = (0..4u64)
        .map(|p| ColmapPoint {
            id: p + 1,
            xyz: [0.1 * p as f64, -0.2, 0.3],
            rgb: [10, 20 * p as u8, 30],
            error: 0.5,
            track: (0..3u32)
                .filter(|i| (*i as u64 % 4) == p)
                .map(|i| (i + 1, 0))
                .collect(),
        })
        .collect();
    ColmapModel {
        cameras,
        images,
        points,
    }
}

fn write_png(path: &Path, w: u32, h: u32) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 9) as u8, (y * 13) as u8, 77]))
        .save(path)
        .unwrap();
}

/// A COLMAP scene folder with the model in both forms; returns (root, sparse dir).
fn colmap_scene(root: &Path) -> PathBuf {
    let model = colmap_model();
    let sparse = root.join("sparse/0");
    colmap::write_binary(&sparse, &model).unwrap();
    colmap::write_text(&sparse, &model).unwrap();
    for im in &model.images {
        write_png(&root.join("images").join(&im.name), CW as u32, CH as u32);
    }
    sparse
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    U8,
    U32,
    I32,
    U64,
    I64,
    F64,
}

/// The fields of a COLMAP binary file as (name, offset, kind), walked over a valid file.
fn colmap_fields(which: &str, b: &[u8]) -> Vec<(String, usize, Kind)> {
    let mut f = Vec::new();
    let mut at = 0usize;
    let u64_at = |at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
    let push = |f: &mut Vec<_>, name: String, kind: Kind, at: &mut usize| {
        f.push((name, *at, kind));
        *at += match kind {
            Kind::U8 => 1,
            Kind::U32 | Kind::I32 => 4,
            _ => 8,
        };
    };
    let n = u64_at(0);
    push(&mut f, "count".into(), Kind::U64, &mut at);
    for r in 0..n {
        match which {
            "cameras" => {
                push(&mut f, format!("cam{r}.id"), Kind::U32, &mut at);
                let model = i32::from_le_bytes(b[at..at + 4].try_into().unwrap());
                push(&mut f, format!("cam{r}.model"), Kind::I32, &mut at);
                push(&mut f, format!("cam{r}.width"), Kind::U64, &mut at);
                push(&mut f, format!("cam{r}.height"), Kind::U64, &mut at);
                let np = if model == 1 { 4 } else { 8 };
                for k in 0..np {
                    push(&mut f, format!("cam{r}.params[{k}]"), Kind::F64, &mut at);
                }
            }
            "images" => {
                push(&mut f, format!("im{r}.id"), Kind::U32, &mut at);
                for k in 0..7 {
                    push(&mut f, format!("im{r}.pose[{k}]"), Kind::F64, &mut at);
                }
                push(&mut f, format!("im{r}.camera_id"), Kind::U32, &mut at);
                at += b[at..].iter().position(|&c| c == 0).unwrap() + 1;
                let np = u64_at(at);
                push(&mut f, format!("im{r}.num_points2D"), Kind::U64, &mut at);
                for k in 0..np {
                    push(&mut f, format!("im{r}.p{k}.x"), Kind::F64, &mut at);
                    push(&mut f, format!("im{r}.p{k}.y"), Kind::F64, &mut at);
                    push(&mut f, format!("im{r}.p{k}.id"), Kind::I64, &mut at);
                }
            }
            _ => {
                push(&mut f, format!("pt{r}.id"), Kind::U64, &mut at);
                for k in 0..3 {
                    push(&mut f, format!("pt{r}.xyz[{k}]"), Kind::F64, &mut at);
                }
                for k in 0..3 {
                    push(&mut f, format!("pt{r}.rgb[{k}]"), Kind::U8, &mut at);
                }
                push(&mut f, format!("pt{r}.error"), Kind::F64, &mut at);
                let len = u64_at(at);
                push(&mut f, format!("pt{r}.track_length"), Kind::U64, &mut at);
                for k in 0..len {
                    push(&mut f, format!("pt{r}.t{k}.image"), Kind::U32, &mut at);
                    push(&mut f, format!("pt{r}.t{k}.idx"), Kind::U32, &mut at);
                }
            }
        }
    }
    assert_eq!(at, b.len(), "{which}: the walk must cover the file");
    f
}

/// Structured mutations of a COLMAP binary file: every field set to edge values (counts huge,
/// ids zero and maximal, floats non-finite), the image name unterminated and not UTF-8.
fn colmap_binary_cases(which: &str, b: &[u8], r: &mut Pcg64) -> Vec<Case> {
    let mut out = vec![Case::new(format!("{which}.bin valid"), b.to_vec())];
    for (name, at, kind) in colmap_fields(which, b) {
        let mut put = |label: String, bytes: &[u8]| {
            let mut m = b.to_vec();
            m[at..at + bytes.len()].copy_from_slice(bytes);
            out.push(Case::new(format!("{which}.bin {name} = {label}"), m));
        };
        match kind {
            Kind::U64 | Kind::I64 => {
                for v in BAD_U64 {
                    put(v.to_string(), &v.to_le_bytes());
                }
            }
            Kind::U32 | Kind::I32 => {
                for v in [0u32, 3, 99, 0x7FFF_FFFF, 0x8000_0000, u32::MAX] {
                    put(v.to_string(), &v.to_le_bytes());
                }
            }
            Kind::F64 => {
                for v in NON_FINITE_F64.iter().chain(&[0.0, -1e308, 1e308]) {
                    put(format!("{v:e}"), &v.to_le_bytes());
                }
            }
            Kind::U8 => put("255".into(), &[255]),
        }
    }
    if which == "images" {
        let nul = b.iter().position(|&c| c == b'.').unwrap();
        let mut m = b.to_vec();
        m[nul - 1] = 0xFF;
        out.push(Case::new("images.bin name not UTF-8", m));
        let mut m = b.to_vec();
        let end = m.iter().rposition(|&c| c == 0).unwrap();
        m.truncate(end);
        out.push(Case::new("images.bin cut before a NUL", m));
        let mut m = b.to_vec();
        for c in m.iter_mut().skip(60) {
            if *c == 0 {
                *c = b'a';
            }
        }
        out.push(Case::new("images.bin no NUL after the first record", m));
    }
    let whole = Case::new(format!("{which}.bin"), b.to_vec());
    out.extend(truncations(&whole, &[8], 80, 40, r));
    out.extend(byte_edits(&whole, 0, 60, r));
    out.push(Case::new(
        format!("{which}.bin trailing byte"),
        [b, &[0]].concat(),
    ));
    out.push(Case::new(format!("{which}.bin doubled"), [b, b].concat()));
    out.push(Case::new(format!("{which}.bin empty"), Vec::new()));
    out
}

/// Line-level mutations of a COLMAP text file: lines removed, duplicated, swapped, every token
/// replaced by words that are not valid numbers, an extra token, CRLF, non-UTF-8.
fn colmap_text_cases(which: &str, t: &str, r: &mut Pcg64) -> Vec<Case> {
    let mut out = vec![Case::new(
        format!("{which}.txt valid"),
        t.as_bytes().to_vec(),
    )];
    let lines: Vec<&str> = t.lines().collect();
    let join = |ls: &[String]| ls.iter().map(|l| format!("{l}\n")).collect::<String>();
    let own = || lines.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    for i in 0..lines.len() {
        let mut ls = own();
        ls.remove(i);
        out.push(Case::new(
            format!("{which}.txt line {i} removed"),
            join(&ls).into(),
        ));
        let mut ls = own();
        ls.insert(i, lines[i].to_string());
        out.push(Case::new(
            format!("{which}.txt line {i} duplicated"),
            join(&ls).into(),
        ));
        if i + 1 < lines.len() {
            let mut ls = own();
            ls.swap(i, i + 1);
            out.push(Case::new(
                format!("{which}.txt lines {i}, {} swapped", i + 1),
                join(&ls).into(),
            ));
        }
        if lines[i].starts_with('#') {
            continue;
        }
        let toks: Vec<&str> = lines[i].split(' ').collect();
        for k in 0..toks.len() {
            for (j, bad) in BAD_TOKENS.iter().enumerate() {
                // Every token with a few words, a rotating sample of the rest.
                if j >= 4 && (j + k + i) % 5 != 0 {
                    continue;
                }
                let mut tk: Vec<String> = toks.iter().map(|s| s.to_string()).collect();
                tk[k] = bad.to_string();
                let mut ls = own();
                ls[i] = tk.join(" ");
                out.push(Case::new(
                    format!("{which}.txt line {i} token {k} = {bad:?}"),
                    join(&ls).into(),
                ));
            }
        }
        let mut ls = own();
        ls[i].push_str(" 7");
        out.push(Case::new(
            format!("{which}.txt line {i} extra token"),
            join(&ls).into(),
        ));
    }
    out.push(Case::new(
        format!("{which}.txt crlf"),
        t.replace('\n', "\r\n").into(),
    ));
    out.push(Case::new(
        format!("{which}.txt not UTF-8"),
        [t.as_bytes(), &[0xC3, 0x28]].concat(),
    ));
    let whole = Case::new(format!("{which}.txt"), t.as_bytes().to_vec());
    out.extend(truncations(&whole, &[], 0, 40, r));
    out.extend(byte_edits(&whole, 0, 40, r));
    out.push(Case::new(format!("{which}.txt empty"), Vec::new()));
    out
}

/// A loaded scene must be usable: finite poses and cameras, positive sizes, finite points.
fn valid_scene(s: &Scene) -> Result<(), String> {
    if s.views.is_empty() {
        return Err("a scene without views loaded".into());
    }
    for v in &s.views {
        let c = &v.camera;
        let cam_ok = [c.fx, c.fy, c.cx, c.cy].iter().all(|x| x.is_finite())
            && c.fx > 0.0
            && c.fy > 0.0
            && c.width > 0
            && c.height > 0;
        let pose_ok = v
            .pose
            .rotation
            .iter()
            .flatten()
            .chain(&v.pose.translation)
            .all(|x| x.is_finite());
        if !cam_ok || !pose_ok {
            return Err(format!(
                "view {} loaded with camera {:?} pose {:?}",
                v.name, v.camera, v.pose
            ));
        }
    }
    if let Some(p) = &s.points {
        if !p.positions.iter().flatten().all(|x| x.is_finite()) {
            return Err("non-finite SfM point loaded".into());
        }
        for t in p.tracks.iter().flatten() {
            if t.0 as usize >= s.views.len() {
                return Err(format!("a track names view {} of {}", t.0, s.views.len()));
            }
        }
    }
    if !(s.extent.is_finite() && s.center.iter().all(|x| x.is_finite())) {
        return Err(format!("extent {} centre {:?}", s.extent, s.center));
    }
    Ok(())
}

/// Loads the scene at `root`; Err(why) when the outcome is not a valid scene or a clear error
/// naming a file inside `root`.
fn check_scene_load(root: &Path, opts: &LoadOptions, want_fix: bool) -> Result<(), String> {
    match Scene::load(root, opts) {
        Ok(s) => valid_scene(&s),
        Err(e) => names_file(&e, root, want_fix),
    }
}

#[test]
fn colmap_corpus() {
    colmap_corpus_run(false);
}

#[test]
fn colmap_huge_coordinates_are_refused() {
    colmap_corpus_run(true);
}

fn colmap_corpus_run(known: bool) {
    let seed = 0xC01_4A9;
    let dir = tmp();
    let root = dir.path().join("scene");
    let sparse = colmap_scene(&root);
    let mut r = rng(seed);
    let mut cases = Vec::new();
    for which in ["cameras", "images", "points3D"] {
        let b = std::fs::read(sparse.join(format!("{which}.bin"))).unwrap();
        cases.extend(colmap_binary_cases(which, &b, &mut r));
        let t = std::fs::read_to_string(sparse.join(format!("{which}.txt"))).unwrap();
        cases.extend(colmap_text_cases(which, &t, &mut r));
    }
    // Scene::load decodes the images: run it on every fourth case, the readers on all.
    let opts = |form| LoadOptions {
        colmap_form: form,
        ..LoadOptions::default()
    };
    let mut k = 0usize;
    // Known issue also: a random edit of an exponent that reads as a huge pose or point.
    let probe = dir.path().join("probe");
    let huge = move |c: &Case| {
        let name = c.name.split(' ').next().unwrap();
        std::fs::write(&probe, &c.bytes).unwrap();
        let big = |v: &f64| v.abs() > 1e100 && v.is_finite();
        huge_coordinate(c)
            || (name == "images.bin"
                && colmap::binary::read_images(&probe)
                    .is_ok_and(|ims| ims.iter().any(|i| i.tvec.iter().any(big))))
            || (name == "points3D.bin"
                && colmap::binary::read_points(&probe)
                    .is_ok_and(|ps| ps.iter().any(|p| p.xyz.iter().any(big))))
    };
    let cases = partition(cases, known, huge);
    let _keep = dir;
    run_corpus("colmap", seed, cases, CORPUS_LIMIT, move |c| {
        let name = c.name.split(' ').next().unwrap();
        let path = sparse.join(name);
        let original = std::fs::read(&path).unwrap();
        std::fs::write(&path, &c.bytes).unwrap();
        let binary = name.ends_with(".bin");
        let read = if binary {
            match name {
                "cameras.bin" => colmap::binary::read_cameras(&path).map(drop),
                "images.bin" => colmap::binary::read_images(&path).map(drop),
                _ => colmap::binary::read_points(&path).map(drop),
            }
        } else {
            match name {
                "cameras.txt" => colmap::text::read_cameras(&path).map(drop),
                "images.txt" => colmap::text::read_images(&path).map(drop),
                _ => colmap::text::read_points(&path).map(drop),
            }
        };
        let mut result = match &read {
            Ok(()) => Ok(()),
            Err(e) => names_file(e, &path, true),
        };
        if let (true, Err(e)) = (c.name.ends_with("valid"), &read) {
            result = Err(format!("a valid file was refused: {e:#}"));
        }
        k += 1;
        if result.is_ok() && (k.is_multiple_of(4) || c.name.ends_with("valid")) {
            let form = if binary {
                lpmsplat::scene::ColmapForm::Binary
            } else {
                lpmsplat::scene::ColmapForm::Text
            };
            result =
                check_scene_load(&root, &opts(form), true).map_err(|w| format!("Scene::load: {w}"));
        }
        std::fs::write(&path, original).unwrap();
        result
    });
}

// ---------------------------------------------------------------------------------------------
// transforms.json (NeRF-synthetic and nerfstudio)
// ---------------------------------------------------------------------------------------------

/// A camera-to-world matrix (OpenGL axes) at `c` looking roughly at the origin.
fn c2w(c: [f64; 3], a: f64) -> Value {
    let (s, co) = a.sin_cos();
    json!([
        [co, 0.0, s, c[0]],
        [0.0, 1.0, 0.0, c[1]],
        [-s, 0.0, co, c[2]],
        [0.0, 0.0, 0.0, 1.0]
    ])
}

/// JSON tokens for numbers: non-finite (Python's `json.dump` writes them), out of range,
/// zero, negative, not a number.
const JSON_TOKENS: [&str; 9] = [
    "NaN",
    "Infinity",
    "-Infinity",
    "1e999",
    "0",
    "-1",
    "1e300",
    "18446744073709551616",
    "\"3\"",
];

#[test]
fn transforms_corpus() {
    transforms_corpus_run(false);
}

#[test]
fn transforms_known_issues() {
    transforms_corpus_run(true);
}

fn transforms_corpus_run(known: bool) {
    let seed = 0x7_EA45;
    let dir = tmp();
    let mut r = rng(seed);
    // NeRF-synthetic: train and test files, images ./train/r_N.png and ./test/r_N.png.
    let ns = dir.path().join("nerf_synthetic");
    let frames = |split: &str, n: usize| -> Value {
        let f: Vec<Value> = (0..n)
            .map(|i| {
                json!({
                    "file_path": format!("./{split}/r_{i}"),
                    "rotation": 0.1,
                    "transform_matrix": c2w([0.5 * i as f64, 0.2, 3.0], 0.1 * i as f64),
                })
            })
            .collect();
        json!({ "camera_angle_x": 0.69, "frames": f })
    };
    for (split, n) in [("train", 2), ("test", 1)] {
        for i in 0..n {
            write_png(&ns.join(format!("{split}/r_{i}.png")), 8, 6);
        }
        std::fs::write(
            ns.join(format!("transforms_{split}.json")),
            frames(split, n).to_string(),
        )
        .unwrap();
    }
    // nerfstudio: one transforms.json with intrinsics, distortion and a split.
    let nst = dir.path().join("nerfstudio");
    let f: Vec<Value> = (0..3)
        .map(|i| {
            write_png(&nst.join(format!("images/frame_{i}.png")), 8, 6);
            json!({
                "file_path": format!("images/frame_{i}.png"),
                "transform_matrix": c2w([0.4 * i as f64, -0.1, 2.5], -0.1 * i as f64),
            })
        })
        .collect();
    let ns_json = json!({
        "w": 8, "h": 6, "fl_x": 7.0, "fl_y": 7.5, "cx": 4.0, "cy": 3.0,
        "k1": 0.01, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "camera_model": "OPENCV",
        "frames": f,
    });
    std::fs::write(nst.join("transforms.json"), ns_json.to_string()).unwrap();

    let mut cases = Vec::new();
    for c in json_cases(
        "nerf_synthetic/transforms_train.json",
        &frames("train", 2),
        &JSON_TOKENS,
        1,
        40,
        &mut r,
    ) {
        cases.push(c);
    }
    for c in json_cases(
        "nerfstudio/transforms.json",
        &ns_json,
        &JSON_TOKENS,
        1,
        40,
        &mut r,
    ) {
        cases.push(c);
    }
    let cases = partition(cases, known, |c| not_utf8(c) || huge_coordinate(c));
    let root = dir.path().to_path_buf();
    run_corpus("transforms", seed, cases, CORPUS_LIMIT, move |c| {
        let rel = c.name.split(' ').next().unwrap();
        let path = root.join(rel);
        let scene = path.parent().unwrap().to_path_buf();
        let original = std::fs::read(&path).unwrap();
        std::fs::write(&path, &c.bytes).unwrap();
        let result = match Scene::load(&scene, &LoadOptions::default()) {
            Ok(s) => valid_scene(&s),
            Err(e) if c.name.ends_with(" valid") => {
                Err(format!("a valid scene was refused: {e:#}"))
            }
            Err(e) => names_file(&e, &scene, true),
        };
        std::fs::write(&path, original).unwrap();
        result
    });
}

// ---------------------------------------------------------------------------------------------
// Video layouts: poses_bounds.npy (Neural 3D Video) and Panoptic train_meta.json
// ---------------------------------------------------------------------------------------------

/// LLFF rows for cameras on a line in front of the origin: [down, right, back, centre, hwf]
/// columns then near and far bounds.
fn n3v_rows(cams: usize, w: u32, h: u32) -> Vec<f64> {
    let mut rows = Vec::new();
    for i in 0..cams {
        let c = [0.3 * i as f64 - 0.3, 0.0, -4.0];
        // Camera-to-world (OpenCV): x right, y down, z forward (+z, toward the origin).
        let (x, y, z) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        for r in 0..3 {
            rows.extend([
                y[r],
                x[r],
                -z[r],
                c[r],
                [h as f64, w as f64, 0.8 * w as f64][r],
            ]);
        }
        rows.extend([0.5, 20.0]);
    }
    rows
}

/// Mutations of a `.npy` file: magic, version, header length, every dict entry, the shape
/// (huge, overflowing, wrong rank), every value non-finite, the data cut and edited.
fn npy_cases(b: &[u8], rows: usize, cols: usize, r: &mut Pcg64) -> Vec<(Case, Expect)> {
    let mut out = vec![(Case::new("valid", b.to_vec()), Expect::Load)];
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = String::from_utf8(b[10..10 + hl].to_vec()).unwrap();
    let data = &b[10 + hl..];
    let with_header = |h: &str| -> Vec<u8> {
        let mut h = h.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut v = b"\x93NUMPY\x01\x00".to_vec();
        v.extend((h.len() as u16).to_le_bytes());
        v.extend(h.as_bytes());
        v
    };
    let shape = format!("({rows}, {cols})");
    for (what, from, to) in [
        ("descr >f8", "'<f8'", "'>f8'"),
        ("descr <f4", "'<f8'", "'<f4'"),
        ("descr <i8", "'<f8'", "'<i8'"),
        ("descr |u1", "'<f8'", "'|u1'"),
        ("descr missing", "'descr'", "'dtype'"),
        ("fortran", "False", "True"),
        ("fortran missing", "'fortran_order'", "'order'"),
        (
            "shape 2^40 rows",
            &shape,
            &format!("(1099511627776, {cols})"),
        ),
        (
            "shape u64::MAX",
            &shape,
            &format!("(18446744073709551615, {cols})"),
        ),
        ("shape overflow 2^62+", &shape, "(4611686018427387904, 4)"),
        ("shape wraps to 0", &shape, "(2305843009213693952, 8)"),
        // (2^61 + 51) × 1 × 8 bytes wraps to 408, the size of the 3 × 17 data.
        (
            "shape wraps to the data size",
            &shape,
            "(2305843009213693955, 1)",
        ),
        (
            "shape too many rows",
            &shape,
            &format!("({}, {cols})", rows + 1),
        ),
        (
            "shape too few rows",
            &shape,
            &format!("({}, {cols})", rows - 1),
        ),
        ("shape 1-D", &shape, &format!("({},)", rows * cols)),
        ("shape 3-D", &shape, &format!("({rows}, {cols}, 1)")),
        ("shape 0 rows", &shape, &format!("(0, {cols})")),
        ("shape negative", &shape, &format!("(-1, {cols})")),
        ("shape not numbers", &shape, "(a, b)"),
        ("shape missing", "'shape'", "'size'"),
    ] {
        let h = header.trim_end().replacen(from, to, 1);
        // The data of the original shape; the f4 one with the same bytes is 2× too long.
        out.push((
            Case::new(what, [with_header(&h), data.to_vec()].concat()),
            Expect::Fail("Fix:".into()),
        ));
    }
    // The same byte count under another shape or a lenient dict still parses; the scene
    // loader then judges the columns.
    for (what, h) in [
        (
            "shape transposed",
            header.replacen(&shape, &format!("({cols}, {rows})"), 1),
        ),
        ("header unterminated", header.replacen('}', "", 1)),
    ] {
        out.push((
            Case::new(what, [with_header(h.trim_end()), data.to_vec()].concat()),
            Expect::Any,
        ));
    }
    // The f4 form of the same array is valid.
    let f4: Vec<u8> = data
        .chunks_exact(8)
        .flat_map(|c| (f64::from_le_bytes(c.try_into().unwrap()) as f32).to_le_bytes())
        .collect();
    out.push((
        Case::new(
            "as <f4",
            [
                with_header(&header.trim_end().replace("'<f8'", "'<f4'")),
                f4,
            ]
            .concat(),
        ),
        Expect::Load,
    ));
    for v in [0u8, 2, 3, 4, 255] {
        let mut m = b.to_vec();
        m[6] = v;
        out.push((Case::new(format!("version {v}"), m), Expect::Any));
    }
    for v in [0u16, 1, 9, hl as u16 - 1, hl as u16 + 1, u16::MAX] {
        let mut m = b.to_vec();
        m[8..10].copy_from_slice(&v.to_le_bytes());
        out.push((
            Case::new(format!("header length {v}"), m),
            Expect::Fail("Fix:".into()),
        ));
    }
    let mut m = b.to_vec();
    m[1] = b'X';
    out.push((Case::new("magic", m), Expect::Fail("magic".into())));
    for k in 0..rows * cols {
        for x in NON_FINITE_F64.iter().chain(&[1e300, -1e308]) {
            let mut m = b.to_vec();
            let o = 10 + hl + 8 * k;
            m[o..o + 8].copy_from_slice(&x.to_le_bytes());
            out.push((Case::new(format!("value {k} = {x:e}"), m), Expect::Any));
        }
    }
    let whole = Case::new("npy", b.to_vec());
    let ends: Vec<usize> = (0..=rows).map(|i| 10 + hl + 8 * cols * i).collect();
    for c in truncations(&whole, &ends, 16, 30, r) {
        out.push((c, Expect::Fail("Fix:".into())));
    }
    for c in byte_edits(&whole, 0, 60, r) {
        out.push((c, Expect::Any));
    }
    out.push((
        Case::new("trailing byte", [b, &[0]].concat()),
        Expect::Fail("data".into()),
    ));
    out.push((Case::new("empty", Vec::new()), Expect::Fail("magic".into())));
    out
}

#[test]
fn n3v_poses_bounds_corpus() {
    n3v_poses_bounds_corpus_run(false);
}

#[test]
fn n3v_huge_coordinates_are_refused() {
    n3v_poses_bounds_corpus_run(true);
}

fn n3v_poses_bounds_corpus_run(known: bool) {
    let seed = 0x4E_3F;
    let dir = tmp();
    let root = dir.path().join("n3v");
    let (cams, w, h) = (3, 8u32, 6u32);
    for i in 0..cams {
        for f in 0..2 {
            write_png(&root.join(format!("cam{i:02}/{f}.png")), w, h);
        }
    }
    let npy_path = root.join("poses_bounds.npy");
    npy::write_array2(&npy_path, cams, 17, &n3v_rows(cams, w, h)).unwrap();
    let b = std::fs::read(&npy_path).unwrap();
    let mut r = rng(seed);
    let cases = npy_cases(&b, cams, 17, &mut r);
    let expects: Vec<Expect> = cases.iter().map(|c| c.1.clone()).collect();
    let cases: Vec<Case> = cases
        .into_iter()
        .enumerate()
        .map(|(i, (c, _))| Case::new(format!("#{i} {}", c.name), c.bytes))
        .collect();
    // Known issue: a file that parses to a huge (finite) value, e.g. from a random byte edit of
    // an exponent, or the explicit 1e300 cases.
    let huge = |c: &Case| {
        huge_coordinate(c)
            || npy::parse_array2(Path::new("x.npy"), &c.bytes)
                .is_ok_and(|a| a.data.iter().any(|v| v.abs() > 1e100 && v.is_finite()))
    };
    let cases = partition(cases, known, huge);
    let mut k = 0usize;
    run_corpus("poses_bounds.npy", seed, cases, CORPUS_LIMIT, move |c| {
        let i: usize = c.name[1..].split(' ').next().unwrap().parse().unwrap();
        std::fs::write(&npy_path, &c.bytes).unwrap();
        let read = npy::read_array2(&npy_path);
        let mut result = match (&read, &expects[i]) {
            (Ok(a), Expect::Fail(want)) => Err(format!(
                "read a {}×{} array (expected an error with {want:?})",
                a.rows, a.cols
            )),
            (Ok(a), _) if a.data.len() != a.rows * a.cols => Err(format!(
                "a {}×{} array holds {} values",
                a.rows,
                a.cols,
                a.data.len()
            )),
            (Ok(_), _) => Ok(()),
            (Err(e), Expect::Load) => Err(format!("a valid file was refused: {e:#}")),
            (Err(e), Expect::Fail(want)) if !format!("{e:#}").contains(want.as_str()) => {
                Err(format!("the error lacks {want:?}: {e:#}"))
            }
            (Err(e), _) => names_file(e, &npy_path, true),
        };
        // The whole scene on a sample (it decodes the frames), and on every file read fine.
        k += 1;
        if result.is_ok() && (read.is_ok() || k.is_multiple_of(8)) {
            result = check_scene_load(&root, &LoadOptions::default(), true)
                .map_err(|w| format!("Scene::load: {w}"));
        }
        result
    });
    std::fs::remove_dir_all(dir.path()).ok();
}

/// Panoptic meta files for cameras `ids`, `frames` frames, fixed cameras.
fn panoptic_meta(ids: &[usize], frames: usize) -> Value {
    let cam = |id: usize| {
        let t = [0.2 * id as f64, 0.0, 4.0];
        let w2c = vec![
            vec![1.0, 0.0, 0.0, t[0]],
            vec![0.0, 1.0, 0.0, t[1]],
            vec![0.0, 0.0, 1.0, t[2]],
            vec![0.0, 0.0, 0.0, 1.0],
        ];
        let k = vec![
            vec![7.0, 0.0, 4.0],
            vec![0.0, 7.5, 3.0],
            vec![0.0, 0.0, 1.0],
        ];
        (k, w2c)
    };
    let per = |g: &dyn Fn(usize, usize) -> Value| -> Value {
        Value::Array(
            (0..frames)
                .map(|f| Value::Array(ids.iter().map(|&i| g(i, f)).collect()))
                .collect(),
        )
    };
    json!({
        "w": 8, "h": 6,
        "k": per(&|i, _| json!(cam(i).0)),
        "w2c": per(&|i, _| json!(cam(i).1)),
        "fn": per(&|i, f| json!(format!("{i}/{f:06}.jpg"))),
        "cam_id": per(&|i, _| json!(i)),
    })
}

#[test]
fn panoptic_meta_corpus() {
    panoptic_meta_corpus_run(false);
}

#[test]
fn panoptic_meta_known_issues() {
    panoptic_meta_corpus_run(true);
}

fn panoptic_meta_corpus_run(known: bool) {
    let seed = 0x9A_40;
    let dir = tmp();
    let root = dir.path().join("panoptic");
    let frames = 2;
    for id in 1..=3 {
        for f in 0..frames {
            write_png(&root.join(format!("ims/{id}/{f:06}.jpg")), 8, 6);
            write_png(&root.join(format!("seg/{id}/{f:06}.png")), 8, 6);
        }
    }
    let train = panoptic_meta(&[1, 3], frames);
    std::fs::write(root.join("train_meta.json"), train.to_string()).unwrap();
    std::fs::write(
        root.join("test_meta.json"),
        panoptic_meta(&[2], frames).to_string(),
    )
    .unwrap();
    let mut r = rng(seed);
    // Every third number: the matrices repeat per frame, so a sample covers every entry kind.
    let cases = json_cases("train_meta.json", &train, &JSON_TOKENS, 3, 40, &mut r);
    let cases = partition(cases, known, |c| not_utf8(c) || huge_coordinate(c));
    let meta = root.join("train_meta.json");
    run_corpus("panoptic", seed, cases, CORPUS_LIMIT, move |c| {
        std::fs::write(&meta, &c.bytes).unwrap();
        match Scene::load(&root, &LoadOptions::default()) {
            Ok(s) => valid_scene(&s),
            Err(e) if c.name.ends_with(" valid") => {
                Err(format!("a valid scene was refused: {e:#}"))
            }
            Err(e) => names_file(&e, &root, true),
        }
    });
}

// ---------------------------------------------------------------------------------------------
// Checkpoints
// ---------------------------------------------------------------------------------------------

use lpmsplat::train::checkpoint::{Checkpoint, SceneFingerprint, MAGIC};

fn checkpoint() -> Checkpoint {
    let extra = vec![ExtraGroup {
        name: "motion".into(),
        stride: 3,
    }];
    let shape = lpmsplat::splats::gpu::SplatShape {
        sh_degree: 1,
        extra: extra.clone(),
    };
    let count = 3u64;
    let set = |s: usize| -> Vec<Vec<f32>> {
        shape
            .strides()
            .iter()
            .enumerate()
            .map(|(g, (_, stride))| {
                (0..count as usize * stride)
                    .map(|k| 0.01 * (k + 10 * g + 100 * s) as f32)
                    .collect()
            })
            .collect()
    };
    Checkpoint {
        fingerprint: SceneFingerprint {
            sh_degree: 1,
            extra,
            views: vec![("a.png".into(), 8, 6), ("b.png".into(), 8, 6)],
            train: vec![0, 1],
            frame: Some(lpmsplat::scene::frame::SceneFrame {
                origin: [0.5, -0.25, 1.0],
                scale: 0.75,
            }),
        },
        iteration: 120,
        adam_step: 119,
        schedule_epoch: 3,
        schedule_next: 1,
        dropped_frames: 0,
        intersection_capacity: 4096,
        count,
        sets: [set(0), set(1), set(2)],
        stats: [vec![0.5; 3], vec![2.0; 3], vec![1.5; 3], vec![0.25; 3]],
        config_json: "{\"iterations\": 7000}".into(),
    }
}

/// The u32 / u64 / f64 fields of a format-4 checkpoint, walked over the valid bytes.
fn checkpoint_fields(b: &[u8]) -> Vec<(String, usize, usize)> {
    let mut f = Vec::new();
    let mut at = 12usize;
    let u32_at = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap()) as usize;
    let u64_at = |at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize;
    let field = |f: &mut Vec<_>, name: &str, size: usize, at: &mut usize| {
        f.push((name.to_string(), *at, size));
        *at += size;
    };
    f.push(("version".into(), 8, 4));
    field(&mut f, "sh_degree", 4, &mut at);
    let groups = u32_at(at);
    field(&mut f, "extra groups", 4, &mut at);
    for g in 0..groups {
        let n = u64_at(at);
        field(&mut f, &format!("extra[{g}].name length"), 8, &mut at);
        at += n;
        field(&mut f, &format!("extra[{g}].stride"), 4, &mut at);
    }
    let views = u32_at(at);
    field(&mut f, "views", 4, &mut at);
    for v in 0..views {
        let n = u64_at(at);
        field(&mut f, &format!("views[{v}].name length"), 8, &mut at);
        at += n;
        field(&mut f, &format!("views[{v}].width"), 4, &mut at);
        field(&mut f, &format!("views[{v}].height"), 4, &mut at);
    }
    let train = u32_at(at);
    field(&mut f, "train", 4, &mut at);
    for t in 0..train {
        field(&mut f, &format!("train[{t}]"), 4, &mut at);
    }
    for k in 0..4 {
        field(&mut f, &format!("frame f64 {k}"), 8, &mut at);
    }
    for name in ["iteration", "adam_step"] {
        field(&mut f, name, 4, &mut at);
    }
    for name in ["epoch", "position"] {
        field(&mut f, name, 8, &mut at);
    }
    field(&mut f, "dropped", 4, &mut at);
    field(&mut f, "intersection capacity", 8, &mut at);
    field(&mut f, "count", 8, &mut at);
    // Float arrays (3 sets × 7 groups, then 4 statistics) and the config: their lengths, and
    // their first value as a float field.
    for k in 0..3 * 7 + 4 + 1 {
        let n = u64_at(at);
        field(&mut f, &format!("array {k} length"), 8, &mut at);
        if k < 25 && n > 0 {
            f.push((format!("array {k} value 0 (f32)"), at, 4));
        }
        at += if k < 25 { 4 * n } else { n };
    }
    assert_eq!(at + 8, b.len(), "the walk must reach the checksum");
    f
}

#[test]
fn checkpoint_corpus() {
    let seed = 0xC4_9E;
    let ck = checkpoint();
    let b = ck.to_bytes();
    // The valid file round-trips (so the corpus starts from what the reader accepts).
    let back = Checkpoint::from_bytes(Path::new("x.bin"), &b).unwrap();
    assert_eq!(back.to_bytes(), b);
    let mut r = rng(seed);
    let mut cases = vec![(Case::new("valid", b.clone()), Expect::Load)];
    for (name, at, size) in checkpoint_fields(&b) {
        let values: Vec<Vec<u8>> = match size {
            4 if name.contains("f32") => NON_FINITE_F32
                .iter()
                .map(|v| v.to_le_bytes().to_vec())
                .collect(),
            4 => [0u32, 1, 2, 4, 0x7FFF_FFFF, u32::MAX]
                .iter()
                .map(|v| v.to_le_bytes().to_vec())
                .collect(),
            _ if name.starts_with("frame") => NON_FINITE_F64
                .iter()
                .chain(&[0.0, -1.0])
                .map(|v| v.to_le_bytes().to_vec())
                .collect(),
            _ => BAD_U64.iter().map(|v| v.to_le_bytes().to_vec()).collect(),
        };
        for v in values {
            let mut m = b.clone();
            if m[at..at + size] == v[..] {
                continue;
            }
            m[at..at + size].copy_from_slice(&v);
            let label = format!("{name} = {v:02x?}");
            // Unsealed: the checksum must catch it (the version is checked first); resealed:
            // the parser must.
            let unsealed = if name == "version" {
                Expect::Fail(String::new())
            } else {
                Expect::Fail("checksum".into())
            };
            cases.push((Case::new(format!("{label} unsealed"), m.clone()), unsealed));
            // The frame: a non-finite origin, a non-finite or non-positive scale.
            let x = f64::from_le_bytes(v.clone().try_into().unwrap_or([0; 8]));
            let bad_frame = name.starts_with("frame")
                && (!x.is_finite() || (name == "frame f64 3" && x <= 0.0));
            let expect = if bad_frame || name.contains("f32") {
                Expect::Fail(String::new())
            } else {
                Expect::Any
            };
            cases.push((Case::new(format!("{label} resealed"), reseal(m)), expect));
        }
    }
    let whole = Case::new("ckpt", b.clone());
    for c in truncations(&whole, &[8, 12, 20], 40, 40, &mut r) {
        let sealed = reseal(c.bytes.clone());
        cases.push((
            Case::new(format!("{} resealed", c.name), sealed),
            Expect::Fail(String::new()),
        ));
        cases.push((c, Expect::Fail(String::new())));
    }
    for c in byte_edits(&whole, 12, 80, &mut r) {
        let sealed = reseal(c.bytes.clone());
        cases.push((
            Case::new(format!("{} resealed", c.name), sealed),
            Expect::Any,
        ));
        // An edit that rewrote a byte with its own value changed nothing.
        let expect = if c.bytes == b {
            Expect::Load
        } else {
            Expect::Fail(String::new())
        };
        cases.push((c, expect));
    }
    cases.push((
        Case::new(
            "trailing bytes resealed",
            reseal([&b[..b.len() - 8], &[0u8; 5], &b[b.len() - 8..]].concat()),
        ),
        Expect::Fail("unexpected bytes".into()),
    ));
    cases.push((
        Case::new("magic only", MAGIC.to_vec()),
        Expect::Fail("magic".into()),
    ));
    cases.push((Case::new("empty", Vec::new()), Expect::Fail("magic".into())));
    let expects: Vec<Expect> = cases.iter().map(|c| c.1.clone()).collect();
    let cases: Vec<Case> = cases
        .into_iter()
        .enumerate()
        .map(|(i, (c, _))| Case::new(format!("#{i} {}", c.name), c.bytes))
        .collect();
    let dir = tmp();
    let path = dir.path().join("checkpoint.bin");
    run_corpus("checkpoint", seed, cases, CORPUS_LIMIT, move |c| {
        let i: usize = c.name[1..].split(' ').next().unwrap().parse().unwrap();
        // `read` on a file for half the cases, `from_bytes` on the bytes for the rest.
        let got = if i.is_multiple_of(2) {
            std::fs::write(&path, &c.bytes).unwrap();
            Checkpoint::read(&path)
        } else {
            Checkpoint::from_bytes(&path, &c.bytes)
        };
        match (got, &expects[i]) {
            (Ok(ck), Expect::Fail(want)) => Err(format!(
                "read a checkpoint of {} Gaussians (expected an error with {want:?})",
                ck.count
            )),
            (Ok(ck), _) => {
                // A loaded checkpoint is consistent: every array has count × stride floats.
                let shape = lpmsplat::splats::gpu::SplatShape {
                    sh_degree: ck.fingerprint.sh_degree,
                    extra: ck.fingerprint.extra.clone(),
                };
                let strides = shape.strides();
                for set in &ck.sets {
                    if set.len() != strides.len()
                        || set
                            .iter()
                            .zip(&strides)
                            .any(|(g, (_, s))| g.len() != ck.count as usize * s)
                    {
                        return Err("array lengths disagree with the count".into());
                    }
                }
                if ck.sets[0].iter().flatten().any(|v| !v.is_finite()) {
                    return Err("loaded non-finite parameters".into());
                }
                Ok(())
            }
            (Err(e), Expect::Load) => Err(format!("a valid checkpoint was refused: {e:#}")),
            (Err(e), Expect::Fail(want)) if !format!("{e:#}").contains(want.as_str()) => {
                Err(format!("the error lacks {want:?}: {e:#}"))
            }
            (Err(e), _) => names_file(&e, &path, true),
        }
    });
}

// ---------------------------------------------------------------------------------------------
// LPIPS weights (safetensors)
// ---------------------------------------------------------------------------------------------

use lpmsplat::lpips::weights::{write_f32, SafeTensors};

#[test]
fn safetensors_corpus() {
    let seed = 0x5AFE;
    let dir = tmp();
    let base_path = dir.path().join("base.safetensors");
    let a: Vec<f32> = (0..6).map(|k| k as f32 * 0.5).collect();
    let bv = [1.0f32, -2.0, 3.0, 4.5];
    let c = [0.25f32, 0.75];
    write_f32(
        &base_path,
        &[("a", &[2, 3], &a), ("b", &[4], &bv), ("c", &[1, 1, 2], &c)],
    )
    .unwrap();
    let b = std::fs::read(&base_path).unwrap();
    let n = u64::from_le_bytes(b[..8].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&b[8..8 + n]).unwrap();
    let data = b[8 + n..].to_vec();
    let pack = |h: &[u8]| -> Vec<u8> { [&(h.len() as u64).to_le_bytes()[..], h, &data].concat() };
    let mut r = rng(seed);
    let mut cases = Vec::new();
    // The header JSON mutated (numbers, values, keys), repacked with its true length.
    for c in json_cases(
        "header",
        &header,
        &[
            "0",
            "1",
            "-1",
            "1e999",
            "NaN",
            "18446744073709551615",
            "4611686018427387905",
            "16",
            "24",
            "2.5",
        ],
        1,
        40,
        &mut r,
    ) {
        cases.push(Case::new(c.name, pack(&c.bytes)));
    }
    // Shapes that overflow the element count: [2^62 + 1, 4] × 4 bytes wraps to 16, the size of
    // tensor b's data.
    for shape in [
        json!([4611686018427387905u64, 4]),
        json!([u64::MAX, u64::MAX]),
        json!([0, 4]),
        json!([]),
    ] {
        let mut h = header.clone();
        h["b"]["shape"] = shape.clone();
        cases.push(Case::new(
            format!("b.shape = {shape}"),
            pack(&serde_json::to_vec(&h).unwrap()),
        ));
    }
    for offs in [
        json!([16, 8]),
        json!([0, 1u64 << 40]),
        json!([0, u64::MAX]),
        json!([u64::MAX, u64::MAX]),
        json!([0]),
        json!([0, 16, 32]),
    ] {
        let mut h = header.clone();
        h["b"]["data_offsets"] = offs.clone();
        cases.push(Case::new(
            format!("b.data_offsets = {offs}"),
            pack(&serde_json::to_vec(&h).unwrap()),
        ));
    }
    // The length prefix: too small, too large, huge.
    for v in BAD_U64
        .iter()
        .copied()
        .chain([n as u64 - 1, n as u64 + 1, (100 << 20) + 1])
    {
        let mut m = b.clone();
        m[..8].copy_from_slice(&v.to_le_bytes());
        cases.push(Case::new(format!("header length = {v}"), m));
    }
    let whole = Case::new("file", b.clone());
    cases.extend(truncations(&whole, &[8, 8 + n], 16, 40, &mut r));
    cases.extend(byte_edits(&whole, 0, 60, &mut r));
    cases.push(Case::new("empty", Vec::new()));
    let path = dir.path().join("w.safetensors");
    run_corpus("safetensors", seed, cases, CORPUS_LIMIT, move |c| {
        std::fs::write(&path, &c.bytes).unwrap();
        let st = match SafeTensors::open(&path) {
            Ok(st) => st,
            Err(e) if c.name == "header valid" => return Err(format!("refused: {e:#}")),
            Err(e) => return names_file(&e, &path, true),
        };
        let names: Vec<String> = st.names().map(str::to_string).collect();
        for name in names {
            let shape = st.shape(&name).unwrap().to_vec();
            for got in [
                st.f32_any_shape(&name),
                st.f32(&name, &shape).map(|v| (shape.clone(), v)),
            ] {
                match got {
                    Ok((s, v)) => {
                        let count = s.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
                        if count != Some(v.len()) {
                            return Err(format!(
                                "tensor {name}: shape {s:?} but {} values",
                                v.len()
                            ));
                        }
                    }
                    Err(e) => names_file(&e, &path, true)?,
                }
            }
        }
        Ok(())
    });
}

// ---------------------------------------------------------------------------------------------
// LPM match cache
// ---------------------------------------------------------------------------------------------

use lpmsplat::lpm::cache::{read_cache, write_cache, CacheMiss, CACHE_VERSION};
use lpmsplat::lpm::PairMatches;

#[test]
fn lpm_cache_corpus() {
    let seed = 0xCAC4E;
    let (sh, st, views) = (0x1234u64, 0x5678u64, 4usize);
    let pairs = vec![
        PairMatches {
            a: 0,
            b: 2,
            xy_a: vec![[1.0, 2.0], [3.5, 4.5]],
            xy_b: vec![[5.0, 6.0], [7.0, 8.0]],
        },
        PairMatches {
            a: 1,
            b: 3,
            xy_a: vec![[0.5, 0.25]],
            xy_b: vec![[9.0, 9.5]],
        },
    ];
    let dir = tmp();
    let path = dir.path().join("matches.bin");
    write_cache(&path, sh, st, &pairs).unwrap();
    let b = std::fs::read(&path).unwrap();
    assert_eq!(read_cache(&path, sh, st, views).unwrap(), pairs);
    // Fields: version, hashes, pair count, then per pair a, b, match count and the floats.
    let mut fields: Vec<(String, usize, usize)> = vec![
        ("version".into(), 8, 4),
        ("scene hash".into(), 12, 8),
        ("settings hash".into(), 20, 8),
        ("pair count".into(), 28, 4),
    ];
    let mut at = 32;
    for (k, p) in pairs.iter().enumerate() {
        for f in ["a", "b", "match count"] {
            fields.push((format!("pair {k} {f}"), at, 4));
            at += 4;
        }
        for m in 0..p.xy_a.len() * 4 {
            fields.push((format!("pair {k} float {m}"), at, 4));
            at += 4;
        }
    }
    assert_eq!(at + 8, b.len());
    let mut r = rng(seed);
    let mut cases = vec![Case::new("valid", b.clone())];
    for (name, at, size) in &fields {
        let values: Vec<Vec<u8>> = if name.contains("float") {
            NON_FINITE_F32
                .iter()
                .map(|v| v.to_le_bytes().to_vec())
                .collect()
        } else if *size == 8 {
            BAD_U64.iter().map(|v| v.to_le_bytes().to_vec()).collect()
        } else {
            [0u32, 1, 2, 3, 4, 5, 0x8000_0000, u32::MAX]
                .iter()
                .map(|v| v.to_le_bytes().to_vec())
                .collect()
        };
        for v in values {
            let mut m = b.clone();
            m[*at..*at + size].copy_from_slice(&v);
            cases.push(Case::new(format!("{name} = {v:02x?} unsealed"), m.clone()));
            cases.push(Case::new(format!("{name} = {v:02x?} resealed"), reseal(m)));
        }
    }
    let whole = Case::new("cache", b.clone());
    for c in truncations(&whole, &[8, 12, 28, 32], 40, 30, &mut r) {
        cases.push(Case::new(
            format!("{} resealed", c.name),
            reseal(c.bytes.clone()),
        ));
        cases.push(c);
    }
    for c in byte_edits(&whole, 8, 60, &mut r) {
        cases.push(Case::new(
            format!("{} resealed", c.name),
            reseal(c.bytes.clone()),
        ));
        cases.push(c);
    }
    cases.push(Case::new("empty", Vec::new()));
    run_corpus("lpm cache", seed, cases, CORPUS_LIMIT, move |c| {
        std::fs::write(&path, &c.bytes).unwrap();
        match read_cache(&path, sh, st, views) {
            Ok(got) => {
                if c.name.contains("unsealed") && c.bytes != b {
                    return Err("a file whose checksum no longer matches was used".into());
                }
                for p in &got {
                    let ok = p.a < p.b
                        && (p.b as usize) < views
                        && p.xy_a.len() == p.xy_b.len()
                        && p.xy_a
                            .iter()
                            .chain(&p.xy_b)
                            .flatten()
                            .all(|v| v.is_finite());
                    if !ok {
                        return Err(format!("an invalid pair was read: {p:?}"));
                    }
                }
                Ok(())
            }
            Err(CacheMiss::Missing) => Err("an existing file read as missing".into()),
            Err(CacheMiss::Stale(why))
                if c.name.starts_with("version") && !why.contains(&CACHE_VERSION.to_string()) =>
            {
                Err(format!("a stale version that does not say which: {why}"))
            }
            // The cache is the program's own file: a miss is reported by the caller with the
            // path (lpm::match_scene) and the matches rebuilt, so the reason is enough here.
            Err(CacheMiss::Stale(why)) | Err(CacheMiss::Corrupt(why)) if why.is_empty() => {
                Err("a miss without a reason".into())
            }
            Err(_) if c.name == "valid" => Err("the valid cache missed".into()),
            Err(_) => Ok(()),
        }
    });
}

// ---------------------------------------------------------------------------------------------
// The CLI, on a sample
// ---------------------------------------------------------------------------------------------

fn lpmsplat() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_lpmsplat"));
    c.env("LPMSPLAT_VALIDATION", "1");
    c
}

#[test]
fn cli_sample_fails_cleanly_and_keeps_existing_outputs() {
    let dir = tmp();
    let d = dir.path();
    let bases = ply_bases(d);
    let le = &bases[0];
    let h = &le.header;
    let bad: Vec<(&str, Vec<u8>)> = vec![
        ("empty", Vec::new()),
        ("not_ply", b"solid cube\nfacet normal 0 0 1\n".to_vec()),
        ("cut", le.bytes()[..le.bytes().len() - 5].to_vec()),
        (
            "count_small",
            [
                h.replace("element vertex 3", "element vertex 1").as_bytes(),
                &le.body,
            ]
            .concat(),
        ),
        (
            "count_huge",
            [
                h.replace("element vertex 3", "element vertex 1099511627776")
                    .as_bytes(),
                &le.body,
            ]
            .concat(),
        ),
        ("nan", {
            let mut b = le.bytes();
            let o = h.len() + 4;
            b[o..o + 4].copy_from_slice(&f32::NAN.to_le_bytes());
            b
        }),
        ("extra_rows", [&le.bytes()[..], &le.body[..le.row]].concat()),
    ];
    let out = d.join("existing.splat");
    let before = b"an existing output the failed export must not touch".to_vec();
    for (name, bytes) in &bad {
        let ply = d.join(format!("{name}.ply"));
        std::fs::write(&ply, bytes).unwrap();
        std::fs::write(&out, &before).unwrap();
        let o = lpmsplat()
            .args(["export", "--ply"])
            .arg(&ply)
            .arg("--splat")
            .arg(&out)
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!o.status.success(), "{name}: export succeeded:\n{text}");
        assert_ne!(
            o.status.code(),
            Some(101),
            "{name}: export panicked:\n{text}"
        );
        assert!(!text.contains("panicked"), "{name}: {text}");
        assert!(
            text.contains(&ply.display().to_string()),
            "{name}: the error does not name the file:\n{text}"
        );
        assert!(text.contains("Fix:"), "{name}: no Fix:\n{text}");
        assert_eq!(
            std::fs::read(&out).unwrap(),
            before,
            "{name}: the existing output changed"
        );
    }
    // The valid file exports over the same output, so the command is not failing for another
    // reason.
    let ply = d.join("good.ply");
    std::fs::write(&ply, le.bytes()).unwrap();
    let o = lpmsplat()
        .args(["export", "--ply"])
        .arg(&ply)
        .arg("--splat")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(&out).unwrap().len(), 3 * 32);

    // `info` on broken scenes: the scene error comes before any device is needed.
    let root = d.join("scene");
    let sparse = colmap_scene(&root);
    std::fs::remove_dir_all(root.join("sparse/0")).ok();
    colmap::write_binary(&sparse, &colmap_model()).unwrap();
    let cams = sparse.join("cameras.bin");
    let good = std::fs::read(&cams).unwrap();
    for (name, bytes) in [
        ("cut", good[..good.len() - 3].to_vec()),
        (
            "count u64::MAX",
            [&u64::MAX.to_le_bytes()[..], &good[8..]].concat(),
        ),
        ("empty", Vec::new()),
    ] {
        std::fs::write(&cams, &bytes).unwrap();
        let o = lpmsplat().arg("info").arg(&root).output().unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!o.status.success(), "info {name}: succeeded:\n{text}");
        assert_ne!(o.status.code(), Some(101), "info {name}: panicked:\n{text}");
        assert!(
            text.contains(&cams.display().to_string()),
            "info {name}: {text}"
        );
        assert!(text.contains("Fix:"), "info {name}: {text}");
    }
}
