//! SpacetimeGaussians' angular-velocity / rotation split (`train::passes::omega_freeze`)
//! against the host reference (`reference::spacetime::omega_marked`): the selection zeroes
//! exactly the unmarked Gaussians' angular velocities and clears the group's Adam moments,
//! the masks zero exactly the right gradients and nothing else, the selection waits for a step
//! that has an optimizer step, and a training run keeps unmarked angular velocities at 0.
//! Validation layer on.

use std::sync::Arc;

use lpmsplat::gpu::{GpuContext, GpuOptions, Recorder};
use lpmsplat::models::with_temporal_groups;
use lpmsplat::reference::spacetime::{omega_marked, temporal_of};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::{random_init, GaussianParams};
use lpmsplat::train::adam::SplatState;
use lpmsplat::train::passes::omega_freeze::OmegaFreezer;
use lpmsplat::train::passes::spacetime_settings::OmegaFreeze;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// A model whose motions, scales and opacities straddle the official thresholds, with every
/// angular velocity non-zero.
fn model(n: usize, seed: u64) -> GaussianParams {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut p = with_temporal_groups(random_init(n, [0.0; 3], [1.0; 3], 9, 0).unwrap(), 1, false);
    for i in 0..n {
        p.log_scales[i] = [0; 3].map(|_| rng.gen_range(-2.5f32..0.0));
        p.opacity_logits[i] = rng.gen_range(-1.0..3.0);
    }
    for e in &mut p.extra {
        let range = match e.group.name.as_str() {
            "motion" => 0.25,
            "omega" => 1.0,
            _ => continue,
        };
        for v in &mut e.values {
            *v = rng.gen_range(-range..range);
            if *v == 0.0 {
                *v = 0.5;
            }
        }
    }
    p
}

fn state(ctx: &Arc<GpuContext>, p: &GaussianParams) -> SplatState {
    let mut s = SplatState::new(ctx, GpuSplats::upload(ctx, p, p.len() + 5).unwrap()).unwrap();
    // Moments that the selection must clear (ω) or keep (the rest).
    for set in [&s.m, &s.v] {
        for (b, _) in set.groups() {
            b.upload(&vec![0.125; b.len()]).unwrap();
        }
    }
    s.set_count(p.len());
    s
}

#[test]
fn selection_and_masks_match_the_reference() {
    let ctx = ctx();
    let n = 2000;
    let p = model(n, 3);
    let f = OmegaFreeze::default();
    let want: Vec<bool> = (0..n)
        .map(|i| {
            let l = p.log_scales[i].map(|v| v as f64);
            omega_marked(
                &temporal_of(&p, i).unwrap(),
                l,
                f.motion_above,
                f.scale_between,
                f.opacity_above,
            )
        })
        .collect();
    let marked = want.iter().filter(|&&m| m).count();
    assert!(
        marked > 20 && marked < n - 20,
        "the model must straddle the thresholds ({marked} of {n} marked)"
    );
    let s = state(&ctx, &p);
    let mut freezer = OmegaFreezer::new(&ctx, f).unwrap();
    let grads = GpuSplats::zeroed_shape(&ctx, "g ", &s.shape(), n, n + 5).unwrap();
    for (b, _) in grads.groups() {
        b.upload(&vec![1.0; b.len()]).unwrap();
    }
    // Before `from`: nothing.
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin().unwrap();
    freezer.record(&mut rec, &s, &grads, f.from - 1).unwrap();
    rec.submit_and_wait().unwrap();
    assert!(!freezer.selected);
    // The selection (at a later step than `from`: it waits for an optimizer step).
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin().unwrap();
    freezer.record(&mut rec, &s, &grads, f.from + 3).unwrap();
    rec.submit_and_wait().unwrap();
    assert!(freezer.selected);
    // The selection step masks too: undo that on the gradients for the masks' check below.
    for (b, _) in grads.groups() {
        b.upload(&vec![1.0; b.len()]).unwrap();
    }
    let after = s.params.download().unwrap();
    let omega = after.extra_values("omega").unwrap();
    let before = p.extra_values("omega").unwrap();
    for i in 0..n {
        let row = &omega[4 * i..4 * i + 4];
        if want[i] {
            assert_eq!(
                row,
                &before[4 * i..4 * i + 4],
                "Gaussian {i}: marked, ω kept"
            );
        } else {
            assert_eq!(row, &[0.0; 4], "Gaussian {i}: unmarked, ω zeroed");
        }
    }
    assert_eq!(after.rotations, p.rotations, "rotations untouched");
    let m = s.m.download().unwrap();
    assert!(m.extra_values("omega").unwrap().iter().all(|&v| v == 0.0));
    assert!(m
        .extra_values("motion")
        .unwrap()
        .iter()
        .all(|&v| v == 0.125));
    assert!(m.rotations.iter().flatten().all(|&v| v == 0.125));
    // The masks: ω = 0 learns no ω, the rest no rotation; nothing else changes.
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.begin().unwrap();
    freezer.record(&mut rec, &s, &grads, f.from + 4).unwrap();
    rec.submit_and_wait().unwrap();
    let g = grads.download().unwrap();
    let g_omega = g.extra_values("omega").unwrap();
    for i in 0..n {
        let (w, r) = if want[i] { (1.0, 0.0) } else { (0.0, 1.0) };
        assert_eq!(
            &g_omega[4 * i..4 * i + 4],
            &[w; 4],
            "Gaussian {i}: ω gradient"
        );
        assert_eq!(g.rotations[i], [r; 4], "Gaussian {i}: rotation gradient");
    }
    assert!(g.positions.iter().flatten().all(|&v| v == 1.0));
    assert!(g.extra_values("motion").unwrap().iter().all(|&v| v == 1.0));
    ctx.check_validation().unwrap();
}

