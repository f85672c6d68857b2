//! MCMC's pieces against their f64 oracle (`lpmsplat::reference::mcmc`): the relocation's
//! opacity and scale formula against a quadrature of the stacked profile it stands for, a
//! relocation and a growth plan applied by the kernels against the plan applied on the host
//! (destination rows poisoned with NaN first), the position noise and the regularisers'
//! gradients (these against finite differences too), with the validation layer on.

use lpmsplat::gpu::{GpuContext, GpuOptions, Recorder};
use lpmsplat::mcmc::gpu::McmcKernels;
use lpmsplat::mcmc::plan::{
    plan_growth, plan_relocation, plan_rng, relocation, sigmoid, MAX_RATIO,
};
use lpmsplat::reference::mcmc as oracle;
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::GaussianParams;
use lpmsplat::train::adam::SplatState;
use lpmsplat::train::density::rng::rng_normal;
use rand::{Rng, SeedableRng};
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn normal(rng: &mut impl Rng) -> f32 {
    let u1: f64 = rng.gen_range(1e-12..1.0);
    let u2: f64 = rng.gen();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// Random Gaussians; a quarter of them dead (opacity below 0.005).
fn random_params(rng: &mut impl Rng, n: usize, degree: u32) -> GaussianParams {
    let mut p = GaussianParams::empty(degree);
    for i in 0..n {
        p.positions.push([(); 3].map(|_| rng.gen_range(-1.0..1.0)));
        p.log_scales
            .push([(); 3].map(|_| rng.gen_range(-6.0..-1.0)));
        p.rotations.push([(); 4].map(|_| normal(rng)));
        p.opacity_logits.push(if i % 4 == 0 {
            rng.gen_range(-12.0..-5.4)
        } else {
            rng.gen_range(-5.0..6.0)
        });
        p.sh_dc.push([(); 3].map(|_| normal(rng)));
    }
    p.sh_rest = (0..n * p.rest_stride()).map(|_| normal(rng)).collect();
    p
}

fn poison_rows(p: &mut GaussianParams, from: usize) {
    let nan = f32::NAN;
    let r = p.rest_stride();
    for i in from..p.len() {
        p.positions[i] = [nan; 3];
        p.log_scales[i] = [nan; 3];
        p.rotations[i] = [nan; 4];
        p.opacity_logits[i] = nan;
        p.sh_dc[i] = [nan; 3];
        for k in 0..r {
            p.sh_rest[i * r + k] = nan;
        }
    }
}

/// `p` on the GPU: its first `n` rows uploaded (the uploader refuses NaN), the rest written
/// as they are (poisoned), the count all of them.
fn upload_poisoned(ctx: &Arc<GpuContext>, p: &GaussianParams, n: usize) -> GpuSplats {
    let total = p.len();
    let mut head = p.clone();
    head.positions.truncate(n);
    head.log_scales.truncate(n);
    head.rotations.truncate(n);
    head.opacity_logits.truncate(n);
    head.sh_dc.truncate(n);
    head.sh_rest.truncate(n * p.rest_stride());
    let mut g = GpuSplats::upload(ctx, &head, total).unwrap();
    let tail = |w: usize| vec![f32::NAN; (total - n) * w];
    for (buf, w) in g.groups() {
        if w > 0 {
            buf.upload_at(n * w, &tail(w)).unwrap();
        }
    }
    g.count = total;
    g
}

fn bits(p: &GaussianParams) -> Vec<u32> {
    let mut v = Vec::new();
    for i in 0..p.len() {
        v.extend(p.positions[i].map(f32::to_bits));
        v.extend(p.log_scales[i].map(f32::to_bits));
        v.extend(p.rotations[i].map(f32::to_bits));
        v.push(p.opacity_logits[i].to_bits());
        v.extend(p.sh_dc[i].map(f32::to_bits));
    }
    v.extend(p.sh_rest.iter().map(|x| x.to_bits()));
    v
}

#[test]
fn the_relocation_formula_matches_the_quadrature_of_the_stacked_profile() {
    for &o in &[0.0051, 0.01, 0.05, 0.2, 0.5, 0.8, 0.95, 0.99, 0.9999] {
        for n in (1..=MAX_RATIO).step_by(5).chain([2, 3, MAX_RATIO]) {
            let (o_new, c) = relocation(o, n, 0.005);
            let want = oracle::scale_factor_by_quadrature(o, o_new, n);
            assert!(
                ((c - want) / want).abs() < 1e-7,
                "o {o}, n {n}: factor {c}, quadrature {want}"
            );
            // Unclamped, n copies let through what the one did.
            let t = 1.0 - (1.0 - o).powi(0) * (1.0 - o_new).powi(n as i32);
            if o_new > 0.005 {
                assert!((t - o).abs() < 1e-12, "o {o}, n {n}: stack {t}");
            }
        }
    }
}

/// A relocation then a growth plan, as a refinement runs them, on the kernels and on the host;
/// moments of every moved row and its source are zero afterwards, every other row untouched.
#[test]
fn relocation_and_growth_on_the_gpu_are_the_plans_applied_on_the_host() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
    let kernels = McmcKernels::new(&ctx).unwrap();
    for (degree, axes) in [(1u32, 3u32), (3, 2)] {
        let (n, m) = (2_000usize, 300usize);
        let mut params = random_params(&mut rng, n + m, degree);
        poison_rows(&mut params, n);
        let mut mom: Vec<GaussianParams> = (0..2)
            .map(|_| random_params(&mut rng, n + m, degree))
            .collect();
        for p in mom.iter_mut() {
            poison_rows(p, n);
        }
        let state = SplatState {
            params: upload_poisoned(&ctx, &params, n),
            m: upload_poisoned(&ctx, &mom[0], n),
            v: upload_poisoned(&ctx, &mom[1], n),
        };
        let mut logits = params.opacity_logits[..n].to_vec();
        let reloc = plan_relocation(&mut logits, None, 0.005, &mut plan_rng(5, 900, 0));
        let grow = plan_growth(&mut logits, None, m, 0.005, &mut plan_rng(5, 900, 1));
        assert!(reloc.copies.len() > 400 && grow.copies.len() == m);
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        let a = kernels.upload(&reloc).unwrap();
        let b = kernels.upload(&grow).unwrap();
        kernels.record_plan(&mut rec, &state, &a, axes).unwrap();
        kernels.record_plan(&mut rec, &state, &b, axes).unwrap();
        rec.submit_and_wait().unwrap();

        let mut want = params.clone();
        let (m0, m1) = mom.split_at_mut(1);
        for plan in [&reloc, &grow] {
            oracle::apply_plan(
                &mut want,
                &mut [&mut m0[0], &mut m1[0]],
                plan,
                axes as usize,
            );
        }
        let got = state.params.download().unwrap();
        assert_eq!(bits(&got), bits(&want), "degree {degree}: parameters");
        assert_eq!(
            bits(&state.m.download().unwrap()),
            bits(&m0[0]),
            "first moments"
        );
        assert_eq!(
            bits(&state.v.download().unwrap()),
            bits(&m1[0]),
            "second moments"
        );
        assert!(got.opacity_logits.iter().all(|l| l.is_finite()));
        // The opacities the host planned with are the GPU's.
        assert_eq!(&got.opacity_logits[..n], &logits[..]);
        // No Gaussian is dead after a refinement.
        assert!(got
            .opacity_logits
            .iter()
            .all(|&l| sigmoid(l as f64) > 0.005 - 1e-6));
        if axes == 2 {
            // A surfel's third log-scale is no scale: never corrected.
            for &(d, s) in &reloc.copies {
                assert_eq!(
                    got.log_scales[d as usize][2],
                    params.log_scales[s as usize][2]
                );
            }
        }
    }
    ctx.check_validation().unwrap();
}

