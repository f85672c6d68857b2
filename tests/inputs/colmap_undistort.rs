//! Undistortion against known 3D points and a synthetic pattern.

use crate::colmap_support::{all_models, project_distorted, rng};
use lpmsplat::scene::undistort::{
    distort_pixel, undistort_image, undistort_normalized, undistort_pixel,
};
use lpmsplat::scene::{CameraModel, Image};
use rand::Rng;

/// The lund_door camera (1296x1936, SIMPLE_RADIAL) and strong versions of every distorted
/// model, plus the random realistic ones.
fn distorted_models(w: u32, h: u32) -> Vec<CameraModel> {
    let mut r = rng(10);
    let mut models: Vec<CameraModel> = all_models(&mut r, w, h)
        .into_iter()
        .filter(|m| m.is_distorted())
        .collect();
    let (f, cx, cy) = (w as f64, w as f64 * 0.5, h as f64 * 0.5);
    models.extend([
        CameraModel::SimpleRadial { f, cx, cy, k: -0.2 },
        CameraModel::SimpleRadial { f, cx, cy, k: 0.25 },
        CameraModel::Radial {
            f,
            cx,
            cy,
            k1: -0.25,
            k2: 0.05,
        },
        CameraModel::OpenCv {
            fx: f,
            fy: 1.1 * f,
            cx: cx + 7.0,
            cy: cy - 5.0,
            k1: 0.2,
            k2: -0.05,
            p1: 0.01,
            p2: -0.015,
        },
    ]);
    models
}

#[test]
fn undistorted_pixels_match_the_pinhole_projection_of_3d_points() {
    let mut r = rng(11);
    let mut lund = vec![CameraModel::SimpleRadial {
        f: 2435.38,
        cx: 648.0,
        cy: 968.0,
        k: -0.0336422,
    }];
    lund.extend(distorted_models(1296, 1936));
    let mut checked = 0;
    for model in lund {
        let (fx, fy, cx, cy) = model.pinhole_part();
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            // A random 3D point in front of the camera, inside its field of view.
            let z = r.gen_range(0.5..50.0);
            let p = [r.gen_range(-0.5..0.5) * z, r.gen_range(-0.7..0.7) * z, z];
            let src = project_distorted(&model, p);
            if !(src[0] >= 0.0 && src[1] >= 0.0 && src[0] <= 1296.0 && src[1] <= 1936.0) {
                continue;
            }
            let pinhole = [fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy];
            let got = undistort_pixel(&model, src[0], src[1])
                .unwrap_or_else(|| panic!("{model:?}: no undistortion at {src:?}"));
            worst = worst.max((got[0] - pinhole[0]).hypot(got[1] - pinhole[1]));
            let back = distort_pixel(&model, pinhole[0], pinhole[1]);
            assert!((back[0] - src[0]).hypot(back[1] - src[1]) < 1e-9);
            checked += 1;
        }
        assert!(
            worst < 0.1,
            "{model:?}: reprojection error {worst} px after undistortion"
        );
        // Without undistortion the same pixels would be off by far more: the check has teeth.
        let corner = distort_pixel(&model, 0.0, 0.0);
        assert!(
            corner[0].hypot(corner[1]) > 0.5,
            "{model:?}: no visible distortion"
        );
    }
    assert!(checked > 10_000);
}

#[test]
fn pinhole_models_pass_through() {
    let mut r = rng(12);
    for model in all_models(&mut r, 64, 48)
        .into_iter()
        .filter(|m| !m.is_distorted())
    {
        let (u, v) = (r.gen_range(0.0..64.0), r.gen_range(0.0..48.0));
        assert_eq!(undistort_pixel(&model, u, v), Some([u, v]));
        let img = Image {
            width: 4,
            height: 3,
            rgb: (0..36).map(|i| i as f32 / 36.0).collect(),
            alpha: None,
        };
        assert_eq!(undistort_image(&model, &img), img);
    }
}

#[test]
fn no_answer_past_the_fold_of_a_strong_barrel_distortion() {
    // r_d = r (1 + k r²) peaks at r_d = 2/3 · 1/sqrt(3|k|) ≈ 0.70 for k = -0.3: nothing maps
    // beyond that, and the pixels there must not get a made-up answer.
    let model = CameraModel::SimpleRadial {
        f: 100.0,
        cx: 50.0,
        cy: 50.0,
        k: -0.3,
    };
    assert!(undistort_normalized(&model, 0.8, 0.0).is_none());
    assert!(undistort_pixel(&model, 50.0 + 80.0, 50.0).is_none());
    assert!(undistort_pixel(&model, f64::NAN, 1.0).is_none());
    let [x, y] = undistort_normalized(&model, 0.6, 0.0).unwrap();
    assert!(x > 0.6 && x < 1.0 / 0.9f64.sqrt() && y == 0.0, "{x}");
}

