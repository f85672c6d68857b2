//! PLY read/write in the Inria layout: bit-exact round trips, the channel-major f_rest order,
//! leniency towards other writers, and an error naming file and field for every bad input.

use std::path::{Path, PathBuf};

use lpmsplat::error::InputError;
use lpmsplat::splats::model::sh_rest_coeffs;
use lpmsplat::splats::ply::property_names;
use lpmsplat::splats::{
    ply_comments, read_ply, read_ply_with_degree, require_nonempty, write_ply,
    write_ply_with_comments, GaussianParams,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// A value drawn from a mix of ordinary, tiny, subnormal, huge and signed-zero floats.
fn wild(rng: &mut Pcg64) -> f32 {
    let sign = if rng.gen::<bool>() { 1.0 } else { -1.0 };
    match rng.gen_range(0..8) {
        0 => sign * rng.gen_range(1e-38f32..1e-30),
        1 => sign * f32::from_bits(rng.gen_range(1..0x007f_ffff)), // subnormal
        2 => sign * rng.gen_range(1e30f32..3.4e38),
        3 => sign * 0.0,
        4 => sign * f32::MAX,
        _ => rng.gen_range(-10.0f32..10.0),
    }
}

fn random_model(n: usize, degree: u32, seed: u64) -> GaussianParams {
    let mut rng = Pcg64::seed_from_u64(seed);
    let r = &mut rng;
    GaussianParams {
        sh_degree: degree,
        positions: (0..n).map(|_| [wild(r), wild(r), wild(r)]).collect(),
        log_scales: (0..n).map(|_| [wild(r), wild(r), wild(r)]).collect(),
        rotations: (0..n)
            .map(|_| [wild(r), wild(r), wild(r), wild(r)])
            .collect(),
        opacity_logits: (0..n).map(|_| wild(r)).collect(),
        sh_dc: (0..n).map(|_| [wild(r), wild(r), wild(r)]).collect(),
        sh_rest: (0..n * sh_rest_coeffs(degree) * 3)
            .map(|_| wild(r))
            .collect(),
        extra: Vec::new(),
    }
}

fn bits3(v: &[[f32; 3]]) -> Vec<u32> {
    v.iter().flatten().map(|x| x.to_bits()).collect()
}

fn assert_bit_equal(a: &GaussianParams, b: &GaussianParams) {
    assert_eq!(a.sh_degree, b.sh_degree);
    assert_eq!(a.len(), b.len());
    assert_eq!(bits3(&a.positions), bits3(&b.positions));
    assert_eq!(bits3(&a.log_scales), bits3(&b.log_scales));
    assert_eq!(bits3(&a.sh_dc), bits3(&b.sh_dc));
    let r = |v: &[[f32; 4]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(r(&a.rotations), r(&b.rotations));
    let f = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(f(&a.opacity_logits), f(&b.opacity_logits));
    assert_eq!(f(&a.sh_rest), f(&b.sh_rest));
}

/// The header a writer of the Inria layout produces, as text.
fn inria_header(n: usize, degree: u32, format: &str, ty: &str) -> String {
    let mut h = format!("ply\nformat {format} 1.0\nelement vertex {n}\n");
    for name in property_names(degree) {
        h.push_str(&format!("property {ty} {name}\n"));
    }
    h.push_str("end_header\n");
    h
}

/// Checks that `err` is an [`InputError`] for `path` whose field mentions `field`.
fn assert_input_error(err: &anyhow::Error, path: &Path, field: &str) {
    let text = format!("{err:#}");
    let ie = err
        .downcast_ref::<InputError>()
        .unwrap_or_else(|| panic!("not an InputError: {text}"));
    assert_eq!(ie.file, path, "{text}");
    assert!(
        ie.field.contains(field),
        "field {:?} lacks {field:?}: {text}",
        ie.field
    );
    assert!(text.contains(&path.display().to_string()), "{text}");
    assert!(!ie.fix.is_empty(), "{text}");
}

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn round_trip_is_bit_exact_for_every_degree() {
    let dir = tmp();
    for degree in 0..=3 {
        let model = random_model(777, degree, 10 + degree as u64);
        model.validate().unwrap();
        let path = dir.path().join(format!("deg{degree}.ply"));
        write_ply(&path, &model).unwrap();
        let n_props = 17 + 3 * sh_rest_coeffs(degree);
        let bytes = std::fs::read(&path).unwrap();
        let header_len = inria_header(777, degree, "binary_little_endian", "float").len();
        assert_eq!(bytes.len(), header_len + 777 * n_props * 4);
        let back = read_ply(&path).unwrap();
        assert_bit_equal(&model, &back);

        // Reading and writing again reproduces the file byte for byte.
        let again = dir.path().join(format!("deg{degree}_again.ply"));
        write_ply(&again, &back).unwrap();
        assert_eq!(bytes, std::fs::read(&again).unwrap());
    }
}

#[test]
fn comments_round_trip_and_leave_the_model_alone() {
    let dir = tmp();
    let model = random_model(50, 1, 3);
    let plain = dir.path().join("plain.ply");
    write_ply(&plain, &model).unwrap();
    assert!(ply_comments(&plain).unwrap().is_empty());
    let noted = dir.path().join("noted.ply");
    let comments = vec![
        "lpmsplat video segment 0..50".to_string(),
        "two  words".into(),
    ];
    write_ply_with_comments(&noted, &model, &comments).unwrap();
    assert_eq!(ply_comments(&noted).unwrap(), comments);
    assert_bit_equal(&model, &read_ply(&noted).unwrap());
    let text = String::from_utf8_lossy(&std::fs::read(&noted).unwrap()[..200]).to_string();
    assert!(
        text.starts_with(
            "ply\nformat binary_little_endian 1.0\ncomment lpmsplat video segment 0..50\n"
        ),
        "{text}"
    );
    // A comment must be one line; the file already there is left as it was.
    let before = std::fs::read(&noted).unwrap();
    let e = write_ply_with_comments(&noted, &model, &["a\nb".into()]).unwrap_err();
    assert!(format!("{e:#}").contains("one line"), "{e:#}");
    assert_eq!(std::fs::read(&noted).unwrap(), before);
}

#[test]
fn writer_emits_the_inria_header_and_zero_normals() {
    let dir = tmp();
    let model = random_model(5, 2, 3);
    let path = dir.path().join("m.ply");
    write_ply(&path, &model).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header = inria_header(5, 2, "binary_little_endian", "float");
    assert_eq!(&bytes[..header.len()], header.as_bytes());
    let body = &bytes[header.len()..];
    let row = 17 + 3 * 8;
    let at = |i: usize, k: usize| {
        let o = (i * row + k) * 4;
        f32::from_le_bytes(body[o..o + 4].try_into().unwrap())
    };
    for i in 0..5 {
        assert_eq!([at(i, 3), at(i, 4), at(i, 5)], [0.0; 3]);
        assert_eq!(at(i, 0).to_bits(), model.positions[i][0].to_bits());
        // f_rest_{c*8+k} holds coefficient k of channel c.
        for c in 0..3 {
            for k in 0..8 {
                let expect = model.sh_rest[i * 24 + k * 3 + c];
                assert_eq!(at(i, 9 + c * 8 + k).to_bits(), expect.to_bits());
            }
        }
        assert_eq!(at(i, 33).to_bits(), model.opacity_logits[i].to_bits());
        assert_eq!(at(i, 34).to_bits(), model.log_scales[i][0].to_bits());
        assert_eq!(at(i, 37).to_bits(), model.rotations[i][0].to_bits());
    }
}

#[test]
fn f_rest_is_channel_major_in_a_hand_built_file() {
    // Degree 1: 3 coefficients per channel, f_rest_0..8. f_rest_j holds 100 + j.
    let dir = tmp();
    let path = dir.path().join("hand.ply");
    let mut bytes = inria_header(2, 1, "binary_little_endian", "float").into_bytes();
    for v in 0..2 {
        let base = 1000.0 * v as f32;
        let mut row = vec![1.0 + base, 2.0 + base, 3.0 + base, 0.0, 0.0, 0.0];
        row.extend([10.0, 11.0, 12.0].map(|x| x + base));
        row.extend((0..9).map(|j| 100.0 + j as f32 + base));
        row.push(-2.0 + base);
        row.extend([-3.0, -4.0, -5.0].map(|x| x + base));
        row.extend([0.5, 0.25, 0.125, 0.0625].map(|x| x + base));
        for x in row {
            bytes.extend(x.to_le_bytes());
        }
    }
    std::fs::write(&path, &bytes).unwrap();
    let m = read_ply(&path).unwrap();
    assert_eq!(m.sh_degree, 1);
    for v in 0..2 {
        let base = 1000.0 * v as f32;
        assert_eq!(m.positions[v], [1.0 + base, 2.0 + base, 3.0 + base]);
        assert_eq!(m.sh_dc[v], [10.0 + base, 11.0 + base, 12.0 + base]);
        assert_eq!(m.opacity_logits[v], -2.0 + base);
        assert_eq!(m.log_scales[v], [-3.0 + base, -4.0 + base, -5.0 + base]);
        assert_eq!(
            m.rotations[v],
            [0.5 + base, 0.25 + base, 0.125 + base, 0.0625 + base]
        );
        let rest = m.sh_rest_of(v).unwrap();
        for coef in 0..3 {
            for channel in 0..3 {
                let j = channel * 3 + coef;
                assert_eq!(rest[coef * 3 + channel], 100.0 + j as f32 + base);
            }
        }
    }
}

/// Writes `model` as an ASCII PLY whose vertex properties come in a shuffled order, some as
/// doubles, with extra properties and elements the reader must skip.
fn write_foreign(path: &Path, model: &GaussianParams, seed: u64, format: &str) {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut names = property_names(model.sh_degree);
    names.retain(|n| !n.starts_with('n')); // no normals: they are optional
    names.push("red".into());
    names.push("confidence".into());
    for i in (1..names.len()).rev() {
        let j = rng.gen_range(0..=i);
        names.swap(i, j);
    }
    let types: Vec<&str> = names
        .iter()
        .map(|n| match n.as_str() {
            "red" => "uchar",
            "confidence" => "int",
            _ if rng.gen::<bool>() => "double",
            _ => "float",
        })
        .collect();
    let rest = model.rest_coeffs();
    let value = |i: usize, name: &str| -> f64 {
        let num = |p: &str| name.strip_prefix(p).map(|s| s.parse::<usize>().unwrap());
        if let Some(k) = num("f_rest_") {
            let (c, coef) = (k / rest, k % rest);
            return model.sh_rest[i * rest * 3 + coef * 3 + c] as f64;
        }
        if let Some(k) = num("f_dc_") {
            return model.sh_dc[i][k] as f64;
        }
        if let Some(k) = num("scale_") {
            return model.log_scales[i][k] as f64;
        }
        if let Some(k) = num("rot_") {
            return model.rotations[i][k] as f64;
        }
        match name {
            "x" => model.positions[i][0] as f64,
            "y" => model.positions[i][1] as f64,
            "z" => model.positions[i][2] as f64,
            "opacity" => model.opacity_logits[i] as f64,
            "red" => 200.0,
            "confidence" => -7.0,
            _ => unreachable!(),
        }
    };
    let n = model.len();
    let mut text = format!("ply\r\nformat {format} 1.0\r\ncomment written by a test\r\n");
    // An element before the vertices, with a list, which the reader has to skip.
    text.push_str("element camera 2\r\nproperty list uchar float k\r\nproperty int id\r\n");
    text.push_str(&format!("element vertex {n}\r\n"));
    for (name, ty) in names.iter().zip(&types) {
        text.push_str(&format!("property {ty} {name}\r\n"));
    }
    text.push_str("element face 1\r\nproperty list uchar int vertex_indices\r\nend_header\r\n");
    let mut body: Vec<u8> = Vec::new();
    let big = format == "binary_big_endian";
    if format == "ascii" {
        body.extend(b"3 1.5 2.5 3.5 7\n0 8\n");
    } else {
        for (len, id) in [(3u8, 7i32), (0, 8)] {
            body.push(len);
            for k in 0..len {
                let v = 1.5f32 + k as f32;
                body.extend(if big {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                });
            }
            body.extend(if big {
                id.to_be_bytes()
            } else {
                id.to_le_bytes()
            });
        }
    }
    for i in 0..n {
        let mut line = Vec::new();
        for (name, ty) in names.iter().zip(&types) {
            let v = value(i, name);
            if format == "ascii" {
                // `{:?}` prints the shortest text that parses back to the same value.
                line.push(match *ty {
                    "double" => format!("{v:?}"),
                    "float" => format!("{:?}", v as f32),
                    _ => format!("{}", v as i64),
                });
            } else {
                let bytes: Vec<u8> = match *ty {
                    "double" if big => v.to_be_bytes().to_vec(),
                    "double" => v.to_le_bytes().to_vec(),
                    "float" if big => (v as f32).to_be_bytes().to_vec(),
                    "float" => (v as f32).to_le_bytes().to_vec(),
                    "uchar" => vec![v as u8],
                    _ if big => (v as i32).to_be_bytes().to_vec(),
                    _ => (v as i32).to_le_bytes().to_vec(),
                };
                body.extend(bytes);
            }
        }
        if format == "ascii" {
            body.extend(line.join(" ").into_bytes());
            body.push(b'\n');
        }
    }
    if format == "ascii" {
        body.extend(b"3 0 1 2\n");
    } else {
        body.push(3);
        for k in 0..3i32 {
            body.extend(if big {
                k.to_be_bytes()
            } else {
                k.to_le_bytes()
            });
        }
    }
    let mut bytes = text.into_bytes();
    bytes.extend(body);
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn reader_accepts_ascii_shuffled_doubles_and_extra_properties() {
    let dir = tmp();
    for (k, format) in ["ascii", "binary_little_endian", "binary_big_endian"]
        .iter()
        .enumerate()
    {
        for degree in [0, 1, 3] {
            let model = random_model(40, degree, 100 + degree as u64);
            let path = dir.path().join(format!("{format}_{degree}.ply"));
            write_foreign(&path, &model, k as u64 * 10 + degree as u64, format);
            let back = read_ply(&path).unwrap_or_else(|e| panic!("{format} {degree}: {e:#}"));
            // Every value was a float to begin with, so doubles convert back exactly.
            assert_bit_equal(&model, &back);
        }
    }
}

#[test]
fn lowering_the_degree_on_read_keeps_the_lower_bands() {
    let dir = tmp();
    let model = random_model(50, 3, 7);
    let path = dir.path().join("d3.ply");
    write_ply(&path, &model).unwrap();
    for max in 0..=3 {
        let back = read_ply_with_degree(&path, max).unwrap();
        assert_eq!(back.sh_degree, max);
        assert_bit_equal(&model.clone().with_sh_degree(max).unwrap(), &back);
        // The kept coefficients are the model's first ones, coefficient-major.
        let keep = sh_rest_coeffs(max) * 3;
        for i in 0..50 {
            assert_eq!(
                back.sh_rest_of(i).unwrap(),
                &model.sh_rest_of(i).unwrap()[..keep]
            );
        }
    }
    // Asking for more than the file has keeps the file's degree.
    let d1 = dir.path().join("d1.ply");
    write_ply(&d1, &model.clone().with_sh_degree(1).unwrap()).unwrap();
    assert_eq!(read_ply_with_degree(&d1, 3).unwrap().sh_degree, 1);
}

#[test]
fn empty_model_reads_but_require_nonempty_refuses_it() {
    let dir = tmp();
    let path = dir.path().join("empty.ply");
    write_ply(&path, &GaussianParams::empty(2)).unwrap();
    let m = read_ply(&path).unwrap();
    assert_eq!((m.len(), m.sh_degree), (0, 2));
    let err = require_nonempty(&path, &m).unwrap_err();
    assert_input_error(&err, &path, "vertex");
    require_nonempty(&path, &random_model(1, 0, 1)).unwrap();
}

/// A valid degree-1 file with 4 vertices, as header text and body bytes.
fn good_file(seed: u64) -> (String, Vec<u8>) {
    let model = random_model(4, 1, seed);
    let dir = tmp();
    let path = dir.path().join("g.ply");
    write_ply(&path, &model).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header = inria_header(4, 1, "binary_little_endian", "float");
    (header.clone(), bytes[header.len()..].to_vec())
}

fn write_bytes(dir: &Path, name: &str, parts: &[&[u8]]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, parts.concat()).unwrap();
    path
}

#[test]
fn bad_inputs_name_the_file_and_the_field() {
    let dir = tmp();
    let d = dir.path();
    let (header, body) = good_file(5);

    // Missing file.
    let missing = d.join("nope.ply");
    assert_input_error(&read_ply(&missing).unwrap_err(), &missing, "file");

    // Not a PLY.
    let p = write_bytes(d, "not.ply", &[b"\x89PNG\r\n\x1a\n some binary"]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "header");
    let p = write_bytes(d, "empty.ply", &[]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "header");

    // Missing required properties, each in turn.
    for name in ["x", "f_dc_2", "opacity", "scale_1", "rot_3"] {
        let h = header.replace(&format!("property float {name}\n"), "");
        let p = write_bytes(d, &format!("miss_{name}.ply"), &[h.as_bytes(), &body]);
        let err = read_ply(&p).unwrap_err();
        assert_input_error(&err, &p, &format!("property {name}"));
    }
    // A compressed splat PLY (chunk bounds, packed vertices) is named as such.
    let packed = "ply\nformat binary_little_endian 1.0\nelement chunk 1\nproperty float min_x\n\
                  element vertex 1\nproperty uint packed_position\nproperty uint packed_rotation\n\
                  property uint packed_scale\nproperty uint packed_color\nend_header\n";
    let p = write_bytes(d, "packed.ply", &[packed.as_bytes(), &[0u8; 20]]);
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, "property x");
    assert!(format!("{err:#}").contains("compressed"), "{err:#}");
    // A gap in f_rest: 9 f_rest_* properties but f_rest_4 renamed.
    let h = header.replace("property float f_rest_4\n", "property float f_rest_9\n");
    let p = write_bytes(d, "gap.ply", &[h.as_bytes(), &body]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "property f_rest_4");

    // Wrong number of f_rest properties.
    let h = header.replace("property float f_rest_8\n", "");
    let p = write_bytes(d, "rest8.ply", &[h.as_bytes(), &body]);
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, "f_rest");
    assert!(format!("{err:#}").contains("8 f_rest"), "{err:#}");

    // Truncated: the last vertex is cut short.
    let row = (17 + 9) * 4;
    let p = write_bytes(d, "trunc.ply", &[header.as_bytes(), &body[..3 * row + 10]]);
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, "vertex 3");
    // Truncated inside the header.
    let p = write_bytes(d, "trunc_header.ply", &[&header.as_bytes()[..40]]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "header");

    // NaN and infinity, at known vertices and properties.
    let names = property_names(1);
    for (vertex, prop, value) in [
        (2, "f_rest_7", f32::NAN),
        (1, "y", f32::INFINITY),
        (3, "rot_0", f32::NEG_INFINITY),
    ] {
        let k = names.iter().position(|n| n == prop).unwrap();
        let mut b = body.clone();
        let o = (vertex * (17 + 9) + k) * 4;
        b[o..o + 4].copy_from_slice(&value.to_le_bytes());
        let p = write_bytes(d, &format!("nan_{prop}.ply"), &[header.as_bytes(), &b]);
        let err = read_ply(&p).unwrap_err();
        assert_input_error(&err, &p, &format!("vertex {vertex}, property {prop}"));
    }
    // A double too large for f32 is as bad as infinity.
    let ascii = format!(
        "ply\nformat ascii 1.0\nelement vertex 1\n{}end_header\n",
        property_names(0)
            .iter()
            .map(|n| format!("property double {n}\n"))
            .collect::<String>()
    );
    let mut vals = vec!["0.5"; 17];
    let scale0 = property_names(0)
        .iter()
        .position(|n| n == "scale_0")
        .unwrap();
    vals[scale0] = "1e300";
    let p = write_bytes(
        d,
        "huge.ply",
        &[ascii.as_bytes(), vals.join(" ").as_bytes()],
    );
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "vertex 0, property scale_0");
    // An unparseable ASCII value.
    vals[scale0] = "abc";
    let p = write_bytes(d, "abc.ply", &[ascii.as_bytes(), vals.join(" ").as_bytes()]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "vertex 0, property scale_0");
    // A truncated ASCII body.
    let p = write_bytes(
        d,
        "ascii_trunc.ply",
        &[ascii.as_bytes(), vals[..scale0].join(" ").as_bytes()],
    );
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "vertex 0, property scale_0");

    // Unsupported format, integer-typed parameters, no vertex element.
    let h = header.replace("binary_little_endian", "binary_middle_endian");
    let p = write_bytes(d, "fmt.ply", &[h.as_bytes(), &body]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "header line 2");
    let h = header.replace("property float opacity", "property uchar opacity");
    let p = write_bytes(d, "int.ply", &[h.as_bytes(), &body]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "property opacity");
    let h = header.replace("element vertex", "element points");
    let p = write_bytes(d, "novertex.ply", &[h.as_bytes(), &body]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "element vertex");
}

