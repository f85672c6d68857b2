//! SpacetimeGaussians' full model on the GPU against the f64 reference
//! (`reference::decoder`): the feature channels the rasterizer blends beside a raw (unclamped,
//! view-independent) base colour, their backward (features' and geometry's gradients), and the
//! per-pixel decoder forward and backward with its weight reduction; the reference decoder
//! against finite differences. Outputs poisoned with NaN first; validation layer on.
#![allow(clippy::needless_range_loop)]

use std::sync::Arc;

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::backward::{preprocess_backward, rasterize_backward, ProjectedGrads};
use lpmsplat::reference::decoder::{self, FEATURE_CHANNELS, INPUTS, WEIGHTS};
use lpmsplat::reference::raster::rasterize;
use lpmsplat::reference::{self, scenes, RefGaussians, RenderSettings};
use lpmsplat::render::backward::{Backward, BackwardArgs, FeatureGrads};
use lpmsplat::render::decoder::{Decoder, DecoderFrame};
use lpmsplat::render::forward::{Capacity, FeatureChannels, FrameSettings, Renderer};
use lpmsplat::render::layout::{CameraGpu, RenderConstants};
use lpmsplat::scene::{PinholeCamera, Pose};
use lpmsplat::splats::gpu::GpuSplats;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

const NAN_BITS: u32 = 0x7FC0_0000;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// `|g − r| ≤ rel·|r| + floor·max|r|`, and every value finite.
fn compare(what: &str, gpu: &[f32], want: &[f64], rel: f64, floor: f64) {
    assert_eq!(gpu.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, (&g, &r)) in gpu.iter().zip(want).enumerate() {
        assert!(g.is_finite(), "{what}[{i}] = {g} (reference {r})");
        let err = (g as f64 - r).abs();
        let tol = rel * r.abs() + floor * scale;
        assert!(
            err <= tol,
            "{what}[{i}]: GPU {g:e} vs reference {r:e} (error {err:e}, tolerance {tol:e}, max {scale:e})"
        );
    }
}

/// A random scene with DC coefficients spanning negative values (raw features are not clamped)
/// and `FEATURE_CHANNELS` random features per Gaussian, rounded to f32.
fn scene(seed: u64, n: usize, w: u32, h: u32) -> (RefGaussians, Vec<f64>, PinholeCamera, Pose) {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut g = scenes::random_gaussians(&mut rng, n);
    for sh in g.sh.iter_mut() {
        sh[0] = [0; 3].map(|_| rng.gen_range(-1.5..1.5f32) as f64);
    }
    let g = RefGaussians::from_params(&g.to_params(0));
    let features = (0..n * FEATURE_CHANNELS)
        .map(|_| rng.gen_range(-2.0..2.0f32) as f64)
        .collect();
    let (camera, pose) = scenes::random_view(&mut rng, w, h);
    (g, features, camera, pose)
}

/// The reference frame of the full model's rasterizer: the 3DGS preprocess and bins with the
/// colour replaced by the raw DC values (`out.projected`), blended over `background`
/// (`out.raster`), and the feature image (`[pix·FEATURE_CHANNELS + c]`).
fn raw_reference_frame(
    g: &RefGaussians,
    features: &[f64],
    camera: &PinholeCamera,
    pose: &Pose,
    background: [f64; 3],
    settings: &RenderSettings,
) -> (reference::RenderOutput, Vec<f64>) {
    let mut out = reference::render(g, camera, pose, 0, background, settings).unwrap();
    for (p, sh) in out.projected.iter_mut().zip(&g.sh) {
        p.rgb = sh[0];
        p.rgb_clamped = [false; 3];
    }
    out.raster = rasterize(&out.projected, &out.bins, camera, background, settings).unwrap();
    let feature_image = decoder::rasterize_features(
        &out.projected,
        &out.bins,
        camera,
        features,
        FEATURE_CHANNELS,
        settings,
    )
    .unwrap();
    (out, feature_image)
}

