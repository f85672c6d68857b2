//! The CPU reference forward pass against independent brute-force computations on tiny scenes.

use std::f64::consts::PI;

use lpmsplat::reference::scenes::{random_gaussians, random_view};
use lpmsplat::reference::{self, sh, RefGaussians, RenderSettings};
use lpmsplat::scene::{PinholeCamera, Pose};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn one_gaussian(
    pos: [f64; 3],
    log_scale: [f64; 3],
    q: [f64; 4],
    logit: f64,
    dc: [f64; 3],
) -> RefGaussians {
    let mut sh = [[0.0; 3]; 16];
    sh[0] = dc;
    RefGaussians {
        positions: vec![pos],
        log_scales: vec![log_scale],
        rotations: vec![q],
        opacity_logits: vec![logit],
        sh: vec![sh],
    }
}

fn concat(parts: &[RefGaussians]) -> RefGaussians {
    let mut g = RefGaussians::default();
    for p in parts {
        g.positions.extend(&p.positions);
        g.log_scales.extend(&p.log_scales);
        g.rotations.extend(&p.rotations);
        g.opacity_logits.extend(&p.opacity_logits);
        g.sh.extend(&p.sh);
    }
    g
}

fn camera(w: u32, h: u32, f: f64) -> PinholeCamera {
    PinholeCamera {
        fx: f,
        fy: f,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        width: w,
        height: h,
    }
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

fn all_finite(out: &reference::RenderOutput) -> bool {
    out.raster.image.iter().flatten().all(|v| v.is_finite())
        && out.raster.final_transmittance.iter().all(|v| v.is_finite())
}

/// Rodrigues' formula: rotation by `angle` about the unit `axis`.
fn rodrigues(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let [x, y, z] = axis;
    let k = [[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]];
    let (s, c) = angle.sin_cos();
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let k2: f64 = (0..3).map(|m| k[i][m] * k[m][j]).sum();
            r[i][j] = if i == j { 1.0 } else { 0.0 } + s * k[i][j] + (1.0 - c) * k2;
        }
    }
    r
}

#[test]
fn sh_basis_is_orthonormal_on_the_sphere() {
    // ∫ Y_i Y_j dΩ over the unit sphere, dΩ = dz dφ: midpoint rule in z, uniform in φ (exact
    // for the trigonometric polynomials in φ that products of degree-3 harmonics are).
    let (nz, nphi) = (2000, 32);
    let mut gram = [[0.0; 16]; 16];
    for iz in 0..nz {
        let z = -1.0 + (iz as f64 + 0.5) * 2.0 / nz as f64;
        let r = (1.0 - z * z).sqrt();
        for ip in 0..nphi {
            let phi = ip as f64 * 2.0 * PI / nphi as f64;
            let b = sh::basis(3, [r * phi.cos(), r * phi.sin(), z]);
            let w = (2.0 / nz as f64) * (2.0 * PI / nphi as f64);
            for (row, bi) in gram.iter_mut().zip(b) {
                for (g, bj) in row.iter_mut().zip(b) {
                    *g += w * bi * bj;
                }
            }
        }
    }
    for (i, row) in gram.iter().enumerate() {
        for (j, &value) in row.iter().enumerate() {
            let want = if i == j { 1.0 } else { 0.0 };
            assert!((value - want).abs() < 1e-5, "<Y{i}, Y{j}> = {value}");
        }
    }
    // Constants from their closed forms, and the degree-1 sign convention of the PLY files.
    assert!((sh::SH_C0 - 0.5 / PI.sqrt()).abs() < 1e-15);
    assert!((sh::SH_C1 - (3.0 / (4.0 * PI)).sqrt()).abs() < 1e-15);
    let b = sh::basis(1, [0.0, 0.0, 1.0]);
    assert!((b[2] - sh::SH_C1).abs() < 1e-15 && b[1] == 0.0 && b[3] == 0.0);
    let b = sh::basis(1, [1.0, 0.0, 0.0]);
    assert!((b[3] + sh::SH_C1).abs() < 1e-15);
}

#[test]
fn sh_basis_gradient_matches_finite_differences() {
    let mut rng = Pcg64::seed_from_u64(11);
    for _ in 0..50 {
        let d: [f64; 3] = [0; 3].map(|_| rng.gen_range(-1.5..1.5));
        let g = sh::basis_gradient(3, d);
        let h = 1e-6;
        for axis in 0..3 {
            let (mut dp, mut dm) = (d, d);
            dp[axis] += h;
            dm[axis] -= h;
            let (bp, bm) = (sh::basis(3, dp), sh::basis(3, dm));
            for k in 0..16 {
                let fd = (bp[k] - bm[k]) / (2.0 * h);
                assert!(
                    (fd - g[k][axis]).abs() < 1e-7,
                    "basis {k} axis {axis}: {fd} vs {}",
                    g[k][axis]
                );
            }
        }
    }
}

