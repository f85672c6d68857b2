//! The GPU backward pass (rasterizer backward + preprocess backward) against the f64 CPU
//! reference backward, on random small scenes fed with the reference forward pass in the GPU
//! contract layout. The scenes are rounded to f32 first so both sides see the same values.
//! Both atomic paths (float atomicAdd where the device has it, compare-and-swap forced) run on
//! every scene. Output buffers are poisoned with NaN before each run, so anything left unwritten
//! (or written past `count`) is caught.

use crate::child_run;

use crate::kernel_fixtures::{
    gaussian_params, gpu_forward_fixture, round_gaussians_to_f32, round_view_to_f32,
};
use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::scenes::{random_gaussians, random_view};
use lpmsplat::reference::{self, mip, Gradients, RefGaussians, RenderSettings};
use lpmsplat::render::backward::{
    pixel_layouts, AtomicMode, Backward, BackwardArgs, FeatureGrads, RasterVariant, GRAD2D_STRIDE,
};
use lpmsplat::render::layout::{CameraGpu, RenderConstants};
use lpmsplat::render::projected::ProjectedBuffers;
use lpmsplat::scene::{PinholeCamera, Pose};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::model::sh_rest_coeffs;
use lpmsplat::splats::sh_planes;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::sync::Arc;

const NAN_BITS: u32 = 0x7FC0_0000;
/// Extra Gaussians of room in the gradient buffers: they must stay poisoned.
const SPARE: usize = 5;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

struct Scene {
    gaussians: RefGaussians,
    camera: PinholeCamera,
    pose: Pose,
    /// Active degree of the render.
    degree: usize,
    /// Degree of the parameter buffers (≥ `degree`).
    stored_degree: u32,
    background: [f64; 3],
    settings: RenderSettings,
    dl_dimage: Vec<[f64; 3]>,
    /// Mip-Splatting's 3D filter (f32-exact values): the reference renders the fused
    /// parameters and takes its gradients back through `mip::fuse_backward`.
    filter3d: Option<Vec<f64>>,
    /// Feature channels (SpacetimeGaussians' full model): values `[g·C + c]` and
    /// dL/d(feature image) `[pix·C + c]`, f32-exact.
    features: Option<SceneFeatures>,
}

struct SceneFeatures {
    channels: usize,
    values: Vec<f64>,
    dl_dimage: Vec<f64>,
}

impl Scene {
    fn random(rng: &mut Pcg64, n: usize, width: u32, height: u32, degree: usize) -> Scene {
        let gaussians = random_gaussians(rng, n);
        let (camera, pose) = random_view(rng, width, height);
        Scene::new(rng, gaussians, camera, pose, degree)
    }

    fn new(
        rng: &mut Pcg64,
        gaussians: RefGaussians,
        camera: PinholeCamera,
        pose: Pose,
        degree: usize,
    ) -> Scene {
        let (camera, pose) = round_view_to_f32(&camera, &pose);
        let pixels = (camera.width * camera.height) as usize;
        Scene {
            gaussians: round_gaussians_to_f32(&gaussians),
            camera,
            pose,
            degree,
            stored_degree: rng.gen_range(degree as u32..=3),
            background: [0.0; 3],
            settings: RenderSettings::default(),
            dl_dimage: (0..pixels)
                .map(|_| [0; 3].map(|_| rng.gen_range(-1.0f32..1.0) as f64))
                .collect(),
            filter3d: None,
            features: None,
        }
    }

    /// The same scene with `channels` random feature channels and random dL/d(feature image).
    fn with_features(mut self, rng: &mut Pcg64, channels: usize) -> Scene {
        let pixels = (self.camera.width * self.camera.height) as usize;
        let mut draw =
            |n: usize| -> Vec<f64> { (0..n).map(|_| rng.gen_range(-1.5f32..1.5) as f64).collect() };
        self.features = Some(SceneFeatures {
            channels,
            values: draw(self.gaussians.len() * channels),
            dl_dimage: draw(pixels * channels),
        });
        self
    }
}

/// What the GPU produced, read back.
struct GpuResult {
    grad2d: Vec<f32>,
    positions: Vec<f32>,
    log_scales: Vec<f32>,
    rotations: Vec<f32>,
    opacity_logits: Vec<f32>,
    sh_dc: Vec<f32>,
    sh_rest: Vec<f32>,
    view_grad_norm: Vec<f32>,
    /// With pixel counting on: the per-splat counts, and the reference's.
    pixel_count: Option<(Vec<u32>, Vec<u32>)>,
    /// With the absolute gradient on: the GPU's, per Gaussian.
    abs_grad: Option<Vec<f32>>,
    /// With feature channels: their gradients `[g·C + c]` and the reference's.
    feature_grads: Option<(Vec<f32>, Vec<f64>)>,
    float_atomics: bool,
}

fn run_gpu(ctx: &Arc<GpuContext>, mode: AtomicMode, s: &Scene) -> (GpuResult, Gradients) {
    run_gpu_pixels(ctx, mode, None, RasterVariant::default(), s)
}

/// The largest pixels-per-invocation layout this device runs that is at most `wanted`: a test
/// written for 16 pixels (whole subgroups on lavapipe's 8) runs 8 on a GPU with subgroups of 32.
fn layout(ctx: &GpuContext, wanted: u32) -> u32 {
    let layouts = pixel_layouts(&ctx.info);
    *layouts
        .iter()
        .rev()
        .find(|&&p| p <= wanted)
        .unwrap_or(&layouts[0])
}