/// The scene on the GPU: its splats, the camera (index 1, behind a decoy at 0) and the
/// feature channels.
fn upload_frame(
    ctx: &Arc<GpuContext>,
    g: &RefGaussians,
    features: &[f64],
    camera: &PinholeCamera,
    pose: &Pose,
) -> (GpuSplats, CameraGpu, GpuBuffer<CameraGpu>, GpuBuffer<f32>) {
    let splats = GpuSplats::upload(ctx, &g.to_params(0), g.len()).unwrap();
    let cam = CameraGpu::new(camera, pose);
    let mut decoy = cam;
    decoy.r0[3] += 1.0;
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[decoy, cam]).unwrap();
    let f32s: Vec<f32> = features.iter().map(|&x| x as f32).collect();
    let feats = GpuBuffer::from_slice(ctx, "features", &f32s).unwrap();
    (splats, cam, cameras, feats)
}

#[test]
fn feature_channels_and_raw_colour_match_the_reference_forward_and_backward() {
    let ctx = ctx();
    let settings = RenderSettings::default();
    let mut constants = RenderConstants::from_settings(&settings);
    constants.flags |= RenderConstants::RAW_COLOUR;
    for (seed, n, w, h) in [
        (1u64, 60usize, 37u32, 29u32),
        (2, 150, 50, 33),
        (3, 8, 17, 16),
    ] {
        let (g, features, camera, pose) = scene(seed, n, w, h);
        let label = format!("seed {seed}");
        let background = [0.2, 0.5, 0.9];

        // Reference: the 3DGS preprocess and bins, the colour replaced by the raw DC values.
        let (out, feature_image) =
            raw_reference_frame(&g, &features, &camera, &pose, background, &settings);
        let (projected, raster) = (&out.projected, &out.raster);

        // GPU forward (camera 1 behind a decoy).
        let (splats, cam, cameras, feats) = upload_frame(&ctx, &g, &features, &camera, &pose);
        let mut renderer = Renderer::new(
            &ctx,
            Capacity {
                gaussians: n,
                intersections: 1 << 14,
                pixels: (w * h) as usize,
                tiles: cam.tile_count() as usize,
            },
        )
        .unwrap();
        renderer
            .frame
            .image
            .upload(&vec![f32::NAN; renderer.frame.image.len()])
            .unwrap();
        let frame = FrameSettings {
            sh_degree: 0,
            background: background.map(|v| v as f32),
            constants,
            filter3d: None,
            features: Some(FeatureChannels {
                values: &feats,
                channels: FEATURE_CHANNELS as u32,
                decoded_by: None,
            }),
        };
        renderer
            .render_blocking(&splats, &cameras, 1, &cam, &frame)
            .unwrap();
        let px = (w * h) as usize;
        let image = renderer.read_image().unwrap();
        let want: Vec<f64> = raster.image.iter().flatten().copied().collect();
        compare(&format!("{label} image"), &image, &want, 1e-4, 1e-5);
        let got = renderer
            .feature_image()
            .expect("features were rendered")
            .read_range(0, px * FEATURE_CHANNELS)
            .unwrap();
        compare(
            &format!("{label} feature image"),
            &got,
            &feature_image,
            1e-4,
            1e-5,
        );

        // Backward from random image and feature-image gradients.
        let mut rng = Pcg64::seed_from_u64(seed ^ 0xBAC);
        let dl_image: Vec<[f64; 3]> = (0..px)
            .map(|_| [0; 3].map(|_| rng.gen_range(-1.0..1.0f32) as f64))
            .collect();
        let dl_features: Vec<f64> = (0..px * FEATURE_CHANNELS)
            .map(|_| rng.gen_range(-1.0..1.0f32) as f64)
            .collect();
        let colour = rasterize_backward(
            projected, &out.bins, raster, background, &settings, &dl_image,
        )
        .unwrap();
        let (geometry, want_feature_grads) = decoder::rasterize_features_backward(
            projected,
            &out.bins,
            raster,
            &features,
            FEATURE_CHANNELS,
            &settings,
            &dl_features,
        )
        .unwrap();
        // The raw colour's gradient is the DC coefficients' as it is; the rest goes through
        // the 3DGS preprocess backward with no colour gradient.
        let mut total = ProjectedGrads::zeros(n);
        for i in 0..n {
            for c in 0..2 {
                total.mean2d[i][c] = colour.mean2d[i][c] + geometry.mean2d[i][c];
            }
            for c in 0..3 {
                total.conic[i][c] = colour.conic[i][c] + geometry.conic[i][c];
            }
            total.opacity[i] = colour.opacity[i] + geometry.opacity[i];
        }
        let params_want =
            preprocess_backward(&g, projected, &camera, &pose, 0, &settings, &total).unwrap();

        let dl_buf = GpuBuffer::from_slice(
            &ctx,
            "dl_dimage",
            &dl_image
                .iter()
                .flatten()
                .map(|&v| v as f32)
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let dl_feat_buf = GpuBuffer::from_slice(
            &ctx,
            "dl_dfeatures",
            &dl_features.iter().map(|&x| x as f32).collect::<Vec<_>>(),
        )
        .unwrap();
        let feature_grads = GpuBuffer::<f32>::new(
            &ctx,
            "feature grads",
            n * FEATURE_CHANNELS,
            lpmsplat::gpu::BufferKind::DeviceLocal,
        )
        .unwrap();
        let grads = GpuSplats::zeroed(&ctx, "grad_", 0, n, n).unwrap();
        let vgn = GpuBuffer::<f32>::from_slice(&ctx, "vgn", &vec![0.0; n]).unwrap();
        let bwd = Backward::new(&ctx, n)
            .unwrap()
            .with_feature_channels(&ctx, FEATURE_CHANNELS as u32)
            .unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        for (buf, _) in grads.groups() {
            rec.fill(buf, NAN_BITS);
        }
        rec.fill(&feature_grads, NAN_BITS);
        rec.barrier();
        let fb = &renderer.frame;
        bwd.record(
            &ctx,
            &mut rec,
            &BackwardArgs {
                cameras: &cameras,
                camera_index: 1,
                camera: &cam,
                projected: &fb.projected,
                tile_ranges: &fb.tile_ranges,
                sorted_ids: renderer.sorted_ids(),
                final_t: &fb.final_t,
                last_index: &fb.last_index,
                dl_dimage: &dl_buf,
                splats: &splats,
                grads: &grads,
                view_grad_norm: &vgn,
                filter3d: None,
                pixel_count: None,
                abs_grad: None,
                count: n,
                sh_degree: 0,
                constants,
                background: background.map(|v| v as f32),
                features: Some(FeatureGrads {
                    values: &feats,
                    dl_dimage: &dl_feat_buf,
                    grads: &feature_grads,
                    channels: FEATURE_CHANNELS as u32,
                }),
            },
        )
        .unwrap();
        rec.barrier();
        rec.submit_and_wait().unwrap();
        let (rel, floor) = (2e-3, 2e-4);
        compare(
            &format!("{label} feature gradients"),
            &feature_grads.read().unwrap(),
            &want_feature_grads,
            rel,
            floor,
        );
        let flat3 = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
        compare(
            &format!("{label} dc gradients (raw colour)"),
            &grads.sh_dc.read().unwrap(),
            &flat3(&colour.rgb),
            rel,
            floor,
        );
        compare(
            &format!("{label} position gradients"),
            &grads.positions.read().unwrap(),
            &flat3(&params_want.positions),
            1e-2,
            1e-3,
        );
        compare(
            &format!("{label} log-scale gradients"),
            &grads.log_scales.read().unwrap(),
            &flat3(&params_want.log_scales),
            1e-2,
            1e-3,
        );
        compare(
            &format!("{label} opacity gradients"),
            &grads.opacity_logits.read().unwrap(),
            &params_want.opacity_logits,
            1e-2,
            1e-3,
        );
    }
}

/// Random decoder inputs for `px` pixels and random weights, rounded to f32.
fn decoder_inputs(rng: &mut Pcg64, px: usize) -> (Vec<f64>, Vec<[f64; 3]>, Vec<[f64; 6]>) {
    let mut r = |a: f32, b: f32| rng.gen_range(a..b) as f64;
    let w = (0..WEIGHTS).map(|_| r(-0.5, 0.5)).collect();
    let base = (0..px).map(|_| [0; 3].map(|_| r(-3.0, 3.0))).collect();
    let feats = (0..px).map(|_| [0; 6].map(|_| r(-2.0, 2.0))).collect();
    (w, base, feats)
}

#[test]
fn reference_decoder_backward_matches_finite_differences() {
    let mut rng = Pcg64::seed_from_u64(7);
    for _ in 0..20 {
        let (w, base, feats) = decoder_inputs(&mut rng, 1);
        let dir = {
            let d = [0; 3].map(|_| rng.gen_range(-1.0..1.0f64));
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d.map(|v| v / n)
        };
        let origin = [0; 3].map(|_| rng.gen_range(-4.0..4.0f64));
        let x = decoder::decoder_input(feats[0], origin, dir);
        let dl = [0; 3].map(|_| rng.gen_range(-1.0..1.0f64));
        let loss = |w: &[f64], b: [f64; 3], x: &[f64; INPUTS]| {
            let rgb = decoder::decode(w, b, x);
            (0..3).map(|c| rgb[c] * dl[c]).sum::<f64>()
        };
        let mut dw = vec![0.0; WEIGHTS];
        let (db, df) = decoder::decode_backward(&w, base[0], &x, dl, &mut dw);
        let h = 1e-6;
        let check = |what: &str, analytic: f64, plus: f64, minus: f64| {
            let fd = (plus - minus) / (2.0 * h);
            assert!(
                (analytic - fd).abs() <= 1e-6 + 1e-5 * fd.abs(),
                "{what}: analytic {analytic:e}, finite difference {fd:e}"
            );
        };
        for k in 0..WEIGHTS {
            let (mut wp, mut wm) = (w.clone(), w.clone());
            wp[k] += h;
            wm[k] -= h;
            check(
                &format!("W[{k}]"),
                dw[k],
                loss(&wp, base[0], &x),
                loss(&wm, base[0], &x),
            );
        }
        for c in 0..3 {
            let (mut bp, mut bm) = (base[0], base[0]);
            bp[c] += h;
            bm[c] -= h;
            check(
                &format!("B[{c}]"),
                db[c],
                loss(&w, bp, &x),
                loss(&w, bm, &x),
            );
        }
        for c in 0..6 {
            let (mut xp, mut xm) = (x, x);
            xp[c] += h;
            xm[c] -= h;
            check(
                &format!("feature[{c}]"),
                df[c],
                loss(&w, base[0], &xp),
                loss(&w, base[0], &xm),
            );
        }
    }
}

/// The time features `[f_spec, (t − c)·f_t]` against central differences of a random linear
/// loss, with `t − c` held constant as in training (the specification's chain rule,
/// docs/algorithms/base-models.md §4.4, gives the temporal centre no gradient through the
/// features: only `∂L/∂f_t = Δ·∂L/∂F[6:9]`).
#[test]
fn reference_time_features_backward_matches_finite_differences() {
    let mut rng = Pcg64::seed_from_u64(13);
    let h = 1e-6;
    for case in 0..50 {
        let f_spec = [0; 3].map(|_| rng.gen_range(-2.0..2.0f64));
        let f_t = [0; 3].map(|_| rng.gen_range(-2.0..2.0f64));
        let (t, c) = (rng.gen_range(0.0..1.0f64), rng.gen_range(-0.5..1.5f64));
        let dl = [0; 6].map(|_| rng.gen_range(-1.0..1.0f64));
        let loss = |s: [f64; 3], ft: [f64; 3]| -> f64 {
            let f = decoder::time_features(s, ft, t, c);
            (0..6).map(|k| f[k] * dl[k]).sum()
        };
        let (gs, gt) = decoder::time_features_backward(dl, t, c);
        for k in 0..3 {
            let (mut sp, mut sm) = (f_spec, f_spec);
            sp[k] += h;
            sm[k] -= h;
            let fd = (loss(sp, f_t) - loss(sm, f_t)) / (2.0 * h);
            assert!(
                (fd - gs[k]).abs() < 1e-8,
                "case {case} f_spec[{k}]: fd {fd} vs {}",
                gs[k]
            );
            let (mut tp, mut tm) = (f_t, f_t);
            tp[k] += h;
            tm[k] -= h;
            let fd = (loss(f_spec, tp) - loss(f_spec, tm)) / (2.0 * h);
            assert!(
                (fd - gt[k]).abs() < 1e-8,
                "case {case} f_t[{k}]: fd {fd} vs {}",
                gt[k]
            );
        }
    }
}

#[test]
fn decoder_matches_the_reference_forward_and_backward() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(11);
    // Every layout on this device: one pixel an invocation (GPUs), 8 (CPU drivers), and 3 (not
    // a power of two; 16, the largest allowed, compiles for 15 s on lavapipe).
    for per_invocation in [1, 3, 8] {
        decoder_matches_with(&ctx, &mut rng, per_invocation);
    }
    assert!(Decoder::with_pixels_per_invocation(&ctx, 0).is_err());
    assert!(Decoder::with_pixels_per_invocation(&ctx, 17).is_err());
    ctx.check_validation().unwrap();
}

