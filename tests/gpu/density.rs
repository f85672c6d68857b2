//! GPU density control against the host reference (`reference::density`): statistics,
//! decisions, compaction of every per-Gaussian buffer, split samples (a 2DGS surfel's in its
//! plane), opacity reset, growth past the capacity, the decision hook. Validation on;
//! destinations poisoned before every step.

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::density::{self as reference, HostState, HostStats};
use lpmsplat::render::layout::ProjectedBoundsGpu;
use lpmsplat::splats::gpu::{grown_capacity, GpuSplats};
use lpmsplat::splats::{ExtraGroup, ExtraValues, GaussianParams};
use lpmsplat::train::adam::SplatState;
use lpmsplat::train::density::abs_quantile::abs_grad_threshold;
use lpmsplat::train::density::budget::{self, BudgetCut};
use lpmsplat::train::density::growth::{BudgetCurve, Growth};
use lpmsplat::train::density::region::{GrowthRegion, RegionBand};
use lpmsplat::train::density::rng::fold_seed;
use lpmsplat::train::density::{
    reset_logit, DensifyArgs, DensifyPhase, DensityConfig, DensityControl, ScoreInput, Statistic,
    Thresholds, DECIDE_CLONE, DECIDE_LOWERED, DECIDE_REMOVE, DECIDE_SPLIT,
};
use rand::{Rng, SeedableRng};
use std::sync::Arc;

