//! The CPU reference backward pass against central finite differences of its forward pass.
//!
//! Most checks run in smooth mode (`RenderSettings::smooth`: no 1/255 alpha cutoff, no
//! transmittance stop, no 0.99 alpha clamp) where the image is a smooth function of the
//! parameters. One test runs the engine's normal settings on dense, opaque scenes so the alpha
//! clamp and the transmittance stop are exercised. In both, a finite-difference step that
//! changes which splats reach a pixel (the 3σ tile lists, the contributor counts, a colour
//! clamp) is a discontinuity: it is detected by comparing the ± evaluations with the unperturbed
//! one and that parameter is skipped; the tests assert such skips are rare.

use lpmsplat::reference::scenes::{random_gaussians, random_view};
use lpmsplat::reference::{
    self, backward, mip, rasterize, sample_splat, sh, Gradients, RefGaussians, RenderOutput,
    RenderSettings,
};
use lpmsplat::scene::{PinholeCamera, Pose};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

struct Case {
    gaussians: RefGaussians,
    camera: PinholeCamera,
    pose: Pose,
    degree: usize,
    background: [f64; 3],
    settings: RenderSettings,
    /// dL/d(image): the loss is Σ weights · image.
    weights: Vec<[f64; 3]>,
    /// Mip-Splatting's 3D filter (one standard deviation per Gaussian), folded into the
    /// parameters before rendering; its gradient goes back through `mip::fuse_backward`.
    filter3d: Option<Vec<f64>>,
}

impl Case {
    fn render(&self, g: &RefGaussians) -> RenderOutput {
        let fused = self.filter3d.as_ref().map(|f| mip::fuse(g, f).unwrap());
        reference::render(
            fused.as_ref().unwrap_or(g),
            &self.camera,
            &self.pose,
            self.degree,
            self.background,
            &self.settings,
        )
        .unwrap()
    }

    fn loss_of(&self, out: &RenderOutput) -> f64 {
        dot_image(&out.raster.image, &self.weights)
    }

    fn gradients(&self) -> (RenderOutput, Gradients) {
        let out = self.render(&self.gaussians);
        let fused = self
            .filter3d
            .as_ref()
            .map(|f| mip::fuse(&self.gaussians, f).unwrap());
        let mut grads = backward(
            fused.as_ref().unwrap_or(&self.gaussians),
            &self.camera,
            &self.pose,
            self.degree,
            self.background,
            &self.settings,
            &out,
            &self.weights,
        )
        .unwrap();
        if let Some(f) = &self.filter3d {
            grads.params = mip::fuse_backward(&self.gaussians, f, &grads.params).unwrap();
        }
        (out, grads)
    }
}

fn dot_image(image: &[[f64; 3]], weights: &[[f64; 3]]) -> f64 {
    image
        .iter()
        .zip(weights)
        .map(|(p, w)| p[0] * w[0] + p[1] * w[1] + p[2] * w[2])
        .sum()
}

/// Same set of contributing splats per pixel and the same colour clamps.
fn same_structure(a: &RenderOutput, b: &RenderOutput) -> bool {
    a.bins.lists == b.bins.lists
        && a.raster.last_contributor == b.raster.last_contributor
        && a.raster.contributors == b.raster.contributors
        && a.projected
            .iter()
            .zip(&b.projected)
            .all(|(p, q)| p.rgb_clamped == q.rgb_clamped)
}

const GROUPS: [(&str, usize); 5] = [
    ("position", 3),
    ("log_scale", 3),
    ("rotation", 4),
    ("opacity_logit", 1),
    ("sh", 48),
];

fn param_mut(g: &mut RefGaussians, group: usize, i: usize, c: usize) -> &mut f64 {
    match group {
        0 => &mut g.positions[i][c],
        1 => &mut g.log_scales[i][c],
        2 => &mut g.rotations[i][c],
        3 => &mut g.opacity_logits[i],
        _ => &mut g.sh[i][c / 3][c % 3],
    }
}

fn param_grad(g: &Gradients, group: usize, i: usize, c: usize) -> f64 {
    let p = &g.params;
    match group {
        0 => p.positions[i][c],
        1 => p.log_scales[i][c],
        2 => p.rotations[i][c],
        3 => p.opacity_logits[i],
        _ => p.sh[i][c / 3][c % 3],
    }
}