/// As `run_gpu`, with `pixels` per invocation of the rasterizer backward instead of the
/// device's default (the GPU layout, 1, runs on lavapipe too this way).
fn run_gpu_pixels(
    ctx: &Arc<GpuContext>,
    mode: AtomicMode,
    pixels: Option<u32>,
    variant: RasterVariant,
    s: &Scene,
) -> (GpuResult, Gradients) {
    let count_pixels = variant.count_pixels;
    let fused = s
        .filter3d
        .as_ref()
        .map(|f| mip::fuse(&s.gaussians, f).unwrap());
    let rendered = fused.as_ref().unwrap_or(&s.gaussians);
    let forward = reference::render(
        rendered,
        &s.camera,
        &s.pose,
        s.degree,
        s.background,
        &s.settings,
    )
    .unwrap();
    let mut want = reference::backward(
        rendered,
        &s.camera,
        &s.pose,
        s.degree,
        s.background,
        &s.settings,
        &forward,
        &s.dl_dimage,
    )
    .unwrap();
    // Feature channels blend with the colour's weights: their gradients reach the geometry
    // too, and from there the parameters.
    let mut want_features = None;
    if let Some(f) = &s.features {
        let (geometry, grads) = reference::decoder::rasterize_features_backward(
            &forward.projected,
            &forward.bins,
            &forward.raster,
            &f.values,
            f.channels,
            &s.settings,
            &f.dl_dimage,
        )
        .unwrap();
        let pg = &mut want.projected;
        for i in 0..pg.opacity.len() {
            for c in 0..2 {
                pg.mean2d[i][c] += geometry.mean2d[i][c];
            }
            for c in 0..3 {
                pg.conic[i][c] += geometry.conic[i][c];
            }
            pg.opacity[i] += geometry.opacity[i];
        }
        want.params = reference::backward::preprocess_backward(
            rendered,
            &forward.projected,
            &s.camera,
            &s.pose,
            s.degree,
            &s.settings,
            &want.projected,
        )
        .unwrap();
        want.ndc_mean2d_norm = reference::backward::ndc_mean2d_norm(&want.projected, &s.camera);
        want_features = Some(grads);
    }
    if let Some(f) = &s.filter3d {
        want.params = mip::fuse_backward(&s.gaussians, f, &want.params).unwrap();
    }
    let fx = gpu_forward_fixture(&forward, &s.camera, &s.pose);
    let n = s.gaussians.len();
    let filter_buf = s.filter3d.as_ref().map(|f| {
        let f32s: Vec<f32> = f.iter().map(|&v| v as f32).collect();
        GpuBuffer::from_slice(ctx, "filter3d", &f32s).unwrap()
    });

    // The camera sits at index 1 behind a decoy, so the kernels must use the index.
    let decoy = CameraGpu::new(
        &PinholeCamera {
            fx: 3.0,
            fy: 3.0,
            cx: 1.0,
            cy: 1.0,
            width: 3,
            height: 2,
        },
        &Pose::IDENTITY,
    );
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[decoy, fx.camera]).unwrap();
    let projected = ProjectedBuffers::from_records(ctx, "projected", &fx.projected).unwrap();
    let tile_ranges = GpuBuffer::from_slice(ctx, "tile_ranges", &fx.tile_ranges).unwrap();
    let sorted_ids = GpuBuffer::from_slice(ctx, "sorted_ids", &fx.sorted_ids).unwrap();
    let final_t = GpuBuffer::from_slice(ctx, "final_t", &fx.final_t).unwrap();
    let last_index = GpuBuffer::from_slice(ctx, "last_index", &fx.last_index).unwrap();
    let dl: Vec<f32> = s.dl_dimage.iter().flatten().map(|&v| v as f32).collect();
    let dl_dimage = GpuBuffer::from_slice(ctx, "dl_dimage", &dl).unwrap();
    let params = gaussian_params(&s.gaussians, s.stored_degree);
    let splats = GpuSplats::upload(ctx, &params, n + SPARE).unwrap();
    let grads = GpuSplats::zeroed(ctx, "grad_", s.stored_degree, n, n + SPARE).unwrap();
    let view_grad_norm = GpuBuffer::<f32>::from_slice(ctx, "vgn", &vec![0.0; n + SPARE]).unwrap();
    let feature_bufs = s.features.as_ref().map(|f| {
        let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<_>>();
        (
            GpuBuffer::from_slice(ctx, "features", &f32s(&f.values)).unwrap(),
            GpuBuffer::from_slice(ctx, "dl_dfeatures", &f32s(&f.dl_dimage)).unwrap(),
            // Poisoned past `count`: the pass zeroes and fills the first count·C only.
            GpuBuffer::<f32>::from_slice(
                ctx,
                "g_features",
                &vec![f32::NAN; (n + SPARE) * f.channels],
            )
            .unwrap(),
        )
    });

    let mut bwd = match pixels {
        Some(p) => Backward::with_pixels(ctx, 1, mode, p).unwrap(),
        None => Backward::with_atomics(ctx, 1, mode).unwrap(),
    };
    bwd.reserve(ctx, n).unwrap();
    bwd = bwd.with_variant(ctx, variant).unwrap();
    // Poisoned: the pass must zero the first `count` and leave the rest.
    let pixel_count =
        GpuBuffer::<u32>::from_slice(ctx, "pixel count", &vec![u32::MAX; n + SPARE]).unwrap();
    let abs_grad =
        GpuBuffer::<f32>::from_slice(ctx, "abs grad", &vec![f32::NAN; n + SPARE]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    for (buf, _) in grads.groups() {
        rec.fill(buf, NAN_BITS);
    }
    rec.fill(&view_grad_norm, NAN_BITS);
    rec.fill(bwd.grad2d(), NAN_BITS);
    let constants = RenderConstants::from_settings(&s.settings);
    bwd.record(
        ctx,
        &mut rec,
        &BackwardArgs {
            cameras: &cameras,
            camera_index: 1,
            camera: &fx.camera,
            projected: &projected,
            tile_ranges: &tile_ranges,
            sorted_ids: &sorted_ids,
            final_t: &final_t,
            last_index: &last_index,
            dl_dimage: &dl_dimage,
            splats: &splats,
            grads: &grads,
            view_grad_norm: &view_grad_norm,
            pixel_count: count_pixels.then_some(&pixel_count),
            abs_grad: variant.abs_grad.then_some(&abs_grad),
            filter3d: filter_buf.as_ref(),
            features: feature_bufs.as_ref().zip(s.features.as_ref()).map(
                |((values, dl_dimage, grads), f)| FeatureGrads {
                    values,
                    dl_dimage,
                    grads,
                    channels: f.channels as u32,
                },
            ),
            count: n,
            sh_degree: s.degree as u32,
            constants,
            background: s.background.map(|v| v as f32),
        },
    )
    .unwrap();
    rec.barrier();
    rec.submit_and_wait().unwrap();

    let all = |b: &GpuBuffer<f32>| b.read().unwrap();
    let result = GpuResult {
        grad2d: all(bwd.grad2d()),
        positions: all(&grads.positions),
        log_scales: all(&grads.log_scales),
        rotations: all(&grads.rotations),
        opacity_logits: all(&grads.opacity_logits),
        sh_dc: all(&grads.sh_dc),
        sh_rest: {
            // The planes in the logical layout, rows past `count` included (poison checked below).
            let planes: Vec<Vec<f32>> = grads.sh_rest.iter().map(all).collect();
            let refs: Vec<&[f32]> = planes.iter().map(Vec::as_slice).collect();
            sh_planes::merge(&refs, n + SPARE, sh_rest_coeffs(s.stored_degree))
        },
        view_grad_norm: all(&view_grad_norm),
        pixel_count: count_pixels.then(|| {
            let got = pixel_count.read().unwrap();
            assert!(
                got[n..].iter().all(|&c| c == u32::MAX),
                "pixel_count: written past count"
            );
            (got[..n].to_vec(), forward.raster.pixel_count.clone())
        }),
        abs_grad: variant.abs_grad.then(|| {
            let got = abs_grad.read().unwrap();
            assert!(
                got[n..].iter().all(|v| v.is_nan()),
                "abs_grad: written past count"
            );
            got[..n].to_vec()
        }),
        feature_grads: feature_bufs
            .as_ref()
            .zip(s.features.as_ref())
            .map(|((_, _, g), f)| {
                let got = g.read().unwrap();
                assert!(
                    got[n * f.channels..].iter().all(|v| v.is_nan()),
                    "feature gradients: written past count"
                );
                (
                    got[..n * f.channels].to_vec(),
                    want_features.clone().expect("computed with the features"),
                )
            }),
        float_atomics: bwd.uses_float_atomics(),
    };
    // Past `count`: untouched (still NaN).
    let rest = 3 * sh_rest_coeffs(s.stored_degree);
    for (name, buf, stride) in [
        ("positions", &result.positions, 3),
        ("log_scales", &result.log_scales, 3),
        ("rotations", &result.rotations, 4),
        ("opacity_logits", &result.opacity_logits, 1),
        ("sh_dc", &result.sh_dc, 3),
        ("sh_rest", &result.sh_rest, rest),
        ("view_grad_norm", &result.view_grad_norm, 1),
    ] {
        assert!(
            buf[n * stride..(n + SPARE) * stride]
                .iter()
                .all(|v| v.is_nan()),
            "{name}: written past count"
        );
    }
    (result, want)
}

