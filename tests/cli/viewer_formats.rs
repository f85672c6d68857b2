//! Our files as splat viewers read them.
//!
//! `point_cloud.ply` is parsed here the way the viewers that load Inria-layout PLYs do (the
//! reference 3DGS `load_ply`, and the web viewers descended from antimatter15/splat): the header
//! up to `end_header\n`, one `vertex` element, properties located by name with their declared
//! types, `f_rest_*` taken in numeric-suffix order and reshaped channel-major (N × 3 × R), scales
//! and rotations by suffix. The decoded Gaussians must equal ours, and the view-dependent colour
//! they give must equal the colour our reference renderer evaluates.
//!
//! `point_cloud.splat` must equal, byte for byte, what those web viewers' own PLY → splat
//! conversion produces from our PLY (done here with their arithmetic: f64, `Uint8ClampedArray`
//! rounding, a stable sort by decreasing size × opacity).

use std::collections::HashMap;

use lpmsplat::reference::sh;
use lpmsplat::splats::model::sh_rest_coeffs;
use lpmsplat::splats::splat_file::SPLAT_ROW_BYTES;
use lpmsplat::splats::{write_ply, write_splat, GaussianParams};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn random_model(n: usize, degree: u32, seed: u64) -> GaussianParams {
    let mut rng = Pcg64::seed_from_u64(seed);
    let r = &mut rng;
    let mut u = |lo: f32, hi: f32| r.gen_range(lo..hi);
    let mut m = GaussianParams::empty(degree);
    for _ in 0..n {
        m.positions.push([u(-5.0, 5.0), u(-5.0, 5.0), u(-5.0, 5.0)]);
        m.log_scales
            .push([u(-9.0, 1.0), u(-9.0, 1.0), u(-9.0, 1.0)]);
        m.rotations
            .push([u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0), u(0.05, 1.0)]);
        m.opacity_logits.push(u(-8.0, 8.0));
        // Past the [0, 1] colour range on purpose: the byte conversion clamps.
        m.sh_dc.push([u(-4.0, 4.0), u(-4.0, 4.0), u(-4.0, 4.0)]);
    }
    m.sh_rest = (0..n * sh_rest_coeffs(degree) * 3)
        .map(|_| u(-0.5, 0.5))
        .collect();
    // Extremes a viewer must survive: a huge scale (exp overflows f32 to +inf) and opacities
    // far in both tails.
    if n > 3 {
        m.log_scales[1] = [95.0, 95.0, 0.0];
        m.opacity_logits[2] = 80.0;
        m.opacity_logits[3] = -80.0;
    }
    m
}

/// A PLY as the viewers parse it: property name → (offset in the row, type), the row size, the
/// vertex count and the body.
struct ViewerPly {
    count: usize,
    row: usize,
    props: HashMap<String, (usize, String)>,
    names: Vec<String>,
    body: Vec<u8>,
}

fn parse_like_a_viewer(bytes: &[u8]) -> ViewerPly {
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .expect("viewers look for `end_header\\n`");
    let header = std::str::from_utf8(&bytes[..at]).expect("ASCII header");
    let mut lines = header.lines();
    assert_eq!(lines.next(), Some("ply"));
    assert_eq!(
        lines.next(),
        Some("format binary_little_endian 1.0"),
        "web viewers read little-endian binary only"
    );
    let mut count = None;
    let mut props = HashMap::new();
    let mut names = Vec::new();
    let mut row = 0;
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => {
                assert!(count.is_none(), "one vertex element");
                count = Some(n.parse::<usize>().unwrap());
            }
            ["element", other, ..] => panic!("viewers expect only the vertex element, got {other}"),
            ["property", ty, name] => {
                assert!(count.is_some(), "properties belong to the vertex element");
                let size = match *ty {
                    "double" => 8,
                    "float" | "int" | "uint" => 4,
                    "short" | "ushort" => 2,
                    "uchar" | "char" => 1,
                    t => panic!("type {t} unknown to the viewers"),
                };
                // Gaussian attributes must be float: several viewers read them as Float32.
                assert_eq!(*ty, "float", "{name}");
                props.insert(name.to_string(), (row, ty.to_string()));
                names.push(name.to_string());
                row += size;
            }
            ["comment", ..] | ["obj_info", ..] => {}
            other => panic!("unexpected header line {other:?}"),
        }
    }
    let count = count.expect("element vertex");
    let body = bytes[at + end.len()..].to_vec();
    assert_eq!(body.len(), count * row, "body = vertex count × row size");
    ViewerPly {
        count,
        row,
        props,
        names,
        body,
    }
}