/// Per parameter group: how many components were compared, skipped, and the worst relative
/// error among the non-negligible ones.
#[derive(Default, Debug, Clone, Copy)]
struct GroupStats {
    checked: usize,
    skipped: usize,
    total: usize,
    worst: f64,
}

/// Compares every parameter's analytic gradient with a central difference.
fn check_case(case: &Case, name: &str, stats: &mut [GroupStats; 5]) {
    let (base, grads) = case.gradients();
    let h = 1e-5;
    let mut pairs: Vec<Vec<(f64, f64)>> = vec![Vec::new(); 5];
    let n_coeffs = sh::num_coeffs(case.degree);
    for (group, &(_, comps)) in GROUPS.iter().enumerate() {
        for i in 0..case.gaussians.len() {
            for c in 0..comps {
                let analytic = param_grad(&grads, group, i, c);
                assert!(analytic.is_finite(), "{name}: non-finite gradient");
                if group == 4 && c / 3 >= n_coeffs {
                    // Coefficients above the active degree are never read.
                    assert_eq!(
                        analytic,
                        0.0,
                        "{name}: SH coefficient {} above degree",
                        c / 3
                    );
                    continue;
                }
                stats[group].total += 1;
                let mut g = case.gaussians.clone();
                let x = *param_mut(&mut g, group, i, c);
                *param_mut(&mut g, group, i, c) = x + h;
                let plus = case.render(&g);
                *param_mut(&mut g, group, i, c) = x - h;
                let minus = case.render(&g);
                if !same_structure(&base, &plus) || !same_structure(&base, &minus) {
                    stats[group].skipped += 1;
                    continue;
                }
                let fd = (case.loss_of(&plus) - case.loss_of(&minus)) / (2.0 * h);
                pairs[group].push((analytic, fd));
            }
        }
    }
    for (group, list) in pairs.iter().enumerate() {
        let scale = list
            .iter()
            .map(|(a, f)| a.abs().max(f.abs()))
            .fold(0.0, f64::max);
        for &(a, f) in list {
            let size = a.abs().max(f.abs());
            // Negligible: tiny next to the group's largest gradient in this scene.
            if size <= 1e-4 * scale || size < 1e-8 {
                continue;
            }
            let rel = (a - f).abs() / size;
            stats[group].checked += 1;
            stats[group].worst = stats[group].worst.max(rel);
            assert!(
                rel < 1e-2,
                "{name}: {} gradient {a} vs finite difference {f} (rel {rel:.2e})",
                GROUPS[group].0
            );
        }
    }
}

fn random_weights(rng: &mut Pcg64, camera: &PinholeCamera) -> Vec<[f64; 3]> {
    (0..camera.width * camera.height)
        .map(|_| [0; 3].map(|_| rng.gen_range(-1.0..1.0)))
        .collect()
}

fn background(rng: &mut Pcg64, seed: u64) -> [f64; 3] {
    match seed % 3 {
        0 => [1.0; 3],
        1 => [0.0; 3],
        _ => [0; 3].map(|_| rng.gen_range(0.0..1.0)),
    }
}

const SIZES: [(u32, u32); 6] = [(37, 29), (21, 35), (45, 17), (33, 33), (17, 50), (9, 7)];

fn report(stats: &[GroupStats; 5], min_checked: usize) {
    for (k, s) in stats.iter().enumerate() {
        eprintln!("{:>14}: {s:?}", GROUPS[k].0);
        assert!(
            s.checked >= min_checked,
            "{}: only {} gradients were not negligible",
            GROUPS[k].0,
            s.checked
        );
        assert!(
            s.skipped * 20 <= s.total,
            "{}: {} of {} skipped",
            GROUPS[k].0,
            s.skipped,
            s.total
        );
    }
}

#[test]
fn smooth_mode_gradients_match_finite_differences() {
    let mut stats = [GroupStats::default(); 5];
    for seed in 0..12u64 {
        let mut rng = Pcg64::seed_from_u64(100 + seed);
        let (w, h) = SIZES[seed as usize % SIZES.len()];
        let (camera, pose) = random_view(&mut rng, w, h);
        let case = Case {
            gaussians: random_gaussians(&mut rng, 6),
            camera,
            pose,
            degree: seed as usize % 4,
            background: background(&mut rng, seed),
            settings: RenderSettings::smooth(),
            weights: random_weights(&mut rng, &camera),
            filter3d: None,
        };
        check_case(
            &case,
            &format!("smooth seed {seed} ({w}×{h}, degree {})", case.degree),
            &mut stats,
        );
    }
    report(&stats, 30);
}