#[test]
fn one_gaussian_matches_closed_form() {
    let mut rng = Pcg64::seed_from_u64(1);
    for case in 0..20 {
        let (w, h) = (rng.gen_range(5..45), rng.gen_range(5..45));
        let (cam, pose) = random_view(&mut rng, w, h);
        // A mean inside the view, unprojected from a random pixel at a random depth.
        let (u, v, z) = (
            rng.gen_range(0.0..w as f64),
            rng.gen_range(0.0..h as f64),
            rng.gen_range(2.0..6.0),
        );
        let pc = [(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z];
        let d = [0, 1, 2].map(|k| pc[k] - pose.translation[k]);
        let pos = [0, 1, 2].map(|k| (0..3).map(|m| pose.rotation[m][k] * d[m]).sum::<f64>());

        let axis = {
            let a: [f64; 3] = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
            let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            a.map(|v| v / n)
        };
        let angle = rng.gen_range(0.0..PI);
        let k = rng.gen_range(0.3..3.0); // the quaternion need not be unit
        let (s2, c2) = (0.5 * angle).sin_cos();
        let q = [c2 * k, axis[0] * s2 * k, axis[1] * s2 * k, axis[2] * s2 * k];
        let scales: [f64; 3] = [0; 3].map(|_| rng.gen_range(0.02..0.3));
        let logit = rng.gen_range(-3.0..3.0);
        let dc: [f64; 3] = [0; 3].map(|_| rng.gen_range(-1.5..1.5));
        let bg: [f64; 3] = [0; 3].map(|_| rng.gen_range(0.0..1.0));
        let g = one_gaussian(pos, scales.map(f64::ln), q, logit, dc);
        let settings = RenderSettings::default();
        let out = reference::render(&g, &cam, &pose, 0, bg, &settings).unwrap();

        // Independent 2D covariance: Rodrigues rotation, numerical Jacobian of world → pixel.
        let r = rodrigues(axis, angle);
        let sigma: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                (0..3)
                    .map(|m| r[i][m] * scales[m] * scales[m] * r[j][m])
                    .sum()
            })
        });
        let to_pixel = |p: [f64; 3]| cam.project(pose.transform(p));
        let mut jac = [[0.0; 3]; 2];
        for a in 0..3 {
            let (mut pp, mut pm) = (pos, pos);
            pp[a] += 1e-5;
            pm[a] -= 1e-5;
            let (xp, xm) = (to_pixel(pp), to_pixel(pm));
            for row in 0..2 {
                jac[row][a] = (xp[row] - xm[row]) / 2e-5;
            }
        }
        let cov = |i: usize, j: usize| -> f64 {
            (0..3)
                .map(|a| {
                    (0..3)
                        .map(|b| jac[i][a] * sigma[a][b] * jac[j][b])
                        .sum::<f64>()
                })
                .sum()
        };
        let (ca, cb, cc) = (cov(0, 0) + 0.3, cov(0, 1), cov(1, 1) + 0.3);
        let det = ca * cc - cb * cb;
        let mean = to_pixel(pos);
        let opacity = sigmoid(logit);
        let rgb = dc.map(|c| (c * 0.5 / PI.sqrt() + 0.5).max(0.0));

        let p = &out.projected[0];
        assert!(!p.culled);
        assert!((p.mean2d[0] - mean[0]).abs() < 1e-9 && (p.mean2d[1] - mean[1]).abs() < 1e-9);
        for (got, want) in p.cov2d.iter().zip([ca, cb, cc]) {
            assert!(
                (got - want).abs() < 1e-5 * want.abs().max(1.0),
                "case {case}: cov2d {got} vs {want}"
            );
        }
        for j in 0..h {
            for i in 0..w {
                let (dx, dy) = (mean[0] - (i as f64 + 0.5), mean[1] - (j as f64 + 0.5));
                let maha = (cc * dx * dx - 2.0 * cb * dx * dy + ca * dy * dy) / det;
                let in_tiles = p.touches_tile(i / 16, j / 16);
                if maha <= 9.0 {
                    assert!(
                        in_tiles,
                        "case {case}: pixel ({i},{j}) is within 3σ but its tile is not touched"
                    );
                }
                let raw_alpha = opacity * (-0.5 * maha).exp();
                let alpha = raw_alpha.min(0.99);
                let drawn = in_tiles && alpha >= 1.0 / 255.0;
                let pix = (j * w + i) as usize;
                for ch in 0..3 {
                    let want = if drawn {
                        rgb[ch] * alpha + (1.0 - alpha) * bg[ch]
                    } else {
                        bg[ch]
                    };
                    let got = out.raster.image[pix][ch];
                    assert!(
                        (got - want).abs() < 1e-6,
                        "case {case} pixel ({i},{j}) ch {ch}: {got} vs {want}"
                    );
                }
                assert_eq!(out.raster.last_contributor[pix], drawn as u32);
            }
        }
    }
}

