//! The GPU training loss (L1 + SSIM, value and gradient) against the f64 reference in
//! `lpmsplat::metrics`, the reference gradient against finite differences, and the reference
//! SSIM against a plain direct 2D convolution, in both kernel layouts (segments for CPU drivers,
//! 16×16 tiles for GPUs) on any device. Validation layer on, zero errors required.

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder, TimestampPool};
use lpmsplat::metrics;
use lpmsplat::train::loss::{Loss, LossLayout, LOSS_SLOT_FLOATS};

const LAYOUTS: [LossLayout; 2] = [LossLayout::Segments, LossLayout::Tiles];
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::sync::Arc;

const NAN_BITS: u32 = 0x7FC0_0000;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// Random RGBA8 ground truth: smooth-ish colours, alpha opaque for about half the pixels.
fn random_gt(rng: &mut Pcg64, px: usize) -> Vec<u32> {
    (0..px)
        .map(|_| {
            let r: u32 = rng.gen_range(0..256);
            let g: u32 = rng.gen_range(0..256);
            let b: u32 = rng.gen_range(0..256);
            let a: u32 = if rng.gen_bool(0.5) {
                255
            } else {
                rng.gen_range(0..256)
            };
            r | (g << 8) | (b << 16) | (a << 24)
        })
        .collect()
}

/// The ground truth as the GPU sees it: rgb·a + bg·(1 − a), in f32.
fn composite(gt: &[u32], bg: [f32; 3]) -> Vec<f32> {
    let mut out = Vec::with_capacity(gt.len() * 3);
    for &p in gt {
        let a = (p >> 24) as f32 / 255.0;
        for (c, bgc) in bg.iter().enumerate() {
            let v = ((p >> (8 * c)) & 0xFF) as f32 / 255.0;
            out.push(v * a + bgc * (1.0 - a));
        }
    }
    out
}

/// A render near the ground truth (SSIM in its useful range) or unrelated to it.
fn random_render(rng: &mut Pcg64, gt: &[f32], noise: f32) -> Vec<f32> {
    gt.iter()
        .map(|&g| {
            if noise >= 1.0 {
                rng.gen_range(-0.05..1.05)
            } else {
                g + rng.gen_range(-noise..noise)
            }
        })
        .collect()
}

struct GpuResult {
    terms: [f32; 3],
    grad: Vec<f32>,
}

/// Runs the loss with poisoned outputs (a poisoned tail after the gradient, poisoned slots around
/// the one written) and checks that nothing outside the outputs was written.
#[allow(clippy::too_many_arguments)]
fn run_gpu(
    ctx: &Arc<GpuContext>,
    loss: &Loss,
    render: &[f32],
    gt_px: &[u32],
    w: u32,
    h: u32,
    bg: [f32; 3],
    ssim_weight: f32,
) -> GpuResult {
    let px = (w * h) as usize;
    // The ground truth sits after some other image's pixels, as in the trainer's shared buffer.
    let lead = 13usize;
    let mut gt_all = vec![0xFFFF_FFFFu32; lead];
    gt_all.extend_from_slice(gt_px);
    gt_all.extend(std::iter::repeat_n(0u32, 5));
    let tail = 7;
    let image = GpuBuffer::from_slice(ctx, "render", render).unwrap();
    let gt = GpuBuffer::from_slice(ctx, "gt", &gt_all).unwrap();
    let grad = GpuBuffer::<f32>::new(ctx, "grad", 3 * px + tail, BufferKind::DeviceLocal).unwrap();
    let slot = 2u32;
    let loss_out =
        GpuBuffer::<f32>::new(ctx, "loss", 4 * LOSS_SLOT_FLOATS, BufferKind::DeviceLocal).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    rec.fill(&grad, NAN_BITS);
    rec.fill(&loss_out, NAN_BITS);
    loss.record(
        &mut rec,
        &image,
        &gt,
        lead as u32,
        w,
        h,
        bg,
        &grad,
        &loss_out,
        slot,
        ssim_weight,
    )
    .unwrap();
    rec.submit_and_wait().unwrap();
    let g = grad.read().unwrap();
    assert!(
        g[3 * px..].iter().all(|v| v.to_bits() == NAN_BITS),
        "wrote past the gradient"
    );
    let l = loss_out.read().unwrap();
    for (i, v) in l.iter().enumerate() {
        let ours = i / LOSS_SLOT_FLOATS == slot as usize;
        assert_eq!(v.to_bits() == NAN_BITS, !ours, "loss slot element {i}: {v}");
    }
    let s = slot as usize * LOSS_SLOT_FLOATS;
    GpuResult {
        terms: [l[s], l[s + 1], l[s + 2]],
        grad: g[..3 * px].to_vec(),
    }
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-12)
}

