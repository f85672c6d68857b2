//! GPU Adam against the op-by-op host reference over 100 steps of random gradients, with the
//! Inria learning-rate schedule, validation on.

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::splats::gpu::{logical_group, GpuSplats};
use lpmsplat::splats::sh_planes;
use lpmsplat::splats::GaussianParams;
use lpmsplat::train::adam::{adam_host_step, Adam, SplatState};
use lpmsplat::train::schedule::LearningRates;
use rand::{Rng, SeedableRng};
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// Random values for every field (magnitudes spread over decades, some exact zeros).
fn random_params(rng: &mut impl Rng, n: usize, degree: u32, scale: f32) -> GaussianParams {
    let mut p = GaussianParams::empty(degree);
    let v = |rng: &mut dyn rand::RngCore| -> f32 {
        if rng.gen_bool(0.05) {
            0.0
        } else {
            scale * rng.gen_range(-1.0f32..1.0) * 10f32.powi(rng.gen_range(-4..1))
        }
    };
    for _ in 0..n {
        p.positions.push([(); 3].map(|_| v(rng)));
        p.log_scales.push([(); 3].map(|_| v(rng)));
        p.rotations.push([(); 4].map(|_| v(rng)));
        p.opacity_logits.push(v(rng));
        p.sh_dc.push([(); 3].map(|_| v(rng)));
    }
    let rest = p.rest_stride();
    p.sh_rest = (0..n * rest).map(|_| v(rng)).collect();
    p
}

/// Stored buffers per Gaussian group.
const GROUPS: usize = 5 + sh_planes::PLANES;

/// Flat f32 arrays per stored buffer, in `GpuSplats::groups()` order (SH rest as its planes).
fn flat(p: &GaussianParams) -> [Vec<f32>; GROUPS] {
    let planes = sh_planes::split(&p.sh_rest, p.len(), p.rest_coeffs());
    let groups: Vec<Vec<f32>> = [
        bytemuck::cast_slice(&p.positions).to_vec(),
        bytemuck::cast_slice(&p.log_scales).to_vec(),
        bytemuck::cast_slice(&p.rotations).to_vec(),
        p.opacity_logits.clone(),
        bytemuck::cast_slice(&p.sh_dc).to_vec(),
    ]
    .into_iter()
    .chain(planes)
    .collect();
    groups.try_into().expect("GROUPS buffers")
}

fn ulps(a: f32, b: f32) -> u32 {
    let key = |x: f32| {
        let i = x.to_bits() as i32;
        if i < 0 {
            i32::MIN.wrapping_sub(i)
        } else {
            i
        }
    };
    key(a).wrapping_sub(key(b)).unsigned_abs()
}