#[test]
fn failed_write_leaves_the_existing_file_alone() {
    let dir = tmp();
    let path = dir.path().join("keep.ply");
    let good = random_model(30, 2, 9);
    write_ply(&path, &good).unwrap();
    let before = std::fs::read(&path).unwrap();

    let mut bad = random_model(30, 2, 10);
    bad.log_scales[17][2] = f32::NAN;
    let err = write_ply(&path, &bad).unwrap_err();
    let text = format!("{err:#}");
    assert!(
        text.contains("Gaussian 17") && text.contains("log_scales[2]"),
        "{text}"
    );
    assert!(text.contains(&path.display().to_string()), "{text}");

    let mut short = random_model(30, 2, 11);
    short.sh_rest.pop();
    assert!(write_ply(&path, &short)
        .unwrap_err()
        .to_string()
        .contains("keep.ply"));

    assert_eq!(std::fs::read(&path).unwrap(), before);
    // No temporary files left behind.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");

    // Writing into a folder that does not exist fails with the path in the message.
    let nowhere = dir.path().join("no/such/dir/m.ply");
    assert!(format!("{:#}", write_ply(&nowhere, &good).unwrap_err()).contains("no/such/dir"));
}

#[test]
fn model_helpers() {
    use lpmsplat::splats::model::{
        inverse_sigmoid, rgb_to_sh_dc, sh_dc_to_rgb, sigmoid, ParamField, SH_C0,
    };
    let mut rng = Pcg64::seed_from_u64(1);
    for _ in 0..1000 {
        let p: f32 = rng.gen_range(0.001..0.999);
        assert!((sigmoid(inverse_sigmoid(p)) - p).abs() < 1e-5);
        let c: f32 = rng.gen_range(0.0..1.0);
        assert!((sh_dc_to_rgb(rgb_to_sh_dc(c)) - c).abs() < 1e-6);
        let x: f32 = rng.gen_range(-20.0..20.0);
        let s = sigmoid(x) as f64;
        assert!((s - 1.0 / (1.0 + (-(x as f64)).exp())).abs() < 1e-6);
    }
    assert!((rgb_to_sh_dc(1.0) as f64 - 0.5 / SH_C0).abs() < 1e-6);
    assert_eq!(sigmoid(-200.0), 0.0);
    assert_eq!(sigmoid(200.0), 1.0);
    assert!(inverse_sigmoid(0.0).is_finite() && inverse_sigmoid(1.0).is_finite());
    assert!((inverse_sigmoid(0.0) - (1e-6f64 / (1.0 - 1e-6)).ln() as f32).abs() < 1e-3);

    // validate() names the Gaussian and field; with_sh_degree pads with zeros.
    let mut m = random_model(20, 1, 4);
    m.validate().unwrap();
    m.sh_rest[5 * 9 + 2 * 3 + 1] = f32::NAN;
    assert_eq!(
        m.find_non_finite(),
        Some((
            5,
            ParamField::ShRest {
                coef: 2,
                channel: 1
            }
        ))
    );
    let msg = m.validate().unwrap_err().to_string();
    assert!(
        msg.contains("Gaussian 5") && msg.contains("coef 2") && msg.contains("channel 1"),
        "{msg}"
    );
    m.opacity_logits.pop();
    assert!(m
        .validate()
        .unwrap_err()
        .to_string()
        .contains("opacity_logits"));
    let m = random_model(20, 1, 4);
    let up = m.clone().with_sh_degree(3).unwrap();
    for i in 0..20 {
        let r = up.sh_rest_of(i).unwrap();
        assert_eq!(&r[..9], m.sh_rest_of(i).unwrap());
        assert!(r[9..].iter().all(|&v| v == 0.0));
    }
    assert!(m.clone().with_sh_degree(4).is_err());
    let mut bad = m.clone();
    bad.sh_degree = 4;
    assert!(bad.validate().is_err());
}