/// `|g − r| ≤ rel·|r| + floor·max|r|` over one group of values (the floor is relative to the
/// largest reference value of the group, so gradients negligible for the group are compared
/// against that scale), and no NaN or infinity anywhere.
fn compare(what: &str, gpu: &[f32], want: &[f64], rel: f64, floor: f64) {
    assert_eq!(gpu.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, (&g, &r)) in gpu.iter().zip(want).enumerate() {
        assert!(g.is_finite(), "{what}[{i}] = {g} (reference {r})");
        let err = (g as f64 - r).abs();
        let tol = rel * r.abs() + floor * scale;
        if err > tol {
            panic!(
                "{what}[{i}]: GPU {g:e} vs reference {r:e} (error {err:e}, tolerance {tol:e}, \
                 group max {scale:e})"
            );
        }
    }
}

fn check_against_reference(label: &str, s: &Scene, got: &GpuResult, want: &Gradients) {
    let n = s.gaussians.len();
    let (rel, floor) = (1e-2, 1e-4);
    let pg = &want.projected;
    let g2 = |k: usize| -> Vec<f32> { (0..n).map(|i| got.grad2d[i * GRAD2D_STRIDE + k]).collect() };
    compare(
        &format!("{label} grad mean2d.x"),
        &g2(0),
        &pg.mean2d.iter().map(|v| v[0]).collect::<Vec<_>>(),
        rel,
        floor,
    );
    compare(
        &format!("{label} grad mean2d.y"),
        &g2(1),
        &pg.mean2d.iter().map(|v| v[1]).collect::<Vec<_>>(),
        rel,
        floor,
    );
    for k in 0..3 {
        compare(
            &format!("{label} grad conic[{k}]"),
            &g2(2 + k),
            &pg.conic.iter().map(|v| v[k]).collect::<Vec<_>>(),
            rel,
            floor,
        );
        compare(
            &format!("{label} grad rgb[{k}]"),
            &g2(5 + k),
            &pg.rgb.iter().map(|v| v[k]).collect::<Vec<_>>(),
            rel,
            floor,
        );
    }
    compare(
        &format!("{label} grad opacity"),
        &g2(8),
        &pg.opacity,
        rel,
        floor,
    );

    let p = &want.params;
    let flat3 = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<_>>();
    compare(
        &format!("{label} positions"),
        &got.positions[..3 * n],
        &flat3(&p.positions),
        rel,
        floor,
    );
    compare(
        &format!("{label} log_scales"),
        &got.log_scales[..3 * n],
        &flat3(&p.log_scales),
        rel,
        floor,
    );
    compare(
        &format!("{label} rotations"),
        &got.rotations[..4 * n],
        &p.rotations.iter().flatten().copied().collect::<Vec<_>>(),
        rel,
        floor,
    );
    compare(
        &format!("{label} opacity_logits"),
        &got.opacity_logits[..n],
        &p.opacity_logits,
        rel,
        floor,
    );
    compare(
        &format!("{label} sh_dc"),
        &got.sh_dc[..3 * n],
        &p.sh.iter().flat_map(|c| c[0]).collect::<Vec<_>>(),
        rel,
        floor,
    );
    let rest = sh_rest_coeffs(s.stored_degree) + 1;
    compare(
        &format!("{label} sh_rest"),
        &got.sh_rest[..3 * (rest - 1) * n],
        &p.sh
            .iter()
            .flat_map(|c| c[1..rest].iter().flatten().copied())
            .collect::<Vec<_>>(),
        rel,
        floor,
    );
    compare(
        &format!("{label} view_grad_norm"),
        &got.view_grad_norm[..n],
        &want.ndc_mean2d_norm,
        rel,
        floor,
    );
}