#[test]
fn the_noise_is_the_covariance_shaped_gated_step_of_the_reference() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(23);
    let kernels = McmcKernels::new(&ctx).unwrap();
    let n = 3_000usize;
    let mut params = random_params(&mut rng, n, 0);
    // Opacities across the gate: most near 0, some opaque.
    for (i, l) in params.opacity_logits.iter_mut().enumerate() {
        *l = if i % 3 == 0 {
            4.0
        } else {
            rng.gen_range(-9.0..-2.0)
        };
    }
    let gpu = GpuSplats::upload(&ctx, &params, n).unwrap();
    let (seed, step, amount, k, t) = (99u32, 1234u32, 80.0f32, 100.0f32, 0.005f32);
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin().unwrap();
    kernels.record_noise(&mut rec, &gpu, n, seed, step, amount, (k, t));
    rec.submit_and_wait().unwrap();
    let got = gpu.download().unwrap();
    let mut moved = 0;
    #[allow(clippy::needless_range_loop)]
    for i in 0..n {
        let eps = [0, 1, 2].map(|a| rng_normal(seed, step, i as u32, a));
        let d = oracle::noise_displacement(&params, i, eps, amount as f64, k as f64, t as f64);
        let size = d.iter().map(|v| v * v).sum::<f64>().sqrt();
        for a in 0..3 {
            let g = got.positions[i][a] as f64 - params.positions[i][a] as f64;
            // f32 positions near 1 round at 6e-8; the GPU's exp/log/cos at a few ULP.
            assert!(
                (g - d[a]).abs() <= 1e-4 * size + 2e-7,
                "Gaussian {i} axis {a}: moved {g}, reference {}",
                d[a]
            );
        }
        if size > 1e-6 {
            moved += 1;
        }
        if i % 3 == 0 {
            assert!(size < 1e-30, "an opaque Gaussian moved by {size}");
        }
    }
    assert!(moved > n / 2, "only {moved} Gaussians moved measurably");
    ctx.check_validation().unwrap();
}