/// The bytes of `model` written by [`write_ply`], split into header text and body.
fn written(model: &GaussianParams) -> (String, Vec<u8>) {
    let dir = tmp();
    let path = dir.path().join("m.ply");
    write_ply(&path, model).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    (
        String::from_utf8(bytes[..end].to_vec()).unwrap(),
        bytes[end..].to_vec(),
    )
}

#[test]
fn a_body_longer_than_the_header_declares_is_refused() {
    let dir = tmp();
    let d = dir.path();
    // The reported case: `element vertex 1` over a body of 11,384 rows was read as one
    // Gaussian, silently dropping the other 11,383.
    let n = 11_384;
    let model = random_model(n, 0, 71);
    let (header, body) = written(&model);
    let row = property_names(0).len() * 4;
    assert_eq!(body.len(), n * row);
    for format in ["binary_little_endian", "binary_big_endian"] {
        let h = header
            .replace(&format!("element vertex {n}\n"), "element vertex 1\n")
            .replace("binary_little_endian", format);
        let p = write_bytes(d, &format!("one_{format}.ply"), &[h.as_bytes(), &body]);
        let err = read_ply(&p).unwrap_err();
        assert_input_error(&err, &p, "element vertex 1");
        let text = format!("{err:#}");
        assert!(
            text.contains(&format!("{} vertex rows) more", n - 1)),
            "{text}"
        );
        assert!(text.contains(&format!("{} bytes", (n - 1) * row)), "{text}");
        assert!(text.contains("Fix: the header's count is wrong"), "{text}");
    }
    // The right count reads every row; one stray byte after the last row is refused, and so
    // is a missing one (truncated, the other direction).
    let p = write_bytes(d, "exact.ply", &[header.as_bytes(), &body]);
    assert_eq!(read_ply(&p).unwrap().len(), n);
    let p = write_bytes(d, "stray.ply", &[header.as_bytes(), &body, b"\n"]);
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, &format!("element vertex {n}"));
    assert!(format!("{err:#}").contains("1 bytes"), "{err:#}");
    let p = write_bytes(
        d,
        "short.ply",
        &[header.as_bytes(), &body[..body.len() - 1]],
    );
    assert_input_error(&read_ply(&p).unwrap_err(), &p, &format!("vertex {}", n - 1));

    // An element declared after the vertices is part of the expected size: exactly its bytes
    // read, one more is refused.
    let small = random_model(3, 1, 72);
    let (header, body) = written(&small);
    let h = header.replace(
        "end_header\n",
        "element flags 2\nproperty ushort f\nend_header\n",
    );
    let p = write_bytes(d, "after.ply", &[h.as_bytes(), &body, &[1, 2, 3, 4]]);
    assert_eq!(read_ply(&p).unwrap().len(), 3);
    let p = write_bytes(
        d,
        "after_more.ply",
        &[h.as_bytes(), &body, &[1, 2, 3, 4, 5]],
    );
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, "element vertex 3");
    assert!(format!("{err:#}").contains("1 bytes"), "{err:#}");
    let p = write_bytes(d, "after_short.ply", &[h.as_bytes(), &body, &[1, 2, 3]]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "element flags row 1");
}