/// The same scene through both atomic paths.
fn check_scene(ctx: &Arc<GpuContext>, label: &str, s: &Scene) {
    for mode in [AtomicMode::Auto, AtomicMode::CompareSwap] {
        let (got, want) = run_gpu(ctx, mode, s);
        if mode == AtomicMode::CompareSwap {
            assert!(!got.float_atomics);
        } else {
            assert_eq!(got.float_atomics, ctx.info.float_atomic_add);
        }
        check_against_reference(&format!("{label} ({mode:?})"), s, &got, &want);
    }
    // The other pixels-per-invocation layouts (1 is what GPUs run, with the sums through shared
    // memory; more pixels sum per subgroup straight into global memory, see
    // rasterize_backward.glsl). With Pixel-GS's pixel counting and / or the absolute gradient
    // on: the same gradients, and the counts and absolute gradients.
    for (pixels, count_pixels, abs_grad) in [
        (1, false, false),
        (1, true, false),
        (4, true, true),
        (1, false, true),
        (16, true, false),
    ] {
        let variant = RasterVariant {
            count_pixels,
            abs_grad,
            extra: 0,
        };
        let pixels = layout(ctx, pixels);
        let (got, want) = run_gpu_pixels(ctx, AtomicMode::Auto, Some(pixels), variant, s);
        let label = format!("{label} ({pixels} px/invocation, {variant:?})");
        check_against_reference(&label, s, &got, &want);
        if count_pixels {
            check_pixel_counts(&label, &got);
        }
        if let Some(a) = &got.abs_grad {
            let (rel, floor) = (1e-2, 1e-4);
            compare(
                &format!("{label} abs_grad"),
                a,
                &want.ndc_abs_grad,
                rel,
                floor,
            );
            assert!(
                want.ndc_abs_grad.iter().any(|&v| v > 0.0),
                "{label}: no abs gradient"
            );
            // The norm of a sum is at most the sum of the terms' absolute values (L2 ≤ L1).
            for (i, (&abs, &norm)) in a.iter().zip(&got.view_grad_norm).enumerate() {
                assert!(
                    abs >= norm * 0.999 - 1e-12,
                    "{label}: Gaussian {i}: {abs} < {norm}"
                );
            }
        }
    }
    // The compare-and-swap path of the absolute gradient's atomics.
    let variant = RasterVariant {
        abs_grad: true,
        ..Default::default()
    };
    let (got, want) = run_gpu_pixels(ctx, AtomicMode::CompareSwap, None, variant, s);
    let (rel, floor) = (1e-2, 1e-4);
    compare(
        &format!("{label} abs_grad (compare-and-swap)"),
        got.abs_grad.as_ref().unwrap(),
        &want.ndc_abs_grad,
        rel,
        floor,
    );
}

/// The GPU's per-splat pixel counts against the reference's. The GPU tests alpha ≥ 1/255 in
/// f32 on f32-rounded splats, the reference in f64: a pair right at the threshold may fall on
/// either side, so a few single-pixel differences are allowed (none in most scenes).
fn check_pixel_counts(label: &str, got: &GpuResult) {
    let (gpu, want) = got.pixel_count.as_ref().expect("counted");
    let total: u64 = want.iter().map(|&c| c as u64).sum();
    let off: u64 = gpu
        .iter()
        .zip(want)
        .map(|(&g, &w)| (g as i64 - w as i64).unsigned_abs())
        .sum();
    assert!(
        off <= 2 + total / 1000,
        "{label}: pixel counts differ by {off} over {total} (GPU {:?}… reference {:?}…)",
        &gpu[..gpu.len().min(8)],
        &want[..want.len().min(8)]
    );
    assert!(total > 0, "{label}: no splat contributed to any pixel");
}

