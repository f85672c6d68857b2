//! SpacetimeGaussians' model passes (`train::passes::spacetime`) against the 3DGS passes on the
//! still model the f64 reference computes for the view's time: the same image, the scales' and
//! colours' gradients passed through, and the temporal groups' gradients the reference's chain
//! rule of the 3DGS gradients. A still scene is refused.

use std::sync::Arc;

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::models::{with_temporal_groups, BaseModel};
use lpmsplat::reference::scenes::random_view;
use lpmsplat::reference::spacetime::{instant_backward, Instant, Temporal};
use lpmsplat::render::forward::Capacity;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::{random_init, GaussianParams};
use lpmsplat::train::config::TrainConfig;
use lpmsplat::train::passes::gaussians::GaussianPasses;
use lpmsplat::train::passes::spacetime::SpacetimePasses;
use lpmsplat::train::passes::{FrameArgs, GradArgs, ModelPasses};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn extra<'a>(p: &'a GaussianParams, name: &str) -> &'a [f32] {
    p.extra_values(name).expect("the model has the group")
}

fn temporal_of(p: &GaussianParams, i: usize) -> Temporal {
    lpmsplat::reference::spacetime::temporal_of(p, i).expect("a video model")
}

/// The still model at time `t`, from the reference (no extra groups).
fn still_at(p: &GaussianParams, t: f64) -> GaussianParams {
    lpmsplat::reference::spacetime::still_at(p, t).expect("a video model")
}

struct Frame {
    image: Vec<f32>,
    grads: GaussianParams,
}