#[test]
fn gpu_loss_and_gradient_match_f64_reference() {
    let ctx = ctx();
    for layout in LAYOUTS {
        loss_matches_reference(&ctx, layout);
    }
    ctx.check_validation().unwrap();
}

fn loss_matches_reference(ctx: &Arc<GpuContext>, layout: LossLayout) {
    let ctx = ctx.clone();
    let mut rng = Pcg64::seed_from_u64(7);
    // Start small so that ensure_size has to grow the scratch buffers.
    let mut loss = Loss::with_layout(&ctx, 8, 8, layout).unwrap();
    assert_eq!(loss.layout(), layout);
    // Sizes on both sides of the tiles' 16 pixels and the segments' 16 × 32.
    let sizes = [(1u32, 1u32), (7, 5), (37, 23), (64, 64), (161, 243)];
    let random_bg = [rng.gen(), rng.gen(), rng.gen()];
    let backgrounds = [[0.0f32; 3], [1.0; 3], random_bg];
    for (si, &(w, h)) in sizes.iter().enumerate() {
        loss.ensure_size(&ctx, w, h).unwrap();
        for (bi, &bg) in backgrounds.iter().enumerate() {
            let px = (w * h) as usize;
            let gt_px = random_gt(&mut rng, px);
            let gt = composite(&gt_px, bg);
            let noise = [0.05f32, 0.3, 2.0][(si + bi) % 3];
            let render = random_render(&mut rng, &gt, noise);
            let weight = if bi == 2 { 0.35 } else { 0.2 };
            let (terms, rgrad) =
                metrics::loss_terms_and_grad(&render, &gt, w as usize, h as usize, weight as f64)
                    .unwrap();
            let out = run_gpu(&ctx, &loss, &render, &gt_px, w, h, bg, weight);
            let what = format!("{layout:?} {w}x{h} bg {bg:?} noise {noise}");
            let [l1, ssim, total] = out.terms.map(|v| v as f64);
            assert!(rel(l1, terms.l1) < 1e-4, "{what}: L1 {l1} vs {}", terms.l1);
            // SSIM can be near 0 for unrelated images: compare on the scale of the loss.
            assert!(
                (ssim - terms.ssim).abs() < 1e-4 * terms.ssim.abs().max(0.1),
                "{what}: SSIM {ssim} vs {}",
                terms.ssim
            );
            assert!(
                rel(total, terms.total) < 1e-4,
                "{what}: total {total} vs {}",
                terms.total
            );
            let scale = rgrad.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut worst = 0.0f64;
            for (i, (&g, &r)) in out.grad.iter().zip(&rgrad).enumerate() {
                assert!(g.is_finite(), "{what}: gradient {i} is {g}");
                let e = (g as f64 - r).abs() / scale;
                worst = worst.max(e);
                assert!(e < 2e-4, "{what}: gradient {i}: {g} vs {r} (scale {scale})");
            }
            eprintln!(
                "{what}: loss {total:.6} ssim {ssim:.6}, worst gradient error {worst:.2e} of max"
            );
        }
    }
}