#[test]
fn random_scenes_match_reference() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0xB4C4);
    let sizes = [(37, 23), (50, 41), (16, 16), (29, 57)];
    for (case, &(w, h)) in sizes.iter().cycle().take(8).enumerate() {
        let degree = case % 4;
        let n = rng.gen_range(40..160);
        let mut s = Scene::random(&mut rng, n, w, h, degree);
        s.background = match case % 3 {
            0 => [1.0; 3],
            1 => [0.0; 3],
            _ => [0; 3].map(|_| rng.gen_range(0.0f32..1.0) as f64),
        };
        check_scene(&ctx, &format!("case {case} {w}×{h} deg {degree} n {n}"), &s);
    }
    ctx.check_validation().unwrap();
}

/// Mip-Splatting's filters: the 2D filter (eps2d = 0.1 with the determinant-ratio opacity
/// factor, whose gradient reaches the opacity logit and the 2D covariance; small splats make the
/// factor small, so its terms dominate) and, on every other case, the 3D filter (scales
/// sqrt(s² + f²), opacity × ρ3; its gradient reaches the log-scales twice).
#[test]
fn mip_filters_match_reference() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0x3117);
    for (case, &(w, h)) in [(37, 23), (50, 41), (29, 57)].iter().enumerate() {
        let n = rng.gen_range(60..140);
        let mut s = Scene::random(&mut rng, n, w, h, case % 4);
        for ls in &mut s.gaussians.log_scales {
            *ls = ls.map(|v| (v - 1.5) as f32 as f64);
        }
        s.settings = RenderSettings::mip_splatting();
        // The 3D filter on every other case (f32-exact, from a tenth to twice the largest scale).
        if case % 2 == 0 {
            s.filter3d = Some(
                s.gaussians
                    .log_scales
                    .iter()
                    .map(|l| {
                        let top = l.iter().copied().fold(f64::MIN, f64::max).exp();
                        (top * rng.gen_range(0.1..2.0)) as f32 as f64
                    })
                    .collect(),
            );
        }
        let forward = reference::render(
            &s.gaussians,
            &s.camera,
            &s.pose,
            s.degree,
            s.background,
            &s.settings,
        )
        .unwrap();
        let visible: Vec<f64> = forward
            .projected
            .iter()
            .filter(|p| !p.culled)
            .map(|p| p.compensation)
            .collect();
        assert!(
            visible.iter().any(|&c| c < 0.5),
            "case {case}: no splat is small enough for the compensation to matter"
        );
        check_scene(&ctx, &format!("mip case {case} {w}×{h} n {n}"), &s);
    }
    ctx.check_validation().unwrap();
}

/// Feature channels (SpacetimeGaussians' full model: 6; 48, the most the backward carries)
/// blended beside the colour, in every pixels-per-invocation layout and both atomic paths: their
/// own gradients, and what they add to the geometry's and the parameters'. On CPU drivers more
/// than one pixel an invocation sums the slots per subgroup by the transposing butterfly,
/// whose last chunk is padded with zeros for these slot counts (subgroup_sums.glsl).
#[test]
fn feature_channels_match_reference_in_every_layout() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(0xFEA7);
    for (case, (channels, pixels, mode)) in [
        (6, None, AtomicMode::Auto),
        (6, Some(1), AtomicMode::Auto),
        (6, Some(1), AtomicMode::CompareSwap),
        (6, Some(4), AtomicMode::Auto),
        (6, Some(16), AtomicMode::Auto),
        (48, None, AtomicMode::Auto),
        (48, Some(1), AtomicMode::Auto),
        (48, Some(8), AtomicMode::Auto),
        (24, Some(16), AtomicMode::Auto),
    ]
    .into_iter()
    .enumerate()
    {
        let (w, h) = [(37, 23), (29, 41)][case % 2];
        let n = rng.gen_range(60..140);
        let s = Scene::random(&mut rng, n, w, h, case % 4).with_features(&mut rng, channels);
        let variant = RasterVariant {
            extra: channels as u32,
            ..Default::default()
        };
        let pixels = pixels.map(|p| layout(&ctx, p));
        let (got, want) = run_gpu_pixels(&ctx, mode, pixels, variant, &s);
        let label = format!("{channels} channels, {pixels:?} px/invocation, {mode:?}");
        check_against_reference(&label, &s, &got, &want);
        let (g, r) = got.feature_grads.as_ref().unwrap();
        compare(&format!("{label} feature gradients"), g, r, 1e-2, 1e-4);
        assert!(
            r.iter().any(|&v| v.abs() > 1e-3),
            "{label}: the features got no gradient"
        );
    }
    // More per-pixel feature gradients an invocation than MAX_PIXEL_FEATURES are refused
    // (lavapipe got 16 × 48 wrong on some scenes), with the numbers; a device whose subgroups
    // leave no 16-pixel layout refuses that first, naming the layouts it takes.
    let err = match Backward::with_pixels(&ctx, 4, AtomicMode::Auto, 16) {
        Ok(b) => {
            let err = b
                .with_variant(
                    &ctx,
                    RasterVariant {
                        extra: 48,
                        ..Default::default()
                    },
                )
                .err()
                .expect("16 pixels × 48 channels is refused")
                .to_string();
            assert!(
                err.contains("48 feature channels at 16 pixels") && err.contains("384"),
                "{err}"
            );
            err
        }
        Err(e) => e.to_string(),
    };
    assert_eq!(
        pixel_layouts(&ctx.info).contains(&16),
        err.contains("feature channels"),
        "{err}"
    );
    ctx.check_validation().unwrap();
}