/// Mip-Splatting: the 2D Mip filter's opacity compensation and the 3D filter folded into the
/// parameters, in smooth mode (every gradient) and in normal mode (with the clamps), against
/// finite differences. The filters are a sizeable fraction of the scales, so both the
/// compensation and the fused opacity move with every scale.
#[test]
fn mip_splatting_gradients_match_finite_differences() {
    for smooth in [true, false] {
        let mut stats = [GroupStats::default(); 5];
        let mut floored = 0;
        for seed in 0..8u64 {
            let mut rng = Pcg64::seed_from_u64(300 + seed);
            let (w, h) = SIZES[seed as usize % SIZES.len()];
            let (camera, pose) = random_view(&mut rng, w, h);
            let gaussians = random_gaussians(&mut rng, 6);
            let filter3d: Vec<f64> = gaussians
                .log_scales
                .iter()
                .map(|l| l.iter().copied().fold(f64::MIN, f64::max).exp() * rng.gen_range(0.1..1.0))
                .collect();
            let settings = RenderSettings {
                smooth,
                ..RenderSettings::mip_splatting()
            };
            let case = Case {
                gaussians,
                camera,
                pose,
                degree: seed as usize % 4,
                background: background(&mut rng, seed),
                settings,
                weights: random_weights(&mut rng, &camera),
                filter3d: Some(filter3d),
            };
            let out = case.render(&case.gaussians);
            assert!(out
                .projected
                .iter()
                .filter(|p| !p.culled)
                .all(|p| p.compensation > 0.0 && p.compensation < 1.0));
            floored += out
                .projected
                .iter()
                .filter(|p| p.compensation_floored)
                .count();
            check_case(
                &case,
                &format!("mip smooth={smooth} seed {seed} ({w}×{h})"),
                &mut stats,
            );
        }
        eprintln!("mip smooth={smooth}: {floored} floored compensations");
        report(&stats, 20);
    }
}

#[test]
fn normal_mode_gradients_match_finite_differences_with_clamps_and_stops() {
    let mut stats = [GroupStats::default(); 5];
    let mut stops = 0;
    let mut clamps = 0;
    for seed in 0..8u64 {
        let mut rng = Pcg64::seed_from_u64(200 + seed);
        let (w, h) = SIZES[(seed as usize + 3) % SIZES.len()];
        let (camera, pose) = random_view(&mut rng, w, h);
        let mut gaussians = random_gaussians(&mut rng, 8);
        // Dense and opaque: pulled towards the centre, larger, opacities up to 0.99995.
        for i in 0..gaussians.len() {
            gaussians.positions[i] = gaussians.positions[i].map(|v| v * 0.35);
            gaussians.log_scales[i] = gaussians.log_scales[i].map(|v| v + 1.0);
            gaussians.opacity_logits[i] = rng.gen_range(3.0..10.0);
        }
        let case = Case {
            gaussians,
            camera,
            pose,
            degree: (seed as usize + 1) % 4,
            background: background(&mut rng, seed),
            settings: RenderSettings::default(),
            weights: random_weights(&mut rng, &camera),
            filter3d: None,
        };
        // Count the pixels where the transmittance stop or the alpha clamp actually happened.
        let out = case.render(&case.gaussians);
        for j in 0..h {
            for i in 0..w {
                let pix = (j * w + i) as usize;
                let list = &out.bins.lists[out.bins.tile_of_pixel(i, j)];
                let last = out.raster.last_contributor[pix] as usize;
                let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
                let sample =
                    |g: u32| sample_splat(&out.projected[g as usize], px, py, &case.settings);
                if list[last..].iter().any(|&g| sample(g).is_some()) {
                    stops += 1;
                }
                if list[..last]
                    .iter()
                    .any(|&g| sample(g).is_some_and(|s| s.alpha_clamped))
                {
                    clamps += 1;
                }
            }
        }
        check_case(
            &case,
            &format!("normal seed {seed} ({w}×{h}, degree {})", case.degree),
            &mut stats,
        );
    }
    eprintln!("pixels with a transmittance stop: {stops}, with a clamped alpha: {clamps}");
    assert!(
        stops >= 20 && clamps >= 20,
        "the scenes did not exercise the stop ({stops}) or clamp ({clamps})"
    );
    report(&stats, 30);
}