#[test]
fn hundred_steps_match_the_host_reference() {
    let ctx = ctx();
    let exact = ctx.info.driver.to_lowercase().contains("llvmpipe")
        || ctx.info.name.to_lowercase().contains("llvmpipe");
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2024);
    // An odd count: every group but one has a float count that is not a multiple of 4, so the
    // shader's scalar tail after its vec4 body is covered.
    let (n, degree, steps) = (1_501usize, 3u32, 100u32);
    let capacity = n + 77;
    let params = random_params(&mut rng, n, degree, 1.0);
    let state = SplatState::new(&ctx, GpuSplats::upload(&ctx, &params, capacity).unwrap()).unwrap();
    // Poison the tails past `count`: Adam must not touch them.
    const TAIL: u32 = 0x7FC0_0000;
    let mut rec = Recorder::new(&ctx).unwrap();
    for set in [&state.params, &state.m, &state.v] {
        for (buf, stride) in set.groups() {
            if stride > 0 {
                let tail = vec![f32::from_bits(TAIL); (capacity - n) * stride];
                let mut whole = buf.read_range(0, n * stride).unwrap();
                whole.extend(tail);
                buf.upload(&whole).unwrap();
            }
        }
    }
    // All gradients in one buffer per group, copied into the gradient set step by step, so the
    // 100 steps are one submission. A third of the rows are zero each step (unseen Gaussians).
    let grads = GpuSplats::zeroed(&ctx, "grad ", degree, n, capacity).unwrap();
    let mut all: [Vec<f32>; GROUPS] = Default::default();
    for _ in 0..steps {
        let mut g = random_params(&mut rng, n, degree, 0.3);
        for i in 0..n {
            if rng.gen_bool(0.33) {
                g.positions[i] = [0.0; 3];
                g.log_scales[i] = [0.0; 3];
                g.rotations[i] = [0.0; 4];
                g.opacity_logits[i] = 0.0;
                g.sh_dc[i] = [0.0; 3];
                let r = g.rest_stride();
                g.sh_rest[i * r..(i + 1) * r].fill(0.0);
            }
        }
        for (k, f) in flat(&g).into_iter().enumerate() {
            all[k].extend(f);
        }
    }
    let all_gpu: Vec<GpuBuffer<f32>> = all
        .iter()
        .map(|v| GpuBuffer::from_slice(&ctx, "all grads", v).unwrap())
        .collect();
    let adam = Adam::new(&ctx).unwrap();
    let lrs = LearningRates::default();
    let extent = 4.2;
    rec.begin().unwrap();
    for t in 1..=steps {
        for (k, (buf, stride)) in grads.groups().into_iter().enumerate() {
            let len = n * stride;
            rec.copy_region(&all_gpu[k], (t as usize - 1) * len, buf, 0, len);
        }
        adam.record_state(&ctx, &mut rec, &state, &grads, t, &lrs.at(t, extent), None)
            .unwrap();
    }
    rec.submit_and_wait().unwrap();

    // Host: the same steps.
    let mut hp = flat(&params);
    let mut hm: [Vec<f32>; GROUPS] = std::array::from_fn(|k| vec![0.0; hp[k].len()]);
    let mut hv = hm.clone();
    // The magnitude each value was computed from, for devices that may fuse multiply-adds
    // (SPIR-V allows contraction) and round / and sqrt within a few ulp: a moment that cancels
    // to near zero, or a parameter that crosses zero, carries rounding errors of the size of
    // its operands, not of itself. m and v: the largest |g| (resp. g²) seen, which bounds every
    // intermediate; parameters: the larger end value plus the learning rates summed (Adam's
    // step |m̂ / (√v̂ + ε)| is of order 1).
    let mut scale_p: [Vec<f32>; GROUPS] =
        std::array::from_fn(|k| hp[k].iter().map(|x| x.abs()).collect());
    let mut scale_m: [Vec<f32>; GROUPS] = std::array::from_fn(|k| vec![0.0; hp[k].len()]);
    let mut scale_v = scale_m.clone();
    for t in 1..=steps {
        let lr = lrs.at(t, extent).0;
        for k in 0..GROUPS {
            let len = hp[k].len();
            let lr_k = lr[logical_group(k)];
            let g = &all[k][(t as usize - 1) * len..t as usize * len];
            adam_host_step(&adam.hyper, &mut hp[k], g, &mut hm[k], &mut hv[k], lr_k, t);
            for i in 0..len {
                scale_p[k][i] += lr_k as f32;
                scale_m[k][i] = scale_m[k][i].max(g[i].abs());
                scale_v[k][i] = scale_v[k][i].max(g[i] * g[i]);
            }
        }
    }
    for k in 0..GROUPS {
        for (s, p) in scale_p[k].iter_mut().zip(&hp[k]) {
            *s = s.max(p.abs());
        }
    }
    let mut worst = 0u32;
    let mut worst_scaled = 0f32;
    for (set, host, scale) in [
        (&state.params, &hp, &scale_p),
        (&state.m, &hm, &scale_m),
        (&state.v, &hv, &scale_v),
    ] {
        for (k, (buf, stride)) in set.groups().into_iter().enumerate() {
            let got = buf.read().unwrap();
            let len = n * stride;
            for i in 0..len {
                assert!(got[i].is_finite(), "group {k} element {i} not finite");
                worst = worst.max(ulps(got[i], host[k][i]));
                if scale[k][i] > 0.0 {
                    worst_scaled = worst_scaled.max((got[i] - host[k][i]).abs() / scale[k][i]);
                } else {
                    assert_eq!(
                        got[i], host[k][i],
                        "group {k} element {i}: nothing moved it"
                    );
                }
            }
            assert!(
                got[len..capacity * stride]
                    .iter()
                    .all(|v| v.to_bits() == TAIL),
                "group {k}: Adam wrote past count"
            );
        }
    }
    eprintln!(
        "Adam GPU vs host after {steps} steps: max {worst} ulp, max {worst_scaled:e} of the \
         operands' magnitude ({})",
        ctx.info.name
    );
    if exact {
        assert_eq!(
            worst, 0,
            "lavapipe rounds / and sqrt correctly: expected bit-exact"
        );
    } else {
        // Measured on an H100 (NVIDIA 580): 32896 ulp at worst, on values near zero; 2e-5 of the
        // operands' magnitude is about 170 ulp of it over 100 steps.
        assert!(
            worst_scaled <= 2e-5,
            "max {worst_scaled:e} of the operands' magnitude ({worst} ulp)"
        );
    }
    // The parameters moved, including rows that had zero gradient at the last step.
    let moved = hp[0]
        .iter()
        .zip(flat(&params)[0].iter())
        .filter(|(a, b)| a != b)
        .count();
    assert!(moved > hp[0].len() * 9 / 10, "{moved}");
    ctx.check_validation().unwrap();
}