#[test]
fn dense_opaque_scene_matches_reference() {
    // Opaque, overlapping splats: the alpha_max clamp and the t_min stop are active.
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(77);
    let mut s = Scene::random(&mut rng, 300, 45, 38, 2);
    for (l, ls) in s
        .gaussians
        .opacity_logits
        .iter_mut()
        .zip(&mut s.gaussians.log_scales)
    {
        *l = rng.gen_range(2.0f32..8.0) as f64;
        *ls = ls.map(|v| (v + 0.7) as f32 as f64);
    }
    s.background = [1.0; 3];
    let forward = reference::render(
        &s.gaussians,
        &s.camera,
        &s.pose,
        s.degree,
        s.background,
        &s.settings,
    )
    .unwrap();
    let stopped = forward
        .raster
        .final_transmittance
        .iter()
        .filter(|&&t| t < 0.01)
        .count();
    assert!(
        stopped > 100,
        "scene is not dense enough ({stopped} opaque pixels)"
    );
    check_scene(&ctx, "dense", &s);
    ctx.check_validation().unwrap();
}

#[test]
fn smooth_mode_matches_reference() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(5);
    let mut s = Scene::random(&mut rng, 120, 40, 33, 3);
    s.settings = RenderSettings::smooth();
    s.background = [0.3, 0.6, 0.9];
    check_scene(&ctx, "smooth", &s);
    ctx.check_validation().unwrap();
}

/// Every gradient of the first `count` Gaussians finite.
fn assert_all_finite(label: &str, got: &GpuResult, n: usize, stored_degree: u32) {
    let rest = 3 * sh_rest_coeffs(stored_degree);
    for (name, buf, stride) in [
        ("grad2d", &got.grad2d, GRAD2D_STRIDE),
        ("positions", &got.positions, 3),
        ("log_scales", &got.log_scales, 3),
        ("rotations", &got.rotations, 4),
        ("opacity_logits", &got.opacity_logits, 1),
        ("sh_dc", &got.sh_dc, 3),
        ("sh_rest", &got.sh_rest, rest),
        ("view_grad_norm", &got.view_grad_norm, 1),
    ] {
        if let Some(i) = buf[..n * stride].iter().position(|v| !v.is_finite()) {
            panic!(
                "{label}: {name}[{i}] (Gaussian {}) = {}",
                i / stride.max(1),
                buf[i]
            );
        }
    }
}

#[test]
fn extreme_parameters_give_finite_gradients() {
    // One scene per kind of extreme: 20 extreme Gaussians among 60 ordinary ones, so the
    // extreme ones are not all hidden behind each other. Gradients must be finite, culled
    // Gaussians get zeros, degenerate quaternions no rotation gradient, and the rest still
    // matches the reference.
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(99);
    let (normal, extreme) = (60, 20);
    let n = normal + extreme;
    let ill_conditioned = [0];
    for kind in 0..6 {
        let mut g = random_gaussians(&mut rng, n);
        let (camera, pose) = random_view(&mut rng, 47, 31);
        let center = pose.center();
        for i in normal..n {
            match kind {
                // Scales from 1e-8 to 1e4, log-uniform, per axis; the big ones faint.
                0 => {
                    g.log_scales[i] = [0; 3].map(|_| rng.gen_range(1e-8f64.ln()..1e4f64.ln()));
                    if g.log_scales[i].iter().any(|&l| l > 0.0) {
                        g.opacity_logits[i] = -4.0;
                    }
                }
                1 => g.opacity_logits[i] = if i % 2 == 0 { 50.0 } else { -50.0 },
                2 => {
                    g.rotations[i] = if i % 2 == 0 {
                        [0.0; 4]
                    } else {
                        [0; 4].map(|_| rng.gen_range(-1.0..1.0) * 1e-40)
                    }
                }
                // On, just in front of and behind the near plane, and at the camera centre.
                3 => {
                    let near = s_near();
                    let z = [0.0, near, near * 1.0001, near * 1.5, 2.0 * near, -0.5][i % 6];
                    let xy: [f64; 2] = [rng.gen_range(-0.5..0.5), rng.gen_range(-0.5..0.5)];
                    let cam = [xy[0] * z, xy[1] * z, z];
                    let d = [0, 1, 2].map(|k| cam[k] - pose.translation[k]);
                    let r = pose.rotation;
                    g.positions[i] =
                        [0, 1, 2].map(|k| r[0][k] * d[0] + r[1][k] * d[1] + r[2][k] * d[2]);
                    if z == 0.0 && i % 12 == 0 {
                        g.positions[i] = center;
                    }
                    g.log_scales[i] = [0; 3].map(|_| rng.gen_range(-9.0..-5.0));
                    g.opacity_logits[i] = -3.0;
                }
                // Needle-thin and wide at once, fully opaque.
                4 => {
                    g.log_scales[i] = [rng.gen_range(-18.0..-12.0), -1.0, 0.5];
                    g.opacity_logits[i] = 50.0;
                }
                // Tiny and opaque: sub-pixel footprints (the eps2d dilation dominates).
                _ => {
                    g.log_scales[i] = [0; 3].map(|_| rng.gen_range(-18.0..-8.0));
                    g.opacity_logits[i] = rng.gen_range(3.0..50.0);
                }
            }
        }
        let mut s = Scene::new(&mut rng, g, camera, pose, 3);
        s.background = [1.0; 3];
        let forward = reference::render(
            &s.gaussians,
            &s.camera,
            &s.pose,
            s.degree,
            s.background,
            &s.settings,
        )
        .unwrap();
        for mode in [AtomicMode::Auto, AtomicMode::CompareSwap] {
            let label = format!("extreme kind {kind} ({mode:?})");
            let (got, want) = run_gpu(&ctx, mode, &s);
            assert_all_finite(&label, &got, n, s.stored_degree);
            // Footprints with a condition number past f32 resolution (scales 1e4 against
            // 1e-8) are only required to be finite: the f32 conic cannot represent their long
            // axis, so the gradients along it differ from the f64 reference.
            if !ill_conditioned.contains(&kind) {
                check_against_reference(&label, &s, &got, &want);
            }
            let with_gradient = (normal..n)
                .filter(|&i| want.projected.rgb[i].iter().any(|&v| v != 0.0))
                .count();
            assert!(
                with_gradient >= 3,
                "{label}: only {with_gradient} extreme Gaussians reach a pixel"
            );
            for (i, p) in forward.projected.iter().enumerate() {
                if p.culled {
                    assert_eq!(&got.positions[3 * i..3 * i + 3], &[0.0; 3], "{label}: {i}");
                    assert_eq!(&got.rotations[4 * i..4 * i + 4], &[0.0; 4], "{label}: {i}");
                    assert_eq!(got.view_grad_norm[i], 0.0, "{label}: culled {i}");
                }
                if kind == 2 && i >= normal {
                    assert_eq!(&got.rotations[4 * i..4 * i + 4], &[0.0; 4], "{label}: {i}");
                }
            }
        }
    }
    ctx.check_validation().unwrap();
}