/// Forward and backward of `passes` on `params` for `view`, with `dl` as the image gradient.
fn run(
    ctx: &Arc<GpuContext>,
    passes: &mut dyn ModelPasses,
    params: &GaussianParams,
    cams: &GpuBuffer<CameraGpu>,
    cam: &CameraGpu,
    view: u32,
    dl: &GpuBuffer<f32>,
) -> Frame {
    let n = params.len();
    let config = TrainConfig::default();
    let gpu = GpuSplats::upload(ctx, params, n).unwrap();
    let grads = GpuSplats::zeroed_shape(ctx, "g ", &gpu.shape(), n, n).unwrap();
    for (b, _) in grads.groups() {
        b.upload(&vec![f32::NAN; b.len()]).unwrap();
    }
    let norm = GpuBuffer::<f32>::new(ctx, "norm", n, BufferKind::DeviceLocal).unwrap();
    let frame = FrameArgs {
        params: &gpu,
        cameras: cams,
        view,
        camera: cam,
        sh_degree: 0,
        background: [0.1, 0.2, 0.3],
        iteration: 1,
    };
    let mut rec = Recorder::new(ctx).unwrap();
    rec.begin().unwrap();
    passes.record_forward(&mut rec, &frame, None).unwrap();
    rec.barrier();
    let g = GradArgs {
        frame,
        dl_dimage: dl,
        grads: &grads,
        view_grad_norm: &norm,
        count: n,
        view_in_step: 0,
        views_in_step: 1,
    };
    passes
        .record_backward(ctx, &mut rec, &g, &config, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    assert!(!passes.after_frame().unwrap(), "no intersections dropped");
    let mut grads = grads.download().unwrap();
    grads.sh_degree = 0;
    Frame {
        image: passes.image().read().unwrap(),
        grads,
    }
}

#[test]
#[allow(clippy::needless_range_loop)]
fn spacetime_passes_are_the_3dgs_passes_at_the_views_time() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0x5747);
    let mut config = TrainConfig::default();
    BaseModel::SpacetimeLite.configure(&mut config);
    assert_eq!(config.sh_degree, 0);
    let (w, h) = (48u32, 40u32);
    let views: Vec<CameraGpu> = (0..2)
        .map(|_| {
            let (c, p) = random_view(&mut rng, w, h);
            CameraGpu::new(&c, &p)
        })
        .collect();
    let times = [0.25, 0.7];
    let cams = GpuBuffer::from_slice(&ctx, "cameras", &views).unwrap();
    let n = 400;
    let mut model =
        with_temporal_groups(random_init(n, [0.0; 3], [1.2; 3], 9, 0).unwrap(), 4, false);
    // Motion, spin, spread of temporal scales and opacities: every term of the step matters.
    for e in &mut model.extra {
        let scale = match e.group.name.as_str() {
            "motion" => 0.6,
            "omega" => 0.8,
            "trbf_scale" => 1.5,
            _ => 0.0,
        };
        for v in &mut e.values {
            *v += rng.gen_range(-scale..=scale);
        }
    }
    for (i, o) in model.opacity_logits.iter_mut().enumerate() {
        *o = rng.gen_range(-1.0..3.0);
        // Anisotropic, so that rotations (and the angular velocity) change the image.
        model.log_scales[i] = model.log_scales[i].map(|l| l - 0.7 + rng.gen_range(-0.8..0.8));
        model.sh_dc[i] = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
    }
    let capacity = Capacity {
        gaussians: n,
        intersections: 0,
        pixels: (w * h) as usize,
        tiles: views[0].tile_count().max(views[1].tile_count()) as usize,
    };
    let dl = GpuBuffer::from_slice(
        &ctx,
        "dl",
        &(0..3 * w * h)
            .map(|_| rng.gen_range(-1.0f32..1.0))
            .collect::<Vec<_>>(),
    )
    .unwrap();
    let mut st = SpacetimePasses::new(&ctx, &config, &views, &[0, 1], &times, n, capacity).unwrap();
    let plain = TrainConfig {
        sh_degree: 0,
        ..Default::default()
    };
    let mut gs = GaussianPasses::new(&ctx, &plain, &views, &[0, 1], n, capacity).unwrap();
    for view in 0..2u32 {
        let t = times[view as usize];
        let got = run(
            &ctx,
            &mut st,
            &model,
            &cams,
            &views[view as usize],
            view,
            &dl,
        );
        let still = still_at(&model, t);
        let want = run(
            &ctx,
            &mut gs,
            &still,
            &cams,
            &views[view as usize],
            view,
            &dl,
        );
        let worst = got
            .image
            .iter()
            .zip(&want.image)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 2e-5, "view {view}: image differs by {worst}");
        let lit = want.image.iter().filter(|&&v| v > 0.35).count();
        assert!(
            lit > 100,
            "the scene must cover the view ({lit} bright values)"
        );
        // Scales and colour: passed through.
        let close = |a: f32, b: f32, s: f32| (a - b).abs() <= 1e-4 * s + 1e-7;
        let s_ls = want
            .grads
            .log_scales
            .iter()
            .flatten()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        for (a, b) in got
            .grads
            .log_scales
            .iter()
            .flatten()
            .zip(want.grads.log_scales.iter().flatten())
        {
            assert!(close(*a, *b, s_ls), "log-scale gradient {a} vs {b}");
        }
        // The still model's positions and opacities are the GPU's f32 evaluation on one side
        // and the reference's rounded f64 on the other: gradients agree to f32 rounding.
        let max_abs = |v: &mut dyn Iterator<Item = f32>| v.fold(0.0f32, |m, x| m.max(x.abs()));
        let s_dc = max_abs(&mut want.grads.sh_dc.iter().flatten().copied());
        for (a, b) in got
            .grads
            .sh_dc
            .iter()
            .flatten()
            .zip(want.grads.sh_dc.iter().flatten())
        {
            assert!(close(*a, *b, s_dc), "colour gradient {a} vs {b}");
        }
        let s_p = max_abs(&mut want.grads.positions.iter().flatten().copied());
        let s_r = max_abs(&mut want.grads.rotations.iter().flatten().copied());
        let s_o = max_abs(&mut want.grads.opacity_logits.iter().copied()) as f64;
        // The temporal groups: the reference chain rule of the 3DGS gradients.
        let (mut want_motion, mut want_tc) = (Vec::new(), Vec::new());
        let mut maxima = [0.0f64; 4];
        let mut expected = Vec::new();
        for i in 0..n {
            let d = Instant {
                position: want.grads.positions[i].map(|v| v as f64),
                rotation: want.grads.rotations[i].map(|v| v as f64),
                opacity_logit: want.grads.opacity_logits[i] as f64,
            };
            let g = instant_backward(&temporal_of(&model, i), t, &d);
            for (k, v) in [
                g.motion.iter().fold(0.0f64, |m, x| m.max(x.abs())),
                g.omega.iter().fold(0.0f64, |m, x| m.max(x.abs())),
                g.t_center.abs(),
                g.t_log_scale.abs(),
            ]
            .into_iter()
            .enumerate()
            {
                maxima[k] = maxima[k].max(v);
            }
            want_motion.extend(g.motion);
            want_tc.push(g.t_center);
            expected.push(g);
        }
        assert!(
            maxima.iter().all(|&m| m > 0.0),
            "every temporal group gets a gradient: {maxima:?}"
        );
        for (i, g) in expected.iter().enumerate() {
            let gm = &extra(&got.grads, "motion")[9 * i..9 * i + 9];
            let go = &extra(&got.grads, "omega")[4 * i..4 * i + 4];
            for k in 0..9 {
                assert!(
                    (gm[k] as f64 - g.motion[k]).abs() <= 1e-4 * maxima[0],
                    "view {view} Gaussian {i} motion[{k}]: {} vs {}",
                    gm[k],
                    g.motion[k]
                );
            }
            for k in 0..4 {
                assert!(
                    (go[k] as f64 - g.omega[k]).abs() <= 1e-4 * maxima[1],
                    "view {view} Gaussian {i} omega[{k}]: {} vs {} (rotation grad {:?})",
                    go[k],
                    g.omega[k],
                    want.grads.rotations[i]
                );
            }
            let tc = extra(&got.grads, "trbf_center")[i] as f64;
            let ts = extra(&got.grads, "trbf_scale")[i] as f64;
            assert!(
                (tc - g.t_center).abs() <= 1e-4 * maxima[2],
                "t_center {i}: {tc} vs {}",
                g.t_center
            );
            assert!(
                (ts - g.t_log_scale).abs() <= 1e-4 * maxima[3],
                "t_log_scale {i}: {ts} vs {}",
                g.t_log_scale
            );
            for k in 0..3 {
                let (a, b) = (got.grads.positions[i][k], want.grads.positions[i][k]);
                assert!(close(a, b, s_p), "position gradient {i}: {a} vs {b}");
            }
            for k in 0..4 {
                let (a, b) = (got.grads.rotations[i][k], want.grads.rotations[i][k]);
                assert!(close(a, b, s_r), "rotation gradient {i}: {a} vs {b}");
            }
            let go = got.grads.opacity_logits[i] as f64;
            assert!(
                (go - g.opacity_logit).abs() <= 1e-4 * s_o,
                "opacity {i}: {go} vs {}",
                g.opacity_logit
            );
        }
        // New Gaussians are centred at the frame's time.
        assert_eq!(st.new_gaussian_extras()[2], vec![t as f32]);
    }
    assert_eq!(st.extra_lrs(1, 2.0).len(), 4);
    ctx.check_validation().unwrap();
}