#[test]
fn an_ascii_body_with_undeclared_rows_is_refused_but_trailing_whitespace_is_not() {
    let dir = tmp();
    let d = dir.path();
    let names = property_names(0);
    let header = |n: usize, after: &str| {
        format!(
            "ply\nformat ascii 1.0\nelement vertex {n}\n{}{after}end_header\n",
            names
                .iter()
                .map(|p| format!("property float {p}\n"))
                .collect::<String>()
        )
    };
    let rows: Vec<String> = (0..3)
        .map(|i| {
            (0..names.len())
                .map(|k| format!("{}", 0.25 * (i * names.len() + k) as f32))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect();
    let body = rows.join("\n");
    // Three rows under `element vertex 1`: refused, naming the two undeclared rows.
    let p = write_bytes(d, "one.ply", &[header(1, "").as_bytes(), body.as_bytes()]);
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, "element vertex 1");
    let text = format!("{err:#}");
    assert!(text.contains("2 vertex rows) more"), "{text}");
    assert!(text.contains("Fix: the header's count is wrong"), "{text}");
    // Half a row too many is refused as well.
    let half = format!("{body}\n1 2 3");
    let p = write_bytes(d, "half.ply", &[header(3, "").as_bytes(), half.as_bytes()]);
    let err = read_ply(&p).unwrap_err();
    assert_input_error(&err, &p, "element vertex 3");
    assert!(format!("{err:#}").contains("3 values more"), "{err:#}");
    // The true count, with any trailing whitespace, reads every row.
    for tail in ["", "\n", "\r\n", "\n\n  \t\n"] {
        let b = format!("{body}{tail}");
        let p = write_bytes(d, "exact.ply", &[header(3, "").as_bytes(), b.as_bytes()]);
        let m = read_ply(&p).unwrap();
        assert_eq!(m.len(), 3);
        assert_eq!(m.positions[2][0], 0.25 * (2 * names.len()) as f32);
    }
    // A declared element after the vertices is read past, then nothing more is allowed.
    let h = header(3, "element edge 2\nproperty list uchar int v\n");
    let b = format!("{body}\n2 5 6\n1 7\n");
    let p = write_bytes(d, "edges.ply", &[h.as_bytes(), b.as_bytes()]);
    assert_eq!(read_ply(&p).unwrap().len(), 3);
    let b = format!("{body}\n2 5 6\n1 7\n9\n");
    let p = write_bytes(d, "edges_more.ply", &[h.as_bytes(), b.as_bytes()]);
    assert_input_error(&read_ply(&p).unwrap_err(), &p, "element vertex 3");
}
