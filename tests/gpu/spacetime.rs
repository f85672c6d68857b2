//! SpacetimeGaussians' temporal step on the GPU (`render::spacetime`) against the f64 reference
//! (`reference::spacetime`): forward and backward on random Gaussians with extremes mixed in
//! (opacity logits to ±60, Gaussians far outside their time, tiny and huge temporal scales),
//! outputs poisoned with NaN first, the accumulating backward, and the size checks.

use std::sync::Arc;

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::spacetime::{instant, instant_backward, Instant, Temporal};
use lpmsplat::render::spacetime::{At, InstantBuffers, TemporalBuffers, TemporalStep};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// Random parameters, already rounded to f32 (so both sides see the same numbers).
fn random_params(rng: &mut Pcg64, n: usize) -> Vec<Temporal> {
    (0..n)
        .map(|i| {
            let mut r = |a: f32, b: f32| rng.gen_range(a..b) as f64;
            let mut p = Temporal {
                position: [r(-3.0, 3.0), r(-3.0, 3.0), r(-3.0, 3.0)],
                motion: [0; 9].map(|_| r(-2.0, 2.0)),
                rotation: [r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0)],
                omega: [0; 4].map(|_| r(-1.0, 1.0)),
                opacity_logit: r(-6.0, 6.0),
                t_center: r(0.0, 1.0),
                t_log_scale: r(-3.0, 1.0),
            };
            match i % 7 {
                1 => p.opacity_logit = r(-60.0, 60.0),
                2 => p.t_log_scale = r(-9.0, -5.0), // u up to ~8000: invisible, logit −6e7
                3 => p.t_log_scale = r(2.0, 6.0),   // nearly constant in time
                4 => p.t_center = r(-2.0, 3.0),     // centred outside the segment
                _ => {}
            }
            p
        })
        .collect()
}

struct Host {
    positions: Vec<f32>,
    motion: Vec<f32>,
    rotations: Vec<f32>,
    omega: Vec<f32>,
    opacity_logits: Vec<f32>,
    t_center: Vec<f32>,
    t_log_scale: Vec<f32>,
}

fn flatten(ps: &[Temporal]) -> Host {
    let f = |v: f64| v as f32;
    Host {
        positions: ps.iter().flat_map(|p| p.position.map(f)).collect(),
        motion: ps.iter().flat_map(|p| p.motion.map(f)).collect(),
        rotations: ps.iter().flat_map(|p| p.rotation.map(f)).collect(),
        omega: ps.iter().flat_map(|p| p.omega.map(f)).collect(),
        opacity_logits: ps.iter().map(|p| f(p.opacity_logit)).collect(),
        t_center: ps.iter().map(|p| f(p.t_center)).collect(),
        t_log_scale: ps.iter().map(|p| f(p.t_log_scale)).collect(),
    }
}

struct Device {
    positions: GpuBuffer<f32>,
    motion: GpuBuffer<f32>,
    rotations: GpuBuffer<f32>,
    omega: GpuBuffer<f32>,
    opacity_logits: GpuBuffer<f32>,
    t_center: GpuBuffer<f32>,
    t_log_scale: GpuBuffer<f32>,
}

impl Device {
    fn upload(ctx: &Arc<GpuContext>, h: &Host) -> Device {
        let b = |name: &str, v: &[f32]| GpuBuffer::from_slice(ctx, name, v).unwrap();
        Device {
            positions: b("positions", &h.positions),
            motion: b("motion", &h.motion),
            rotations: b("rotations", &h.rotations),
            omega: b("omega", &h.omega),
            opacity_logits: b("opacity", &h.opacity_logits),
            t_center: b("t_center", &h.t_center),
            t_log_scale: b("t_log_scale", &h.t_log_scale),
        }
    }
    fn buffers(&self) -> TemporalBuffers<'_> {
        TemporalBuffers {
            positions: &self.positions,
            motion: &self.motion,
            rotations: &self.rotations,
            omega: &self.omega,
            opacity_logits: &self.opacity_logits,
            t_center: &self.t_center,
            t_log_scale: &self.t_log_scale,
        }
    }
    fn poison(&self) {
        for b in [
            &self.positions,
            &self.motion,
            &self.rotations,
            &self.omega,
            &self.opacity_logits,
            &self.t_center,
            &self.t_log_scale,
        ] {
            b.upload(&vec![f32::NAN; b.len()]).unwrap();
        }
    }
}