#[test]
fn gpu_loss_is_deterministic_and_zero_gradient_at_the_optimum() {
    let ctx = ctx();
    for layout in LAYOUTS {
        deterministic_with_zero_gradient_at_optimum(&ctx, layout);
    }
    ctx.check_validation().unwrap();
}

fn deterministic_with_zero_gradient_at_optimum(ctx: &Arc<GpuContext>, layout: LossLayout) {
    let ctx = ctx.clone();
    let mut rng = Pcg64::seed_from_u64(8);
    let (w, h) = (45u32, 30u32);
    let loss = Loss::with_layout(&ctx, w, h, layout).unwrap();
    let gt_px: Vec<u32> = random_gt(&mut rng, (w * h) as usize);
    let bg = [0.3, 0.6, 0.9];
    let gt = composite(&gt_px, bg);
    let render = random_render(&mut rng, &gt, 0.2);
    let a = run_gpu(&ctx, &loss, &render, &gt_px, w, h, bg, 0.2);
    let b = run_gpu(&ctx, &loss, &render, &gt_px, w, h, bg, 0.2);
    assert_eq!(a.terms.map(f32::to_bits), b.terms.map(f32::to_bits));
    assert!(a
        .grad
        .iter()
        .zip(&b.grad)
        .all(|(x, y)| x.to_bits() == y.to_bits()));

    // Render == composited ground truth: L1 = 0, SSIM = 1 and the gradient vanishes (SSIM is at
    // its maximum, and L1's subgradient is 0 within metrics::L1_TIE of a match). Half the values
    // are one ulp off the host's composite, as another device's rounding of the composite would
    // leave them (an H100 fuses the multiply-add: L1 = 1.9e-8 there against the host's): still
    // a tie, on every device.
    let nudged: Vec<f32> = gt
        .iter()
        .enumerate()
        .map(|(i, &v)| match i % 4 {
            1 => f32::from_bits(v.to_bits() + 1),
            3 if v > 0.0 => f32::from_bits(v.to_bits() - 1),
            _ => v,
        })
        .collect();
    let n = (w * h * 3) as f32;
    for (what, render) in [("exact", &gt), ("one ulp off", &nudged)] {
        let same = run_gpu(&ctx, &loss, render, &gt_px, w, h, bg, 0.2);
        assert!(same.terms[0].abs() < 1e-6, "{what}: L1 {}", same.terms[0]);
        assert!(
            (same.terms[1] - 1.0).abs() < 1e-5,
            "{what}: SSIM {}",
            same.terms[1]
        );
        assert!(same.terms[2].abs() < 1e-5, "{what}: loss {}", same.terms[2]);
        let worst = same.grad.iter().fold(0.0f32, |m, g| m.max(g.abs() * n));
        assert!(worst < 1e-3, "{what}: gradient at the optimum {worst} / N");
    }
    // Just outside the band L1 speaks again: ±(1 − w) / N from the values moved by 4e-6.
    let moved: Vec<f32> = gt
        .iter()
        .enumerate()
        .map(|(i, &v)| if i % 2 == 0 { v + 4e-6 } else { v })
        .collect();
    let off = run_gpu(&ctx, &loss, &moved, &gt_px, w, h, bg, 0.2);
    for (i, g) in off.grad.iter().enumerate().step_by(2) {
        assert!(
            (g * n - 0.8).abs() < 1e-2,
            "{layout:?}: value {i}, 4e-6 above the ground truth: gradient {} / N",
            g * n
        );
    }
}