impl ViewerPly {
    fn get(&self, i: usize, name: &str) -> f32 {
        let (off, _) = self.props[name];
        let o = i * self.row + off;
        f32::from_le_bytes(self.body[o..o + 4].try_into().unwrap())
    }

    /// The names with `prefix` in numeric-suffix order (as the reference `load_ply` sorts them).
    fn by_suffix(&self, prefix: &str) -> Vec<String> {
        let mut v: Vec<(usize, String)> = self
            .names
            .iter()
            .filter_map(|n| Some((n.strip_prefix(prefix)?.parse().ok()?, n.clone())))
            .collect();
        v.sort();
        v.into_iter().map(|(_, n)| n).collect()
    }
}

#[test]
fn our_ply_reads_in_a_viewer_as_the_same_gaussians_and_colours() {
    let dir = tempfile::tempdir().unwrap();
    for degree in 0..=3u32 {
        let model = random_model(200, degree, 7 + degree as u64);
        let path = dir.path().join(format!("d{degree}.ply"));
        write_ply(&path, &model).unwrap();
        let ply = parse_like_a_viewer(&std::fs::read(&path).unwrap());
        assert_eq!(ply.count, model.len());
        for required in ["x", "y", "z", "opacity", "f_dc_0", "f_dc_1", "f_dc_2"] {
            assert!(ply.props.contains_key(required), "{required}");
        }
        let rest_names = ply.by_suffix("f_rest_");
        // The reference asserts exactly 3·((D+1)² − 1) rest properties for its SH degree D.
        let rest = sh_rest_coeffs(degree);
        assert_eq!(rest_names.len(), 3 * rest);
        let scales = ply.by_suffix("scale_");
        let rots = ply.by_suffix("rot_");
        assert_eq!((scales.len(), rots.len()), (3, 4));

        for i in 0..model.len() {
            let pos = [ply.get(i, "x"), ply.get(i, "y"), ply.get(i, "z")];
            assert_eq!(pos.map(f32::to_bits), model.positions[i].map(f32::to_bits));
            let s: Vec<f32> = scales.iter().map(|n| ply.get(i, n)).collect();
            assert_eq!(s, model.log_scales[i].to_vec());
            let q: Vec<f32> = rots.iter().map(|n| ply.get(i, n)).collect();
            assert_eq!(q, model.rotations[i].to_vec(), "rotation is (w, x, y, z)");
            assert_eq!(ply.get(i, "opacity"), model.opacity_logits[i]);

            // The viewer's coefficients: features_extra reshaped (N, 3, R), i.e. channel-major.
            let mut theirs = [[0.0f64; 3]; 16];
            let mut ours = [[0.0f64; 3]; 16];
            for c in 0..3 {
                theirs[0][c] = ply.get(i, &format!("f_dc_{c}")) as f64;
                ours[0][c] = model.sh_dc[i][c] as f64;
                for k in 0..rest {
                    theirs[1 + k][c] = ply.get(i, &rest_names[c * rest + k]) as f64;
                    ours[1 + k][c] = model.sh_rest[(i * rest + k) * 3 + c] as f64;
                }
            }
            for dir in [[0.0, 0.0, 1.0], [0.6, -0.48, 0.64], [-0.36, 0.8, -0.48]] {
                let a = sh::eval(degree as usize, &theirs, dir);
                let b = sh::eval(degree as usize, &ours, dir);
                assert_eq!(a, b, "gaussian {i}, degree {degree}, direction {dir:?}");
            }
        }
    }
}