fn s_near() -> f64 {
    RenderSettings::default().near
}

#[test]
fn thousand_gaussians_on_one_pixel() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(1000);
    let n = 1000;
    let mut g = random_gaussians(&mut rng, n);
    let (camera, pose) = random_view(&mut rng, 37, 23);
    for i in 0..n {
        g.positions[i] = [0.01, -0.02, 0.03];
        g.log_scales[i] = [0; 3].map(|_| rng.gen_range(-4.0..-2.5));
        g.opacity_logits[i] = rng.gen_range(-3.0..6.0);
    }
    let mut s = Scene::new(&mut rng, g, camera, pose, 1);
    s.background = [0.0; 3];
    for mode in [AtomicMode::Auto, AtomicMode::CompareSwap] {
        let (got, want) = run_gpu(&ctx, mode, &s);
        assert_all_finite("stacked", &got, n, s.stored_degree);
        check_against_reference(&format!("stacked ({mode:?})"), &s, &got, &want);
    }
    ctx.check_validation().unwrap();
}

#[test]
fn off_screen_gaussians_with_clamped_jacobian_match_reference() {
    // Wide Gaussians whose centres lie beyond the 1.3× FoV clamp but whose footprints reach into
    // the image: the EWA Jacobian clamp is active where gradients are not zero.
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(1300);
    let n = 60;
    let mut g = random_gaussians(&mut rng, n);
    let (camera, pose) = random_view(&mut rng, 41, 35);
    let settings = RenderSettings::default();
    let limits = reference::project::jacobian_limits(&camera, &settings);
    for i in 0..n {
        let z = rng.gen_range(2.0..5.0);
        let side = rng.gen_range(0..4);
        let beyond = rng.gen_range(1.05..1.5);
        let (tx, ty) = match side {
            0 => (
                limits[0][0] * beyond,
                rng.gen_range(limits[1][0]..limits[1][1]),
            ),
            1 => (
                limits[0][1] * beyond,
                rng.gen_range(limits[1][0]..limits[1][1]),
            ),
            2 => (
                rng.gen_range(limits[0][0]..limits[0][1]),
                limits[1][0] * beyond,
            ),
            _ => (
                rng.gen_range(limits[0][0]..limits[0][1]),
                limits[1][1] * beyond,
            ),
        };
        let cam = [tx * z, ty * z, z];
        let d = [0, 1, 2].map(|k| cam[k] - pose.translation[k]);
        let r = pose.rotation;
        g.positions[i] = [0, 1, 2].map(|k| r[0][k] * d[0] + r[1][k] * d[1] + r[2][k] * d[2]);
        g.log_scales[i] = [0; 3].map(|_| rng.gen_range((0.3 * z).ln()..(0.8 * z).ln()));
    }
    let mut s = Scene::new(&mut rng, g, camera, pose, 2);
    s.background = [1.0, 0.5, 0.0];
    let forward = reference::render(
        &s.gaussians,
        &s.camera,
        &s.pose,
        s.degree,
        s.background,
        &s.settings,
    )
    .unwrap();
    let (got, want) = run_gpu(&ctx, AtomicMode::Auto, &s);
    let limits = reference::project::jacobian_limits(&s.camera, &s.settings);
    let clamped_with_gradient = forward
        .projected
        .iter()
        .zip(&want.projected.conic)
        .filter(|(p, gc)| {
            let (_, clamped) = reference::project::ewa_jacobian(&s.camera, p.cam_mean, &limits);
            !p.culled && (clamped[0] || clamped[1]) && gc.iter().any(|v| v.abs() > 1e-6)
        })
        .count();
    assert!(
        clamped_with_gradient >= 10,
        "only {clamped_with_gradient} Gaussians with a clamped Jacobian reach the image"
    );
    check_against_reference("off-screen", &s, &got, &want);
    ctx.check_validation().unwrap();
}