const NAN_BITS: u32 = 0x7FC0_0000;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn normal(rng: &mut impl Rng) -> f32 {
    let u1: f64 = rng.gen_range(1e-12..1.0);
    let u2: f64 = rng.gen();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// Random Gaussians whose scales straddle the clone / split / world-size limits of `extent`
/// and whose opacities straddle the prune limit.
fn random_params(rng: &mut impl Rng, n: usize, degree: u32, extent: f32) -> GaussianParams {
    let mut p = GaussianParams::empty(degree);
    for _ in 0..n {
        p.positions.push([(); 3].map(|_| rng.gen_range(-1.0..1.0)));
        let top = (extent * 10f32.powf(rng.gen_range(-3.0..0.0))).ln();
        p.log_scales.push([
            top,
            top - rng.gen_range(0.0..2.0),
            top - rng.gen_range(0.0..2.0),
        ]);
        p.rotations.push([(); 4].map(|_| normal(rng)));
        p.opacity_logits.push(rng.gen_range(-7.0..4.0));
        p.sh_dc.push([(); 3].map(|_| normal(rng)));
    }
    p.sh_rest = (0..n * p.rest_stride())
        .map(|_| normal(rng) * 0.1)
        .collect();
    p
}

/// Moments: any values (v non-negative).
fn random_moments(rng: &mut impl Rng, n: usize, degree: u32, positive: bool) -> GaussianParams {
    let mut p = GaussianParams::empty(degree);
    let mut v = || {
        let x = normal(rng) * 1e-3;
        if positive {
            x.abs()
        } else {
            x
        }
    };
    for _ in 0..n {
        p.positions.push([v(), v(), v()]);
        p.log_scales.push([v(), v(), v()]);
        p.rotations.push([v(), v(), v(), v()]);
        p.opacity_logits.push(v());
        p.sh_dc.push([v(), v(), v()]);
    }
    p.sh_rest = (0..n * p.rest_stride()).map(|_| v()).collect();
    p
}

fn upload_state(ctx: &Arc<GpuContext>, h: &HostState, capacity: usize) -> SplatState {
    // Moments are uploaded through the parameter path (same layout).
    SplatState {
        params: GpuSplats::upload(ctx, &h.params, capacity).unwrap(),
        m: GpuSplats::upload(ctx, &h.m, capacity).unwrap(),
        v: GpuSplats::upload(ctx, &h.v, capacity).unwrap(),
    }
}

fn download_state(s: &SplatState) -> HostState {
    HostState {
        params: s.params.download().unwrap(),
        m: s.m.download().unwrap(),
        v: s.v.download().unwrap(),
    }
}

fn random_stats(rng: &mut impl Rng, n: usize) -> HostStats {
    let denom: Vec<f32> = (0..n).map(|_| rng.gen_range(0..6) as f32).collect();
    HostStats {
        grad_accum: denom
            .iter()
            .map(|&d| d * 10f32.powf(rng.gen_range(-5.0..-2.5)))
            .collect(),
        denom: denom.clone(),
        max_radii: (0..n)
            .map(|_| rng.gen_range(0.0..40.0f32).floor())
            .collect(),
        abs_accum: denom
            .iter()
            .map(|&d| d * 10f32.powf(rng.gen_range(-4.0..-1.5)))
            .collect(),
    }
}

fn upload_stats(dc: &DensityControl, s: &HostStats) {
    dc.stats().grad_accum.upload(&s.grad_accum).unwrap();
    dc.stats().denom.upload(&s.denom).unwrap();
    dc.stats().max_radii.upload(&s.max_radii).unwrap();
    dc.stats().abs_accum.upload(&s.abs_accum).unwrap();
}

/// Adds two extra groups (as a model with its own parameters has) of random values: every
/// path must carry them with their Gaussian.
fn with_extras(mut p: GaussianParams, rng: &mut impl Rng) -> GaussianParams {
    let n = p.len();
    for (name, stride) in [("tag", 2), ("time", 1)] {
        p.extra.push(ExtraValues {
            group: ExtraGroup::new(name, stride),
            values: (0..n * stride).map(|_| normal(rng)).collect(),
        });
    }
    p
}

/// Every buffer of `s` in full (all `capacity` rows), as bits.
fn raw_buffers(s: &SplatState) -> Vec<Vec<u32>> {
    [&s.params, &s.m, &s.v]
        .iter()
        .flat_map(|set| set.groups())
        .filter(|g| g.1 > 0)
        .map(|(b, stride)| bits(&b.read_range(0, s.capacity() * stride).unwrap()))
        .collect()
}

fn bits<T: bytemuck::Pod>(v: &[T]) -> Vec<u32> {
    bytemuck::cast_slice::<T, u32>(v).to_vec()
}

/// Exact comparison except the children's positions (rows ≥ `children_from`), which the GPU
/// computes with its own exp / log / cos.
fn assert_states_match(gpu: &HostState, host: &HostState, children_from: usize, what: &str) {
    assert_eq!(gpu.params.len(), host.params.len(), "{what}: count");
    let (g, h) = (&gpu.params, &host.params);
    for i in 0..h.len() {
        for a in 0..3 {
            let (x, y) = (g.positions[i][a], h.positions[i][a]);
            if i < children_from {
                assert_eq!(x.to_bits(), y.to_bits(), "{what}: position {i}");
            } else {
                assert!(
                    (x - y).abs() <= 2e-5 * (1.0 + y.abs()),
                    "{what}: child {i} position {x} vs {y}"
                );
            }
        }
    }
    assert_eq!(
        bits(&g.log_scales),
        bits(&h.log_scales),
        "{what}: log_scales"
    );
    assert_eq!(bits(&g.rotations), bits(&h.rotations), "{what}: rotations");
    assert_eq!(
        bits(&g.opacity_logits),
        bits(&h.opacity_logits),
        "{what}: opacity"
    );
    assert_eq!(bits(&g.sh_dc), bits(&h.sh_dc), "{what}: sh_dc");
    assert_eq!(bits(&g.sh_rest), bits(&h.sh_rest), "{what}: sh_rest");
    assert_eq!(g.extra.len(), h.extra.len(), "{what}: extra groups");
    for (x, y) in g.extra.iter().zip(&h.extra) {
        assert_eq!(x.group, y.group, "{what}: extra group");
        assert_eq!(
            bits(&x.values),
            bits(&y.values),
            "{what}: extra {}",
            x.group.name
        );
    }
    assert_eq!(gpu.m, host.m, "{what}: first moments");
    assert_eq!(gpu.v, host.v, "{what}: second moments");
}

/// An in-place step writes no row at or past its new count: those rows hold what they held
/// before it (`before`: [`raw_buffers`] of the state before the step).
fn assert_tail_untouched(s: &SplatState, before: &[Vec<u32>], what: &str) {
    let n = s.count();
    let groups: Vec<_> = [&s.params, &s.m, &s.v]
        .iter()
        .flat_map(|set| set.groups())
        .filter(|g| g.1 > 0)
        .map(|(b, stride)| (b.name().to_string(), stride))
        .collect();
    assert_eq!(groups.len(), before.len(), "{what}: group count");
    for ((name, stride), (now, was)) in groups.iter().zip(raw_buffers(s).iter().zip(before)) {
        assert!(
            now[n * stride..] == was[n * stride..],
            "{what}: {name} written past the new count"
        );
    }
}

#[test]
fn constructed_cases_clone_split_and_prune_exactly_the_expected_gaussians() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let extent = 2.0f32;
    let degree = 1;
    let small = (0.005 * extent).ln();
    let mid = (0.05 * extent).ln();
    let huge = (0.5 * extent).ln();
    // (max log-scale, opacity logit, grad_accum, denom)
    let cases: [(f32, f32, f32, f32); 9] = [
        (small, 0.0, 9e-4, 3.0),  // 0: clone
        (mid, 1.0, 9e-4, 3.0),    // 1: split
        (mid, 1.0, 1e-4, 1.0),    // 2: keep (low gradient)
        (small, -6.0, 0.0, 0.0),  // 3: prune (faint)
        (huge, 2.0, 0.0, 2.0),    // 4: prune (world size)
        (small, -6.0, 9e-4, 1.0), // 5: prune, and its clone too
        (mid, 0.5, 5e-3, 0.0),    // 6: keep (never seen: stat 0)
        (small, 0.5, 2e-4, 1.0),  // 7: clone (stat exactly at the threshold)
        (huge, 0.5, 9e-4, 1.0),   // 8: split, children still too large: all removed
    ];
    let n = cases.len();
    let mut params = random_params(&mut rng, n, degree, extent);
    for (i, c) in cases.iter().enumerate() {
        params.log_scales[i] = [c.0 - 0.5, c.0, c.0 - 1.0];
        params.opacity_logits[i] = c.1;
    }
    let host = HostState {
        m: random_moments(&mut rng, n, degree, false),
        v: random_moments(&mut rng, n, degree, true),
        params,
    };
    let stats = HostStats {
        grad_accum: cases.iter().map(|c| c.2).collect(),
        denom: cases.iter().map(|c| c.3).collect(),
        max_radii: vec![100.0; n],
        abs_accum: vec![0.0; n],
    };
    let capacity = 16;
    let mut state = upload_state(&ctx, &host, capacity);
    let cfg = DensityConfig {
        seed: 99,
        ..Default::default()
    };
    let mut dc = DensityControl::new(&ctx, capacity, cfg).unwrap();
    upload_stats(&dc, &stats);
    dc.poison_move_scratch(&state, NAN_BITS).unwrap();
    let before = raw_buffers(&state);
    let args = DensifyArgs {
        extent: extent as f64,
        prune_large: true,
        iteration: 700,
        phase: DensifyPhase::Both,
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    let out = dc.step(&mut rec, &mut state, &args, None).unwrap();
    let d = dc.decisions().read_range(0, n).unwrap();
    assert_eq!(
        d,
        vec![
            DECIDE_CLONE,
            DECIDE_SPLIT,
            0,
            DECIDE_REMOVE,
            DECIDE_REMOVE,
            DECIDE_REMOVE,
            0,
            DECIDE_CLONE,
            DECIDE_REMOVE
        ]
    );
    assert_eq!(
        (
            out.before,
            out.kept,
            out.clones,
            out.split_children,
            out.after
        ),
        (9, 4, 2, 2, 8)
    );
    assert!(!out.grew);
    let gpu = download_state(&state);
    // Survivors 0, 2, 6, 7 in order; clones of 0 and 7; children of 1.
    let p = &host.params;
    for (row, src) in [0usize, 2, 6, 7, 0, 7].into_iter().enumerate() {
        assert_eq!(gpu.params.positions[row], p.positions[src], "row {row}");
        assert_eq!(gpu.params.log_scales[row], p.log_scales[src]);
        assert_eq!(gpu.params.sh_rest_of(row), p.sh_rest_of(src));
        let (m, v) = if row < 4 {
            (host.m.sh_dc[src], host.v.sh_dc[src])
        } else {
            ([0.0; 3], [0.0; 3])
        };
        assert_eq!(gpu.m.sh_dc[row], m, "row {row} moments");
        assert_eq!(gpu.v.sh_dc[row], v, "row {row} moments");
    }
    for row in 6..8 {
        let shrink = 1.6f64.ln() as f32;
        assert_eq!(
            gpu.params.log_scales[row],
            p.log_scales[1].map(|v| v - shrink)
        );
        assert_eq!(gpu.params.rotations[row], p.rotations[1]);
        assert_eq!(gpu.params.opacity_logits[row], p.opacity_logits[1]);
        assert_ne!(gpu.params.positions[row], p.positions[1]);
        assert_eq!(gpu.m.positions[row], [0.0; 3]);
    }
    // And the whole state equals the host reference.
    let t = Thresholds::new(&cfg, &args).unwrap();
    let expect = reference::apply(&host, &d, fold_seed(cfg.seed), 700, t.log_split_shrink);
    assert_states_match(&gpu, &expect, 6, "constructed");
    assert_tail_untouched(&state, &before, "constructed");
    // Statistics are zero after the step.
    for b in [
        &dc.stats().grad_accum,
        &dc.stats().denom,
        &dc.stats().max_radii,
    ] {
        assert!(b.read().unwrap().iter().all(|&v| v == 0.0));
    }
    ctx.check_validation().unwrap();
}

#[test]
fn random_steps_match_the_host_reference_and_grow_past_the_capacity() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(77);
    let (n, degree, extent) = (2_000usize, 2u32, 3.0f32);
    let params = with_extras(random_params(&mut rng, n, degree, extent), &mut rng);
    let m = with_extras(random_moments(&mut rng, n, degree, false), &mut rng);
    let mut v = with_extras(random_moments(&mut rng, n, degree, true), &mut rng);
    for e in &mut v.extra {
        e.values.iter_mut().for_each(|x| *x = x.abs());
    }
    let mut host = HostState { params, m, v };
    let mut state = upload_state(&ctx, &host, n + 50);
    assert_eq!(state.shape().extra.len(), 2);
    let cfg = DensityConfig {
        seed: 0x1234_5678_9abc,
        ..Default::default()
    };
    let mut dc = DensityControl::new(&ctx, n + 50, cfg).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let mut grew = 0;
    for step in 0..7u32 {
        let count = state.count();
        let cap = state.capacity();
        assert_eq!(dc.stats().capacity(), cap);
        let stats = random_stats(&mut rng, count);
        upload_stats(&dc, &stats);
        let mut cfg_step = cfg;
        cfg_step.screen_size_limit = (step == 5).then_some(20.0);
        // Every other step adds the absolute-gradient test (once with the LPM scale).
        cfg_step.abs_grad = step % 2 == 0;
        // Steps 3 and 6 grow only inside a region of two oblique bands (partition's blocks).
        let s = std::f64::consts::FRAC_1_SQRT_2;
        cfg_step.grow_within = (step % 3 == 0 && step > 0).then_some(GrowthRegion {
            bands: [
                RegionBand {
                    axis: [s, s, 0.0],
                    lo: -(extent as f64) / 3.0,
                    hi: f64::INFINITY,
                },
                RegionBand {
                    axis: [0.0, 0.0, 1.0],
                    lo: f64::NEG_INFINITY,
                    hi: extent as f64 / 4.0,
                },
            ],
        });
        dc.config = cfg_step;
        let args = DensifyArgs {
            extent: extent as f64,
            prune_large: step % 2 == 1 && step != 7,
            iteration: 600 + 100 * step,
            phase: DensifyPhase::Both,
        };
        // Some steps lower the threshold for part of the Gaussians (the LPM input).
        let scale: Option<Vec<f32>> = (step % 3 == 2).then(|| {
            (0..count)
                .map(|_| if rng.gen_bool(0.3) { 0.5 } else { 1.0 })
                .collect()
        });
        let scale_buf = scale
            .as_ref()
            .map(|s| GpuBuffer::from_slice(&ctx, "threshold scale", s).unwrap());
        dc.poison_move_scratch(&state, NAN_BITS).unwrap();
        let before = raw_buffers(&state);
        let out = dc
            .step(&mut rec, &mut state, &args, scale_buf.as_ref())
            .unwrap();

        let t = Thresholds::new(&cfg_step, &args).unwrap();
        let q = cfg_step.abs_grad.then(|| {
            abs_grad_threshold(
                &stats.grad_accum,
                &stats.denom,
                &stats.abs_accum,
                t.grad_threshold,
            )
        });
        assert_eq!(dc.last_abs_threshold, q, "step {step}");
        let d = reference::decide_with_abs(&t, &stats, &host.params, scale.as_deref(), q);
        if q.is_some() {
            let without = reference::decide(&t, &stats, &host.params, scale.as_deref());
            let more = |d: &[u32]| d.iter().filter(|&&x| x & 6 != 0).count();
            assert!(
                more(&d) > more(&without),
                "step {step}: the absolute-gradient test densified nothing more"
            );
        }
        assert_eq!(
            dc.decisions().read_range(0, count).unwrap(),
            d,
            "step {step}"
        );
        if let Some(region) = cfg_step.grow_within {
            // The region held something back: without it more would grow, and nothing
            // outside it grew.
            let mut open = t;
            open.region = None;
            let free = reference::decide_with_abs(&open, &stats, &host.params, scale.as_deref(), q);
            let grown = |d: &[u32]| d.iter().filter(|&&x| x & 6 != 0).count();
            assert!(grown(&free) > grown(&d) && grown(&d) > 0, "step {step}");
            for (i, &x) in d.iter().enumerate() {
                let p = host.params.positions[i].map(|v| v as f64);
                assert!(
                    x & 6 == 0 || region.contains(p),
                    "step {step}: {i} grew outside"
                );
            }
        }
        let expect = reference::apply(
            &host,
            &d,
            fold_seed(cfg.seed),
            args.iteration,
            t.log_split_shrink,
        );
        assert_eq!(out.after, expect.params.len(), "step {step}");
        let gpu = download_state(&state);
        assert_states_match(
            &gpu,
            &expect,
            out.kept + out.clones,
            &format!("step {step}"),
        );
        if out.grew {
            grew += 1;
            assert_eq!(state.capacity(), grown_capacity(out.after));
            assert_eq!(dc.stats().capacity(), state.capacity());
        } else {
            assert_eq!(state.capacity(), cap);
            assert_tail_untouched(&state, &before, &format!("step {step}"));
        }
        assert!(out.clones > 0 && out.split_children > 0 && out.kept < count);
        eprintln!("step {step}: {out:?}");
        // Continue from the GPU's state so the children's rounding does not accumulate.
        host = gpu;
    }
    assert!(grew >= 1, "the test must exercise growth");
    ctx.check_validation().unwrap();
}