fn assert_close(what: &str, i: usize, got: f32, want: f64, scale: f64) {
    let tol = 2e-5 * (want.abs() + scale);
    assert!(
        (got as f64 - want).abs() <= tol,
        "{what} of Gaussian {i}: GPU {got} vs reference {want} (tolerance {tol:.2e})"
    );
}

#[test]
fn temporal_step_matches_the_reference() {
    let ctx = ctx();
    let step = TemporalStep::new(&ctx).unwrap();
    let mut rng = Pcg64::seed_from_u64(0x57D5);
    let n = 5_000;
    let params = random_params(&mut rng, n);
    let host = flatten(&params);
    let dev = Device::upload(&ctx, &host);
    let out_p =
        GpuBuffer::<f32>::from_slice(&ctx, "out positions", &vec![f32::NAN; 3 * n]).unwrap();
    let out_r =
        GpuBuffer::<f32>::from_slice(&ctx, "out rotations", &vec![f32::NAN; 4 * n]).unwrap();
    let out_o = GpuBuffer::<f32>::from_slice(&ctx, "out opacity", &vec![f32::NAN; n]).unwrap();
    let grads = Device::upload(&ctx, &host);
    for t in [0.0f32, 0.37, 0.98] {
        let out = InstantBuffers {
            positions: &out_p,
            rotations: &out_r,
            opacity_logits: &out_o,
        };
        let mut rec = Recorder::new(&ctx).unwrap();
        step.record_forward(&mut rec, &dev.buffers(), &out, At { count: n, t })
            .unwrap();
        rec.submit_and_wait().unwrap();
        let (gp, gr, go) = (
            out_p.read().unwrap(),
            out_r.read().unwrap(),
            out_o.read().unwrap(),
        );
        for (i, p) in params.iter().enumerate() {
            let want = instant(p, t as f64);
            let scale = p
                .position
                .iter()
                .chain(&p.motion)
                .fold(0.0f64, |a, v| a.max(v.abs()));
            for k in 0..3 {
                assert_close("position", i, gp[3 * i + k], want.position[k], scale);
            }
            for k in 0..4 {
                assert_close("rotation", i, gr[4 * i + k], want.rotation[k], 1.0);
            }
            assert_close("opacity logit", i, go[i], want.opacity_logit, 1.0);
        }

        // Backward from random still-Gaussian gradients, into poisoned buffers.
        let d: Vec<Instant> = (0..n)
            .map(|_| {
                let mut r = || rng.gen_range(-1.0f32..1.0) as f64;
                Instant {
                    position: [r(), r(), r()],
                    rotation: [r(), r(), r(), r()],
                    opacity_logit: r(),
                }
            })
            .collect();
        let dp = GpuBuffer::from_slice(
            &ctx,
            "d positions",
            &d.iter()
                .flat_map(|x| x.position.map(|v| v as f32))
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let dr = GpuBuffer::from_slice(
            &ctx,
            "d rotations",
            &d.iter()
                .flat_map(|x| x.rotation.map(|v| v as f32))
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let dop = GpuBuffer::from_slice(
            &ctx,
            "d opacity",
            &d.iter().map(|x| x.opacity_logit as f32).collect::<Vec<_>>(),
        )
        .unwrap();
        let d_instant = InstantBuffers {
            positions: &dp,
            rotations: &dr,
            opacity_logits: &dop,
        };
        grads.poison();
        let mut rec = Recorder::new(&ctx).unwrap();
        step.record_backward(
            &mut rec,
            &dev.buffers(),
            &d_instant,
            &grads.buffers(),
            At { count: n, t },
            false,
        )
        .unwrap();
        rec.barrier();
        // A second view accumulated on top doubles every gradient.
        step.record_backward(
            &mut rec,
            &dev.buffers(),
            &d_instant,
            &grads.buffers(),
            At { count: n, t },
            true,
        )
        .unwrap();
        rec.submit_and_wait().unwrap();
        let got = |b: &GpuBuffer<f32>| b.read().unwrap();
        let (gpos, gmot, grot, gom, gop, gtc, gts) = (
            got(&grads.positions),
            got(&grads.motion),
            got(&grads.rotations),
            got(&grads.omega),
            got(&grads.opacity_logits),
            got(&grads.t_center),
            got(&grads.t_log_scale),
        );
        for (i, p) in params.iter().enumerate() {
            let w = instant_backward(p, t as f64, &d[i]);
            let two = |x: f64| 2.0 * x;
            for k in 0..3 {
                assert_close("d position", i, gpos[3 * i + k], two(w.position[k]), 1.0);
            }
            for k in 0..9 {
                assert_close("d motion", i, gmot[9 * i + k], two(w.motion[k]), 1.0);
            }
            for k in 0..4 {
                assert_close("d rotation", i, grot[4 * i + k], two(w.rotation[k]), 1.0);
                assert_close("d omega", i, gom[4 * i + k], two(w.omega[k]), 1.0);
            }
            let s = w
                .opacity_logit
                .abs()
                .max(w.t_center.abs())
                .max(w.t_log_scale.abs())
                .max(1.0);
            assert_close("d opacity logit", i, gop[i], two(w.opacity_logit), s);
            assert_close("d temporal centre", i, gtc[i], two(w.t_center), s);
            assert_close("d temporal log-scale", i, gts[i], two(w.t_log_scale), s);
        }
    }
    // Too small an output is refused, naming it.
    let short = GpuBuffer::<f32>::from_slice(&ctx, "short", &[0.0; 10]).unwrap();
    let out = InstantBuffers {
        positions: &short,
        rotations: &out_r,
        opacity_logits: &out_o,
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = step
        .record_forward(&mut rec, &dev.buffers(), &out, At { count: n, t: 0.5 })
        .unwrap_err()
        .to_string();
    assert!(e.contains("output positions") && e.contains("15000"), "{e}");
    ctx.check_validation().unwrap();
}

/// LPM in time: the centres at the frame's time, NaN for Gaussians whose temporal weight there
/// is below the presence weight; cases within a hair of the weight are skipped (f32 vs f64).
#[test]
fn frame_positions_match_the_reference() {
    use lpmsplat::reference::spacetime::{frame_position, temporal_weight, PRESENT_MIN_WEIGHT};
    let ctx = ctx();
    let step = TemporalStep::new(&ctx).unwrap();
    let mut rng = Pcg64::seed_from_u64(0xF7A3);
    let n = 4_000;
    let params = random_params(&mut rng, n);
    let dev = Device::upload(&ctx, &flatten(&params));
    let out = GpuBuffer::<f32>::from_slice(&ctx, "frame positions", &vec![7.0; 3 * n]).unwrap();
    for t in [0.0f32, 0.5, 0.93] {
        out.upload(&vec![7.0; 3 * n]).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        step.record_positions(
            &mut rec,
            &dev.buffers(),
            &out,
            At { count: n, t },
            PRESENT_MIN_WEIGHT,
        )
        .unwrap();
        rec.submit_and_wait().unwrap();
        let got = out.read().unwrap();
        let (mut present, mut absent) = (0, 0);
        for (i, p) in params.iter().enumerate() {
            let w = temporal_weight(p, t as f64);
            if (w / PRESENT_MIN_WEIGHT - 1.0).abs() < 1e-4 {
                continue;
            }
            let g = &got[3 * i..3 * i + 3];
            match frame_position(p, t as f64, PRESENT_MIN_WEIGHT) {
                Some(want) => {
                    present += 1;
                    let scale = p
                        .position
                        .iter()
                        .chain(&p.motion)
                        .fold(0.0f64, |a, v| a.max(v.abs()));
                    for k in 0..3 {
                        assert_close("frame position", i, g[k], want[k], scale);
                    }
                }
                None => {
                    absent += 1;
                    assert!(
                        g.iter().all(|v| v.is_nan()),
                        "Gaussian {i} (weight {w}): {g:?}"
                    );
                }
            }
        }
        // The random set exercises both sides at every time.
        assert!(
            present > n / 10 && absent > n / 10,
            "t {t}: {present} present, {absent} absent"
        );
    }
    // The presence weight must be a weight.
    let mut rec = Recorder::new(&ctx).unwrap();
    let e = step
        .record_positions(&mut rec, &dev.buffers(), &out, At { count: n, t: 0.5 }, 0.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("presence weight"), "{e}");
    let small = GpuBuffer::<f32>::from_slice(&ctx, "small", &[0.0; 6]).unwrap();
    let e = step
        .record_positions(
            &mut rec,
            &dev.buffers(),
            &small,
            At { count: n, t: 0.5 },
            0.05,
        )
        .unwrap_err()
        .to_string();
    assert!(e.contains("need"), "{e}");
}