/// antimatter15/splat's PLY → splat conversion, with its arithmetic.
fn viewer_convert(ply: &ViewerPly) -> Vec<u8> {
    let key = |i: usize| {
        let s = (0..3).map(|a| ply.get(i, &format!("scale_{a}")) as f64);
        s.sum::<f64>().exp() / (1.0 + (-(ply.get(i, "opacity") as f64)).exp())
    };
    let keys: Vec<f64> = (0..ply.count).map(key).collect();
    let mut order: Vec<usize> = (0..ply.count).collect();
    order.sort_by(|&a, &b| keys[b].partial_cmp(&keys[a]).unwrap()); // stable, like V8's
    let clamp8 = |v: f64| -> u8 {
        if v.is_nan() {
            0
        } else {
            v.clamp(0.0, 255.0).round_ties_even() as u8
        }
    };
    let mut out = Vec::with_capacity(ply.count * 32);
    for &i in &order {
        for n in ["x", "y", "z"] {
            out.extend_from_slice(&ply.get(i, n).to_le_bytes());
        }
        for a in 0..3 {
            let s = (ply.get(i, &format!("scale_{a}")) as f64).exp() as f32;
            out.extend_from_slice(&s.to_le_bytes());
        }
        const C0: f64 = 0.28209479177387814;
        for c in 0..3 {
            out.push(clamp8(
                (0.5 + C0 * ply.get(i, &format!("f_dc_{c}")) as f64) * 255.0,
            ));
        }
        out.push(clamp8(
            1.0 / (1.0 + (-(ply.get(i, "opacity") as f64)).exp()) * 255.0,
        ));
        let q: Vec<f64> = (0..4)
            .map(|k| ply.get(i, &format!("rot_{k}")) as f64)
            .collect();
        let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        for v in q {
            out.push(clamp8(v / len * 128.0 + 128.0));
        }
    }
    out
}

#[test]
fn our_splat_equals_the_viewers_conversion_of_our_ply() {
    let dir = tempfile::tempdir().unwrap();
    for degree in [0u32, 3] {
        let model = random_model(500, degree, 100 + degree as u64);
        let ply_path = dir.path().join("m.ply");
        let splat_path = dir.path().join("m.splat");
        write_ply(&ply_path, &model).unwrap();
        write_splat(&splat_path, &model).unwrap();
        let ours = std::fs::read(&splat_path).unwrap();
        assert_eq!(ours.len(), model.len() * SPLAT_ROW_BYTES);
        let theirs = viewer_convert(&parse_like_a_viewer(&std::fs::read(&ply_path).unwrap()));
        assert_eq!(ours.len(), theirs.len());
        let first_diff = ours.iter().zip(&theirs).position(|(a, b)| a != b);
        assert_eq!(
            first_diff,
            None,
            "byte {first_diff:?} (row {:?})",
            first_diff.map(|b| b / 32)
        );
        // The extremes came through: the first row is the +inf-scale Gaussian.
        let sx = f32::from_le_bytes(ours[12..16].try_into().unwrap());
        assert!(sx.is_infinite() && sx > 0.0, "{sx}");
    }
}

#[test]
fn a_splat_file_is_written_atomically_and_refuses_invalid_models() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.splat");
    std::fs::write(&path, b"keep me").unwrap();
    let mut bad = random_model(10, 0, 1);
    bad.positions[4][1] = f32::NAN;
    let err = write_splat(&path, &bad).unwrap_err();
    assert!(format!("{err:#}").contains("m.splat"), "{err:#}");
    assert_eq!(std::fs::read(&path).unwrap(), b"keep me");
}