#[test]
fn gpu_loss_refuses_bad_arguments() {
    let ctx = ctx();
    let loss = Loss::new(&ctx, 16, 16).unwrap();
    let image =
        GpuBuffer::<f32>::new(&ctx, "render", 16 * 16 * 3, BufferKind::DeviceLocal).unwrap();
    let gt = GpuBuffer::<u32>::new(&ctx, "gt", 16 * 16, BufferKind::DeviceLocal).unwrap();
    let grad = GpuBuffer::<f32>::new(&ctx, "grad", 16 * 16 * 3, BufferKind::DeviceLocal).unwrap();
    let out = GpuBuffer::<f32>::new(&ctx, "loss", 3, BufferKind::DeviceLocal).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let mut call = |w: u32, h: u32, off: u32, slot: u32, weight: f32| {
        loss.record(
            &mut rec, &image, &gt, off, w, h, [0.0; 3], &grad, &out, slot, weight,
        )
    };
    assert!(call(17, 4, 0, 0, 0.2).is_err(), "larger than the scratch");
    assert!(call(0, 4, 0, 0, 0.2).is_err(), "empty image");
    assert!(
        call(16, 16, 1, 0, 0.2).is_err(),
        "ground truth out of range"
    );
    assert!(call(16, 16, 0, 1, 0.2).is_err(), "loss slot out of range");
    assert!(call(16, 16, 0, 0, 1.5).is_err(), "bad weight");
    let small = GpuBuffer::<f32>::new(&ctx, "small", 10, BufferKind::DeviceLocal).unwrap();
    assert!(loss
        .record(&mut rec, &small, &gt, 0, 4, 4, [0.0; 3], &grad, &out, 0, 0.2)
        .is_err());
    assert!(loss
        .record(&mut rec, &image, &gt, 0, 4, 4, [0.0; 3], &small, &out, 0, 0.2)
        .is_err());
    drop(rec);
    ctx.check_validation().unwrap();
}

/// Time of the loss at the size of a downscaled training view; printed, not asserted (the
/// machine is shared).
#[test]
fn gpu_loss_timing() {
    let ctx = ctx();
    for layout in LAYOUTS {
        time_loss(&ctx, layout);
    }
    ctx.check_validation().unwrap();
}

fn time_loss(ctx: &Arc<GpuContext>, layout: LossLayout) {
    let ctx = ctx.clone();
    let mut rng = Pcg64::seed_from_u64(9);
    let (w, h) = (162u32, 242u32);
    let px = (w * h) as usize;
    let loss = Loss::with_layout(&ctx, w, h, layout).unwrap();
    let gt_px = random_gt(&mut rng, px);
    let gt_img = composite(&gt_px, [0.0; 3]);
    let render = random_render(&mut rng, &gt_img, 0.1);
    let image = GpuBuffer::from_slice(&ctx, "render", &render).unwrap();
    let gt = GpuBuffer::from_slice(&ctx, "gt", &gt_px).unwrap();
    let grad = GpuBuffer::<f32>::new(&ctx, "grad", 3 * px, BufferKind::DeviceLocal).unwrap();
    let reps = 30u32;
    let out =
        GpuBuffer::<f32>::new(&ctx, "loss", 3 * reps as usize, BufferKind::DeviceLocal).unwrap();
    let mut pool = TimestampPool::new(&ctx, 4).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let record = |rec: &mut Recorder, slot: u32| {
        let args = (&image, &gt, &grad, &out);
        loss.record(
            rec, args.0, args.1, 0, w, h, [0.0; 3], args.2, args.3, slot, 0.2,
        )
        .unwrap()
    };
    // Warm-up, so first-use costs stay out of the measurement.
    record(&mut rec, 0);
    rec.submit_and_wait().unwrap();
    rec.begin().unwrap();
    let t0 = std::time::Instant::now();
    let c0 = cpu_ticks();
    rec.start_timestamps(&mut pool);
    for i in 0..reps {
        record(&mut rec, i);
    }
    rec.timestamp(&mut pool, "loss");
    rec.submit_and_wait().unwrap();
    let wall = t0.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let cpu = (cpu_ticks() - c0) as f64 * 10.0 / reps as f64;
    let gpu = pool
        .read()
        .map(|t| t.total_ms() / reps as f64)
        .unwrap_or(f64::NAN);
    let l = out.read().unwrap();
    assert!(
        l.chunks(3).all(|s| s == &l[..3]),
        "same loss bits every time"
    );
    eprintln!(
        "loss {layout:?} {w}x{h}: {wall:.2} ms wall, {gpu:.2} ms GPU, {cpu:.1} ms CPU (all driver threads) per call"
    );
}

