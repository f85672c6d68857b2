//! Image loading, area resizing, compositing and PNG output, against hand computations in f64.

use lpmsplat::scene::images::{
    composite_on_background, decode_image, load_images, resize_area, save_png,
};
use lpmsplat::scene::{Image, LoadOptions, Scene};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::path::Path;

fn lego_small() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lego_small")
}

fn random_image(w: u32, h: u32, alpha: bool, rng: &mut Pcg64) -> Image {
    let n = (w * h) as usize;
    Image {
        width: w,
        height: h,
        rgb: (0..3 * n).map(|_| rng.gen::<f32>()).collect(),
        alpha: alpha.then(|| {
            (0..n)
                .map(|_| {
                    if rng.gen_bool(0.2) {
                        0.0
                    } else {
                        rng.gen::<f32>()
                    }
                })
                .collect()
        }),
    }
}

/// Brute-force area average in f64: output pixel (i, j) is the mean of the source over the
/// rectangle [i·sx, (i+1)·sx) × [j·sy, (j+1)·sy), each source pixel weighted by its overlap.
/// Colour is premultiplied by alpha (when present) and divided back.
fn area_oracle(src: &Image, w: u32, h: u32) -> (Vec<f64>, Option<Vec<f64>>) {
    let sx = src.width as f64 / w as f64;
    let sy = src.height as f64 / h as f64;
    let overlap = |a0: f64, a1: f64, b: f64| (a1.min(b + 1.0) - a0.max(b)).max(0.0);
    let mut rgb = vec![0.0; 3 * (w * h) as usize];
    let mut alpha = vec![0.0; (w * h) as usize];
    for j in 0..h {
        for i in 0..w {
            let (x0, x1) = (i as f64 * sx, (i + 1) as f64 * sx);
            let (y0, y1) = (j as f64 * sy, (j + 1) as f64 * sy);
            let mut acc = [0.0f64; 4];
            let mut total = 0.0;
            for y in 0..src.height {
                for x in 0..src.width {
                    let wgt = overlap(x0, x1, x as f64) * overlap(y0, y1, y as f64);
                    if wgt == 0.0 {
                        continue;
                    }
                    let a = src.alpha_at(x, y) as f64;
                    let c = src.pixel(x, y);
                    for k in 0..3 {
                        acc[k] += wgt * c[k] as f64 * a;
                    }
                    acc[3] += wgt * a;
                    total += wgt;
                }
            }
            let p = (j * w + i) as usize;
            let a = acc[3] / total;
            alpha[p] = a;
            for k in 0..3 {
                rgb[3 * p + k] = if a > 0.0 { acc[k] / total / a } else { 0.0 };
            }
        }
    }
    (rgb, src.alpha.as_ref().map(|_| alpha))
}

fn assert_close(got: &[f32], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}");
    for (k, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((*g as f64 - w).abs() <= tol, "{what}[{k}]: {g} vs {w}");
    }
}

#[test]
fn integer_factor_is_the_box_average() {
    let mut rng = Pcg64::seed_from_u64(11);
    // Different factors in x and y, RGB and RGBA.
    for (sw, sh, dw, dh, alpha) in [
        (60, 45, 20, 15, false),
        (48, 36, 12, 18, false),
        (40, 40, 10, 10, true),
    ] {
        let src = random_image(sw, sh, alpha, &mut rng);
        let out = resize_area(&src, dw, dh);
        assert_eq!((out.width, out.height), (dw, dh));
        // Plain box average, written out separately from the oracle for the RGB case.
        if !alpha {
            let (fx, fy) = (sw / dw, sh / dh);
            for j in 0..dh {
                for i in 0..dw {
                    for k in 0..3 {
                        let mut s = 0.0f64;
                        for y in j * fy..(j + 1) * fy {
                            for x in i * fx..(i + 1) * fx {
                                s += src.pixel(x, y)[k] as f64;
                            }
                        }
                        let want = s / (fx * fy) as f64;
                        assert!((out.pixel(i, j)[k] as f64 - want).abs() < 1e-6);
                    }
                }
            }
        }
        let (rgb, a) = area_oracle(&src, dw, dh);
        // Where alpha is near 0 the straight colour is ill-conditioned; compare premultiplied.
        match (&out.alpha, a) {
            (None, None) => assert_close(&out.rgb, &rgb, 1e-6, "rgb"),
            (Some(oa), Some(wa)) => {
                assert_close(oa, &wa, 1e-6, "alpha");
                let pre: Vec<f32> = out
                    .rgb
                    .iter()
                    .enumerate()
                    .map(|(k, c)| c * oa[k / 3])
                    .collect();
                let want: Vec<f64> = rgb.iter().enumerate().map(|(k, c)| c * wa[k / 3]).collect();
                assert_close(&pre, &want, 1e-6, "premultiplied rgb");
            }
            _ => panic!("alpha channel appeared or vanished"),
        }
    }
}