/// The Gaussian budget (`DensityConfig::max_gaussians`): the GPU's scores are the reference's
/// (within the division's ULP allowance; bit for bit on lavapipe), the decisions after `record_decide` are the reference's with the host's cut
/// applied (the kernel's tie rule included: half the Gaussians share one statistic, where the
/// cut falls), the step ends at the cap, and every dropped addition scores no higher than
/// every kept one; a cap the step does not reach changes nothing. Steps 4–6 take the guided
/// and exact modes: 4 the exact budget (every seen Gaussian a candidate, the count lands on the
/// curve's target, score weights given), 5 the paper's ranking over the lowered threshold, 6
/// score weights on one scale under a cap, 7 the exact budget ranked by a strategy's own
/// scores (`ScoreInput::Replace`).
#[test]
fn a_gaussian_budget_keeps_the_additions_furthest_over_their_threshold() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(91);
    let (n, degree, extent) = (3_000usize, 1u32, 3.0f32);
    for step in 0..8u32 {
        let params = random_params(&mut rng, n, degree, extent);
        let m = random_moments(&mut rng, n, degree, false);
        let v = random_moments(&mut rng, n, degree, true);
        let host = HostState { params, m, v };
        let mut stats = random_stats(&mut rng, n);
        for i in 0..n {
            if rng.gen_bool(0.5) {
                stats.grad_accum[i] = 5e-4;
                stats.denom[i] = 1.0;
            }
        }
        // The exact budget's curve: step 2 of 4 from n to 1.5 n (taming: 0.75 of the room).
        let exact = matches!(step, 4 | 7).then_some(BudgetCurve {
            target: n + n / 2,
            growth: Growth::Taming,
            initial: n,
            window: (0, 500, 100),
        });
        let mut cfg = DensityConfig {
            seed: 7,
            abs_grad: step == 2,
            exact_budget: exact,
            rank_lowered: step == 5,
            ..Default::default()
        };
        let args = DensifyArgs {
            extent: extent as f64,
            prune_large: step % 2 == 1 && step != 7,
            iteration: 200 + step,
            phase: DensifyPhase::Both,
        };
        let scale: Option<Vec<f32>> = matches!(step, 1 | 5 | 6).then(|| {
            (0..n)
                .map(|_| if rng.gen_bool(0.3) { 0.5 } else { 1.0 })
                .collect()
        });
        let weight: Option<Vec<f32>> = matches!(step, 4 | 6).then(|| {
            (0..n)
                .map(|_| if rng.gen_bool(0.3) { 1.5 } else { 1.0 })
                .collect()
        });
        // A strategy's own scores: any non-negative value, ties included.
        let own: Option<Vec<f32>> = (step == 7).then(|| {
            (0..n)
                .map(|_| (rng.gen_range(0..400) as f32) * 0.25)
                .collect()
        });
        let t = Thresholds::new(&cfg, &args).unwrap();
        let q = cfg.abs_grad.then(|| {
            abs_grad_threshold(
                &stats.grad_accum,
                &stats.denom,
                &stats.abs_accum,
                t.grad_threshold,
            )
        });
        let free = reference::decide_with_abs(&t, &stats, &host.params, scale.as_deref(), q);
        let natural = budget::after_count(&free);
        // Step 3: a cap above what the step reaches.
        let cap = match step {
            3 => natural + 10,
            4 | 7 => exact.unwrap().target_at(args.iteration, n),
            _ => n + (natural - n) / 3,
        };
        if exact.is_some() {
            assert_eq!(
                cap,
                n + 3 * (n / 2) / 4,
                "the curve's target at step 2 of 4"
            );
            assert!(natural > cap, "every seen Gaussian is a candidate");
        } else {
            cfg.max_gaussians = Some(cap);
        }
        let label = format!("step {step} (cap {cap}, {natural} without it)");

        let mut state = upload_state(&ctx, &host, n);
        let mut dc = DensityControl::new(&ctx, n, cfg).unwrap();
        upload_stats(&dc, &stats);
        let scale_buf = scale
            .as_ref()
            .map(|s| GpuBuffer::from_slice(&ctx, "threshold scale", s).unwrap());
        let weight_buf = weight
            .as_ref()
            .or(own.as_ref())
            .map(|s| GpuBuffer::from_slice(&ctx, "score weight", s).unwrap());
        let score_in = weight_buf.as_ref().map(|b| match own {
            Some(_) => ScoreInput::Replace(b),
            None => ScoreInput::Weight(b),
        });
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.begin().unwrap();
        dc.record_decide(&mut rec, &state, &args, scale_buf.as_ref(), score_in)
            .unwrap();
        rec.submit_and_wait().unwrap();
        rec.begin().unwrap();

        // Vulkan lets a GPU's float division be off by 2.5 ULP (an H100's is, by one: lavapipe
        // and the host divide exactly), and a score is two divisions: within 6 ULP of the
        // reference, and 0 or +inf exactly where it is. The cut and the decisions follow the
        // GPU's own scores, which the budget pass ranks.
        let score_ref = match (&weight, &own) {
            (Some(w), _) => Some(ScoreInput::Weight(w.as_slice())),
            (_, Some(o)) => Some(ScoreInput::Replace(o.as_slice())),
            _ => None,
        };
        let want_scores = reference::scores(
            &t,
            &stats,
            &host.params.positions,
            scale.as_deref(),
            score_ref,
            q,
        );
        let scores = dc.scores().read_range(0, n).unwrap();
        for (i, (&g, &w)) in scores.iter().zip(&want_scores).enumerate() {
            let ulps = (g.to_bits() as i64 - w.to_bits() as i64).abs();
            assert!(
                g.is_finite() == w.is_finite() && (g == 0.0) == (w == 0.0) && ulps <= 6,
                "{label}: score {i} is {g} on the GPU, {w} by the reference ({ulps} ULP)"
            );
        }
        let cut = budget::budget_cut(&free, &scores, cap);
        assert_eq!(dc.last_budget, cut, "{label}");
        let mut want = free.clone();
        if let Some(c) = &cut {
            budget::apply_cut(&mut want, &scores, c);
        }
        let got = dc.decisions().read_range(0, n).unwrap();
        if let Some(i) = (0..n).find(|&i| got[i] != want[i]) {
            panic!(
                "{label}: decision {i} is {} on the GPU, {} by the reference (score {}, cut {cut:?})",
                got[i], want[i], scores[i]
            );
        }
        let out = dc.apply(&mut rec, &mut state, &args).unwrap();
        assert_eq!(out.after, budget::after_count(&want), "{label}");
        match cut {
            None => {
                assert_eq!(step, 3, "{label}: the cap must bind");
                assert_eq!(got, free);
                assert_eq!(out.budget_dropped, 0);
            }
            Some(BudgetCut { dropped, after, .. }) => {
                assert!(after <= cap && out.after == after, "{label}: {out:?}");
                // One addition fewer dropped would not fit (a split pruned anyway saves 2).
                assert!(
                    after + 2 > cap,
                    "{label}: dropped more than needed ({after})"
                );
                assert_eq!(out.budget_dropped, dropped);
                let adds = |d: &[u32], i: usize| budget::adds(d[i]);
                let kept_min = (0..n)
                    .filter(|&i| adds(&got, i))
                    .map(|i| scores[i])
                    .fold(f32::INFINITY, f32::min);
                let dropped_max = (0..n)
                    .filter(|&i| adds(&free, i) && !adds(&got, i))
                    .map(|i| scores[i])
                    .fold(0.0, f32::max);
                assert_eq!(
                    (0..n).filter(|&i| adds(&free, i) && !adds(&got, i)).count(),
                    dropped
                );
                assert!(dropped > 0 && dropped_max <= kept_min, "{label}");
                if exact.is_some() {
                    // Exact: the count is the target (a split pruned anyway may save 2).
                    assert!(
                        after == cap || after + 1 == cap,
                        "{label}: ended at {after}"
                    );
                    assert!(!got.iter().any(|&d| d & DECIDE_LOWERED != 0), "{label}");
                }
                if step == 0 {
                    // The shared statistic is where this cut falls: the tie rule decided.
                    assert_eq!(dropped_max, kept_min, "{label}: the cut is not on the tie");
                }
            }
        }
        eprintln!("{label}: {out:?}");
    }
    ctx.check_validation().unwrap();
}

