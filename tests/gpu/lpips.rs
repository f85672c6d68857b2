//! LPIPS (AlexNet, v0.1 heads) against the reference `lpips` PyPI package.
//!
//! The fixture in tests/data/lpips/ comes from `scripts/lpips_fixture.py`: the real v0.1 linear
//! heads, image pairs, and lpips' distances for an AlexNet trunk filled from a splitmix64 stream
//! (ImageNet weights are not available offline and too big to commit). This test regenerates the
//! trunk bit-exactly, writes trunk + heads into one safetensors file and checks `Lpips::load` and
//! `Lpips::distance` on it.

use lpmsplat::lpips::weights::{write_f32, SafeTensors};
use lpmsplat::lpips::{Lpips, MIN_SIDE, TAP_CHANNELS};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lpips")
}

fn expected() -> Value {
    let text = std::fs::read_to_string(fixture().join("expected.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// (torchvision index, out channels, in channels, kernel) of AlexNet's five convolutions.
const CONVS: [(usize, usize, usize, usize); 5] = [
    (0, 64, 3, 11),
    (3, 192, 64, 5),
    (6, 384, 192, 3),
    (8, 256, 384, 3),
    (10, 256, 256, 3),
];

struct SplitMix64(u64);

impl SplitMix64 {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// The power-of-two exponent nearest 1/sqrt(fan_in), as `round(-0.5 * log2(fan_in))` in Python.
fn bound_exponent(fan_in: usize) -> i32 {
    (-0.5 * (fan_in as f64).log2()).round() as i32
}

/// The trunk of scripts/lpips_fixture.py: (name, shape, values) in stream order.
fn trunk(seed: u64) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let mut rng = SplitMix64(seed);
    let mut out = Vec::new();
    for (idx, cout, cin, k) in CONVS {
        let e = bound_exponent(cin * k * k);
        for (kind, shape) in [("weight", vec![cout, cin, k, k]), ("bias", vec![cout])] {
            let n: usize = shape.iter().product();
            let values = (0..n)
                .map(|_| {
                    let k24 = (rng.next() >> 40) as i64 - (1 << 23);
                    (k24 as f64 * 2f64.powi(e - 23)) as f32
                })
                .collect();
            out.push((format!("features.{idx}.{kind}"), shape, values));
        }
    }
    out
}

/// The shipped v0.1 heads: (name, shape, values).
fn heads() -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let st = SafeTensors::open(&fixture().join("alex_v0.1_heads.safetensors")).unwrap();
    (0..5)
        .map(|i| {
            let name = format!("lin{i}.weight");
            let shape = vec![1, TAP_CHANNELS[i], 1, 1];
            let v = st.f32(&name, &shape).unwrap();
            (name, shape, v)
        })
        .collect()
}

type Tensors = Vec<(String, Vec<usize>, Vec<f32>)>;

fn write(path: &Path, tensors: &Tensors) {
    let refs: Vec<(&str, &[usize], &[f32])> = tensors
        .iter()
        .map(|(n, s, v)| (n.as_str(), s.as_slice(), v.as_slice()))
        .collect();
    write_f32(path, &refs).unwrap();
}

/// Trunk (from the fixture's seed) + shipped heads.
fn all_tensors() -> Tensors {
    let seed = expected()["trunk"]["seed"].as_u64().unwrap();
    let mut t = trunk(seed);
    t.extend(heads());
    t
}

fn load_png(name: &str) -> (Vec<f32>, usize, usize) {
    let img = image::open(fixture().join(name)).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    let v = img.as_raw().iter().map(|&k| k as f32 / 255.0).collect();
    (v, w as usize, h as usize)
}

#[test]
fn trunk_generator_matches_the_fixture_script() {
    let exp = expected();
    let checks = &exp["trunk"]["checks"];
    for (name, _, values) in trunk(exp["trunk"]["seed"].as_u64().unwrap()) {
        let c = &checks[&name];
        // Every value is a multiple of 2^(e−23) below 2^e in size, so these f64 sums are exact
        // whatever the order of summation: they must match numpy's bit for bit.
        let sum: f64 = values.iter().map(|&v| v as f64).sum();
        let sum_abs: f64 = values.iter().map(|&v| (v as f64).abs()).sum();
        assert_eq!(
            values[0] as f64,
            c["first"].as_f64().unwrap(),
            "{name}: first"
        );
        assert_eq!(sum, c["sum"].as_f64().unwrap(), "{name}: sum");
        assert_eq!(sum_abs, c["sum_abs"].as_f64().unwrap(), "{name}: sum |v|");
    }
}

#[test]
fn matches_the_lpips_package() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lpips_random_trunk.safetensors");
    write(&path, &all_tensors());
    let lpips = Lpips::load(&path).unwrap();
    let exp = expected();
    let mut worst: f64 = 0.0;
    let mut worst_rel: f64 = 0.0;
    for p in exp["pairs"].as_array().unwrap() {
        let name = p["name"].as_str().unwrap();
        let (a, w, h) = load_png(p["a"].as_str().unwrap());
        let (b, wb, hb) = load_png(p["b"].as_str().unwrap());
        assert_eq!((w, h), (wb, hb));
        assert_eq!(
            (w, h),
            (
                p["width"].as_u64().unwrap() as usize,
                p["height"].as_u64().unwrap() as usize
            )
        );
        let taps = lpips.distance_per_tap(&a, &b, w, h).unwrap();
        let d = lpips.distance(&a, &b, w, h).unwrap();
        assert_eq!(d, taps.iter().sum::<f64>(), "{name}: distance = Σ taps");
        let e64 = p["lpips_f64"].as_f64().unwrap();
        let e32 = p["lpips_f32"].as_f64().unwrap();
        let err = (d - e64).abs();
        let rel = err / e64.abs().max(1e-12);
        println!(
            "{name:24} rust {d:.10} torch f64 {e64:.10} f32 {e32:.10} |Δ| {err:.2e} rel {rel:.2e}"
        );
        for (t, (&r, e)) in taps
            .iter()
            .zip(p["per_tap_f64"].as_array().unwrap())
            .enumerate()
        {
            let e = e.as_f64().unwrap();
            assert!(
                (r - e).abs() <= 1e-6 + 1e-4 * e.abs(),
                "{name}: tap {t}: rust {r} vs torch {e}"
            );
        }
        // The brief's bound, and a tighter relative one (the distances of a random trunk are
        // small, so 1e-4 absolute alone would be weak).
        assert!(err < 1e-4, "{name}: rust {d} vs torch f64 {e64}");
        assert!(
            err <= 1e-9 + 1e-5 * e64.abs(),
            "{name}: rust {d} vs torch f64 {e64}"
        );
        assert!(
            (d - e32).abs() < 1e-4,
            "{name}: rust {d} vs torch f32 {e32}"
        );
        worst = worst.max(err);
        if e64 > 0.0 {
            worst_rel = worst_rel.max(rel);
        }
        if name.starts_with("identical") {
            assert_eq!(d, 0.0, "{name}: identical images");
        }
    }
    println!("max |rust − torch f64| = {worst:.3e} (max relative {worst_rel:.3e})");
}

#[test]
fn identical_images_give_zero() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    write(&path, &all_tensors());
    let lpips = Lpips::load(&path).unwrap();
    let (a, w, h) = load_png("shift_200x150_a.png");
    assert_eq!(lpips.distance(&a, &a, w, h).unwrap(), 0.0);
    let (b, _, _) = load_png("shift_200x150_b.png");
    let ab = lpips.distance(&a, &b, w, h).unwrap();
    let ba = lpips.distance(&b, &a, w, h).unwrap();
    assert!(ab > 0.0);
    assert_eq!(ab, ba, "symmetric");
}