#[test]
fn a_still_scene_is_refused() {
    let ctx = ctx();
    let mut config = TrainConfig::default();
    BaseModel::SpacetimeLite.configure(&mut config);
    let mut rng = Pcg64::seed_from_u64(1);
    let (c, p) = random_view(&mut rng, 16, 16);
    let cams = [CameraGpu::new(&c, &p)];
    let e = BaseModel::SpacetimeLite
        .model()
        .passes(
            &ctx,
            &config,
            &cams,
            &[0],
            None,
            10,
            Capacity::for_frame(10, &cams[0]),
        )
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("video scene") && e.contains("Fix:"), "{e}");
}

/// `|g − r| ≤ rel·|r| + floor·max|r|` over a group, every value finite.
fn compare(what: &str, gpu: &[f32], want: &[f64], rel: f64, floor: f64) {
    assert_eq!(gpu.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        scale > 0.0,
        "{what}: the reference is all zero (the test checks nothing)"
    );
    for (i, (&g, &r)) in gpu.iter().zip(want).enumerate() {
        let err = (g as f64 - r).abs();
        assert!(
            g.is_finite() && err <= rel * r.abs() + floor * scale,
            "{what}[{i}]: GPU {g:e} vs reference {r:e} (max {scale:e})"
        );
    }
}