#[test]
fn split_children_are_samples_of_the_parent_and_deterministic() {
    let ctx = ctx();
    let n = 12_000usize;
    let extent = 1.0f32;
    let mut p = GaussianParams::empty(0);
    let (mean, ls) = (
        [0.3f32, -1.2, 2.0],
        [0.2f32.ln(), 0.05f32.ln(), 0.1f32.ln()],
    );
    let q = [0.8f32, 0.3, -0.4, 0.2];
    for _ in 0..n {
        p.positions.push(mean);
        p.log_scales.push(ls);
        p.rotations.push(q);
        p.opacity_logits.push(1.0);
        p.sh_dc.push([0.1, 0.2, 0.3]);
    }
    let zeros = GaussianParams {
        positions: vec![[0.0; 3]; n],
        log_scales: vec![[0.0; 3]; n],
        rotations: vec![[0.0; 4]; n],
        opacity_logits: vec![0.0; n],
        sh_dc: vec![[0.0; 3]; n],
        ..GaussianParams::empty(0)
    };
    let host = HostState {
        params: p,
        m: zeros.clone(),
        v: zeros,
    };
    let stats = HostStats {
        grad_accum: vec![1e-3; n],
        denom: vec![1.0; n],
        max_radii: vec![0.0; n],
        abs_accum: vec![0.0; n],
    };
    let args = DensifyArgs {
        extent: extent as f64,
        prune_large: false,
        iteration: 1200,
        phase: DensifyPhase::Both,
    };
    let run = |seed: u64| {
        let mut state = upload_state(&ctx, &host, n);
        let cfg = DensityConfig {
            seed,
            ..Default::default()
        };
        let mut dc = DensityControl::new(&ctx, n, cfg).unwrap();
        upload_stats(&dc, &stats);
        let mut rec = Recorder::new(&ctx).unwrap();
        let out = dc.step(&mut rec, &mut state, &args, None).unwrap();
        assert_eq!((out.kept, out.split_children, out.after), (0, 2 * n, 2 * n));
        assert!(out.grew, "2n children do not fit a capacity of n");
        download_state(&state).params
    };
    let a = run(5);
    // Mean and covariance of the children against the parent's N(mean, R S² Rᵀ).
    let m = 2 * n;
    let mut mu = [0.0f64; 3];
    for x in &a.positions {
        for k in 0..3 {
            mu[k] += x[k] as f64 / m as f64;
        }
    }
    let mut cov = [[0.0f64; 3]; 3];
    for x in &a.positions {
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] += (x[r] as f64 - mu[r]) * (x[c] as f64 - mu[c]) / m as f64;
            }
        }
    }
    let qd = q.map(|v| v as f64);
    let (u, _) = lpmsplat::reference::project::normalize_quat(qd).unwrap();
    let rot = lpmsplat::reference::project::quat_to_rotation(u);
    let s2 = ls.map(|v| (2.0 * v as f64).exp());
    for r in 0..3 {
        let var = (0..3).map(|k| rot[r][k] * rot[r][k] * s2[k]).sum::<f64>();
        let se = (var / m as f64).sqrt();
        assert!((mu[r] - mean[r] as f64).abs() < 4.0 * se, "mean axis {r}");
        for c in 0..3 {
            let want = (0..3).map(|k| rot[r][k] * rot[c][k] * s2[k]).sum::<f64>();
            assert!(
                (cov[r][c] - want).abs() < 0.05 * 0.04,
                "cov[{r}][{c}] {} vs {want}",
                cov[r][c]
            );
        }
    }
    let shrink = 1.6f64.ln() as f32;
    assert!(a.log_scales.iter().all(|s| *s == ls.map(|v| v - shrink)));
    assert!(a.rotations.iter().all(|r| *r == q));
    // Deterministic for a seed, different for another.
    let b = run(5);
    assert_eq!(bits(&a.positions), bits(&b.positions));
    let c = run(6);
    assert_ne!(a.positions[0], c.positions[0]);
    ctx.check_validation().unwrap();
}