#[test]
fn backward_under_subgroup_size_16() {
    // lavapipe runs with subgroup size 16 when LP_NATIVE_VECTOR_WIDTH=512 (set before the driver
    // loads, hence a child process), so the subgroup reduction is covered at two sizes. Other
    // drivers ignore the variable.
    child_run::rerun_under_subgroup_size_16(
        module_path!(),
        &[
            "random_scenes_match_reference",
            "thousand_gaussians_on_one_pixel",
        ],
    );
}

#[test]
fn record_refuses_mismatched_arguments() {
    let ctx = ctx();
    // More feature channels than the per-splat sums hold, or a layout without whole subgroups:
    // refused with the numbers, before any pipeline is built.
    let too_many = lpmsplat::render::backward::MAX_FEATURE_CHANNELS + 1;
    let err = Backward::new(&ctx, 4)
        .unwrap()
        .with_variant(
            &ctx,
            RasterVariant {
                extra: too_many,
                ..Default::default()
            },
        )
        .err()
        .expect("must refuse");
    assert!(
        err.to_string()
            .contains(&format!("{too_many} feature channels")),
        "{err}"
    );
    let err = Backward::with_pixels(&ctx, 4, AtomicMode::Auto, 3)
        .err()
        .expect("must refuse");
    let layouts = pixel_layouts(&ctx.info);
    let takes = match layouts.len() {
        5 => "1, 2, 4, 8 or 16",
        4 => "1, 2, 4 or 8",
        3 => "1, 2 or 4",
        n => panic!("{n} layouts for subgroups of {}", ctx.info.subgroup_size),
    };
    assert!(
        err.to_string()
            .contains(&format!("this device takes {takes}")),
        "{err}"
    );
    let mut rng = Pcg64::seed_from_u64(3);
    let s = Scene::random(&mut rng, 10, 20, 18, 1);
    let forward = reference::render(
        &s.gaussians,
        &s.camera,
        &s.pose,
        s.degree,
        s.background,
        &s.settings,
    )
    .unwrap();
    let fx = gpu_forward_fixture(&forward, &s.camera, &s.pose);
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[fx.camera]).unwrap();
    let projected = ProjectedBuffers::from_records(&ctx, "projected", &fx.projected).unwrap();
    let tile_ranges = GpuBuffer::from_slice(&ctx, "tile_ranges", &fx.tile_ranges).unwrap();
    let sorted_ids = GpuBuffer::from_slice(&ctx, "sorted_ids", &fx.sorted_ids).unwrap();
    let final_t = GpuBuffer::from_slice(&ctx, "final_t", &fx.final_t).unwrap();
    let last_index = GpuBuffer::from_slice(&ctx, "last_index", &fx.last_index).unwrap();
    let short_image = GpuBuffer::<f32>::from_slice(&ctx, "dl", &[0.0; 7]).unwrap();
    let dl_dimage = GpuBuffer::<f32>::from_slice(&ctx, "dl", &vec![0.5; fx.image.len()]).unwrap();
    let splats = GpuSplats::upload(&ctx, &gaussian_params(&s.gaussians, 1), 10).unwrap();
    let grads = GpuSplats::zeroed(&ctx, "grad_", 1, 10, 10).unwrap();
    let vgn = GpuBuffer::<f32>::from_slice(&ctx, "vgn", &[0.0; 10]).unwrap();
    let small = Backward::new(&ctx, 4).unwrap();
    let big = Backward::new(&ctx, 20).unwrap();
    let args = |count: usize, sh_degree: u32, camera_index: u32, dl: &'static str| BackwardArgs {
        cameras: &cameras,
        camera_index,
        camera: &fx.camera,
        projected: &projected,
        tile_ranges: &tile_ranges,
        sorted_ids: &sorted_ids,
        final_t: &final_t,
        last_index: &last_index,
        dl_dimage: if dl == "short" {
            &short_image
        } else {
            &dl_dimage
        },
        splats: &splats,
        grads: &grads,
        view_grad_norm: &vgn,
        pixel_count: None,
        abs_grad: None,
        count,
        sh_degree,
        constants: RenderConstants::default(),
        background: [0.0; 3],
        filter3d: None,
        features: None,
    };
    let mut rec = Recorder::new(&ctx).unwrap();
    let err = |r: anyhow::Result<()>| r.unwrap_err().to_string();
    assert!(err(small.record(&ctx, &mut rec, &args(10, 1, 0, ""))).contains("reserve"));
    assert!(err(big.record(&ctx, &mut rec, &args(10, 2, 0, ""))).contains("SH degree"));
    assert!(err(big.record(&ctx, &mut rec, &args(10, 1, 1, ""))).contains("camera index"));
    assert!(err(big.record(&ctx, &mut rec, &args(11, 1, 0, ""))).contains("count"));
    assert!(err(big.record(&ctx, &mut rec, &args(10, 1, 0, "short"))).contains("dl_dimage"));
    // The refused calls recorded nothing; a valid one still works.
    assert_eq!(rec.dispatch_count(), 0);
    big.record(&ctx, &mut rec, &args(10, 1, 0, "")).unwrap();
    rec.submit_and_wait().unwrap();
    assert!(vgn.read().unwrap().iter().all(|v| v.is_finite()));
    ctx.check_validation().unwrap();
}