#[test]
fn smallest_side_matches_lpips() {
    assert_eq!(
        MIN_SIDE as u64,
        expected()["smallest_side"].as_u64().unwrap()
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    write(&path, &all_tensors());
    let lpips = Lpips::load(&path).unwrap();
    for (w, h) in [(30, 40), (40, 30), (10, 10)] {
        let img = vec![0.5f32; w * h * 3];
        let msg = format!("{:#}", lpips.distance(&img, &img, w, h).unwrap_err());
        assert!(msg.contains(&format!("{w}×{h}")), "{msg}");
        assert!(msg.contains("31×31"), "{msg}");
    }
    let img = vec![0.5f32; 31 * 31 * 3];
    assert_eq!(lpips.distance(&img, &img, 31, 31).unwrap(), 0.0);
    // Mismatched lengths and non-finite values are refused too.
    let msg = format!("{:#}", lpips.distance(&img, &img[3..], 31, 31).unwrap_err());
    assert!(msg.contains("second image"), "{msg}");
    let mut nan = img.clone();
    nan[7] = f32::NAN;
    let msg = format!("{:#}", lpips.distance(&nan, &img, 31, 31).unwrap_err());
    assert!(msg.contains("first image") && msg.contains("NaN"), "{msg}");
}

#[test]
fn missing_file_says_how_to_get_the_weights() {
    let path = Path::new("/nonexistent/lpips_alex.safetensors");
    let msg = format!("{:#}", Lpips::load(path).unwrap_err());
    assert!(msg.contains("/nonexistent/lpips_alex.safetensors"), "{msg}");
    assert!(msg.contains("does not exist"), "{msg}");
    assert!(msg.contains("scripts/convert_lpips_weights.py"), "{msg}");
    assert!(msg.contains("LPIPS weights"), "{msg}");
}

#[test]
fn malformed_files_name_the_file_and_the_tensor() {
    let dir = tempfile::tempdir().unwrap();
    let good = all_tensors();
    let load_err = |tensors: &Tensors, file: &str| {
        let path = dir.path().join(file);
        write(&path, tensors);
        let msg = format!("{:#}", Lpips::load(&path).unwrap_err());
        assert!(msg.contains(file), "{msg}");
        msg
    };

    // Wrong shape: conv2 with 3×3 kernels.
    let mut t = good.clone();
    t[2] = (
        "features.3.weight".into(),
        vec![192, 64, 3, 3],
        vec![0.0; 192 * 64 * 9],
    );
    let msg = load_err(&t, "shape.safetensors");
    assert!(msg.contains("features.3.weight"), "{msg}");
    assert!(
        msg.contains("[192, 64, 3, 3]") && msg.contains("[192, 64, 5, 5]"),
        "{msg}"
    );

    // Missing head.
    let t: Tensors = good
        .iter()
        .filter(|(n, _, _)| n != "lin4.weight")
        .cloned()
        .collect();
    let msg = load_err(&t, "missing.safetensors");
    assert!(
        msg.contains("lin4.weight") && msg.contains("missing"),
        "{msg}"
    );

    // Non-finite weight.
    let mut t = good.clone();
    t[11].2[5] = f32::INFINITY;
    let msg = load_err(&t, "inf.safetensors");
    assert!(msg.contains("lin1.weight") && msg.contains("inf"), "{msg}");

    // Truncated file.
    let path = dir.path().join("truncated.safetensors");
    write(&path, &good);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let msg = format!("{:#}", Lpips::load(&path).unwrap_err());
    assert!(
        msg.contains("truncated.safetensors") && msg.contains("truncated"),
        "{msg}"
    );
    std::fs::write(&path, &bytes[..5]).unwrap();
    let msg = format!("{:#}", Lpips::load(&path).unwrap_err());
    assert!(msg.contains("truncated"), "{msg}");
    std::fs::write(&path, &bytes[..100]).unwrap();
    let msg = format!("{:#}", Lpips::load(&path).unwrap_err());
    assert!(msg.contains("truncated"), "{msg}");

    // Wrong dtype: the heads file with lin0 relabelled F16 (and its byte range halved).
    let path = dir.path().join("dtype.safetensors");
    let header = r#"{"lin0.weight":{"dtype":"F16","shape":[1,64,1,1],"data_offsets":[0,128]}}"#;
    let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend_from_slice(&[0u8; 128]);
    std::fs::write(&path, &bytes).unwrap();
    let st = SafeTensors::open(&path).unwrap();
    let msg = format!("{:#}", st.f32("lin0.weight", &[1, 64, 1, 1]).unwrap_err());
    assert!(
        msg.contains("dtype.safetensors") && msg.contains("lin0.weight"),
        "{msg}"
    );
    assert!(msg.contains("F16") && msg.contains("F32"), "{msg}");

    // Not JSON.
    let path = dir.path().join("garbage.safetensors");
    let mut bytes = 16u64.to_le_bytes().to_vec();
    bytes.extend_from_slice(b"this is not json");
    std::fs::write(&path, &bytes).unwrap();
    let msg = format!("{:#}", Lpips::load(&path).unwrap_err());
    assert!(
        msg.contains("garbage.safetensors") && msg.contains("JSON"),
        "{msg}"
    );
}

/// Reads the file the reference writer produced for the heads (Python `safetensors`, with
/// `__metadata__` and header padding) and writes it back with ours: same tensors.
#[test]
fn safetensors_round_trip() {
    let st = SafeTensors::open(&fixture().join("alex_v0.1_heads.safetensors")).unwrap();
    let names: Vec<&str> = st.names().collect();
    assert_eq!(
        names,
        [
            "lin0.weight",
            "lin1.weight",
            "lin2.weight",
            "lin3.weight",
            "lin4.weight"
        ]
    );
    let h = heads();
    let total: usize = h.iter().map(|(_, _, v)| v.len()).sum();
    assert_eq!(total, 64 + 192 + 384 + 256 + 256);
    assert!(h.iter().all(|(_, _, v)| v.iter().all(|&x| x >= 0.0)));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("heads.safetensors");
    write(&path, &h);
    let back = SafeTensors::open(&path).unwrap();
    for (name, shape, values) in &h {
        assert_eq!(back.shape(name).unwrap(), shape.as_slice());
        assert_eq!(&back.f32_any_shape(name).unwrap().1, values);
    }
}

/// Timing (release build): `cargo test --release --test gpu lpips:: -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    write(&path, &all_tensors());
    let t = std::time::Instant::now();
    let lpips = Lpips::load(&path).unwrap();
    println!("load: {:.3} s", t.elapsed().as_secs_f64());
    for (w, h) in [(1352usize, 1014usize), (245, 184), (64, 64)] {
        let a: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 7919) % 256) as f32 / 255.0)
            .collect();
        let b: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 104729) % 256) as f32 / 255.0)
            .collect();
        lpips.distance(&a, &b, w, h).unwrap(); // warm-up
        let reps = if w > 1000 { 3 } else { 10 };
        let t = std::time::Instant::now();
        for _ in 0..reps {
            std::hint::black_box(lpips.distance(&a, &b, w, h).unwrap());
        }
        let s = t.elapsed().as_secs_f64() / reps as f64;
        println!(
            "{w}×{h} pair: {:.1} ms ({} threads)",
            s * 1e3,
            rayon::current_num_threads()
        );
    }
}