#[test]
fn two_gaussians_blend_nearest_first_whatever_their_order() {
    // Isotropic Gaussians centred on pixel (10, 7) of an identity-pose camera, so alpha there is
    // exactly the opacity, and one pixel to the right it is o·exp(−½/(σ² + 0.3)).
    let cam = PinholeCamera {
        fx: 30.0,
        fy: 30.0,
        cx: 10.5,
        cy: 7.5,
        width: 23,
        height: 19,
    };
    let (near_z, far_z, s) = (2.0, 3.0, 0.05f64);
    let near = one_gaussian(
        [0.0, 0.0, near_z],
        [s.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        0.4,
        [0.9, -0.3, 0.1],
    );
    let far = one_gaussian(
        [0.0, 0.0, far_z],
        [s.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        -0.2,
        [-0.5, 0.7, 1.2],
    );
    let bg = [0.2, 0.5, 0.9];
    let rgb = |g: &RefGaussians| g.sh[0][0].map(|c| c * sh::SH_C0 + 0.5);
    let (on, of) = (sigmoid(0.4), sigmoid(-0.2));
    let expect = |an: f64, af: f64| -> [f64; 3] {
        let (cn, cf) = (rgb(&near), rgb(&far));
        [0, 1, 2].map(|c| cn[c] * an + cf[c] * af * (1.0 - an) + bg[c] * (1.0 - an) * (1.0 - af))
    };
    let falloff = |z: f64| (-0.5 / ((cam.fx * s / z).powi(2) + 0.3)).exp();
    for scene in [
        concat(&[near.clone(), far.clone()]),
        concat(&[far.clone(), near.clone()]),
    ] {
        let out = reference::render(
            &scene,
            &cam,
            &Pose::IDENTITY,
            0,
            bg,
            &RenderSettings::default(),
        )
        .unwrap();
        let centre = out.raster.image[7 * 23 + 10];
        let right = out.raster.image[7 * 23 + 11];
        let (wc, wr) = (
            expect(on, of),
            expect(on * falloff(near_z), of * falloff(far_z)),
        );
        for c in 0..3 {
            assert!((centre[c] - wc[c]).abs() < 1e-12, "{centre:?} vs {wc:?}");
            assert!((right[c] - wr[c]).abs() < 1e-12, "{right:?} vs {wr:?}");
        }
        let t = out.raster.final_transmittance[7 * 23 + 10];
        assert!((t - (1.0 - on) * (1.0 - of)).abs() < 1e-12);
        assert_eq!(out.raster.last_contributor[7 * 23 + 10], 2);
    }
}

#[test]
fn empty_and_off_screen_scenes_show_the_background() {
    let cam = camera(21, 13, 20.0);
    let bg = [0.3, 0.6, 0.1];
    let empty = RefGaussians::default();
    let out = reference::render(
        &empty,
        &cam,
        &Pose::IDENTITY,
        3,
        bg,
        &RenderSettings::default(),
    )
    .unwrap();
    assert!(out.raster.image.iter().all(|p| *p == bg));
    assert!(out.raster.final_transmittance.iter().all(|&t| t == 1.0));
    // Far to the side: not culled (it is in front) but touches no tile.
    let side = one_gaussian(
        [50.0, 0.0, 2.0],
        [0.01f64.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        3.0,
        [1.0; 3],
    );
    let out = reference::render(
        &side,
        &cam,
        &Pose::IDENTITY,
        0,
        bg,
        &RenderSettings::default(),
    )
    .unwrap();
    assert!(!out.projected[0].culled);
    assert_eq!(out.projected[0].tiles_touched(), 0);
    assert!(out.raster.image.iter().all(|p| *p == bg));
}

#[test]
fn gaussians_on_or_behind_the_near_plane_are_culled() {
    let cam = camera(16, 16, 20.0);
    let settings = RenderSettings {
        near: 0.5,
        ..RenderSettings::default()
    };
    let bg = [0.0; 3];
    for (z, culled) in [
        (0.5, true),
        (0.5 * (1.0 + 1e-12), false),
        (0.0, true),
        (-3.0, true),
        (f64::NAN, true),
    ] {
        let g = one_gaussian(
            [0.0, 0.0, z],
            [0.1f64.ln(); 3],
            [1.0, 0.0, 0.0, 0.0],
            2.0,
            [1.0; 3],
        );
        let out = reference::render(&g, &cam, &Pose::IDENTITY, 0, bg, &settings).unwrap();
        assert_eq!(out.projected[0].culled, culled, "z = {z}");
        assert!(all_finite(&out));
        if culled {
            assert_eq!(out.projected[0].tiles_touched(), 0);
            assert!(out.raster.image.iter().all(|p| *p == bg));
        } else {
            assert!(out.raster.image.iter().any(|p| p[0] > 0.0));
        }
    }
}

#[test]
fn degenerate_quaternions_render_as_the_identity() {
    let cam = camera(17, 15, 25.0);
    let render = |q: [f64; 4]| {
        let g = one_gaussian(
            [0.1, -0.05, 2.0],
            [0.2f64.ln(), 0.05f64.ln(), 0.1f64.ln()],
            q,
            1.0,
            [0.4, 0.0, -0.4],
        );
        reference::render(
            &g,
            &cam,
            &Pose::IDENTITY,
            0,
            [1.0; 3],
            &RenderSettings::default(),
        )
        .unwrap()
    };
    let identity = render([1.0, 0.0, 0.0, 0.0]);
    for q in [
        [0.0; 4],
        [1e-310, 0.0, 0.0, 0.0],
        [-0.0, 1e-13, 0.0, -1e-13],
    ] {
        let out = render(q);
        assert!(all_finite(&out));
        assert_eq!(out.raster.image, identity.raster.image, "q = {q:?}");
    }
    // A small but regular quaternion is normalised, not replaced.
    let a = render([0.0, 1e-6, 0.0, 0.0]);
    let b = render([0.0, 1.0, 0.0, 0.0]);
    for (x, y) in a
        .raster
        .image
        .iter()
        .flatten()
        .zip(b.raster.image.iter().flatten())
    {
        assert!((x - y).abs() < 1e-12);
    }
}

#[test]
fn opacity_extremes() {
    let cam = PinholeCamera {
        fx: 30.0,
        fy: 30.0,
        cx: 8.5,
        cy: 8.5,
        width: 17,
        height: 17,
    };
    let bg = [0.25, 0.5, 0.75];
    let centre = 8 * 17 + 8;
    // Logit −50: alpha ≈ 2e-22 < 1/255 everywhere, so the image is exactly the background.
    let g = one_gaussian(
        [0.0, 0.0, 2.0],
        [0.1f64.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        -50.0,
        [1.0; 3],
    );
    let out =
        reference::render(&g, &cam, &Pose::IDENTITY, 0, bg, &RenderSettings::default()).unwrap();
    assert!(out.raster.image.iter().all(|p| *p == bg));
    // Logit +50: alpha is clamped to 0.99 at the centre.
    let g = one_gaussian(
        [0.0, 0.0, 2.0],
        [0.1f64.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        50.0,
        [1.0; 3],
    );
    let out =
        reference::render(&g, &cam, &Pose::IDENTITY, 0, bg, &RenderSettings::default()).unwrap();
    let rgb = sh::SH_C0 + 0.5;
    for (got, b) in out.raster.image[centre].iter().zip(bg) {
        assert!((got - (0.99 * rgb + 0.01 * b)).abs() < 1e-12);
    }
    assert!((out.raster.final_transmittance[centre] - 0.01).abs() < 1e-12);
}

#[test]
fn extreme_scales_stay_finite() {
    let cam = camera(40, 33, 35.0);
    let tiny = one_gaussian(
        [0.0, 0.0, 2.0],
        [1e-8f64.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        1.0,
        [0.5; 3],
    );
    let out = reference::render(
        &tiny,
        &cam,
        &Pose::IDENTITY,
        0,
        [0.0; 3],
        &RenderSettings::default(),
    )
    .unwrap();
    assert!(all_finite(&out));
    let p = &out.projected[0];
    // Only the dilation is left: cov2d ≈ 0.3·I, radius = ceil(3·√0.3) = 2.
    assert!(
        (p.cov2d[0] - 0.3).abs() < 1e-9
            && p.cov2d[1].abs() < 1e-12
            && (p.cov2d[2] - 0.3).abs() < 1e-9
    );
    assert_eq!(p.radius, 2.0);

    let huge = one_gaussian(
        [0.0, 0.0, 2.0],
        [1e4f64.ln(), 1e-8f64.ln(), 1e4f64.ln()],
        [0.3, 0.1, 0.9, -0.2],
        1.0,
        [0.5; 3],
    );
    let out = reference::render(
        &huge,
        &cam,
        &Pose::IDENTITY,
        3,
        [0.0; 3],
        &RenderSettings::default(),
    )
    .unwrap();
    assert!(all_finite(&out));
    let p = &out.projected[0];
    if !p.culled {
        let (tx, ty) = RenderSettings::default().tile_grid(40, 33);
        assert_eq!(p.tiles_touched(), (tx * ty) as u64);
        assert!(p.conic.iter().all(|v| v.is_finite()));
    }
    // Both extremes at once, with a far-away and a huge-logit Gaussian, in one scene.
    let far = one_gaussian(
        [3.0, -2.0, 1e6],
        [1.0f64.ln(); 3],
        [0.0; 4],
        50.0,
        [2.0, -3.0, 0.0],
    );
    let scene = concat(&[tiny, huge, far]);
    let out = reference::render(
        &scene,
        &cam,
        &Pose::IDENTITY,
        3,
        [1.0; 3],
        &RenderSettings::default(),
    )
    .unwrap();
    assert!(all_finite(&out));
}

#[test]
fn thousands_of_splats_on_one_pixel_stop_at_the_transmittance_floor() {
    let cam = PinholeCamera {
        fx: 20.0,
        fy: 20.0,
        cx: 5.5,
        cy: 4.5,
        width: 11,
        height: 9,
    };
    let n = 3000;
    let parts: Vec<RefGaussians> = (0..n)
        .map(|k| {
            one_gaussian(
                [0.0, 0.0, 2.0 + k as f64 * 1e-3],
                [0.02f64.ln(); 3],
                [1.0, 0.0, 0.0, 0.0],
                0.0,
                [0.3; 3],
            )
        })
        .collect();
    let scene = concat(&parts);
    let out = reference::render(
        &scene,
        &cam,
        &Pose::IDENTITY,
        0,
        [1.0; 3],
        &RenderSettings::default(),
    )
    .unwrap();
    assert!(all_finite(&out));
    let centre = 4 * 11 + 5;
    // alpha = 0.5 at the centre: 0.5^13 ≥ 1e-4 > 0.5^14, so 13 splats contribute.
    assert_eq!(out.raster.contributors[centre], 13);
    assert_eq!(out.raster.last_contributor[centre], 13);
    assert!((out.raster.final_transmittance[centre] - 0.5f64.powi(13)).abs() < 1e-15);
    for (&t, &last) in out
        .raster
        .final_transmittance
        .iter()
        .zip(&out.raster.last_contributor)
    {
        assert!(t >= 1e-4 && (last as usize) < n);
    }
}

#[test]
fn tiles_touched_are_consistent_with_the_radius() {
    let mut rng = Pcg64::seed_from_u64(5);
    let settings = RenderSettings::default();
    for _ in 0..10 {
        let (w, h) = (rng.gen_range(1..70), rng.gen_range(1..70));
        let (cam, pose) = random_view(&mut rng, w, h);
        let mut g = random_gaussians(&mut rng, 30);
        for s in g.log_scales.iter_mut() {
            s[0] += rng.gen_range(-1.0..2.0); // some large ones, spanning several tiles
        }
        let out = reference::render(&g, &cam, &pose, 3, [0.0; 3], &settings).unwrap();
        let (tiles_x, tiles_y) = settings.tile_grid(w, h);
        for (gi, p) in out.projected.iter().enumerate() {
            let in_lists = out
                .bins
                .lists
                .iter()
                .filter(|l| l.contains(&(gi as u32)))
                .count() as u64;
            assert_eq!(in_lists, p.pairs(&settings));
            assert!(in_lists <= p.tiles_touched());
            if p.culled {
                continue;
            }
            // λmax by sweeping directions: radius = ceil(3·sqrt(λmax)).
            let [a, b, c] = p.cov2d;
            let lambda = (0..20000)
                .map(|k| {
                    let (s, co) = (k as f64 * PI / 20000.0).sin_cos();
                    a * co * co + 2.0 * b * s * co + c * s * s
                })
                .fold(0.0, f64::max);
            let r3 = 3.0 * lambda.sqrt();
            assert!(
                p.radius >= r3 - 1e-9 && p.radius < r3 * (1.0 + 1e-6) + 1.0,
                "radius {} vs 3σ {r3}",
                p.radius
            );
            let det = a * c - b * b;
            for ty in 0..tiles_y {
                for tx in 0..tiles_x {
                    // Brute force: does any pixel centre of the tile lie within 3σ?
                    let within = (ty * 16..((ty + 1) * 16).min(h)).any(|j| {
                        (tx * 16..((tx + 1) * 16).min(w)).any(|i| {
                            let (dx, dy) =
                                (p.mean2d[0] - i as f64 - 0.5, p.mean2d[1] - j as f64 - 0.5);
                            let m2 = (c * dx * dx - 2.0 * b * dx * dy + a * dy * dy) / det;
                            // Within 3σ and bright enough not to be skipped by alpha_min.
                            m2 <= 9.0 && p.opacity * (-0.5 * m2).exp() >= settings.alpha_min
                        })
                    });
                    let touched = p.touches_tile(tx, ty);
                    let paired =
                        out.bins.lists[(ty * tiles_x + tx) as usize].contains(&(gi as u32));
                    if within {
                        assert!(
                            touched && paired,
                            "tile ({tx},{ty}) holds a pixel the splat reaches but is not paired"
                        );
                    }
                    if paired {
                        assert!(touched, "tile ({tx},{ty}) paired outside the rectangle");
                        // Paired only where the ellipse q <= q_cut meets the tile's pixel
                        // centres, up to the documented margin (1e-3 px + 1e-6 relative).
                        let q_cut = reference::project::splat_q_cut(p.opacity, &settings);
                        let m = 2e-3 + 1e-5 * (p.mean2d[0].abs() + p.mean2d[1].abs() + p.radius);
                        let lo = [tx as f64 * 16.0 + 0.5 - m, ty as f64 * 16.0 + 0.5 - m];
                        let hi = [lo[0] + 15.0 + 2.0 * m, lo[1] + 15.0 + 2.0 * m];
                        let q = min_q_over_box(p.mean2d, p.conic, lo, hi);
                        assert!(
                            q <= q_cut * (1.0 + 1e-9),
                            "tile ({tx},{ty}) paired but min q {q} > q_cut {q_cut}"
                        );
                    }
                    if touched {
                        // A touched tile overlaps the bounding square [mean − r, mean + r].
                        let (x0, y0) = ((tx * 16) as f64, (ty * 16) as f64);
                        assert!(
                            x0 <= p.mean2d[0] + p.radius && x0 + 16.0 >= p.mean2d[0] - p.radius
                        );
                        assert!(
                            y0 <= p.mean2d[1] + p.radius && y0 + 16.0 >= p.mean2d[1] - p.radius
                        );
                    }
                }
            }
        }
        // Each tile's list is ordered by depth, ties by index.
        for list in &out.bins.lists {
            for pair in list.windows(2) {
                let (d0, d1) = (
                    out.projected[pair[0] as usize].depth,
                    out.projected[pair[1] as usize].depth,
                );
                assert!(d0 < d1 || (d0 == d1 && pair[0] < pair[1]));
            }
        }
    }
}

/// The least of `q(x − mean) = dᵀ·conic·d` over the box `[lo, hi]`, by dense sampling of its
/// edges refined around the best sample (a convex quadratic whose minimum lies outside a box is
/// smallest on its boundary): independent of the closed form the binning uses.
fn min_q_over_box(mean: [f64; 2], conic: [f64; 3], lo: [f64; 2], hi: [f64; 2]) -> f64 {
    let [a, b, c] = conic;
    let q = |x: f64, y: f64| {
        let (dx, dy) = (x - mean[0], y - mean[1]);
        a * dx * dx + 2.0 * b * dx * dy + c * dy * dy
    };
    if (lo[0]..=hi[0]).contains(&mean[0]) && (lo[1]..=hi[1]).contains(&mean[1]) {
        return 0.0;
    }
    let edge = |p0: [f64; 2], p1: [f64; 2]| {
        let at = |t: f64| q(p0[0] + t * (p1[0] - p0[0]), p0[1] + t * (p1[1] - p0[1]));
        // Convex along the edge: a ternary search finds its minimum on [0, 1].
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for _ in 0..200 {
            let (m0, m1) = (t0 + (t1 - t0) / 3.0, t1 - (t1 - t0) / 3.0);
            if at(m0) <= at(m1) {
                t1 = m1;
            } else {
                t0 = m0;
            }
        }
        at(0.5 * (t0 + t1)).min(at(0.0)).min(at(1.0))
    };
    let (x0, y0, x1, y1) = (lo[0], lo[1], hi[0], hi[1]);
    edge([x0, y0], [x1, y0])
        .min(edge([x0, y1], [x1, y1]))
        .min(edge([x0, y0], [x0, y1]))
        .min(edge([x1, y0], [x1, y1]))
}

/// Pairing a splat only with the tiles its ellipse reaches (`Projected::row_tiles`) leaves out
/// pairs that the rasterizer would skip at every pixel: the image, the transmittance, every
/// per-pixel count and every gradient are the same as with the whole rectangle, exactly, while
/// elongated splats lose a good share of their pairs.
#[test]
fn pairing_by_ellipse_changes_no_pixel_and_no_gradient() {
    use reference::backward::rasterize_backward;
    use reference::raster::{rasterize, TileBins};
    let mut rng = Pcg64::seed_from_u64(0xE111);
    let settings = RenderSettings::default();
    let (mut pairs, mut rect_pairs) = (0u64, 0u64);
    for _ in 0..6 {
        let (w, h) = (rng.gen_range(40..120), rng.gen_range(40..120));
        let (cam, pose) = random_view(&mut rng, w, h);
        let mut g = random_gaussians(&mut rng, 40);
        for (s, o) in g.log_scales.iter_mut().zip(&mut g.opacity_logits) {
            s[0] += rng.gen_range(0.0..3.0); // long thin splats at every angle
            s[1] -= rng.gen_range(0.0..1.0);
            *o = rng.gen_range(-4.0..3.0); // faint ones too: a shorter reach
        }
        let out = reference::render(&g, &cam, &pose, 3, [0.1, 0.2, 0.3], &settings).unwrap();
        let mut rect = out.bins.clone();
        for list in &mut rect.lists {
            list.clear();
        }
        for (gi, p) in out.projected.iter().enumerate() {
            if p.culled {
                continue;
            }
            for ty in p.tile_min[1]..p.tile_max[1] {
                for tx in p.tile_min[0]..p.tile_max[0] {
                    rect.lists[(ty * rect.tiles_x + tx) as usize].push(gi as u32);
                }
            }
            rect_pairs += p.tiles_touched();
        }
        for list in &mut rect.lists {
            list.sort_by(|&x, &y| {
                let (dx, dy) = (
                    out.projected[x as usize].depth,
                    out.projected[y as usize].depth,
                );
                dx.total_cmp(&dy).then(x.cmp(&y))
            });
        }
        pairs += out.bins.intersections();
        let by_rect: TileBins = rect;
        let r = rasterize(&out.projected, &by_rect, &cam, [0.1, 0.2, 0.3], &settings).unwrap();
        assert_eq!(r.image, out.raster.image);
        assert_eq!(r.final_transmittance, out.raster.final_transmittance);
        assert_eq!(r.contributors, out.raster.contributors);
        assert_eq!(r.pixel_count, out.raster.pixel_count);
        assert_eq!(r.median_depth, out.raster.median_depth);
        let dl: Vec<[f64; 3]> = (0..(w * h) as usize)
            .map(|_| [rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), 0.5])
            .collect();
        let bg = [0.1, 0.2, 0.3];
        let ga = rasterize_backward(&out.projected, &out.bins, &out.raster, bg, &settings, &dl);
        let gb = rasterize_backward(&out.projected, &by_rect, &r, bg, &settings, &dl);
        assert_eq!(ga.unwrap(), gb.unwrap());
    }
    // Not vacuous: the ellipse leaves out a good share of the rectangles' tiles.
    assert!(
        (pairs as f64) < 0.8 * rect_pairs as f64,
        "{pairs} pairs of {rect_pairs}"
    );
    eprintln!("pairs by ellipse: {pairs} of the rectangles' {rect_pairs}");
}

/// The row span at its extremes: what it returns where it cannot bound the ellipse, and that
/// it stays exact for far-off means and needle-thin or huge footprints.
#[test]
fn ellipse_row_span_at_the_extremes() {
    use reference::project::{ellipse_row_span, RowSpan};
    let band = [0.5, 15.5];
    // Never above alpha_min: no tile; smooth mode or no finite cut: every tile.
    assert_eq!(
        ellipse_row_span([8.0, 8.0], [1.0, 0.0, 1.0], -1.0, band),
        RowSpan::Empty
    );
    assert_eq!(
        ellipse_row_span([8.0, 8.0], [1.0, 0.0, 1.0], f64::INFINITY, band),
        RowSpan::Whole
    );
    // Badly conditioned (det ≤ 1e-4·ac), degenerate or non-finite conics: every tile.
    for conic in [
        [1.0, 0.99999, 1.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, -1.0],
        [f64::NAN, 0.0, 1.0],
        [1.0, f64::INFINITY, 1.0],
    ] {
        assert_eq!(
            ellipse_row_span([8.0, 8.0], conic, 10.0, band),
            RowSpan::Whole,
            "{conic:?}"
        );
    }
    assert_eq!(
        ellipse_row_span([f64::NAN, 8.0], [1.0, 0.0, 1.0], 10.0, band),
        RowSpan::Whole
    );
    // A circle of radius 2 around (100, 8): x from 98 to 102, plus the margin.
    match ellipse_row_span([100.0, 8.0], [1.0, 0.0, 1.0], 4.0, band) {
        RowSpan::Pixels(lo, hi) => {
            assert!(
                (lo - 98.0).abs() < 3e-3 && lo < 98.0 && (hi - 102.0).abs() < 3e-3 && hi > 102.0
            )
        }
        other => panic!("{other:?}"),
    }
    // The same circle just above the band reaches it in a narrow span; 0.5 px higher, not at all.
    match ellipse_row_span([100.0, -1.4], [1.0, 0.0, 1.0], 4.0, band) {
        RowSpan::Pixels(lo, hi) => assert!(lo > 99.0 && hi < 101.0 && lo < hi, "{lo} {hi}"),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        ellipse_row_span([100.0, -1.6], [1.0, 0.0, 1.0], 4.0, band),
        RowSpan::Empty
    );
    // Far from the origin (4K and beyond): the margin grows with the coordinates, the span stays
    // around the true one.
    for x in [1e4, 1e6, 1e7] {
        match ellipse_row_span([x, 8.0], [1.0, 0.0, 1.0], 4.0, band) {
            RowSpan::Pixels(lo, hi) => {
                let m = 1e-3 + 1e-6 * (x + 8.0 + 4.0);
                assert!(
                    (lo - (x - 2.0 - m)).abs() < 1e-6 * x && (hi - (x + 2.0 + m)).abs() < 1e-6 * x
                );
            }
            other => panic!("{other:?}"),
        }
    }
    // A needle at 45° (standard deviations 100 and 1 px; det = 4e-4·ac, just bounded): the
    // band of rows 0.5..15.5 through its centre meets it where x ≈ y (−3.7 to 19.7), not over
    // the 424 px its x-extent spans.
    let (l1, l2) = (1e4f64, 1.0f64); // variances along (1, 1)/√2 and (1, −1)/√2
    let (a, b) = ((l1 + l2) / 2.0, (l1 - l2) / 2.0);
    let det = a * a - b * b;
    let conic = [a / det, -b / det, a / det];
    match ellipse_row_span([8.0, 8.0], conic, 9.0, band) {
        RowSpan::Pixels(lo, hi) => {
            assert!(
                (lo + 3.738).abs() < 0.01 && (hi - 19.738).abs() < 0.01,
                "{lo} {hi}"
            )
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn equal_depths_sort_by_index() {
    let cam = camera(16, 16, 20.0);
    let a = one_gaussian(
        [0.1, 0.0, 2.0],
        [0.1f64.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        [1.0, 0.0, 0.0],
    );
    let b = one_gaussian(
        [-0.1, 0.0, 2.0],
        [0.1f64.ln(); 3],
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        [0.0, 1.0, 0.0],
    );
    let scene = concat(&[a.clone(), b.clone(), a]);
    let out = reference::render(
        &scene,
        &cam,
        &Pose::IDENTITY,
        0,
        [0.0; 3],
        &RenderSettings::default(),
    )
    .unwrap();
    assert_eq!(out.bins.lists[0], vec![0, 1, 2]);
}

#[test]
fn jacobian_clamp_uses_the_asymmetric_field_of_view() {
    // Principal point off-centre: the x/z limits are −1.3·cx/fx and 1.3·(W − cx)/fx.
    let cam = PinholeCamera {
        fx: 20.0,
        fy: 22.0,
        cx: 4.0,
        cy: 9.0,
        width: 30,
        height: 14,
    };
    let settings = RenderSettings::default();
    let (s, z) = (0.2f64, 2.0);
    for (x_over_z, tx) in [
        (-2.0, -1.3 * 4.0 / 20.0),
        (3.0, 1.3 * 26.0 / 20.0),
        (0.1, 0.1),
    ] {
        let g = one_gaussian(
            [x_over_z * z, 0.0, z],
            [s.ln(); 3],
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            [0.0; 3],
        );
        let p = reference::preprocess(&g, &cam, &Pose::IDENTITY, 0, &settings).unwrap()[0];
        // Isotropic Σ = s²·I: Σ2D = s²·J Jᵀ + 0.3·I with J = [[fx/z, 0, −fx·tx/z], [0, fy/z, 0]].
        let (j00, j02, j11) = (cam.fx / z, -cam.fx * tx / z, cam.fy / z);
        let want = [
            s * s * (j00 * j00 + j02 * j02) + 0.3,
            0.0,
            s * s * j11 * j11 + 0.3,
        ];
        for k in 0..3 {
            assert!(
                (p.cov2d[k] - want[k]).abs() < 1e-12,
                "x/z = {x_over_z}: {:?} vs {want:?}",
                p.cov2d
            );
        }
        // The mean itself is not clamped.
        assert!((p.mean2d[0] - (cam.fx * x_over_z + cam.cx)).abs() < 1e-12);
    }
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let cam = camera(8, 8, 10.0);
    let mut g = one_gaussian(
        [0.0, 0.0, 2.0],
        [0.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        [0.0; 3],
    );
    let s = RenderSettings::default();
    assert!(reference::render(&g, &cam, &Pose::IDENTITY, 4, [0.0; 3], &s).is_err());
    assert!(reference::render(&g, &camera(0, 8, 10.0), &Pose::IDENTITY, 0, [0.0; 3], &s).is_err());
    assert!(reference::render(
        &g,
        &cam,
        &Pose::IDENTITY,
        0,
        [0.0; 3],
        &RenderSettings { tile_size: 0, ..s }
    )
    .is_err());
    g.opacity_logits.push(1.0);
    let err = reference::render(&g, &cam, &Pose::IDENTITY, 0, [0.0; 3], &s).unwrap_err();
    assert!(err.to_string().contains("opacity_logits"), "{err}");
}

/// `alpha_min_edges` flags exactly the pixels where two footprints of the same splats (here the
/// reference's and a copy with the opacity nudged by 1 %) disagree on the alpha_min test,
/// plus those within its band, and none in smooth mode.
#[test]
fn alpha_min_edges_flag_the_pixels_whose_blend_decision_can_flip() {
    let mut rng = Pcg64::seed_from_u64(0xed6e);
    let settings = RenderSettings::default();
    let (mut flagged, mut flips) = (0usize, 0usize);
    for _ in 0..20 {
        let n = rng.gen_range(1..40);
        let g = random_gaussians(&mut rng, n);
        let (cam, pose) = random_view(&mut rng, 48, 40);
        let r = reference::render(&g, &cam, &pose, 0, [0.0; 3], &settings).unwrap();
        let nudged: Vec<reference::Footprint> = r
            .projected
            .iter()
            .map(|p| reference::Footprint {
                opacity: p.opacity * (1.0 + 1e-2),
                ..reference::Footprint::of(p)
            })
            .collect();
        let band = 1e-6;
        let edges =
            reference::alpha_min_edges(&r.projected, &nudged, &r.bins, &cam, &settings, band);
        for j in 0..cam.height {
            for i in 0..cam.width {
                let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
                let list = &r.bins.lists[r.bins.tile_of_pixel(i, j)];
                // Each splat's raw alpha in both footprints.
                let alphas: Vec<(f64, f64)> = list
                    .iter()
                    .map(|&k| {
                        let exact = reference::Footprint::of(&r.projected[k as usize]);
                        (
                            exact.raw_alpha(px, py),
                            nudged[k as usize].raw_alpha(px, py),
                        )
                    })
                    .collect();
                let min = settings.alpha_min;
                let in_band = |a: f64| (min * (1.0 - band)..=min * (1.0 + band)).contains(&a);
                let flipped = alphas.iter().filter(|(a, b)| (*a >= min) != (*b >= min));
                let expect = alphas
                    .iter()
                    .filter(|(a, b)| (*a >= min) != (*b >= min) || in_band(*a) || in_band(*b))
                    .count() as u32;
                let pix = (j * cam.width + i) as usize;
                assert_eq!(edges[pix], expect, "pixel ({i}, {j})");
                flagged += (edges[pix] > 0) as usize;
                flips += flipped.count();
            }
        }
        let smooth = RenderSettings {
            smooth: true,
            ..settings
        };
        let none = reference::alpha_min_edges(&r.projected, &nudged, &r.bins, &cam, &smooth, band);
        assert!(none.iter().all(|&e| e == 0));
    }
    assert!(
        flips > 0 && flagged > 0,
        "the scenes never put a splat at the edge"
    );
    eprintln!("{flagged} pixels flagged, {flips} flipped decisions");
}