/// 2DGS's split on the GPU path: surfels live in the 3DGS buffers with the unused third
/// log-scale (`UNUSED_LOG_SCALE`, e^−20), so a split samples its children in the parent's
/// plane, as the official 2DGS split does (std (s_u, s_v, 0)): each child's offset along the
/// parent's normal (the rotation's third column) is f32 rounding of the position, while its
/// offsets along the two tangent axes, divided by the parent's two scales, are standard
/// normal. The children keep the rotation and every log-scale shrinks by ln 1.6, the third
/// included (it only gets smaller).
#[test]
fn surfel_split_children_stay_in_the_parents_plane() {
    use lpmsplat::train::passes::surfels::UNUSED_LOG_SCALE;
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
    let n = 2_000usize;
    let mut p = GaussianParams::empty(0);
    for _ in 0..n {
        p.positions.push([(); 3].map(|_| rng.gen_range(-2.0..2.0)));
        // In-plane scales 0.03–0.3 of an extent of 1: all above percent_dense, so all split.
        p.log_scales.push([
            rng.gen_range(0.03f32.ln()..0.3f32.ln()),
            rng.gen_range(0.03f32.ln()..0.3f32.ln()),
            UNUSED_LOG_SCALE,
        ]);
        p.rotations.push([(); 4].map(|_| normal(&mut rng)));
        p.opacity_logits.push(1.0);
        p.sh_dc.push([0.1, 0.2, 0.3]);
    }
    let host = HostState {
        m: random_moments(&mut rng, n, 0, false),
        v: random_moments(&mut rng, n, 0, true),
        params: p.clone(),
    };
    let stats = HostStats {
        grad_accum: vec![1e-3; n],
        denom: vec![1.0; n],
        max_radii: vec![0.0; n],
        abs_accum: vec![0.0; n],
    };
    let mut state = upload_state(&ctx, &host, 2 * n);
    let mut dc = DensityControl::new(
        &ctx,
        2 * n,
        DensityConfig {
            seed: 3,
            ..Default::default()
        },
    )
    .unwrap();
    upload_stats(&dc, &stats);
    let args = DensifyArgs {
        extent: 1.0,
        prune_large: false,
        iteration: 900,
        phase: DensifyPhase::Both,
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    let out = dc.step(&mut rec, &mut state, &args, None).unwrap();
    assert_eq!((out.kept, out.split_children, out.after), (0, 2 * n, 2 * n));
    let c = download_state(&state).params;
    let shrink = 1.6f64.ln() as f32;
    let (mut worst_normal, mut worst_rel) = (0.0f64, 0.0f64);
    let mut moments = [0.0f64; 2];
    for (row, parent) in (0..2 * n).map(|r| (r, r / 2)) {
        assert_eq!(
            c.rotations[row], p.rotations[parent],
            "child {row}'s rotation"
        );
        assert_eq!(
            c.log_scales[row],
            p.log_scales[parent].map(|v| v - shrink),
            "child {row}'s log-scales"
        );
        let q = p.rotations[parent].map(|v| v as f64);
        let (u, _) = lpmsplat::reference::project::normalize_quat(q).unwrap();
        let r = lpmsplat::reference::project::quat_to_rotation(u);
        let d: [f64; 3] =
            [0, 1, 2].map(|k| c.positions[row][k] as f64 - p.positions[parent][k] as f64);
        let along = |axis: usize| (0..3).map(|k| r[k][axis] * d[k]).sum::<f64>();
        // Rounding: the position's f32 ulp (|p| ≤ 2·√3 + 1) and the parent's as the input.
        let ulp = 2.0 * f32::EPSILON as f64 * 4.5;
        worst_normal = worst_normal.max(along(2).abs());
        assert!(
            along(2).abs() <= ulp,
            "child {row}: {:e} off its parent's plane (offset {d:?})",
            along(2)
        );
        let s = p.log_scales[parent].map(|v| (v as f64).exp());
        for (m, axis) in moments.iter_mut().zip([0, 1]) {
            *m += (along(axis) / s[axis]).powi(2) / (2 * n) as f64;
        }
        let tangent = (along(0).powi(2) + along(1).powi(2)).sqrt();
        worst_rel = worst_rel.max(along(2).abs() / tangent.max(1e-30));
    }
    eprintln!(
        "{} children: largest offset along the normal {worst_normal:e} ({worst_rel:e} of the \
         in-plane offset); in-plane variance / scale²: {:.3}, {:.3}",
        2 * n,
        moments[0],
        moments[1]
    );
    // Standard normal samples: the variance of 4,000 is 1 within 0.1 (4.5 standard errors).
    for m in moments {
        assert!((m - 1.0).abs() < 0.1, "in-plane variance / scale² {m}");
    }
    ctx.check_validation().unwrap();
}

#[test]
fn statistics_accumulate_only_visible_gaussians() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let n = 5_000;
    // With the absolute-gradient statistic, which accumulates over the same views.
    let cfg = DensityConfig {
        abs_grad: true,
        ..Default::default()
    };
    let dc = DensityControl::new(&ctx, n + 10, cfg).unwrap();
    let mut host = HostStats::zeros(n + 10);
    let norms = GpuBuffer::<f32>::new(&ctx, "norms", n, BufferKind::DeviceLocal).unwrap();
    let abs = GpuBuffer::<f32>::new(&ctx, "abs", n, BufferKind::DeviceLocal).unwrap();
    let proj =
        GpuBuffer::<ProjectedBoundsGpu>::new(&ctx, "projected bounds", n, BufferKind::DeviceLocal)
            .unwrap();
    for view in 0..5 {
        let nv: Vec<f32> = (0..n).map(|_| rng.gen_range(0.0..1e-3)).collect();
        let av: Vec<f32> = (0..n).map(|_| rng.gen_range(0.0..1e-2)).collect();
        let radii: Vec<f32> = (0..n)
            .map(|_| {
                if rng.gen_bool(0.4) {
                    0.0
                } else {
                    rng.gen_range(1..50) as f32
                }
            })
            .collect();
        let projected: Vec<ProjectedBoundsGpu> = radii
            .iter()
            .map(|&radius| ProjectedBoundsGpu {
                // Other fields are garbage on purpose: only the radius may matter.
                depth: -1.0,
                tile_min: [u32::MAX; 2],
                radius,
                flags: 0xFFFF_FFFF,
                ..bytemuck::Zeroable::zeroed()
            })
            .collect();
        norms.upload(&nv).unwrap();
        abs.upload(&av).unwrap();
        proj.upload(&projected).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        // Count smaller than the buffers on one view: the rest must stay untouched.
        let count = if view == 2 { n - 100 } else { n };
        dc.record_accumulate(&mut rec, &norms, &proj, None, Some(&abs), 1.0, count)
            .unwrap();
        rec.submit_and_wait().unwrap();
        host.accumulate_with_abs(&nv[..count], &radii[..count], &av[..count]);
    }
    assert_eq!(
        bits(&dc.stats().abs_accum.read().unwrap()),
        bits(&host.abs_accum)
    );
    // The absolute gradients are required once the statistic is on.
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = dc
        .record_accumulate(&mut rec, &norms, &proj, None, None, 1.0, n)
        .unwrap_err();
    assert!(e.to_string().contains("abs_grad"), "{e}");
    assert_eq!(
        bits(&dc.stats().grad_accum.read().unwrap()),
        bits(&host.grad_accum)
    );
    assert_eq!(dc.stats().denom.read().unwrap(), host.denom);
    assert_eq!(dc.stats().max_radii.read().unwrap(), host.max_radii);
    assert!(host.denom.contains(&0.0) && host.denom.contains(&5.0));
    // Too many Gaussians for the buffers is refused.
    let mut rec = Recorder::new(&ctx).unwrap();
    assert!(dc
        .record_accumulate(&mut rec, &norms, &proj, None, Some(&abs), 1.0, n + 1)
        .is_err());
    ctx.check_validation().unwrap();
}

/// Pixel-GS's statistic on random views: bit-equal to the host reference, max radii as ADC's.
#[test]
fn pixel_weighted_statistics_match_the_host_reference() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(31);
    let n = 4_000;
    let extent = 3.5f64;
    let cfg = DensityConfig {
        statistic: Statistic::pixel_gs(),
        ..Default::default()
    };
    let (mode, depth_scale) = cfg.statistic.kernel_mode(extent).unwrap();
    assert_eq!(mode, 1);
    assert_eq!(depth_scale, (1.0 / (0.37f64 * extent)) as f32);
    let dc = DensityControl::new(&ctx, n, cfg).unwrap();
    let mut host = HostStats::zeros(n);
    let norms = GpuBuffer::<f32>::new(&ctx, "norms", n, BufferKind::DeviceLocal).unwrap();
    let counts = GpuBuffer::<u32>::new(&ctx, "pixel counts", n, BufferKind::DeviceLocal).unwrap();
    let proj =
        GpuBuffer::<ProjectedBoundsGpu>::new(&ctx, "projected bounds", n, BufferKind::DeviceLocal)
            .unwrap();
    for _view in 0..4 {
        let nv: Vec<f32> = (0..n).map(|_| rng.gen_range(0.0..1e-3)).collect();
        let radii: Vec<f32> = (0..n)
            .map(|_| {
                if rng.gen_bool(0.3) {
                    0.0
                } else {
                    rng.gen_range(1..40) as f32
                }
            })
            .collect();
        // Counts 0 (visible but past every pixel's last contributor) to large; depths on both
        // sides of 0.37·extent, so the factor is clamped at 1 for some.
        let pc: Vec<u32> = (0..n).map(|_| rng.gen_range(0..3000)).collect();
        let depth: Vec<f32> = (0..n).map(|_| rng.gen_range(0.01..4.0)).collect();
        let projected: Vec<ProjectedBoundsGpu> = (0..n)
            .map(|i| ProjectedBoundsGpu {
                radius: radii[i],
                depth: depth[i],
                ..bytemuck::Zeroable::zeroed()
            })
            .collect();
        norms.upload(&nv).unwrap();
        counts.upload(&pc).unwrap();
        proj.upload(&projected).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        dc.record_accumulate(&mut rec, &norms, &proj, Some(&counts), None, extent, n)
            .unwrap();
        rec.submit_and_wait().unwrap();
        host.accumulate_pixel_weighted(&nv, &radii, &pc, &depth, depth_scale);
    }
    assert_eq!(
        bits(&dc.stats().grad_accum.read().unwrap()),
        bits(&host.grad_accum)
    );
    assert_eq!(dc.stats().denom.read().unwrap(), host.denom);
    assert_eq!(dc.stats().max_radii.read().unwrap(), host.max_radii);
    // The pixel-weighted statistic without counts is refused with the fix.
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = dc
        .record_accumulate(&mut rec, &norms, &proj, None, None, extent, n)
        .unwrap_err()
        .to_string();
    assert!(e.contains("pixel counts"), "{e}");
    ctx.check_validation().unwrap();
}

