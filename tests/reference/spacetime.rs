//! SpacetimeGaussians' temporal step in the f64 reference: its opacity logit against the
//! plain product σ(o)·g, its gradients against central differences (with Δ held fixed in the
//! motion and rotation for the temporal centre, as the official computation detaches it), and
//! finiteness at the extremes.

use lpmsplat::reference::spacetime::{
    instant, instant_backward, instant_detached, temporal_weight, Instant, Temporal,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// A parameter of a copy, to perturb.
type Field = Box<dyn Fn(&mut Temporal) -> &mut f64>;

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

fn random_temporal(rng: &mut Pcg64) -> Temporal {
    let mut r = |a: f64, b: f64| rng.gen_range(a..b);
    Temporal {
        position: [r(-2.0, 2.0), r(-2.0, 2.0), r(-2.0, 2.0)],
        motion: [0; 9].map(|_| r(-1.5, 1.5)),
        rotation: [r(0.2, 1.0), r(-0.5, 0.5), r(-0.5, 0.5), r(-0.5, 0.5)],
        omega: [0; 4].map(|_| r(-1.0, 1.0)),
        opacity_logit: r(-4.0, 4.0),
        t_center: r(0.0, 1.0),
        t_log_scale: r(-2.5, 0.5),
    }
}

/// A random linear loss of the instant's outputs.
fn random_weights(rng: &mut Pcg64) -> Instant {
    let mut r = || rng.gen_range(-1.0..1.0);
    Instant {
        position: [r(), r(), r()],
        rotation: [r(), r(), r(), r()],
        opacity_logit: r(),
    }
}

fn loss(i: &Instant, w: &Instant) -> f64 {
    (0..3).map(|k| i.position[k] * w.position[k]).sum::<f64>()
        + (0..4).map(|k| i.rotation[k] * w.rotation[k]).sum::<f64>()
        + i.opacity_logit * w.opacity_logit
}

#[test]
fn the_opacity_logit_is_the_logit_of_the_product() {
    let mut rng = Pcg64::seed_from_u64(3);
    for _ in 0..2000 {
        let mut p = random_temporal(&mut rng);
        p.opacity_logit = rng.gen_range(-30.0..30.0);
        p.t_log_scale = rng.gen_range(-6.0..2.0);
        let t = rng.gen_range(0.0..1.0);
        let want = sigmoid(p.opacity_logit) * temporal_weight(&p, t);
        let got = sigmoid(instant(&p, t).opacity_logit);
        assert!(
            (got - want).abs() <= 1e-12 * want.max(1e-300),
            "{p:?} t={t}: {got} vs {want}"
        );
    }
}

#[test]
fn gradients_match_central_differences() {
    let mut rng = Pcg64::seed_from_u64(11);
    let h = 1e-6;
    let mut worst: f64 = 0.0;
    for case in 0..300 {
        let p = random_temporal(&mut rng);
        let t = rng.gen_range(0.0..1.0);
        let w = random_weights(&mut rng);
        let g = instant_backward(&p, t, &w);
        let delta = t - p.t_center;
        // Every parameter as (getter into a copy, analytic gradient).
        let mut checks: Vec<(Field, f64)> = Vec::new();
        for k in 0..3 {
            checks.push((
                Box::new(move |q: &mut Temporal| &mut q.position[k]),
                g.position[k],
            ));
        }
        for k in 0..9 {
            checks.push((
                Box::new(move |q: &mut Temporal| &mut q.motion[k]),
                g.motion[k],
            ));
        }
        for k in 0..4 {
            checks.push((
                Box::new(move |q: &mut Temporal| &mut q.rotation[k]),
                g.rotation[k],
            ));
            checks.push((
                Box::new(move |q: &mut Temporal| &mut q.omega[k]),
                g.omega[k],
            ));
        }
        checks.push((
            Box::new(|q: &mut Temporal| &mut q.opacity_logit),
            g.opacity_logit,
        ));
        checks.push((Box::new(|q: &mut Temporal| &mut q.t_center), g.t_center));
        checks.push((
            Box::new(|q: &mut Temporal| &mut q.t_log_scale),
            g.t_log_scale,
        ));
        let scale = checks.iter().map(|c| c.1.abs()).fold(1e-3, f64::max);
        for (n, (get, analytic)) in checks.iter().enumerate() {
            let eval = |s: f64| {
                let mut q = p;
                *get(&mut q) += s;
                // Δ in the motion and rotation stays the unperturbed one.
                loss(&instant_detached(&q, t, delta), &w)
            };
            let fd = (eval(h) - eval(-h)) / (2.0 * h);
            let err = (fd - analytic).abs() / (analytic.abs() + 1e-3 * scale);
            worst = worst.max(err);
            assert!(
                err < 1e-6,
                "case {case} parameter {n}: fd {fd} vs {analytic}"
            );
        }
    }
    eprintln!("worst relative error {worst:.2e}");
}

#[test]
fn the_temporal_centre_learns_only_through_the_opacity() {
    let mut rng = Pcg64::seed_from_u64(5);
    let p = random_temporal(&mut rng);
    let w = Instant {
        position: [1.0, -2.0, 0.5],
        rotation: [0.3, 0.1, -0.7, 0.2],
        opacity_logit: 0.0,
    };
    let g = instant_backward(&p, 0.4, &w);
    assert_eq!(g.t_center, 0.0);
    assert_eq!(g.t_log_scale, 0.0);
    assert!(g.motion.iter().all(|&m| m != 0.0));
}

#[test]
fn extremes_stay_finite() {
    let base = Temporal {
        position: [0.0; 3],
        motion: [1.0; 9],
        rotation: [1.0, 0.0, 0.0, 0.0],
        omega: [0.5; 4],
        opacity_logit: 0.0,
        t_center: 0.5,
        t_log_scale: 0.0,
    };
    let w = Instant {
        position: [1.0; 3],
        rotation: [1.0; 4],
        opacity_logit: 1.0,
    };
    for o in [-80.0, -30.0, 0.0, 17.0, 40.0, 80.0, 100.0, 400.0] {
        for s in [-40.0, -10.0, 0.0, 10.0, 40.0] {
            for t in [0.0, 0.5, 0.5 + 1e-9, 1.0] {
                let p = Temporal {
                    opacity_logit: o,
                    t_log_scale: s,
                    ..base
                };
                let i = instant(&p, t);
                let g = instant_backward(&p, t, &w);
                let all = [i.opacity_logit, g.opacity_logit, g.t_center, g.t_log_scale];
                // A Gaussian 0.5 from its centre at s = −40 has u² ≈ 1e34: its logit is −1e34
                // (opacity exactly 0) and its centre/scale gradients huge but finite.
                assert!(
                    all.iter().all(|v| v.is_finite()),
                    "o={o} s={s} t={t}: {all:?}"
                );
                if t == 0.5 {
                    // At the temporal centre the opacity is the base opacity.
                    assert!(
                        (sigmoid(i.opacity_logit) - sigmoid(o)).abs() < 1e-15,
                        "o={o}"
                    );
                }
            }
        }
    }
}