/// The full model's passes against the f64 reference chain: the model at the view's time,
/// its raw base colour and feature channels blended, decoded per pixel; backward through the
/// decoder, both blends, the projection and the temporal step.
#[test]
#[allow(clippy::needless_range_loop)]
fn spacetime_full_passes_match_the_reference_chain() {
    use lpmsplat::reference::backward::{preprocess_backward, rasterize_backward, ProjectedGrads};
    use lpmsplat::reference::decoder::{self, FEATURE_CHANNELS};
    use lpmsplat::reference::raster::rasterize;
    use lpmsplat::reference::{render, RefGaussians, RenderSettings};
    use lpmsplat::train::passes::spacetime::initial_decoder_weights;

    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0xF011);
    let mut config = TrainConfig::default();
    BaseModel::SpacetimeFull.configure(&mut config);
    let (w, h) = (40u32, 32u32);
    let (camera, pose) = random_view(&mut rng, w, h);
    let cam = CameraGpu::new(&camera, &pose);
    let cams = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
    let t = 0.4f64;
    let n = 250;
    let mut model =
        BaseModel::SpacetimeFull.initialise(random_init(n, [0.0; 3], [1.2; 3], 9, 0).unwrap(), 4);
    for e in &mut model.extra {
        let scale = match e.group.name.as_str() {
            "motion" => 0.6,
            "omega" => 0.8,
            "trbf_scale" => 1.5,
            "f_spec" | "f_t" => 1.5,
            _ => 0.0,
        };
        for v in &mut e.values {
            *v += rng.gen_range(-scale..=scale);
        }
    }
    for i in 0..n {
        model.opacity_logits[i] = rng.gen_range(-1.0..3.0);
        model.log_scales[i] = model.log_scales[i].map(|l| l - 0.7 + rng.gen_range(-0.8..0.8));
        model.sh_dc[i] = [0; 3].map(|_| rng.gen_range(-1.5..1.5));
    }
    let capacity = Capacity {
        gaussians: n,
        intersections: 0,
        pixels: (w * h) as usize,
        tiles: cam.tile_count() as usize,
    };
    let dl: Vec<f32> = (0..3 * w * h)
        .map(|_| rng.gen_range(-1.0f32..1.0))
        .collect();
    let dl_buf = GpuBuffer::from_slice(&ctx, "dl", &dl).unwrap();
    let mut st = SpacetimePasses::new(&ctx, &config, &[cam], &[0], &[t], n, capacity).unwrap();
    let got = run(&ctx, &mut st, &model, &cams, &cam, 0, &dl_buf);

    // Reference forward.
    let settings = RenderSettings::default();
    let still = still_at(&model, t);
    let g = RefGaussians::from_params(&still);
    let out = render(&g, &camera, &pose, 0, [0.0; 3], &settings).unwrap();
    let mut projected = out.projected.clone();
    for (p, sh) in projected.iter_mut().zip(&g.sh) {
        p.rgb = sh[0];
        p.rgb_clamped = [false; 3];
    }
    let raster = rasterize(&projected, &out.bins, &camera, [0.0; 3], &settings).unwrap();
    let (f_spec, f_t) = (extra(&model, "f_spec"), extra(&model, "f_t"));
    let centres = extra(&model, "trbf_center");
    let d = |v: f32| v as f64;
    let features: Vec<f64> = (0..n)
        .flat_map(|i| {
            let at = |v: &[f32]| [0, 1, 2].map(|c| d(v[3 * i + c]));
            decoder::time_features(at(f_spec), at(f_t), t, d(centres[i]))
        })
        .collect();
    let fimg = decoder::rasterize_features(
        &projected,
        &out.bins,
        &camera,
        &features,
        FEATURE_CHANNELS,
        &settings,
    )
    .unwrap();
    let fimg6: Vec<[f64; 6]> = fimg
        .chunks(6)
        .map(|c| std::array::from_fn(|k| c[k]))
        .collect();
    let weights: Vec<f64> = initial_decoder_weights(config.seed)
        .iter()
        .map(|&v| d(v))
        .collect();
    let rgb = decoder::decode_image(&weights, &raster.image, &fimg6, &camera, &pose);
    let px = (w * h) as usize;
    let want_image: Vec<f64> = rgb.iter().flatten().copied().collect();
    compare(
        "decoded image",
        &got.image[..3 * px],
        &want_image,
        1e-4,
        1e-5,
    );
    let lit = raster
        .final_transmittance
        .iter()
        .filter(|&&t| t < 0.5)
        .count();
    assert!(
        lit > px / 4,
        "the scene must cover the view ({lit} of {px} pixels)"
    );

    // Reference backward.
    let dl64: Vec<[f64; 3]> = dl.chunks(3).map(|c| [d(c[0]), d(c[1]), d(c[2])]).collect();
    let (db, df, _) =
        decoder::decode_image_backward(&weights, &raster.image, &fimg6, &camera, &pose, &dl64);
    let colour =
        rasterize_backward(&projected, &out.bins, &raster, [0.0; 3], &settings, &db).unwrap();
    let df_flat: Vec<f64> = df.iter().flatten().copied().collect();
    let (geometry, fgrads) = decoder::rasterize_features_backward(
        &projected,
        &out.bins,
        &raster,
        &features,
        FEATURE_CHANNELS,
        &settings,
        &df_flat,
    )
    .unwrap();
    let mut total = ProjectedGrads::zeros(n);
    for i in 0..n {
        total.mean2d[i] = [0, 1].map(|c| colour.mean2d[i][c] + geometry.mean2d[i][c]);
        total.conic[i] = [0, 1, 2].map(|c| colour.conic[i][c] + geometry.conic[i][c]);
        total.opacity[i] = colour.opacity[i] + geometry.opacity[i];
    }
    let pg = preprocess_backward(&g, &projected, &camera, &pose, 0, &settings, &total).unwrap();
    let (mut motion, mut t_center, mut spec, mut ft) = (vec![], vec![], vec![], vec![]);
    let mut positions = vec![];
    for i in 0..n {
        let tg = instant_backward(
            &temporal_of(&model, i),
            t,
            &Instant {
                position: pg.positions[i],
                rotation: pg.rotations[i],
                opacity_logit: pg.opacity_logits[i],
            },
        );
        motion.extend(tg.motion);
        t_center.push(tg.t_center);
        positions.extend(tg.position);
        let (s, f) = decoder::time_features_backward(
            std::array::from_fn(|k| fgrads[6 * i + k]),
            t,
            d(centres[i]),
        );
        spec.extend(s);
        ft.extend(f);
    }
    let (rel, floor) = (1e-2, 2e-3);
    let flat3 = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
    compare(
        "base colour (dc) gradients",
        &flat3(&got.grads.sh_dc),
        &colour.rgb.iter().flatten().copied().collect::<Vec<_>>(),
        rel,
        floor,
    );
    compare(
        "f_spec gradients",
        extra(&got.grads, "f_spec"),
        &spec,
        rel,
        floor,
    );
    compare("f_t gradients", extra(&got.grads, "f_t"), &ft, rel, floor);
    compare(
        "position gradients",
        &flat3(&got.grads.positions),
        &positions,
        rel,
        floor,
    );
    compare(
        "motion gradients",
        extra(&got.grads, "motion"),
        &motion,
        rel,
        floor,
    );
    compare(
        "temporal centre gradients",
        extra(&got.grads, "trbf_center"),
        &t_center,
        rel,
        floor,
    );
}