/// What Pixel-GS changes: a large Gaussian with a strong gradient in the one view where it
/// covers many pixels, and a weak one in several views where it covers a few (seen edge-on or
/// far away), stays below the threshold under ADC's per-view average and crosses it under the
/// pixel-weighted one; the same Gaussian close to the cameras is held back by the depth factor.
/// GPU decisions equal the host reference's under both statistics.
#[test]
fn pixel_weighting_densifies_large_gaussians_adc_averages_away() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(32);
    let extent = 2.0f64;
    let n = 3;
    let mut params = random_params(&mut rng, n, 0, extent as f32);
    for i in 0..n {
        params.log_scales[i] = [(0.005 * extent as f32).ln(); 3]; // clone-sized
        params.opacity_logits[i] = 1.0;
    }
    // Gaussian 0: far (depth 3 > 0.37·2), the profile above. 1: the same at depth 0.2 (φ ≈ 0.07).
    // 2: a small Gaussian with a uniform gradient just above the threshold in every view.
    // Views: (pixel counts, gradient norms) per Gaussian.
    let views: [([u32; 3], [f32; 3]); 5] = [
        ([400, 400, 20], [8e-4, 8e-4, 3e-4]),
        ([2, 2, 20], [1e-5, 1e-5, 3e-4]),
        ([2, 2, 20], [1e-5, 1e-5, 3e-4]),
        ([2, 2, 20], [1e-5, 1e-5, 3e-4]),
        ([2, 2, 20], [1e-5, 1e-5, 3e-4]),
    ];
    let depth = [3.0f32, 0.2, 3.0];
    let args = DensifyArgs {
        extent,
        prune_large: false,
        iteration: 500,
        phase: DensifyPhase::Both,
    };
    let mut densified = Vec::new();
    for statistic in [Statistic::Gradient, Statistic::pixel_gs()] {
        let cfg = DensityConfig {
            statistic,
            ..Default::default()
        };
        let mut dc = DensityControl::new(&ctx, 8, cfg).unwrap();
        let host_state = HostState {
            m: random_moments(&mut rng, n, 0, false),
            v: random_moments(&mut rng, n, 0, true),
            params: params.clone(),
        };
        let state = upload_state(&ctx, &host_state, 8);
        let mut host = HostStats::zeros(n);
        let (_, depth_scale) = statistic.kernel_mode(extent).unwrap();
        let norms = GpuBuffer::<f32>::new(&ctx, "norms", n, BufferKind::DeviceLocal).unwrap();
        let counts = GpuBuffer::<u32>::new(&ctx, "counts", n, BufferKind::DeviceLocal).unwrap();
        let proj = GpuBuffer::<ProjectedBoundsGpu>::new(
            &ctx,
            "projected bounds",
            n,
            BufferKind::DeviceLocal,
        )
        .unwrap();
        let radii = [30.0f32; 3];
        proj.upload(
            &(0..n)
                .map(|i| ProjectedBoundsGpu {
                    radius: radii[i],
                    depth: depth[i],
                    ..bytemuck::Zeroable::zeroed()
                })
                .collect::<Vec<_>>(),
        )
        .unwrap();
        for (pc, nv) in &views {
            norms.upload(nv).unwrap();
            counts.upload(pc).unwrap();
            let mut rec = Recorder::new(&ctx).unwrap();
            dc.record_accumulate(&mut rec, &norms, &proj, Some(&counts), None, extent, n)
                .unwrap();
            rec.submit_and_wait().unwrap();
            match statistic {
                Statistic::Gradient => host.accumulate(nv, &radii),
                _ => host.accumulate_pixel_weighted(nv, &radii, pc, &depth, depth_scale),
            }
        }
        let mut rec = Recorder::new(&ctx).unwrap();
        dc.record_decide(&mut rec, &state, &args, None, None)
            .unwrap();
        rec.submit_and_wait().unwrap();
        let gpu = dc.decisions().read_range(0, n).unwrap();
        let want = reference::decide(
            &Thresholds::new(&cfg, &args).unwrap(),
            &host,
            &host_state.params,
            None,
        );
        assert_eq!(
            gpu, want,
            "{statistic:?}: GPU decisions vs the host reference"
        );
        densified.push(
            gpu.iter()
                .map(|d| d & DECIDE_CLONE != 0)
                .collect::<Vec<_>>(),
        );
    }
    assert_eq!(densified[0], vec![false, false, true], "ADC");
    assert_eq!(densified[1], vec![true, false, true], "Pixel-GS");
    ctx.check_validation().unwrap();
}

#[test]
fn opacity_reset_caps_opacity_and_clears_only_the_opacity_moments() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(8);
    let (n, degree) = (3_000, 1);
    let mut host = HostState {
        params: random_params(&mut rng, n, degree, 1.0),
        m: random_moments(&mut rng, n, degree, false),
        v: random_moments(&mut rng, n, degree, true),
    };
    let state = upload_state(&ctx, &host, n);
    let cfg = DensityConfig::default();
    let dc = DensityControl::new(&ctx, n, cfg).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    dc.record_opacity_reset(&mut rec, &state).unwrap();
    rec.submit_and_wait().unwrap();
    let max_logit = reset_logit(&cfg).unwrap();
    assert!((max_logit as f64 - (0.01f64 / 0.99).ln()).abs() < 1e-6);
    let before = host.params.opacity_logits.clone();
    reference::reset_opacity(&mut host, max_logit);
    let gpu = download_state(&state);
    assert_states_match(&gpu, &host, n, "opacity reset");
    let capped = before.iter().filter(|&&x| x > max_logit).count();
    assert!(capped > n / 2 && capped < n, "{capped}");
    assert!(gpu.m.opacity_logits.iter().all(|&v| v == 0.0));
    assert!(
        gpu.m.sh_dc.iter().any(|v| v[0] != 0.0),
        "other moments kept"
    );
    ctx.check_validation().unwrap();
}

/// Mip-Splatting's filter-aware reset: the opacity the renderer uses, σ(x)·ρ3, is capped at
/// 0.01 (stored σ(x') = 0.01 / ρ3 where it was above), against an f64 computation; Gaussians
/// whose filtered opacity is already below keep their logit bit for bit.
#[test]
fn filtered_opacity_reset_caps_the_rendered_opacity() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(81);
    let (n, degree) = (2_000, 0);
    let host = HostState {
        params: random_params(&mut rng, n, degree, 1.0),
        m: random_moments(&mut rng, n, degree, false),
        v: random_moments(&mut rng, n, degree, true),
    };
    let filter: Vec<f32> = host
        .params
        .log_scales
        .iter()
        .map(|l| l[0].exp() * rng.gen_range(0.0f32..3.0))
        .collect();
    let state = upload_state(&ctx, &host, n);
    let fbuf = GpuBuffer::from_slice(&ctx, "filter3d", &filter).unwrap();
    let cfg = DensityConfig::default();
    let dc = DensityControl::new(&ctx, n, cfg).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    dc.record_opacity_reset_filtered(&mut rec, &state, Some(&fbuf))
        .unwrap();
    rec.submit_and_wait().unwrap();
    let got = state.params.opacity_logits.read_range(0, n).unwrap();
    let (mut capped, mut kept) = (0, 0);
    for i in 0..n {
        let phi = (filter[i] as f64).powi(2);
        let rho: f64 = host.params.log_scales[i]
            .iter()
            .map(|&l| {
                let s2 = (2.0 * l as f64).exp();
                (s2 / (s2 + phi)).sqrt()
            })
            .product();
        let x = host.params.opacity_logits[i] as f64;
        let effective = rho / (1.0 + (-x).exp());
        if effective > 0.01 * (1.0 + 1e-4) {
            let after = rho / (1.0 + (-(got[i] as f64)).exp());
            assert!(
                (after / 0.01 - 1.0).abs() < 1e-3,
                "{i}: rendered opacity {after}"
            );
            capped += 1;
        } else if effective < 0.01 * (1.0 - 1e-4) {
            assert_eq!(got[i], host.params.opacity_logits[i], "{i}");
            kept += 1;
        }
    }
    assert!(
        capped > n / 4 && kept > n / 10,
        "{capped} capped, {kept} kept"
    );
    assert!(state
        .m
        .opacity_logits
        .read_range(0, n)
        .unwrap()
        .iter()
        .all(|&v| v == 0.0));
    ctx.check_validation().unwrap();
}