#[test]
fn the_regulariser_gradients_are_the_references_and_its_finite_differences() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(29);
    let kernels = McmcKernels::new(&ctx).unwrap();
    let n = 1_500usize;
    let params = random_params(&mut rng, n, 0);
    let start = random_params(&mut rng, n, 0);
    for (axes, weights) in [(3u32, (0.01, 0.02)), (2, (0.3, 0.0))] {
        let p = GpuSplats::upload(&ctx, &params, n).unwrap();
        let g = GpuSplats::upload(&ctx, &start, n).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        kernels.record_regularise(&mut rec, &p, &g, n, weights, axes);
        rec.submit_and_wait().unwrap();
        let got = g.download().unwrap();
        let (_, gl, gs) = oracle::regulariser(&params, weights.0, weights.1, axes as usize);
        #[allow(clippy::needless_range_loop)]
        for i in 0..n {
            let d = got.opacity_logits[i] as f64 - start.opacity_logits[i] as f64;
            assert!(
                (d - gl[i]).abs()
                    <= 1e-6 * start.opacity_logits[i].abs() as f64 + 1e-9 * gl[i].abs() + 1e-12
            );
            for a in 0..3 {
                let d = got.log_scales[i][a] as f64 - start.log_scales[i][a] as f64;
                let tol = 1e-6 * start.log_scales[i][a].abs() as f64 + 1e-5 * gs[i][a].abs();
                assert!((d - gs[i][a]).abs() <= tol, "{i} {a}: {d} vs {}", gs[i][a]);
                if a as u32 >= axes {
                    assert_eq!(got.log_scales[i][a], start.log_scales[i][a]);
                }
            }
        }
        // The oracle's gradient against central differences of its loss.
        for i in [0usize, 7, 400] {
            let h = 1e-3f32;
            // The perturbations as f32 makes them.
            let (l, ls) = (params.opacity_logits[i], params.log_scales[i][0]);
            let f = |dl: f32, ds: f32| {
                let mut q = params.clone();
                q.opacity_logits[i] = l + dl;
                q.log_scales[i][0] = ls + ds;
                oracle::regulariser(&q, weights.0, weights.1, axes as usize).0
            };
            let span = |x: f32| ((x + h) as f64) - ((x - h) as f64);
            let fd_l = (f(h, 0.0) - f(-h, 0.0)) / span(l);
            let fd_s = (f(0.0, h) - f(0.0, -h)) / span(ls);
            assert!(
                (fd_l - gl[i]).abs() <= 1e-5 * gl[i].abs() + 1e-12,
                "{fd_l} {}",
                gl[i]
            );
            assert!(
                (fd_s - gs[i][0]).abs() <= 1e-5 * gs[i][0].abs() + 1e-12,
                "{fd_s} {}",
                gs[i][0]
            );
        }
    }
    ctx.check_validation().unwrap();
}