#[test]
fn bad_calls_are_refused() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let p = random_params(&mut rng, 10, 1, 1.0);
    let state = SplatState::new(&ctx, GpuSplats::upload(&ctx, &p, 10).unwrap()).unwrap();
    let grads = GpuSplats::zeroed(&ctx, "g ", 1, 10, 10).unwrap();
    let small = GpuSplats::zeroed(&ctx, "g ", 1, 5, 5).unwrap();
    let other_degree = GpuSplats::zeroed(&ctx, "g ", 2, 10, 10).unwrap();
    let adam = Adam::new(&ctx).unwrap();
    let lrs = LearningRates::default().at(1, 1.0);
    let mut rec = Recorder::new(&ctx).unwrap();
    let (pa, m, v) = (&state.params, &state.m, &state.v);
    assert!(adam
        .record(&ctx, &mut rec, pa, &grads, m, v, 10, 0, &lrs, None)
        .is_err());
    assert!(adam
        .record(&ctx, &mut rec, pa, &small, m, v, 10, 1, &lrs, None)
        .is_err());
    assert!(adam
        .record(&ctx, &mut rec, pa, &other_degree, m, v, 10, 1, &lrs, None)
        .is_err());
    assert!(adam
        .record(&ctx, &mut rec, pa, &grads, m, v, 11, 1, &lrs, None)
        .is_err());
    let mut nan = lrs.clone();
    nan.0[3] = f64::NAN;
    assert!(adam
        .record(&ctx, &mut rec, pa, &grads, m, v, 10, 1, &nan, None)
        .is_err());
    adam.record(&ctx, &mut rec, pa, &grads, m, v, 10, 1, &lrs, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    ctx.check_validation().unwrap();
}