#[test]
fn decisions_can_be_edited_between_decide_and_apply() {
    // The LPM hook: extra pruning OR-ed into the decisions before the scan.
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(12);
    let (n, degree, extent) = (1_000usize, 0u32, 2.0f32);
    let host = HostState {
        params: random_params(&mut rng, n, degree, extent),
        m: random_moments(&mut rng, n, degree, false),
        v: random_moments(&mut rng, n, degree, true),
    };
    let cap = 4 * n;
    let mut state = upload_state(&ctx, &host, cap);
    let cfg = DensityConfig::default();
    let mut dc = DensityControl::new(&ctx, cap, cfg).unwrap();
    let stats = random_stats(&mut rng, n);
    upload_stats(&dc, &stats);
    let args = DensifyArgs {
        extent: extent as f64,
        prune_large: false,
        iteration: 900,
        phase: DensifyPhase::Both,
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    dc.record_decide(&mut rec, &state, &args, None, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    rec.begin().unwrap();
    let mut d = dc.decisions().read_range(0, n).unwrap();
    for (i, w) in d.iter_mut().enumerate() {
        if i % 7 == 0 {
            *w |= DECIDE_REMOVE;
        }
    }
    dc.decisions().upload(&d).unwrap();
    dc.poison_move_scratch(&state, NAN_BITS).unwrap();
    let before = raw_buffers(&state);
    let out = dc.apply(&mut rec, &mut state, &args).unwrap();
    let t = Thresholds::new(&cfg, &args).unwrap();
    let expect = reference::apply(&host, &d, fold_seed(cfg.seed), 900, t.log_split_shrink);
    assert_eq!(out.after, expect.params.len());
    assert_states_match(
        &download_state(&state),
        &expect,
        out.kept + out.clones,
        "hook",
    );
    assert_tail_untouched(&state, &before, "hook");
    // apply needs a matching record_decide.
    assert!(dc.apply(&mut rec, &mut state, &args).is_err());
    let bad = DensifyArgs {
        extent: 0.0,
        ..args
    };
    assert!(dc
        .record_decide(&mut rec, &state, &bad, None, None)
        .is_err());
    ctx.check_validation().unwrap();
}

/// A density context for 3D Gaussians with no render behind it (extent 1, a 1×1 image of
/// `dummies`), the model's new-Gaussian extras `extras`.
fn bare_context<'a>(
    ctx: &'a Arc<GpuContext>,
    rec: &'a mut Recorder,
    state: &'a mut SplatState,
    density: &'a mut DensityControl,
    dummies: (&'a GpuBuffer<f32>, &'a GpuBuffer<u32>),
    extras: Vec<Vec<f32>>,
) -> lpmsplat::train::strategy::DensityContext<'a> {
    lpmsplat::train::strategy::DensityContext {
        ctx,
        rec,
        state,
        density,
        extent: 1.0,
        render: dummies.0,
        truth: dummies.1,
        truth_offset_px: 0,
        width: 1,
        height: 1,
        primitive: lpmsplat::train::strategy::Primitive::Gaussian,
        raw_colour: false,
        new_extras: extras,
        moving: None,
        opacity_filter: None,
    }
}

/// LPM's point addition writes the model's extra groups of every new Gaussian from the
/// model's row (`DensityContext::new_extras`), keeps the old rows, grows past the capacity, and
/// refuses rows that do not match the groups.
#[test]
fn added_gaussians_carry_the_models_extra_groups() {
    use lpmsplat::lpm::strategy::{append_gaussians, NewGaussian};
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let n = 40usize;
    let params = with_extras(random_params(&mut rng, n, 1, 2.0), &mut rng);
    let m = with_extras(random_moments(&mut rng, n, 1, false), &mut rng);
    let v = with_extras(random_moments(&mut rng, n, 1, true), &mut rng);
    let host = HostState { params, m, v };
    let mut state = upload_state(&ctx, &host, n + 2);
    let mut density = DensityControl::new(&ctx, n + 2, DensityConfig::default()).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin().unwrap();
    let dummy_f = GpuBuffer::<f32>::from_slice(&ctx, "render", &[0.0; 3]).unwrap();
    let dummy_u = GpuBuffer::<u32>::from_slice(&ctx, "truth", &[0]).unwrap();
    let rows: Vec<NewGaussian> = (0..5)
        .map(|k| NewGaussian {
            position: [k as f32, 1.0, 2.0],
            scale: 0.1,
            color: [0.2, 0.4, 0.6],
            opacity: 0.1,
            camera_center: [0.0, 0.0, -5.0],
        })
        .collect();
    let mut append = |state: &mut SplatState, extras: Vec<Vec<f32>>| {
        let mut t = bare_context(
            &ctx,
            &mut rec,
            state,
            &mut density,
            (&dummy_f, &dummy_u),
            extras,
        );
        append_gaussians(&mut t, &rows)
    };
    let e = append(&mut state, vec![vec![0.0; 2]])
        .unwrap_err()
        .to_string();
    assert!(e.contains("1 extra rows for its 2 extra groups"), "{e}");
    let e = append(&mut state, vec![vec![0.0; 3], vec![0.0]])
        .unwrap_err()
        .to_string();
    assert!(e.contains("extra"), "{e}");
    append(&mut state, vec![vec![7.0, -7.0], vec![0.25]]).unwrap();
    assert_eq!(state.count(), n + 5);
    assert!(state.capacity() >= n + 5, "grew past the capacity");
    let got = download_state(&state);
    for (k, e) in got.params.extra.iter().enumerate() {
        let s = e.group.stride;
        assert_eq!(
            e.values[..n * s],
            host.params.extra[k].values[..],
            "old rows kept"
        );
        let row = if k == 0 { vec![7.0, -7.0] } else { vec![0.25] };
        for i in n..n + 5 {
            assert_eq!(e.values[i * s..(i + 1) * s], row[..], "group {k} row {i}");
        }
        for set in [&got.m, &got.v] {
            assert!(
                set.extra[k].values[n * s..].iter().all(|&x| x == 0.0),
                "zero moments"
            );
            assert_eq!(set.extra[k].values[..n * s].len(), n * s);
        }
    }
    ctx.check_validation().unwrap();
}