#[test]
fn training_keeps_unmarked_angular_velocities_at_zero() {
    use lpmsplat::scene::{images, LoadOptions, Scene};
    use lpmsplat::train::trainer::Trainer;
    let ctx = ctx();
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/n3v_tiny");
    let scene = Scene::load(&fixture, &LoadOptions::default()).unwrap();
    let images = images::load_images(&scene, &scene.train).unwrap();
    let mut cfg = lpmsplat::train::config::TrainConfig {
        iterations: 60,
        ..Default::default()
    };
    lpmsplat::models::BaseModel::SpacetimeLite.configure(&mut cfg);
    let mut st = *cfg
        .model_settings::<lpmsplat::train::passes::spacetime::SpacetimeTraining>()
        .unwrap();
    st.guided = None;
    // The opacity test alone decides (densification starts after this run).
    st.omega_freeze = Some(OmegaFreeze {
        from: 30,
        motion_above: -1.0,
        scale_between: [0.0, 1e9],
        opacity_above: 0.5,
    });
    cfg.set_model(st);
    let (center, half) = scene.random_init_box();
    let mut init = lpmsplat::models::BaseModel::SpacetimeLite
        .initialise(random_init(800, center, [half; 3], 5, 0).unwrap(), 0);
    // Opacities on both sides of the threshold.
    for (i, o) in init.opacity_logits.iter_mut().enumerate() {
        *o = if i % 2 == 0 { -1.5 } else { 1.5 };
    }
    let mut t = Trainer::new(&ctx, &scene, &images, &init, cfg).unwrap();
    for _ in 0..29 {
        t.step().unwrap();
    }
    let at_29 = t.state.params.download().unwrap();
    let opacity = |p: &GaussianParams, i: usize| 1.0 / (1.0 + (-p.opacity_logits[i]).exp());
    for _ in 29..60 {
        t.step().unwrap();
    }
    let end = t.state.params.download().unwrap();
    assert_eq!(end.len(), at_29.len(), "no density step in this run");
    let (w29, w60) = (
        at_29.extra_values("omega").unwrap(),
        end.extra_values("omega").unwrap(),
    );
    let mut frozen = 0;
    for i in 0..end.len() {
        // Iteration 30's selection read the model after step 29.
        if opacity(&at_29, i) <= 0.5 {
            assert_eq!(
                &w60[4 * i..4 * i + 4],
                &[0.0; 4],
                "Gaussian {i}: unmarked ω stays 0"
            );
            frozen += 1;
        } else {
            // A marked Gaussian keeps its angular velocity and goes on learning it (its
            // rotation gets no more gradient; Adam's momentum still moves it a little, as in
            // the official code, which masks the gradient only).
            assert_ne!(
                &w60[4 * i..4 * i + 4],
                &w29[4 * i..4 * i + 4],
                "Gaussian {i}: marked ω learns"
            );
        }
    }
    assert!(
        frozen > 0 && frozen < end.len(),
        "{frozen} of {} frozen",
        end.len()
    );
    ctx.check_validation().unwrap();
}