/// User + system CPU time of this process in clock ticks (Linux; 0 elsewhere).
fn cpu_ticks() -> u64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1.to_string();
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
        })
        .unwrap_or(0)
}

/// SSIM by a direct 11×11 double loop, zero-padded, written independently of the separable one.
fn direct_ssim_map(a: &[f32], b: &[f32], w: usize, h: usize) -> Vec<f64> {
    let sigma = 1.5f64;
    let mut win = [[0.0f64; 11]; 11];
    let mut total = 0.0;
    for (i, row) in win.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            let (di, dj) = (i as f64 - 5.0, j as f64 - 5.0);
            *v = (-(di * di + dj * dj) / (2.0 * sigma * sigma)).exp();
            total += *v;
        }
    }
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut out = vec![0.0; w * h * 3];
    for c in 0..3 {
        for y in 0..h {
            for x in 0..w {
                let (mut mx, mut my, mut xx, mut yy, mut xy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for (i, row) in win.iter().enumerate() {
                    for (j, &v) in row.iter().enumerate() {
                        let (sy, sx) = (y as i64 + i as i64 - 5, x as i64 + j as i64 - 5);
                        if sy < 0 || sx < 0 || sy >= h as i64 || sx >= w as i64 {
                            continue;
                        }
                        let k = (sy as usize * w + sx as usize) * 3 + c;
                        let (p, q) = (a[k] as f64, b[k] as f64);
                        let g = v / total;
                        mx += g * p;
                        my += g * q;
                        xx += g * p * p;
                        yy += g * q * q;
                        xy += g * p * q;
                    }
                }
                let vx = xx - mx * mx;
                let vy = yy - my * my;
                let cov = xy - mx * my;
                out[(y * w + x) * 3 + c] = ((2.0 * mx * my + c1) * (2.0 * cov + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2));
            }
        }
    }
    out
}