#[test]
fn fractional_factor_is_the_coverage_weighted_average() {
    let mut rng = Pcg64::seed_from_u64(12);
    for (sw, sh, dw, dh) in [(37, 23, 10, 9), (50, 30, 33, 17), (7, 5, 11, 8)] {
        let src = random_image(sw, sh, false, &mut rng);
        let out = resize_area(&src, dw, dh);
        let (rgb, _) = area_oracle(&src, dw, dh);
        assert_close(&out.rgb, &rgb, 1e-5, "rgb");
        // Area averaging keeps the mean.
        let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        assert!((mean(&out.rgb) - mean(&src.rgb)).abs() < 1e-5);
    }
    let same = random_image(9, 7, true, &mut rng);
    assert_eq!(resize_area(&same, 9, 7), same);
}

#[test]
fn resize_commutes_with_compositing() {
    let mut rng = Pcg64::seed_from_u64(13);
    let src = random_image(48, 32, true, &mut rng);
    let bg = [0.2f32, 0.7, 1.0];
    for (w, h) in [(12, 8), (17, 11)] {
        let a = composite_on_background(&resize_area(&src, w, h), bg);
        let b = resize_area(&composite_on_background(&src, bg), w, h);
        assert!(a.alpha.is_none() && b.alpha.is_none());
        let b64: Vec<f64> = b.rgb.iter().map(|&x| x as f64).collect();
        assert_close(&a.rgb, &b64, 1e-5, "composite");
    }
}

#[test]
fn composite_on_background_is_over() {
    let mut rng = Pcg64::seed_from_u64(14);
    let img = random_image(13, 7, true, &mut rng);
    let bg = [rng.gen::<f32>(), rng.gen(), rng.gen()];
    let out = composite_on_background(&img, bg);
    assert!(out.alpha.is_none());
    for y in 0..7 {
        for x in 0..13 {
            let a = img.alpha_at(x, y) as f64;
            for ((&c, &b), &o) in img.pixel(x, y).iter().zip(&bg).zip(&out.pixel(x, y)) {
                let want = c as f64 * a + b as f64 * (1.0 - a);
                assert!((o as f64 - want).abs() < 1e-6);
            }
        }
    }
    let opaque = random_image(5, 4, false, &mut rng);
    assert_eq!(composite_on_background(&opaque, bg), opaque);
}

#[test]
fn image_accessors() {
    let mut img = Image::new(4, 3);
    assert_eq!(
        (img.rgb.len(), img.alpha.is_none(), img.len()),
        (36, true, 12)
    );
    img.set_pixel(3, 2, [0.1, 0.2, 0.3]);
    assert_eq!(img.pixel(3, 2), [0.1, 0.2, 0.3]);
    assert_eq!(&img.rgb[33..36], &[0.1, 0.2, 0.3]);
    assert_eq!(img.alpha_at(1, 1), 1.0);
}

#[test]
fn save_png_round_trips_8_bit() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Pcg64::seed_from_u64(15);
    for alpha in [false, true] {
        let mut img = random_image(21, 9, alpha, &mut rng);
        img.rgb[0] = 1.7; // clamps to 255
        img.rgb[1] = -0.3; // clamps to 0
        let path = dir.path().join(format!("out_{alpha}.png"));
        save_png(&path, &img).unwrap();
        let back = decode_image(&path).unwrap();
        assert_eq!(
            (back.width, back.height, back.alpha.is_some()),
            (21, 9, alpha)
        );
        let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() / 255.0;
        for (g, w) in back.rgb.iter().zip(&img.rgb) {
            assert!((g - q(*w)).abs() < 1e-6, "{g} vs {w}");
        }
        if let (Some(ga), Some(wa)) = (&back.alpha, &img.alpha) {
            for (g, w) in ga.iter().zip(wa) {
                assert!((g - q(*w)).abs() < 1e-6);
            }
        }
    }
    // A failed save leaves the existing file alone and no temporary behind.
    let path = dir.path().join("out_false.png");
    let before = std::fs::read(&path).unwrap();
    let mut bad = Image::new(4, 4);
    bad.rgb.pop();
    assert!(save_png(&path, &bad).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), before);
    assert!(save_png(&dir.path().join("no/such/dir/x.png"), &Image::new(2, 2)).is_err());
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
}