/// One visible Gaussian on `pose`'s optical axis at camera z = `z`, as a video model.
fn one_on_axis(pose: &lpmsplat::scene::Pose, z: f64) -> GaussianParams {
    let mut p = random_init(1, [0.0; 3], [0.0; 3], 1, 0).unwrap();
    p.positions[0] = pose.inverse_transform([0.0, 0.0, z]).map(|v| v as f32);
    p.log_scales[0] = [(0.2 * z).ln() as f32; 3];
    p.opacity_logits[0] = 3.0;
    p.sh_dc[0] = [1.5; 3];
    p
}

#[test]
fn video_models_cull_at_the_official_near_plane() {
    // SpacetimeGaussians' official code culls camera z ≤ 0.2 (the Inria rasterizer); the
    // still models keep gsplat's 0.01. A Gaussian at z = 0.1 must vanish from a video
    // model's training frame and its eval render, and stay in a 3DGS render; at z = 0.5 the
    // video model draws it too.
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0x2EA2);
    let (w, h) = (32u32, 24u32);
    let (c, pose) = random_view(&mut rng, w, h);
    let cam = CameraGpu::new(&c, &pose);
    let cams = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
    let bg = [0.1f32, 0.2, 0.3];
    let lit = |img: &[f32]| {
        img.chunks_exact(3)
            .filter(|p| p.iter().zip(&bg).any(|(a, b)| (a - b).abs() > 1e-3))
            .count()
    };
    let mut config = TrainConfig::default();
    BaseModel::SpacetimeLite.configure(&mut config);
    assert_eq!(
        config.render_constants().near,
        lpmsplat::render::spacetime::SPACETIME_NEAR
    );
    let capacity = Capacity {
        gaussians: 1,
        intersections: 0,
        pixels: (w * h) as usize,
        tiles: cam.tile_count() as usize,
    };
    let dl = GpuBuffer::from_slice(&ctx, "dl", &vec![0.0f32; (3 * w * h) as usize]).unwrap();
    for (z, drawn) in [(0.03, false), (0.5, true)] {
        let still = one_on_axis(&pose, z);
        let video = BaseModel::SpacetimeLite.initialise(still.clone(), 3);
        // Training: the model's passes.
        let mut passes =
            SpacetimePasses::new(&ctx, &config, &[cam], &[0], &[0.5], 1, capacity).unwrap();
        let frame = run(&ctx, &mut passes, &video, &cams, &cam, 0, &dl);
        assert_eq!(lit(&frame.image) > 0, drawn, "training frame at z = {z}");
        // Evaluation: the renderer `eval` and `render` use for the model.
        let gpu = GpuSplats::upload(&ctx, &video, 1).unwrap();
        let mut view = BaseModel::SpacetimeLite
            .view_renderer(&ctx, 1, &cam, Some(vec![0.5]), None)
            .unwrap();
        let image = view.render(&gpu, &cams, 0, &cam, bg).unwrap();
        assert_eq!(lit(&image) > 0, drawn, "eval render at z = {z}");
        // 3DGS draws it at both depths.
        let gpu = GpuSplats::upload(&ctx, &still, 1).unwrap();
        let mut view = BaseModel::Gaussians3d
            .view_renderer(&ctx, 1, &cam, None, None)
            .unwrap();
        let image = view.render(&gpu, &cams, 0, &cam, bg).unwrap();
        assert!(lit(&image) > 0, "3DGS render at z = {z}");
    }
    ctx.check_validation().unwrap();
}