#[test]
fn rasterizer_gradients_and_ndc_statistic_match_finite_differences() {
    let mut checked = 0;
    for seed in 0..6u64 {
        let mut rng = Pcg64::seed_from_u64(300 + seed);
        let (w, h) = SIZES[seed as usize % SIZES.len()];
        let (camera, pose) = random_view(&mut rng, w, h);
        let case = Case {
            gaussians: random_gaussians(&mut rng, 6),
            camera,
            pose,
            degree: 3,
            background: background(&mut rng, seed),
            settings: RenderSettings::smooth(),
            weights: random_weights(&mut rng, &camera),
            filter3d: None,
        };
        let (base, grads) = case.gradients();
        // Perturb the preprocess outputs directly and re-blend with the same tile lists.
        let loss = |projected: &[reference::Projected]| {
            let r = rasterize(
                projected,
                &base.bins,
                &camera,
                case.background,
                &case.settings,
            )
            .unwrap();
            dot_image(&r.image, &case.weights)
        };
        let step = 1e-6;
        for i in 0..case.gaussians.len() {
            let fd = |set: &dyn Fn(&mut reference::Projected, f64)| {
                let (mut p, mut m) = (base.projected.clone(), base.projected.clone());
                set(&mut p[i], step);
                set(&mut m[i], -step);
                (loss(&p) - loss(&m)) / (2.0 * step)
            };
            let g = &grads.projected;
            let fd_u = fd(&|p, d| p.mean2d[0] += d);
            let fd_v = fd(&|p, d| p.mean2d[1] += d);
            let pairs = [
                (g.mean2d[i][0], fd_u),
                (g.mean2d[i][1], fd_v),
                (g.conic[i][0], fd(&|p, d| p.conic[0] += d)),
                (g.conic[i][1], fd(&|p, d| p.conic[1] += d)),
                (g.conic[i][2], fd(&|p, d| p.conic[2] += d)),
                (g.rgb[i][0], fd(&|p, d| p.rgb[0] += d)),
                (g.rgb[i][1], fd(&|p, d| p.rgb[1] += d)),
                (g.rgb[i][2], fd(&|p, d| p.rgb[2] += d)),
                (g.opacity[i], fd(&|p, d| p.opacity += d)),
                // Density control's statistic from the finite-difference mean2d gradient.
                (
                    grads.ndc_mean2d_norm[i],
                    (fd_u * w as f64 / 2.0).hypot(fd_v * h as f64 / 2.0),
                ),
            ];
            for (k, (a, f)) in pairs.into_iter().enumerate() {
                let size = a.abs().max(f.abs());
                if size < 1e-7 {
                    continue;
                }
                checked += 1;
                assert!(
                    (a - f).abs() < 1e-3 * size,
                    "seed {seed} Gaussian {i} quantity {k}: {a} vs {f}"
                );
            }
        }
    }
    assert!(checked > 200, "only {checked} non-negligible comparisons");
}

#[test]
fn a_colour_clamped_at_zero_passes_no_gradient() {
    let camera = PinholeCamera {
        fx: 30.0,
        fy: 30.0,
        cx: 9.0,
        cy: 8.0,
        width: 19,
        height: 17,
    };
    let mut sh = [[0.0; 3]; 16];
    sh[0] = [-3.0, 0.8, 0.1]; // red: 0.28·(−3) + 0.5 < 0
    sh[1] = [0.1, 0.2, -0.1];
    let gaussians = RefGaussians {
        positions: vec![[0.05, -0.02, 2.0]],
        log_scales: vec![[0.1f64.ln(); 3]],
        rotations: vec![[1.0, 0.0, 0.0, 0.0]],
        opacity_logits: vec![0.5],
        sh: vec![sh],
    };
    let mut rng = Pcg64::seed_from_u64(7);
    let case = Case {
        gaussians,
        camera,
        pose: Pose::IDENTITY,
        degree: 1,
        background: [0.5; 3],
        settings: RenderSettings::smooth(),
        weights: random_weights(&mut rng, &camera),
        filter3d: None,
    };
    let (out, grads) = case.gradients();
    assert_eq!(out.projected[0].rgb_clamped, [true, false, false]);
    assert_eq!(out.projected[0].rgb[0], 0.0);
    let g = &grads.params.sh[0];
    assert!(g[0][0] == 0.0 && g[1][0] == 0.0);
    assert!(g[0][1] != 0.0 && g[0][2] != 0.0 && g[1][1] != 0.0);
    let mut stats = [GroupStats::default(); 5];
    check_case(&case, "clamped colour", &mut stats);
}