#[test]
fn decodes_jpeg() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("x.jpg");
    let mut rng = Pcg64::seed_from_u64(16);
    let c: [u8; 3] = rng.gen();
    image::RgbImage::from_fn(24, 16, |_, _| image::Rgb(c))
        .save(&path)
        .unwrap();
    let img = decode_image(&path).unwrap();
    assert_eq!((img.width, img.height, img.alpha.is_none()), (24, 16, true));
    // A flat colour survives JPEG within a few levels.
    for px in img.rgb.chunks(3) {
        for k in 0..3 {
            assert!((px[k] - c[k] as f32 / 255.0).abs() < 4.0 / 255.0);
        }
    }
    std::fs::write(&path, b"\xff\xd8 truncated").unwrap();
    let e = format!("{:#}", decode_image(&path).unwrap_err());
    assert!(e.contains("x.jpg") && e.contains("truncated"), "{e}");
}

#[test]
fn lego_small_images() {
    let scene = Scene::load(&lego_small(), &LoadOptions::default()).unwrap();
    let all: Vec<usize> = (0..scene.views.len()).collect();
    let imgs = load_images(&scene, &all).unwrap();
    assert_eq!(imgs.len(), 11);
    for (img, v) in imgs.iter().zip(&scene.views) {
        assert_eq!((img.width, img.height), (100, 100));
        let a = img.alpha.as_ref().expect("RGBA");
        // The object on a transparent background: both fully clear and fully opaque pixels.
        assert!(a.iter().filter(|&&x| x == 0.0).count() > 1000, "{}", v.name);
        assert!(a.iter().filter(|&&x| x == 1.0).count() > 500, "{}", v.name);
        assert!(img.rgb.iter().all(|x| (0.0..=1.0).contains(x)));
        assert_eq!(img, &decode_image(&v.image_path).unwrap());
    }
    // In the order asked for.
    let two = load_images(&scene, &[7, 2]).unwrap();
    assert_eq!((&two[0], &two[1]), (&imgs[7], &imgs[2]));
    assert!(load_images(&scene, &[11]).is_err());

    // -r 2: the 2×2 area average of the full image (premultiplied), to f32 precision.
    let half = Scene::load(
        &lego_small(),
        &LoadOptions {
            resolution_factor: Some(2),
            ..Default::default()
        },
    )
    .unwrap();
    let small = load_images(&half, &[3]).unwrap().remove(0);
    let (rgb, a) = area_oracle(&imgs[3], 50, 50);
    let a = a.unwrap();
    assert_close(small.alpha.as_ref().unwrap(), &a, 1e-6, "alpha");
    let pre: Vec<f32> = small
        .rgb
        .iter()
        .enumerate()
        .map(|(k, c)| c * small.alpha.as_ref().unwrap()[k / 3])
        .collect();
    let want: Vec<f64> = rgb.iter().enumerate().map(|(k, c)| c * a[k / 3]).collect();
    assert_close(&pre, &want, 1e-6, "premultiplied rgb");
}

#[test]
fn image_of_the_wrong_size_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(lego_small()).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            std::fs::create_dir_all(dir.path().join(e.file_name())).unwrap();
            for f in std::fs::read_dir(e.path()).unwrap() {
                let f = f.unwrap();
                std::fs::copy(f.path(), dir.path().join(e.file_name()).join(f.file_name()))
                    .unwrap();
            }
        } else {
            std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
        }
    }
    let scene = Scene::load(dir.path(), &LoadOptions::default()).unwrap();
    // The image changes on disk after the scene was read.
    let v = &scene.views[1];
    save_png(&v.image_path, &Image::new(80, 100)).unwrap();
    let e = format!("{:#}", load_images(&scene, &[0, 1]).unwrap_err());
    assert!(
        e.contains(&v.image_path.display().to_string())
            && e.contains("80x100")
            && e.contains("100x100"),
        "{e}"
    );
}