/// A model's extra groups are optimised like the built-in ones, with their own learning rates
/// appended in order; a learning-rate list of the wrong length is refused.
#[test]
fn extra_groups_get_their_own_learning_rates() {
    use lpmsplat::splats::{ExtraGroup, ExtraValues};
    let ctx = ctx();
    let exact = ctx.info.driver.to_lowercase().contains("llvmpipe")
        || ctx.info.name.to_lowercase().contains("llvmpipe");
    let mut rng = rand_pcg::Pcg64::seed_from_u64(99);
    let n = 301usize;
    let mut params = random_params(&mut rng, n, 1, 1.0);
    let mut grads_host = random_params(&mut rng, n, 1, 0.3);
    for (name, stride) in [("motion", 9usize), ("t_center", 1)] {
        let group = ExtraGroup::new(name, stride);
        params.extra.push(ExtraValues {
            group: group.clone(),
            values: (0..n * stride).map(|_| rng.gen_range(-1.0..1.0)).collect(),
        });
        grads_host.extra.push(ExtraValues {
            group,
            values: (0..n * stride).map(|_| rng.gen_range(-0.1..0.1)).collect(),
        });
    }
    let state = SplatState::new(&ctx, GpuSplats::upload(&ctx, &params, n).unwrap()).unwrap();
    let grads = GpuSplats::upload(&ctx, &grads_host, n).unwrap();
    let adam = Adam::new(&ctx).unwrap();
    let mut lrs = LearningRates::default().at(1, 1.0);
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = adam
        .record_state(&ctx, &mut rec, &state, &grads, 1, &lrs, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("6 learning rates for 8 parameter groups"), "{e}");
    lrs.0.extend([0.02, 0.3]);
    let mut rec = Recorder::new(&ctx).unwrap();
    adam.record_state(&ctx, &mut rec, &state, &grads, 1, &lrs, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    let got = state.params.download().unwrap();
    for (k, lr) in [(0usize, 0.02), (1, 0.3)] {
        let mut p = params.extra[k].values.clone();
        let g = &grads_host.extra[k].values;
        let (mut m, mut v) = (vec![0.0; p.len()], vec![0.0; p.len()]);
        adam_host_step(&Default::default(), &mut p, g, &mut m, &mut v, lr, 1);
        for (i, (a, b)) in got.extra[k].values.iter().zip(&p).enumerate() {
            let ok = if exact {
                a.to_bits() == b.to_bits()
            } else {
                (a - b).abs() <= 1e-6
            };
            assert!(ok, "extra group {k} value {i}: GPU {a} vs host {b}");
        }
        assert!(
            got.extra[k].values != params.extra[k].values,
            "group {k} moved"
        );
    }
    ctx.check_validation().unwrap();
}

/// SH rest planes wholly above the active coefficients are not updated (their parameters and
/// moments stay bit for bit, even under non-zero gradients, which the trainer never gives
/// them); the other groups, a partly used plane included, take the host reference's step.
#[test]
fn planes_above_the_active_degree_are_skipped() {
    let ctx = ctx();
    let exact = ctx.info.driver.to_lowercase().contains("llvmpipe")
        || ctx.info.name.to_lowercase().contains("llvmpipe");
    let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
    let n = 203usize;
    let params = random_params(&mut rng, n, 3, 1.0);
    let grads_host = random_params(&mut rng, n, 3, 0.3);
    let adam = Adam::new(&ctx).unwrap();
    let lrs = LearningRates::default().at(1, 1.0);
    // Degrees 0..3 use 0, 3, 8 and 15 rest coefficients: planes 0..5 hold 3 each.
    for (active, used_planes) in [(0usize, 0usize), (3, 1), (8, 3), (15, 5)] {
        let state = SplatState::new(&ctx, GpuSplats::upload(&ctx, &params, n).unwrap()).unwrap();
        let grads = GpuSplats::upload(&ctx, &grads_host, n).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        adam.record_state(&ctx, &mut rec, &state, &grads, 1, &lrs, Some(active))
            .unwrap();
        rec.submit_and_wait().unwrap();
        let (before, g) = (flat(&params), flat(&grads_host));
        for (k, (buf, _)) in state.params.groups().into_iter().enumerate() {
            let got = buf.read_range(0, before[k].len()).unwrap();
            let m = state.m.groups()[k]
                .0
                .read_range(0, before[k].len())
                .unwrap();
            let plane = k.checked_sub(5);
            if plane.is_some_and(|p| p >= used_planes) {
                assert_eq!(
                    got.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    before[k].iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    "active {active}: plane {plane:?} was updated"
                );
                assert!(m.iter().all(|&x| x.to_bits() == 0), "plane {plane:?}: m");
            } else {
                let mut p = before[k].clone();
                let (mut hm, mut hv) = (vec![0.0; p.len()], vec![0.0; p.len()]);
                let lr = lrs.0[logical_group(k)];
                adam_host_step(&adam.hyper, &mut p, &g[k], &mut hm, &mut hv, lr, 1);
                for (i, (a, b)) in got.iter().zip(&p).enumerate() {
                    let ok = if exact {
                        a.to_bits() == b.to_bits()
                    } else {
                        (a - b).abs() <= 1e-6 * (1.0 + b.abs())
                    };
                    assert!(ok, "active {active}, group {k}, value {i}: {a} vs {b}");
                }
            }
        }
    }
    ctx.check_validation().unwrap();
}