fn all_finite(g: &Gradients) -> bool {
    let p = &g.params;
    p.positions.iter().flatten().all(|v| v.is_finite())
        && p.log_scales.iter().flatten().all(|v| v.is_finite())
        && p.rotations.iter().flatten().all(|v| v.is_finite())
        && p.opacity_logits.iter().all(|v| v.is_finite())
        && p.sh.iter().flatten().flatten().all(|v| v.is_finite())
        && g.ndc_mean2d_norm.iter().all(|v| v.is_finite())
}

#[test]
fn gradients_stay_finite_at_the_extremes() {
    let camera = PinholeCamera {
        fx: 25.0,
        fy: 25.0,
        cx: 12.0,
        cy: 10.0,
        width: 24,
        height: 21,
    };
    let settings = RenderSettings::default();
    let mut rng = Pcg64::seed_from_u64(9);
    let mut g = RefGaussians::default();
    let mut push = |p: [f64; 3], s: [f64; 3], q: [f64; 4], l: f64| {
        let mut sh = [[0.0; 3]; 16];
        for c in sh.iter_mut() {
            *c = [0; 3].map(|_| rng.gen_range(-0.5..0.5));
        }
        g.positions.push(p);
        g.log_scales.push(s.map(f64::ln));
        g.rotations.push(q);
        g.opacity_logits.push(l);
        g.sh.push(sh);
    };
    push([0.0, 0.0, 2.0], [1e-8; 3], [1.0, 0.0, 0.0, 0.0], 0.0);
    push(
        [0.1, 0.0, 3.0],
        [1e4, 1e-8, 1e4],
        [0.3, 0.1, 0.9, -0.2],
        0.0,
    );
    push([0.0, 0.1, 2.5], [0.1; 3], [0.0; 4], 50.0);
    push([0.0, -0.1, 2.5], [0.1; 3], [1e-310, 0.0, 0.0, 0.0], -50.0);
    push(
        [0.0, 0.0, settings.near * (1.0 + 1e-9)],
        [0.05; 3],
        [0.7, 0.1, 0.0, 0.3],
        1.0,
    );
    push(
        [0.0, 0.0, settings.near],
        [0.05; 3],
        [0.7, 0.1, 0.0, 0.3],
        1.0,
    );
    push([-3.0, 2.0, -1.0], [0.2; 3], [0.7, 0.1, 0.0, 0.3], 1.0);
    push([1e6, -1e6, 1e6], [1.0; 3], [0.7, 0.1, 0.0, 0.3], 1.0);
    for k in 0..2000 {
        push(
            [0.02, -0.01, 1.0 + k as f64 * 1e-4],
            [0.03, 0.02, 0.04],
            [0.9, 0.1, -0.3, 0.2],
            0.5,
        );
    }
    for degree in [0, 3] {
        let out =
            reference::render(&g, &camera, &Pose::IDENTITY, degree, [1.0; 3], &settings).unwrap();
        let weights = random_weights(&mut rng, &camera);
        let grads = backward(
            &g,
            &camera,
            &Pose::IDENTITY,
            degree,
            [1.0; 3],
            &settings,
            &out,
            &weights,
        )
        .unwrap();
        assert!(all_finite(&grads));
        // The degenerate quaternions get no gradient.
        assert_eq!(grads.params.rotations[2], [0.0; 4]);
        assert_eq!(grads.params.rotations[3], [0.0; 4]);
        // Culled Gaussians (on the near plane, behind the camera) get none at all.
        assert!(out.projected[5].culled && out.projected[6].culled);
        assert_eq!(grads.params.positions[5], [0.0; 3]);
        assert_eq!(grads.params.positions[6], [0.0; 3]);
    }
}

#[test]
fn mismatched_image_gradient_is_an_error() {
    let mut rng = Pcg64::seed_from_u64(3);
    let (camera, pose) = random_view(&mut rng, 10, 12);
    let g = random_gaussians(&mut rng, 3);
    let s = RenderSettings::default();
    let out = reference::render(&g, &camera, &pose, 2, [0.0; 3], &s).unwrap();
    let weights = vec![[1.0; 3]; 119];
    assert!(backward(&g, &camera, &pose, 2, [0.0; 3], &s, &out, &weights).is_err());
}