/// A smooth checker-like pattern on the undistorted image plane (period 12 px), with a
/// different phase per channel so that channel mix-ups show.
fn pattern(u: f64, v: f64, c: usize) -> f32 {
    let t = std::f64::consts::TAU / 12.0;
    (0.5 + 0.45 * ((u * t + c as f64).sin() * (v * t).cos())) as f32
}

/// Undistorted pixel of a source pixel by plain fixed-point iteration: an inversion written
/// independently of the library's Newton solver.
fn reference_undistort(model: &CameraModel, u: f64, v: f64) -> [f64; 2] {
    let (fx, fy, cx, cy) = model.pinhole_part();
    let (xd, yd) = ((u - cx) / fx, (v - cy) / fy);
    let (mut x, mut y) = (xd, yd);
    for _ in 0..500 {
        let (dx, dy) = model.distort_normalized(x, y);
        x += xd - dx;
        y += yd - dy;
    }
    let (dx, dy) = model.distort_normalized(x, y);
    assert!(
        (dx - xd).hypot(dy - yd) < 1e-12,
        "reference inversion did not converge"
    );
    [fx * x + cx, fy * y + cy]
}

#[test]
fn undistorted_pattern_lands_on_the_pinhole_grid() {
    let (w, h) = (96u32, 80u32);
    let (f, cx, cy) = (90.0, 47.0, 41.5);
    for model in [
        CameraModel::SimpleRadial {
            f,
            cx,
            cy,
            k: -0.12,
        },
        CameraModel::Radial {
            f,
            cx,
            cy,
            k1: 0.1,
            k2: -0.03,
        },
        CameraModel::OpenCv {
            fx: f,
            fy: 0.95 * f,
            cx,
            cy,
            k1: -0.1,
            k2: 0.02,
            p1: 0.004,
            p2: -0.003,
        },
    ] {
        // The distorted photo of the pattern: each source pixel shows the pattern at its
        // undistorted position. Alpha carries a pattern too.
        let mut rgb = Vec::new();
        let mut alpha = Vec::new();
        for j in 0..h {
            for i in 0..w {
                let [u, v] = reference_undistort(&model, i as f64 + 0.5, j as f64 + 0.5);
                rgb.extend((0..3).map(|c| pattern(u, v, c)));
                alpha.push(pattern(v, u, 0));
            }
        }
        let src = Image {
            width: w,
            height: h,
            rgb,
            alpha: Some(alpha),
        };
        let out = undistort_image(&model, &src);
        assert_eq!((out.width, out.height), (w, h));
        let out_alpha = out.alpha.as_ref().unwrap();
        let (mut err, mut raw_err, mut n, mut outside) = (0.0f64, 0.0f64, 0, 0);
        for j in 0..h as usize {
            for i in 0..w as usize {
                let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
                let s = distort_pixel(&model, u, v);
                let k = j * w as usize + i;
                // Only where the source covers the pixel with a full bilinear footprint.
                if !(s[0] >= 1.0 && s[1] >= 1.0 && s[0] <= w as f64 - 1.0 && s[1] <= h as f64 - 1.0)
                {
                    if !(s[0] >= 0.0 && s[1] >= 0.0 && s[0] <= w as f64 && s[1] <= h as f64) {
                        assert_eq!(&out.rgb[3 * k..3 * k + 3], &[0.0; 3]);
                        assert_eq!(out_alpha[k], 0.0);
                        outside += 1;
                    }
                    continue;
                }
                for c in 0..3 {
                    err = err.max((out.rgb[3 * k + c] - pattern(u, v, c)).abs() as f64);
                    raw_err = raw_err.max((src.rgb[3 * k + c] - pattern(u, v, c)).abs() as f64);
                }
                err = err.max((out_alpha[k] - pattern(v, u, 0)).abs() as f64);
                n += 1;
            }
        }
        assert!(n > (w * h) as usize / 2);
        // Bilinear sampling of a 12 px period costs a few percent of the amplitude at most.
        assert!(err < 0.05, "{model:?}: max error {err}");
        assert!(
            raw_err > 0.3,
            "{model:?}: the distortion is too weak to test ({raw_err})"
        );
        if matches!(model, CameraModel::Radial { .. }) {
            assert!(
                outside > 0,
                "pincushion corners should fall outside the source"
            );
        }
    }
}