fn decoder_matches_with(ctx: &Arc<GpuContext>, rng: &mut Pcg64, per_invocation: u32) {
    let ctx = ctx.clone();
    let mut decoder = Decoder::with_pixels_per_invocation(&ctx, per_invocation).unwrap();
    // Sizes that are not multiples of the workgroup or of the pixels an invocation, one larger
    // than a few workgroups.
    for (w, h) in [(19u32, 13u32), (64, 40), (5, 3), (97, 61)] {
        let px = (w * h) as usize;
        let (weights, base, feats) = decoder_inputs(rng, px);
        let (camera, pose) = scenes::random_view(rng, w, h);
        let cam = CameraGpu::new(&camera, &pose);
        let mut decoy = cam;
        decoy.r0[0] = 0.3;
        let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[decoy, cam]).unwrap();
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        let flat3: Vec<f64> = base.iter().flatten().copied().collect();
        let flat6: Vec<f64> = feats.iter().flatten().copied().collect();
        let base_buf = GpuBuffer::from_slice(&ctx, "base", &f32s(&flat3)).unwrap();
        let feat_buf = GpuBuffer::from_slice(&ctx, "features", &f32s(&flat6)).unwrap();
        let w_buf = GpuBuffer::from_slice(&ctx, "weights", &f32s(&weights)).unwrap();
        decoder.reserve(px).unwrap();
        let frame = DecoderFrame {
            cameras: &cameras,
            camera_index: 1,
            camera: &cam,
            base: &base_buf,
            features: &feat_buf,
            weights: &w_buf,
        };
        let dl: Vec<[f64; 3]> = (0..px)
            .map(|_| [0; 3].map(|_| rng.gen_range(-1.0..1.0f32) as f64))
            .collect();
        let dl_buf = GpuBuffer::from_slice(
            &ctx,
            "dl_drgb",
            &dl.iter().flatten().map(|&v| v as f32).collect::<Vec<_>>(),
        )
        .unwrap();
        // Gradients accumulate on top of a known value with `accumulate`.
        let wg = GpuBuffer::from_slice(&ctx, "weight grads", &vec![0.25f32; WEIGHTS]).unwrap();
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.fill(decoder.image(), NAN_BITS);
        rec.fill(decoder.dl_dbase(), NAN_BITS);
        rec.fill(decoder.dl_dfeatures(), NAN_BITS);
        rec.barrier();
        decoder.record_forward(&mut rec, &frame).unwrap();
        decoder
            .record_backward(&mut rec, &frame, &dl_buf, &wg, true, 0.5)
            .unwrap();
        rec.barrier();
        rec.submit_and_wait().unwrap();

        let want_rgb = decoder::decode_image(&weights, &base, &feats, &camera, &pose);
        let (want_db, want_df, want_dw) =
            decoder::decode_image_backward(&weights, &base, &feats, &camera, &pose, &dl);
        let label = format!("{w}×{h}, {per_invocation} pixels an invocation");
        let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
        compare(
            &format!("{label} decoded"),
            &decoder.image().read_range(0, 3 * px).unwrap(),
            &flat(&want_rgb),
            1e-5,
            1e-6,
        );
        compare(
            &format!("{label} dL/dB"),
            &decoder.dl_dbase().read_range(0, 3 * px).unwrap(),
            &flat(&want_db),
            1e-4,
            1e-5,
        );
        compare(
            &format!("{label} dL/dfeatures"),
            &decoder.dl_dfeatures().read_range(0, 6 * px).unwrap(),
            &want_df.iter().flatten().copied().collect::<Vec<_>>(),
            1e-4,
            1e-5,
        );
        let want_acc: Vec<f64> = want_dw.iter().map(|v| 0.5 * v + 0.25).collect();
        compare(
            &format!("{label} dL/dW (accumulated, scaled by 1/2)"),
            &wg.read().unwrap(),
            &want_acc,
            1e-4,
            1e-5,
        );

        // Without `accumulate` the sum replaces the buffer, and it is the same bits each time.
        let mut rec = Recorder::new(&ctx).unwrap();
        decoder
            .record_backward(&mut rec, &frame, &dl_buf, &wg, false, 1.0)
            .unwrap();
        rec.barrier();
        rec.submit_and_wait().unwrap();
        let first = wg.read().unwrap();
        compare(&format!("{label} dL/dW"), &first, &want_dw, 1e-4, 1e-5);
        let mut rec = Recorder::new(&ctx).unwrap();
        decoder
            .record_backward(&mut rec, &frame, &dl_buf, &wg, false, 1.0)
            .unwrap();
        rec.barrier();
        rec.submit_and_wait().unwrap();
        assert_eq!(
            first,
            wg.read().unwrap(),
            "{label}: the weight reduction is deterministic"
        );
    }
}