/// MCMC guided by surface samples (LPM's `--lpm-surface-share`): the dead rows `plan_seeded`
/// picks hold exactly the samples, written as LPM's added points are (position, log-scale,
/// identity rotation, opacity logit, SH DC, zero SH rest, the model's extra row, zero moments),
/// over dead rows poisoned first; the other dead rows are relocated onto live ones as
/// `plan_relocation_of` plans; the rows no plan touches keep every bit; the count stays at
/// the budget, though the samples were staged past the capacity.
#[test]
fn mcmc_moves_dead_gaussians_onto_a_guides_surface_samples() {
    use lpmsplat::lpm::strategy::NewGaussian;
    use lpmsplat::mcmc::plan::{dead_rows, plan_relocation_of, plan_rng, plan_seeded};
    use lpmsplat::mcmc::{McmcConfig, McmcStrategy};
    use lpmsplat::splats::SH_C0;
    use lpmsplat::train::strategy::{DensityStrategy, Guide, IterationView, Primitive};
    const POISON: f32 = 7.77e7;
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let n = 60usize;
    let mut params = with_extras(random_params(&mut rng, n, 1, 2.0), &mut rng);
    let mut m = with_extras(random_moments(&mut rng, n, 1, false), &mut rng);
    let mut v = with_extras(random_moments(&mut rng, n, 1, true), &mut rng);
    let rs = params.rest_stride();
    for i in (0..n).step_by(3) {
        params.opacity_logits[i] = -9.0;
        // Poison (the upload refuses NaN): values no written row holds.
        params.sh_rest[i * rs..(i + 1) * rs].fill(POISON);
        for set in [&mut m, &mut v] {
            set.positions[i] = [POISON; 3];
            set.sh_dc[i] = [POISON; 3];
            set.sh_rest[i * rs..(i + 1) * rs].fill(POISON);
        }
    }
    let host = HostState { params, m, v };
    let mut state = upload_state(&ctx, &host, n);
    let mut density = DensityControl::new(&ctx, n, DensityConfig::default()).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin().unwrap();
    let dummy_f = GpuBuffer::<f32>::from_slice(&ctx, "render", &[0.0; 3]).unwrap();
    let dummy_u = GpuBuffer::<u32>::from_slice(&ctx, "truth", &[0]).unwrap();
    let ones = vec![1.0f32; n];
    let weight = GpuBuffer::<f32>::from_slice(&ctx, "weight", &ones).unwrap();
    let samples: Vec<NewGaussian> = (0..7)
        .map(|k| NewGaussian {
            position: [k as f32 * 0.1, -0.3, 0.7],
            scale: 0.01 * (k + 1) as f32,
            color: [0.1 * k as f32, 0.5, 0.9],
            opacity: 0.1,
            camera_center: [0.0, 0.0, -5.0],
        })
        .collect();
    let budget = BudgetCurve {
        target: n,
        growth: Growth::Mcmc,
        initial: n,
        window: (0, 1000, 100),
    };
    let mut config = McmcConfig::with_budget(budget);
    config.seed = 3;
    let mut mcmc = McmcStrategy::new(&ctx, config, Primitive::Gaussian).unwrap();
    let extras = vec![vec![0.5, -0.5], vec![0.25]];
    let it = 500;
    {
        let mut t = bare_context(
            &ctx,
            &mut rec,
            &mut state,
            &mut density,
            (&dummy_f, &dummy_u),
            extras.clone(),
        );
        let args = DensifyArgs {
            extent: 1.0,
            prune_large: false,
            iteration: it,
            phase: DensifyPhase::Both,
        };
        let at = IterationView {
            iteration: it,
            view: 0,
            background: [0.0; 3],
        };
        let guide = Guide {
            weight: &weight,
            samples: &samples,
            sample_share: 0.5,
        };
        mcmc.densify_guided(&mut t, &at, &args, &guide).unwrap();
    }
    rec.submit_and_wait().unwrap();
    assert_eq!(state.count(), n, "the count is the budget's");
    assert!(
        state.capacity() > n,
        "the samples were staged past the capacity"
    );
    let got = download_state(&state);

    // What the plans say.
    let dead = dead_rows(&host.params.opacity_logits, 0.005);
    assert!(
        dead.len() >= n / 3,
        "every third row and the random ones below 0.005"
    );
    let seeded = plan_seeded(&dead, samples.len(), 0.5, &mut plan_rng(3, it, 2));
    assert_eq!(seeded.len(), 7, "at least ⌊½ · 20⌋ = 10 rows, 7 samples");
    let moving: Vec<u32> = dead
        .iter()
        .copied()
        .filter(|r| seeded.iter().all(|s| s.0 != *r))
        .collect();
    let mut logits = host.params.opacity_logits.clone();
    let reloc = plan_relocation_of(
        &mut logits,
        Some(&ones),
        0.005,
        &moving,
        &mut plan_rng(3, it, 0),
    );
    assert_eq!(reloc.copies.len(), moving.len());

    for &(row, k) in &seeded {
        let (r, g) = (row as usize, &samples[k as usize]);
        let p = &got.params;
        assert_eq!(bits(&p.positions[r]), bits(&g.position), "row {r}");
        assert_eq!(bits(&p.log_scales[r]), bits(&[g.scale.ln(); 3]), "row {r}");
        assert_eq!(p.rotations[r], [1.0, 0.0, 0.0, 0.0]);
        let logit = (g.opacity / (1.0 - g.opacity)).ln() as f32;
        assert_eq!(p.opacity_logits[r].to_bits(), logit.to_bits());
        let dc = g.color.map(|c| ((c as f64 - 0.5) / SH_C0) as f32);
        assert_eq!(bits(&p.sh_dc[r]), bits(&dc));
        assert!(p.sh_rest[r * rs..(r + 1) * rs].iter().all(|&x| x == 0.0));
        for (e, row) in p.extra.iter().zip(&extras) {
            let s = e.group.stride;
            assert_eq!(e.values[r * s..(r + 1) * s], row[..]);
        }
        for set in [&got.m, &got.v] {
            assert_eq!(set.positions[r], [0.0; 3]);
            assert_eq!(set.sh_dc[r], [0.0; 3]);
            assert_eq!(set.opacity_logits[r], 0.0);
            assert!(set.sh_rest[r * rs..(r + 1) * rs].iter().all(|&x| x == 0.0));
        }
    }
    let mut touched = std::collections::HashSet::new();
    for &(dst, src) in &reloc.copies {
        let (d, s) = (dst as usize, src as usize);
        assert_eq!(
            bits(&got.params.positions[d]),
            bits(&host.params.positions[s]),
            "relocated row {d} sits on its source {s}"
        );
        touched.extend([d, s]);
    }
    for &(row, l, _) in &reloc.updates {
        assert_eq!(got.params.opacity_logits[row as usize], l, "row {row}");
        touched.insert(row as usize);
    }
    touched.extend(seeded.iter().map(|s| s.0 as usize));
    for i in (0..n).filter(|i| !touched.contains(i)) {
        assert_eq!(got.params.positions[i], host.params.positions[i], "row {i}");
        assert_eq!(
            bits(&got.params.log_scales[i]),
            bits(&host.params.log_scales[i])
        );
        assert_eq!(
            got.params.opacity_logits[i].to_bits(),
            host.params.opacity_logits[i].to_bits()
        );
        assert_eq!(bits(&got.m.sh_dc[i]), bits(&host.m.sh_dc[i]));
    }
    ctx.check_validation().unwrap();
}

/// Device-local bytes of every buffer of `s`.
fn state_bytes(s: &SplatState) -> u64 {
    groups_of(s).iter().map(|g| g.0.byte_len()).sum()
}

/// Every buffer of `s` with its floats per Gaussian.
fn groups_of(s: &SplatState) -> Vec<(&GpuBuffer<f32>, usize)> {
    [&s.params, &s.m, &s.v]
        .iter()
        .flat_map(|set| set.groups())
        .collect()
}

/// How many buffers of `s` are longer than `capacity` rows need.
fn buffers_past(s: &SplatState, capacity: usize) -> usize {
    groups_of(s)
        .iter()
        .filter(|(b, w)| b.len() > (capacity * w).max(1))
        .count()
}

#[test]
fn a_state_grows_one_buffer_at_a_time_and_running_out_part_way_keeps_every_gaussian() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(91);
    let (n, degree) = (3_000usize, 3u32);
    let host = HostState {
        params: with_extras(random_params(&mut rng, n, degree, 2.0), &mut rng),
        m: with_extras(random_moments(&mut rng, n, degree, false), &mut rng),
        v: with_extras(random_moments(&mut rng, n, degree, true), &mut rng),
    };

    // Enough memory: every row kept, every buffer at the new capacity, and at the peak the
    // old state, the new one and one buffer being copied at most (a whole second state
    // beside the first was 3× the state).
    let ctx = ctx_with_limit(None);
    let mut state = upload_state(&ctx, &host, n);
    let before = state_bytes(&state);
    let widest = groups_of(&state)
        .iter()
        .map(|g| g.0.byte_len())
        .max()
        .unwrap();
    let base = ctx.memory.in_use() - before;
    let mut rec = Recorder::new(&ctx).unwrap();
    state.grow(&ctx, &mut rec, 2 * n).unwrap();
    assert_eq!((state.count(), state.capacity()), (n, 2 * n));
    for (b, w) in groups_of(&state) {
        assert_eq!(b.len(), (2 * n * w).max(1), "{}", b.name());
    }
    assert_states_match(&download_state(&state), &host, n, "grown");
    let peak = ctx.memory.peak() - base;
    assert!(
        peak <= 2 * before + widest,
        "growing a state of {before} bytes to twice its capacity peaked at {peak}"
    );
    assert!(
        state.grow(&ctx, &mut rec, n).is_err(),
        "a state shrank by growing"
    );
    ctx.check_validation().unwrap();
    drop((state, rec, ctx));

    // Too little memory for the bigger state: an out-of-memory error, part of the buffers
    // grown, and the state still holds every Gaussian bit for bit at its old capacity.
    let ctx = ctx_with_limit(Some(base + 2 * before - before / 3));
    let mut state = upload_state(&ctx, &host, n);
    assert_eq!(ctx.memory.in_use(), base + before);
    let mut rec = Recorder::new(&ctx).unwrap();
    let err = state.grow(&ctx, &mut rec, 2 * n).unwrap_err();
    assert!(
        lpmsplat::gpu::out_of_memory(&err).is_some(),
        "not an out-of-memory error: {err:#}"
    );
    assert_eq!((state.count(), state.capacity()), (n, n));
    let grown = buffers_past(&state, n);
    assert!(
        grown > 0 && grown < groups_of(&state).len(),
        "{grown} buffers grew: not part-way"
    );
    assert_states_match(&download_state(&state), &host, n, "after running out");
    ctx.check_validation().unwrap();
}

fn ctx_with_limit(limit: Option<u64>) -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions {
        memory_limit: limit,
        ..GpuOptions::for_tests()
    })
    .unwrap()
}