#[test]
fn cpu_ssim_matches_direct_convolution_and_identity() {
    let mut rng = Pcg64::seed_from_u64(10);
    for &(w, h) in &[(1usize, 1usize), (3, 9), (20, 13)] {
        let a: Vec<f32> = (0..w * h * 3).map(|_| rng.gen()).collect();
        let b: Vec<f32> = a.iter().map(|v| v + rng.gen_range(-0.2..0.2)).collect();
        let sep = metrics::ssim_map(&a, &b, w, h).unwrap();
        let direct = direct_ssim_map(&a, &b, w, h);
        for (i, (s, d)) in sep.iter().zip(&direct).enumerate() {
            assert!((s - d).abs() < 1e-10, "{w}x{h} element {i}: {s} vs {d}");
        }
        let mean = direct.iter().sum::<f64>() / direct.len() as f64;
        assert!((metrics::ssim(&a, &b, w, h).unwrap() - mean).abs() < 1e-12);
        assert!((metrics::ssim(&a, &a, w, h).unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(metrics::psnr(&a, &a).unwrap(), f64::INFINITY);
        assert_eq!(metrics::l1(&a, &a).unwrap(), 0.0);
        assert!(metrics::psnr(&a, &b).unwrap().is_finite());
    }
}

#[test]
fn cpu_gradient_matches_finite_differences() {
    let mut rng = Pcg64::seed_from_u64(12);
    for &(w, h, weight, noise) in &[
        (7usize, 5usize, 0.2f64, 0.1f32),
        (13, 11, 1.0, 0.3),
        (1, 1, 0.2, 0.2),
        (16, 3, 0.5, 2.0),
    ] {
        let gt: Vec<f32> = (0..w * h * 3).map(|_| rng.gen()).collect();
        let render = random_render(&mut rng, &gt, noise);
        let (_, grad) = metrics::loss_and_grad(&render, &gt, w, h, weight).unwrap();
        let scale = grad.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let step = 1e-3f32;
        let mut checked = 0;
        for i in 0..render.len() {
            // Keep the L1 kink out of the difference quotient.
            if (render[i] - gt[i]).abs() < 2.0 * step {
                continue;
            }
            let mut p = render.clone();
            let mut m = render.clone();
            p[i] += step;
            m[i] -= step;
            let lp = metrics::loss_and_grad(&p, &gt, w, h, weight).unwrap().0;
            let lm = metrics::loss_and_grad(&m, &gt, w, h, weight).unwrap().0;
            let fd = (lp - lm) / (p[i] as f64 - m[i] as f64);
            let g = grad[i];
            if g.abs() > 1e-3 * scale {
                assert!(
                    rel(g, fd) < 1e-2,
                    "{w}x{h} w {weight}: element {i}: analytic {g} vs fd {fd}"
                );
            } else {
                assert!((g - fd).abs() < 1e-4 * scale, "{w}x{h}: element {i}");
            }
            checked += 1;
        }
        assert!(checked > render.len() / 2, "too few elements checked");
    }
}

/// The loss mask pass (`glsl/train/mask_grads.comp`) against its oracle
/// (`reference::loss_mask`): random gradients and cells at image sizes on both sides of a cell
/// and of a workgroup, grids finer and coarser than the image, a masked view after an unmasked
/// one in the same buffer; the tail past the gradient poisoned and left alone.
#[test]
fn loss_mask_zeroes_exactly_the_unlearned_cells_pixels() {
    use lpmsplat::reference::loss_mask::mask_gradient;
    use lpmsplat::scene::loss_masks::LossMasks;
    use lpmsplat::train::loss_mask::GpuLossMasks;
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(11);
    for &(w, h, cols, rows) in &[
        (1u32, 1u32, 1u32, 1u32),
        (7, 5, 3, 2),
        (37, 23, 32, 32),
        (161, 243, 5, 40),
        (20, 9, 40, 17),
    ] {
        let cells = (cols * rows) as usize;
        let mask: Vec<bool> = (0..cells).map(|_| rng.gen_bool(0.5)).collect();
        // View 0 unmasked, view 1 masked (its bits after nothing), view 2 masked differently.
        let other: Vec<bool> = mask.iter().map(|b| !b).collect();
        let masks = LossMasks {
            cols,
            rows,
            views: vec![None, Some(mask.clone()), Some(other.clone())],
        };
        let gpu = GpuLossMasks::new(&ctx, &masks).unwrap();
        let px = (w * h) as usize;
        let grad: Vec<f32> = (0..3 * px).map(|_| rng.gen_range(-1.0..1.0)).collect();
        for (view, cells_of) in [(0usize, None), (1, Some(&mask)), (2, Some(&other))] {
            let mut data = grad.clone();
            data.extend([f32::from_bits(NAN_BITS); 5]);
            let buf = GpuBuffer::from_slice(&ctx, "grad", &data).unwrap();
            let mut rec = Recorder::new(&ctx).unwrap();
            gpu.record(&mut rec, view, w, h, &buf).unwrap();
            rec.submit_and_wait().unwrap();
            let got = buf.read().unwrap();
            assert!(got[3 * px..].iter().all(|v| v.to_bits() == NAN_BITS));
            let g64: Vec<f64> = grad.iter().map(|&v| v as f64).collect();
            let want = match cells_of {
                Some(c) => mask_gradient(&g64, w, h, c, cols, rows),
                None => g64,
            };
            for (i, (a, b)) in got[..3 * px].iter().zip(&want).enumerate() {
                assert_eq!(
                    *a as f64, *b,
                    "{w}×{h}, {cols}×{rows}, view {view}, float {i}"
                );
            }
        }
    }
    ctx.check_validation().unwrap();
}