#[test]
fn time_features_match_the_reference_forward_and_backward() {
    use lpmsplat::render::decoder::{FeatureGroups, TimeFeatures};
    let ctx = ctx();
    let tf = TimeFeatures::new(&ctx).unwrap();
    let mut rng = Pcg64::seed_from_u64(5);
    let (n, spare) = (300usize, 7usize);
    let mut r = |a: f32, b: f32| rng.gen_range(a..b);
    let f_spec: Vec<f32> = (0..3 * n).map(|_| r(-2.0, 2.0)).collect();
    let f_t: Vec<f32> = (0..3 * n).map(|_| r(-2.0, 2.0)).collect();
    let centres: Vec<f32> = (0..n).map(|_| r(-0.5, 1.5)).collect();
    let d_feat: Vec<f32> = (0..6 * n).map(|_| r(-1.0, 1.0)).collect();
    let t = 0.37f32;
    let b = |name: &str, v: &[f32]| GpuBuffer::from_slice(&ctx, name, v).unwrap();
    let nan = |len: usize| vec![f32::NAN; len];
    let (fs, ft, tc, dfb) = (
        b("f_spec", &f_spec),
        b("f_t", &f_t),
        b("c", &centres),
        b("d", &d_feat),
    );
    let out = b("features", &nan(6 * (n + spare)));
    let (gs, gt) = (
        b("g f_spec", &nan(3 * (n + spare))),
        b("g f_t", &nan(3 * (n + spare))),
    );
    let params = FeatureGroups {
        f_spec: &fs,
        f_t: &ft,
        t_center: &tc,
    };
    let grads = FeatureGroups {
        f_spec: &gs,
        f_t: &gt,
        t_center: &tc,
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    tf.record_forward(&mut rec, &params, &out, n, t).unwrap();
    tf.record_backward(&mut rec, &params, &dfb, &grads, n, t)
        .unwrap();
    rec.barrier();
    rec.submit_and_wait().unwrap();
    let (got, got_s, got_t) = (out.read().unwrap(), gs.read().unwrap(), gt.read().unwrap());
    let d = |v: f32| v as f64;
    for i in 0..n {
        let at = |v: &[f32], k: usize| [0, 1, 2].map(|c| d(v[3 * i + c + k]));
        let want = decoder::time_features(at(&f_spec, 0), at(&f_t, 0), d(t), d(centres[i]));
        let dl = std::array::from_fn(|c| d(d_feat[6 * i + c]));
        let (ws, wt) = decoder::time_features_backward(dl, d(t), d(centres[i]));
        compare("features", &got[6 * i..6 * i + 6], &want, 1e-6, 0.0);
        compare("d f_spec", &got_s[3 * i..3 * i + 3], &ws, 1e-6, 0.0);
        compare("d f_t", &got_t[3 * i..3 * i + 3], &wt, 1e-6, 0.0);
    }
    assert!(
        got[6 * n..].iter().all(|v| v.is_nan()),
        "written past count"
    );
    assert!(
        got_s[3 * n..].iter().all(|v| v.is_nan()),
        "written past count"
    );
}

/// The rasterizer's fused epilogue (frames that are displayed: `render`, `eval`, `bench fps`):
/// the decoded RGB of each pixel straight from the blend equals the f64 reference's decoder
/// applied to its blended base colour (over a background) and features, and the separate
/// decoder pass's output on the same frame, in every pixels-per-invocation layout the device
/// runs.
#[test]
fn fused_decoder_epilogue_matches_the_reference_and_the_decoder_pass() {
    let ctx = ctx();
    let settings = RenderSettings::default();
    let mut constants = RenderConstants::from_settings(&settings);
    constants.flags |= RenderConstants::RAW_COLOUR;
    let layouts: Vec<u32> = if ctx.info.subgroup_shuffle {
        vec![1, 2, 4, 8]
    } else {
        vec![1]
    };
    for (seed, n, w, h) in [(21u64, 3000usize, 61u32, 40u32), (22, 40, 16, 16)] {
        let (g, features, camera, pose) = scene(seed, n, w, h);
        let background = [0.3, -0.2, 0.7];
        let (out, feature_image) =
            raw_reference_frame(&g, &features, &camera, &pose, background, &settings);
        let raster = &out.raster;
        let px = (w * h) as usize;
        let feats: Vec<[f64; 6]> = (0..px)
            .map(|p| std::array::from_fn(|c| feature_image[p * FEATURE_CHANNELS + c]))
            .collect();
        let mut rng = Pcg64::seed_from_u64(seed ^ 0xDEC);
        let (weights, _, _) = decoder_inputs(&mut rng, 0);
        let want = decoder::decode_image(&weights, &raster.image, &feats, &camera, &pose);
        let want: Vec<f64> = want.iter().flatten().copied().collect();

        let (splats, cam, cameras, feat_buf) = upload_frame(&ctx, &g, &features, &camera, &pose);
        let f32s: Vec<f32> = weights.iter().map(|&x| x as f32).collect();
        let w_buf = GpuBuffer::from_slice(&ctx, "weights", &f32s).unwrap();
        let capacity = Capacity {
            gaussians: n,
            intersections: 1 << 14,
            pixels: px,
            tiles: cam.tile_count() as usize,
        };
        let frame = |decoded_by| FrameSettings {
            sh_degree: 0,
            background: background.map(|v| v as f32),
            constants,
            filter3d: None,
            features: Some(FeatureChannels {
                values: &feat_buf,
                channels: FEATURE_CHANNELS as u32,
                decoded_by,
            }),
        };
        for &pixels in &layouts {
            let label = format!("seed {seed}, {w}×{h}, {pixels} pixels an invocation");
            let mut renderer = Renderer::new(&ctx, capacity)
                .unwrap()
                .with_raster_pixels(pixels)
                .unwrap();
            // The separate pass: base and feature images, then the decoder.
            renderer
                .render_blocking(&splats, &cameras, 1, &cam, &frame(None))
                .unwrap();
            let mut dec = Decoder::with_pixels_per_invocation(&ctx, pixels).unwrap();
            dec.reserve(px).unwrap();
            let mut rec = Recorder::new(&ctx).unwrap();
            rec.begin().unwrap();
            dec.record_forward(
                &mut rec,
                &DecoderFrame {
                    cameras: &cameras,
                    camera_index: 1,
                    camera: &cam,
                    base: &renderer.frame.image,
                    features: renderer.feature_image().unwrap(),
                    weights: &w_buf,
                },
            )
            .unwrap();
            rec.barrier();
            rec.submit_and_wait().unwrap();
            let separate = dec.image().read_range(0, 3 * px).unwrap();

            // Fused, into a poisoned image.
            renderer
                .frame
                .image
                .upload(&vec![f32::NAN; renderer.frame.image.len()])
                .unwrap();
            renderer
                .render_blocking(&splats, &cameras, 1, &cam, &frame(Some(&w_buf)))
                .unwrap();
            assert!(
                renderer.feature_image().is_none(),
                "{label}: a decoded frame keeps no feature image"
            );
            let fused = renderer.read_image().unwrap();
            compare(&format!("{label} fused"), &fused, &want, 1e-4, 1e-5);
            compare(
                &format!("{label} decoder pass"),
                &separate,
                &want,
                1e-4,
                1e-5,
            );
            for (i, (a, b)) in fused.iter().zip(&separate).enumerate() {
                assert!(
                    (a - b).abs() <= 2e-6,
                    "{label}: fused {a} against the decoder pass {b} at {i}"
                );
            }
        }
    }

    // The epilogue decodes SpacetimeGaussians' 6 channels with its 90 weights, nothing else.
    let (g, features, camera, pose) = scene(23, 10, 16, 16);
    let splats = GpuSplats::upload(&ctx, &g.to_params(0), 10).unwrap();
    let cam = CameraGpu::new(&camera, &pose);
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
    let f32s: Vec<f32> = features.iter().map(|&x| x as f32).collect();
    let feat_buf = GpuBuffer::from_slice(&ctx, "features", &f32s).unwrap();
    let short = GpuBuffer::from_slice(&ctx, "weights", &vec![0.1f32; WEIGHTS - 1]).unwrap();
    let full = GpuBuffer::from_slice(&ctx, "weights", &vec![0.1f32; WEIGHTS]).unwrap();
    let mut renderer = Renderer::for_camera(&ctx, 10, &cam).unwrap();
    for (channels, weights) in [(FEATURE_CHANNELS as u32, &short), (3, &full)] {
        let frame = FrameSettings {
            features: Some(FeatureChannels {
                values: &feat_buf,
                channels,
                decoded_by: Some(weights),
            }),
            ..FrameSettings::plain(0, [0.0; 3])
        };
        let e = renderer
            .render_blocking(&splats, &cameras, 0, &cam, &frame)
            .unwrap_err()
            .to_string();
        assert!(e.contains("decoder"), "{e}");
    }
    ctx.check_validation().unwrap();
}
