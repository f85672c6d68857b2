//! The GPU surfel (2DGS) backward against the f64 reference backward
//! (`reference::surfel::backward`): random scenes with random gradients on every output
//! (image, alpha, depth numerator, median depth, normal, distortion), both atomic paths, smooth
//! and normal mode, low-pass-dominated scenes, the official densification statistic, and the
//! unused third log-scale of a 3DGS-shaped buffer; the regularisers' passes against
//! `reference::surfel::regularise`, their forward values (surface depth, normal-consistency
//! terms, both losses) and their gradients. Outputs are poisoned first; the validation layer is
//! on.
#![allow(clippy::too_many_arguments)]

use crate::child_run;

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::reference::scenes;
use lpmsplat::reference::surfel::regularise;
use lpmsplat::reference::surfel::{
    self, random_surfels, RefSurfels, SurfelGradients, SurfelOutputGrads, SurfelSettings,
};
use lpmsplat::render::forward::Capacity;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::render::surfel::backward::{SurfelBackward, SurfelBackwardArgs, MAP_GRADS_STRIDE};
use lpmsplat::render::surfel::forward::{SurfelFrameSettings, SurfelRenderer};
use lpmsplat::render::surfel::layout::{SurfelConstants, MAPS_STRIDE};
use lpmsplat::render::surfel::regularise::{RegulariserWeights, SurfelRegularisers};
use lpmsplat::scene::{PinholeCamera, Pose};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::GaussianParams;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

/// The unused third log-scale: a kernel that read it would see surfels e^30 wide.
const THIRD: f32 = 30.0;

struct Scene {
    surfels: RefSurfels,
    camera: PinholeCamera,
    pose: Pose,
    sh_degree: u32,
    background: [f32; 3],
    settings: SurfelSettings,
    /// f32 values (the GPU's inputs), also given to the reference.
    weights: SurfelOutputGrads,
}

fn random_scene(rng: &mut Pcg64, settings: SurfelSettings, shrink: f64) -> Scene {
    let n = rng.gen_range(1..40);
    let mut surfels = random_surfels(rng, n);
    for l in &mut surfels.log_scales {
        *l = l.map(|v| v + shrink);
    }
    let (w, h) = (rng.gen_range(1..56), rng.gen_range(1..56));
    let (camera, pose) = scenes::random_view(rng, w, h);
    let px = (w * h) as usize;
    let mut weights = SurfelOutputGrads::zeros(px);
    let mut r = |lo: f32, hi: f32| rng.gen_range(lo..hi) as f64;
    for p in 0..px {
        weights.image[p] = [r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0)];
        weights.alpha[p] = r(-1.0, 1.0);
        weights.depth[p] = r(-0.3, 0.3);
        weights.median_depth[p] = r(-0.3, 0.3);
        weights.normal[p] = [r(-1.0, 1.0), r(-1.0, 1.0), r(-1.0, 1.0)];
        weights.distortion[p] = r(-100.0, 100.0);
    }
    let mut scene = Scene {
        surfels,
        camera,
        pose,
        sh_degree: rng.gen_range(0..=3),
        background: [rng.gen(), rng.gen(), rng.gen()],
        settings,
        weights,
    };
    leave_out_grazing_hits(&mut scene);
    scene
}

/// A surfel seen at a grazing angle hits some pixels' rays far beyond the scene (thousands of
/// units in smooth mode, where nothing is too faint to blend): that hit's depth and its
/// derivatives come out of a near-singular intersection (1/p₃), where f32 keeps few digits of
/// what f64 computes. Pixels with a hit beyond 20 units (the scenes lie within ~6) are left out
/// of the loss: zero gradients on every output there.
fn leave_out_grazing_hits(s: &mut Scene) {
    let params = s.surfels.to_params(3, THIRD);
    let exact = RefSurfels::from_params(&params);
    let fwd = surfel::render(&exact, &s.camera, &s.pose, 0, [0.0; 3], &s.settings).unwrap();
    for j in 0..s.camera.height {
        for i in 0..s.camera.width {
            let far = fwd.bins.lists[fwd.bins.tile_of_pixel(i, j)]
                .iter()
                .any(|&g| {
                    let p = &fwd.projected[g as usize];
                    surfel::sample_surfel(p, i as f64 + 0.5, j as f64 + 0.5, &s.settings)
                        .is_ok_and(|h| h.z > 20.0)
                });
            if far {
                let pix = (j * s.camera.width + i) as usize;
                let w = &mut s.weights;
                w.image[pix] = [0.0; 3];
                w.normal[pix] = [0.0; 3];
                w.alpha[pix] = 0.0;
                w.depth[pix] = 0.0;
                w.median_depth[pix] = 0.0;
                w.distortion[pix] = 0.0;
            }
        }
    }
}

struct GpuResult {
    params: GaussianParams,
    view_grad_norm: Vec<f32>,
    last_index: Vec<u32>,
    median_index: Vec<u32>,
    tile_lists: Vec<Vec<u32>>,
}

/// `pixels`: pixels per invocation of the rasterizer backward (None: the device's default).
fn run_gpu(
    ctx: &Arc<GpuContext>,
    s: &Scene,
    compare_swap: bool,
    pixels: Option<u32>,
) -> (GpuResult, RefSurfels) {
    run_gpu_with(ctx, s, compare_swap, pixels, false)
}

/// `run_gpu`; `full_lists`: the rasterizers' subgroups visit every surfel of their tile.
fn run_gpu_with(
    ctx: &Arc<GpuContext>,
    s: &Scene,
    compare_swap: bool,
    pixels: Option<u32>,
    full_lists: bool,
) -> (GpuResult, RefSurfels) {
    let params = s.surfels.to_params(3, THIRD);
    let exact = RefSurfels::from_params(&params);
    let n = params.len();
    let splats = GpuSplats::upload(ctx, &params, n.max(1)).unwrap();
    let grads = GpuSplats::zeroed(ctx, "grad_", 3, n, n.max(1)).unwrap();
    for (buf, _) in grads.groups() {
        buf.upload(&vec![f32::NAN; buf.len()]).unwrap();
    }
    let view_grad_norm = GpuBuffer::from_slice(ctx, "vgn", &vec![f32::NAN; n.max(1)]).unwrap();
    let cam = CameraGpu::new(&s.camera, &s.pose);
    let mut decoy = cam;
    decoy.r0[3] += 1.0;
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[decoy, cam]).unwrap();
    let mut constants = SurfelConstants::from_settings(&s.settings);
    if full_lists {
        constants.flags |= SurfelConstants::FULL_LISTS;
    }
    let mut renderer = SurfelRenderer::new(ctx, Capacity::single()).unwrap();
    renderer
        .render_blocking(
            &splats,
            3,
            &cameras,
            1,
            &cam,
            &SurfelFrameSettings {
                sh_degree: s.sh_degree,
                background: s.background,
                constants,
            },
        )
        .unwrap();
    let w = &s.weights;
    let dl_dimage: Vec<f32> = w.image.iter().flatten().map(|&v| v as f32).collect();
    let mut dl_dmaps = Vec::with_capacity(w.alpha.len() * MAP_GRADS_STRIDE);
    for p in 0..w.alpha.len() {
        dl_dmaps.extend(
            [
                w.alpha[p],
                w.depth[p],
                w.median_depth[p],
                w.normal[p][0],
                w.normal[p][1],
                w.normal[p][2],
                w.distortion[p],
                0.0,
            ]
            .map(|v| v as f32),
        );
    }
    let dl_dimage = GpuBuffer::from_slice(ctx, "dl_dimage", &dl_dimage).unwrap();
    let dl_dmaps = GpuBuffer::from_slice(ctx, "dl_dmaps", &dl_dmaps).unwrap();
    let backward = match pixels {
        Some(p) => SurfelBackward::with_pixels(ctx, n, compare_swap, p).unwrap(),
        None => SurfelBackward::new(ctx, n, compare_swap).unwrap(),
    };
    let mut rec = Recorder::new(ctx).unwrap();
    backward
        .record(
            ctx,
            &mut rec,
            &renderer,
            &SurfelBackwardArgs {
                cameras: &cameras,
                camera_index: 1,
                camera: &cam,
                dl_dimage: &dl_dimage,
                dl_dmaps: &dl_dmaps,
                splats: &splats,
                scale_stride: 3,
                grads: &grads,
                view_grad_norm: &view_grad_norm,
                count: n,
                sh_degree: s.sh_degree,
                constants,
                background: s.background,
            },
            None,
        )
        .unwrap();
    rec.submit_and_wait().unwrap();
    let px = (s.camera.width * s.camera.height) as usize;
    let f = &renderer.base.frame;
    let ranges = f
        .tile_ranges
        .read_range(0, cam.tile_count() as usize)
        .unwrap();
    let ids = renderer.base.sorted_ids().read().unwrap();
    let result = GpuResult {
        params: grads.download().unwrap(),
        view_grad_norm: view_grad_norm.read_range(0, n).unwrap(),
        last_index: f.last_index.read_range(0, px).unwrap(),
        median_index: renderer.surfel.median_index.read_range(0, px).unwrap(),
        tile_lists: ranges
            .iter()
            .map(|r| ids[r[0] as usize..r[1] as usize].to_vec())
            .collect(),
    };
    (result, exact)
}

/// The default `(rel, floor)` of [`compare`].
const TOLERANCE: (f64, f64) = (1e-2, 2e-4);

/// `|g − r| ≤ rel·|r| + floor·max|r|` over one group, and nothing non-finite.
fn compare(what: &str, gpu: &[f32], want: &[f64], rel: f64, floor: f64) {
    compare_at_scale(what, gpu, want, rel, floor, 0.0);
}

/// [`compare`] with the floor relative to at least `min_scale`.
fn compare_at_scale(what: &str, gpu: &[f32], want: &[f64], rel: f64, floor: f64, min_scale: f64) {
    assert_eq!(gpu.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(min_scale, |m, v| m.max(v.abs()));
    for (i, (&g, &r)) in gpu.iter().zip(want).enumerate() {
        assert!(g.is_finite(), "{what}[{i}] = {g} (reference {r})");
        let err = (g as f64 - r).abs();
        let tol = rel * r.abs() + floor * scale;
        assert!(
            err <= tol,
            "{what}[{i}]: GPU {g:e} vs reference {r:e} (error {err:e}, tolerance {tol:e}, group \
             max {scale:e})"
        );
    }
}

/// Runs one scene on the GPU and the reference; false when the f32 forward's structure (tile
/// lists, last or median contributor) differs from the f64 one, so the gradients are not
/// comparable.
fn check_scene(
    ctx: &Arc<GpuContext>,
    label: &str,
    s: &Scene,
    compare_swap: bool,
    pixels: Option<u32>,
    (rel, floor): (f64, f64),
) -> bool {
    let (got, exact) = run_gpu(ctx, s, compare_swap, pixels);
    let bg = s.background.map(|v| v as f64);
    let deg = s.sh_degree as usize;
    let fwd = surfel::render(&exact, &s.camera, &s.pose, deg, bg, &s.settings).unwrap();
    if got.tile_lists != fwd.bins.lists
        || got.last_index != fwd.raster.last_contributor
        || got.median_index != fwd.raster.median_contributor
    {
        eprintln!("{label}: the f32 forward's structure differs; not compared");
        return false;
    }
    let want: SurfelGradients = surfel::backward(
        &exact,
        &s.camera,
        &s.pose,
        deg,
        bg,
        &s.settings,
        &fwd,
        &s.weights,
    )
    .unwrap();
    let n = exact.len();
    let p = &want.params;
    let g = &got.params;
    let flat3 = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
    let want3 = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<f64>>();
    // The geometry groups share one floor: the largest of their reference gradients (world
    // units of a scene of size ~1; log-scales and quaternions are dimensionless). A group whose
    // gradients are all tiny, e.g. the log-scales of sub-pixel surfels or of a loss on the
    // median depth alone (exactly 0: the hit point does not depend on the scales), is a
    // difference of per-pixel terms far larger than itself, which f32 leaves at that floor.
    let geometry = p
        .positions
        .iter()
        .flatten()
        .chain(p.log_scales.iter().flatten())
        .chain(p.rotations.iter().flatten())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    compare_at_scale(
        &format!("{label} positions"),
        &flat3(&g.positions),
        &want3(&p.positions),
        rel,
        floor,
        geometry,
    );
    let gpu_scales: Vec<f32> = g.log_scales.iter().flat_map(|l| [l[0], l[1]]).collect();
    compare_at_scale(
        &format!("{label} log_scales"),
        &gpu_scales,
        &p.log_scales.iter().flatten().copied().collect::<Vec<_>>(),
        rel,
        floor,
        geometry,
    );
    assert!(
        g.log_scales.iter().all(|l| l[2] == 0.0),
        "{label}: the unused third log-scale got a gradient"
    );
    compare_at_scale(
        &format!("{label} rotations"),
        &g.rotations.iter().flatten().copied().collect::<Vec<_>>(),
        &p.rotations.iter().flatten().copied().collect::<Vec<_>>(),
        rel,
        floor,
        geometry,
    );
    compare(
        &format!("{label} opacity_logits"),
        &g.opacity_logits,
        &p.opacity_logits,
        rel,
        floor,
    );
    compare(
        &format!("{label} sh_dc"),
        &flat3(&g.sh_dc),
        &p.sh.iter().flat_map(|c| c[0]).collect::<Vec<_>>(),
        rel,
        floor,
    );
    let rest = g.rest_coeffs();
    compare(
        &format!("{label} sh_rest"),
        &g.sh_rest,
        &p.sh
            .iter()
            .flat_map(|c| c[1..=rest].iter().flatten().copied())
            .collect::<Vec<_>>(),
        rel,
        floor,
    );
    compare(
        &format!("{label} view_grad_norm"),
        &got.view_grad_norm,
        &want.ndc_center_norm,
        rel,
        floor,
    );
    assert_eq!(got.view_grad_norm.len(), n);
    true
}

fn run(settings: SurfelSettings, seeds: u64, shrink: f64, tolerance: (f64, f64), label: &str) {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(900 + seeds + shrink.abs() as u64);
    let mut compared = 0;
    for seed in 0..seeds {
        let s = random_scene(&mut rng, settings, shrink);
        // Both atomic paths on alternate seeds, and the pixels-per-invocation layouts in turn:
        // the device's default, 1 (GPUs: sums through shared memory) and 4 (CPU drivers:
        // per-subgroup sums straight to global memory).
        let cas = seed % 2 == 1;
        let pixels = [None, Some(1), Some(4)][(seed % 3) as usize];
        if check_scene(
            &ctx,
            &format!("{label} seed {seed} (cas {cas}, pixels {pixels:?})"),
            &s,
            cas,
            pixels,
            tolerance,
        ) {
            compared += 1;
        }
    }
    assert!(
        compared * 10 >= seeds * 9,
        "{label}: only {compared} of {seeds} scenes comparable"
    );
    ctx.check_validation().unwrap();
}

/// The per-subgroup lists (surfels whose reach meets the subgroup's pixels, before its last
/// contributor) give the gradients of full lists: the same sums. Lavapipe on several threads
/// adds the tiles' sums by atomics in an order that depends on timing, which the lists change,
/// so there the comparison allows 1e-4 of the largest gradient; the test also re-runs itself
/// on one lavapipe thread (LP_NUM_THREADS=1, a child process), where the order is fixed and
/// the gradients must be equal bit for bit.
#[test]
fn reach_culled_lists_give_the_gradients_of_full_lists() {
    let one_thread = std::env::var("LP_NUM_THREADS").as_deref() == Ok("1");
    if !child_run::is_child() {
        child_run::run_child(
            module_path!(),
            &[("LP_NUM_THREADS", "1")],
            &[
                "--exact",
                "reach_culled_lists_give_the_gradients_of_full_lists",
            ],
            1,
        );
    }
    let ctx = ctx();
    let exact = one_thread && ctx.info.device_type.starts_with("CPU");
    let mut rng = Pcg64::seed_from_u64(0x5EED);
    for seed in 0..12 {
        let s = random_scene(&mut rng, SurfelSettings::default(), [0.0, -3.0][seed % 2]);
        let pixels = [None, Some(2), Some(8)][seed % 3];
        let label = format!("seed {seed}, pixels {pixels:?}");
        let (a, _) = run_gpu_with(&ctx, &s, false, pixels, false);
        let (b, _) = run_gpu_with(&ctx, &s, false, pixels, true);
        assert_eq!(a.last_index, b.last_index, "{label}");
        let groups = |p: &GaussianParams| -> Vec<(&'static str, Vec<f32>)> {
            vec![
                ("positions", p.positions.iter().flatten().copied().collect()),
                (
                    "log_scales",
                    p.log_scales.iter().flatten().copied().collect(),
                ),
                ("rotations", p.rotations.iter().flatten().copied().collect()),
                ("opacity_logits", p.opacity_logits.clone()),
                ("sh_dc", p.sh_dc.iter().flatten().copied().collect()),
                ("sh_rest", p.sh_rest.clone()),
            ]
        };
        for ((name, ga), (_, gb)) in groups(&a.params).into_iter().zip(groups(&b.params)) {
            let scale = gb.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-20);
            for (i, (x, y)) in ga.iter().zip(&gb).enumerate() {
                assert!(
                    if exact { x.to_bits() == y.to_bits() } else { (x - y).abs() <= 1e-4 * scale },
                    "{label}: {name}[{i}] culled {x} vs full {y} (group max {scale}, exact {exact})"
                );
            }
        }
    }
    ctx.check_validation().unwrap();
}

#[test]
fn random_scenes_match_the_reference_backward() {
    run(SurfelSettings::default(), 40, 0.0, TOLERANCE, "normal");
}

#[test]
fn smooth_mode_matches_the_reference_backward() {
    run(SurfelSettings::smooth(), 20, 0.0, TOLERANCE, "smooth");
}

/// Sub-pixel surfels: the low-pass filter decides most pixels, so most of the kernel's
/// gradient goes to the box centre and through the box formula.
#[test]
fn lowpass_dominated_scenes_match_the_reference_backward() {
    run(SurfelSettings::default(), 20, -3.0, TOLERANCE, "low-pass");
}

#[test]
fn a_short_gradient_buffer_is_refused() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(3);
    let s = random_scene(&mut rng, SurfelSettings::default(), 0.0);
    let params = s.surfels.to_params(3, THIRD);
    let n = params.len();
    let splats = GpuSplats::upload(&ctx, &params, n).unwrap();
    let grads = GpuSplats::zeroed(&ctx, "grad_", 3, n, n).unwrap();
    let cam = CameraGpu::new(&s.camera, &s.pose);
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
    let renderer = SurfelRenderer::new(&ctx, Capacity::for_frame(n, &cam)).unwrap();
    let short = GpuBuffer::from_slice(&ctx, "short", &[0.0f32; 3]).unwrap();
    let vgn = GpuBuffer::from_slice(&ctx, "vgn", &vec![0.0f32; n]).unwrap();
    let backward = SurfelBackward::new(&ctx, n, false).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let err = backward
        .record(
            &ctx,
            &mut rec,
            &renderer,
            &SurfelBackwardArgs {
                cameras: &cameras,
                camera_index: 0,
                camera: &cam,
                dl_dimage: &short,
                dl_dmaps: &short,
                splats: &splats,
                scale_stride: 3,
                grads: &grads,
                view_grad_norm: &vgn,
                count: n,
                sh_degree: 0,
                constants: SurfelConstants::default(),
                background: [0.0; 3],
            },
            None,
        )
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("dl_dimage") || err.contains("dl_dmaps"),
        "{err}"
    );
}

/// One frame of a dense random scene (interior pixels with a surface to take normals of) with
/// the regularisers: the GPU frame and its regulariser passes, and the reference forward of
/// the same f32 values.
struct RegularisedFrame {
    camera: PinholeCamera,
    weights: RegulariserWeights,
    px: usize,
    renderer: SurfelRenderer,
    regs: SurfelRegularisers,
    /// dL/d(maps) as the GPU wrote it (poisoned before).
    dl_dmaps: Vec<f32>,
    fwd: surfel::SurfelRenderOutput,
}

impl RegularisedFrame {
    /// Whether the f32 frame blended the same surfels as the f64 one (else not comparable).
    fn comparable(&self) -> bool {
        let f = &self.renderer.base.frame;
        f.last_index.read_range(0, self.px).unwrap() == self.fwd.raster.last_contributor
    }
}

/// Draws the scene of `seed` from `rng` (normal weight 0.05–0.15, distortion 100, expected
/// depth on even seeds and median on odd ones) and runs both sides.
fn regularised_frame(ctx: &Arc<GpuContext>, rng: &mut Pcg64, seed: u64) -> RegularisedFrame {
    // These random scenes lie 2–6 units from the camera, a scene of extent about 4, where the
    // default near plane (0.05 of a unit extent) is the official 0.2 units. With 0.05 here
    // the distortion map's depths m(z) = 1 − near/z crowd within 2 % of 1, and its f32
    // differences, not the kernels, decide the comparison.
    let settings = SurfelSettings {
        near: 0.2,
        ..SurfelSettings::default()
    };
    let mut s = random_scene(rng, settings, 0.8);
    for _ in 0..20 {
        let extra = random_surfels(rng, 1);
        s.surfels.positions.extend(extra.positions);
        s.surfels
            .log_scales
            .extend(extra.log_scales.iter().map(|l| l.map(|v| v + 0.8)));
        s.surfels.rotations.extend(extra.rotations);
        s.surfels.opacity_logits.extend(extra.opacity_logits);
        s.surfels.sh.extend(extra.sh);
    }
    let weights = RegulariserWeights {
        normal: 0.05 * (1 + seed % 3) as f32,
        distortion: 100.0,
        depth_ratio: (seed % 2) as f32,
    };
    let params = s.surfels.to_params(3, THIRD);
    let exact = RefSurfels::from_params(&params);
    let n = params.len();
    let splats = GpuSplats::upload(ctx, &params, n).unwrap();
    let cam = CameraGpu::new(&s.camera, &s.pose);
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[cam]).unwrap();
    let mut renderer = SurfelRenderer::new(ctx, Capacity::single()).unwrap();
    let constants = SurfelConstants::from_settings(&s.settings);
    renderer
        .render_blocking(
            &splats,
            3,
            &cameras,
            0,
            &cam,
            &SurfelFrameSettings {
                sh_degree: s.sh_degree,
                background: s.background,
                constants,
            },
        )
        .unwrap();
    let px = (s.camera.width * s.camera.height) as usize;
    let regs = SurfelRegularisers::new(ctx, px).unwrap();
    // The scratch outputs too: a pass that skipped a pixel would leave NaN.
    regs.surf_depth.upload(&vec![f32::NAN; px]).unwrap();
    regs.terms.upload(&vec![f32::NAN; px]).unwrap();
    let dl_dmaps =
        GpuBuffer::from_slice(ctx, "dl_dmaps", &vec![f32::NAN; px * MAP_GRADS_STRIDE]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    regs.record(&mut rec, &renderer, &cameras, 0, &cam, &weights, &dl_dmaps)
        .unwrap();
    rec.submit_and_wait().unwrap();
    let bg = s.background.map(|v| v as f64);
    let fwd = surfel::render(
        &exact,
        &s.camera,
        &s.pose,
        s.sh_degree as usize,
        bg,
        &s.settings,
    )
    .unwrap();
    RegularisedFrame {
        camera: s.camera,
        weights,
        px,
        renderer,
        regs,
        dl_dmaps: dl_dmaps.read().unwrap(),
        fwd,
    }
}

/// The regularisers' GPU passes (surface depth, depth normals, gather) against
/// `reference::surfel::regularise` on the same frames: every slot of dL/d(maps).
#[test]
fn regulariser_map_gradients_match_the_reference() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(4242);
    let (mut compared, mut with_normals) = (0, 0);
    for seed in 0..16u64 {
        let frame = regularised_frame(&ctx, &mut rng, seed);
        if !frame.comparable() {
            continue;
        }
        let RegularisedFrame {
            camera,
            weights,
            px,
            dl_dmaps: got,
            fwd,
            ..
        } = frame;
        let (_, gn) = regularise::normal_consistency(
            &fwd.raster,
            &camera,
            weights.depth_ratio as f64,
            weights.normal as f64,
        );
        let (_, gd) = regularise::distortion_loss(&fwd.raster, weights.distortion as f64);
        let slot =
            |k: usize| -> Vec<f32> { (0..px).map(|p| got[p * MAP_GRADS_STRIDE + k]).collect() };
        let label = format!("regularisers seed {seed}");
        compare(&format!("{label} alpha"), &slot(0), &gn.alpha, 1e-2, 2e-3);
        compare(&format!("{label} depth"), &slot(1), &gn.depth, 1e-2, 2e-3);
        compare(
            &format!("{label} median"),
            &slot(2),
            &gn.median_depth,
            1e-2,
            2e-3,
        );
        for k in 0..3 {
            let want: Vec<f64> = gn.normal.iter().map(|v| v[k]).collect();
            compare(
                &format!("{label} normal[{k}]"),
                &slot(3 + k),
                &want,
                1e-2,
                2e-3,
            );
        }
        compare(
            &format!("{label} distortion"),
            &slot(6),
            &gd.distortion,
            1e-6,
            0.0,
        );
        if gn.normal.iter().any(|v| *v != [0.0; 3]) {
            with_normals += 1;
        }
        compared += 1;
    }
    assert!(compared >= 12, "only {compared} of 16 scenes comparable");
    assert!(
        with_normals >= 10,
        "only {with_normals} scenes had surface normals"
    );
    ctx.check_validation().unwrap();
}

/// The regularisers' forward values on the GPU against `reference::surfel::regularise` on the
/// same frames (the scenes of `regulariser_map_gradients_match_the_reference`): the
/// surface-depth map, the per-pixel normal-consistency term `1 − alpha·N·n̂` and the two losses
/// (λ·mean of the terms, λ·mean of the distortion map). Measured on lavapipe: surface depth
/// within 3.3e-5 (relative), terms within 2.4e-5, losses within 1.3e-4 (relative).
#[test]
fn regulariser_forward_values_match_the_reference() {
    let ctx = ctx();
    let mut rng = Pcg64::seed_from_u64(4242);
    let (mut compared, mut with_normals) = (0, 0);
    let (mut worst_depth, mut worst_term, mut worst_loss) = (0.0f64, 0.0f64, 0.0f64);
    for seed in 0..16u64 {
        let frame = regularised_frame(&ctx, &mut rng, seed);
        if !frame.comparable() {
            continue;
        }
        let (px, w) = (frame.px, &frame.weights);
        let raster = &frame.fwd.raster;
        let label = format!("regularisers seed {seed} (depth ratio {})", w.depth_ratio);
        let got_depth = frame.regs.surf_depth.read_range(0, px).unwrap();
        let got_terms = frame.regs.terms.read_range(0, px).unwrap();
        let maps = frame
            .renderer
            .surfel
            .maps
            .read_range(0, px * MAPS_STRIDE)
            .unwrap();
        let (depth, _) = regularise::surface_depth(raster, w.depth_ratio as f64);
        compare(
            &format!("{label} surface depth"),
            &got_depth,
            &depth,
            1e-4,
            1e-5,
        );
        for (g, r) in got_depth.iter().zip(&depth) {
            worst_depth = worst_depth.max((*g as f64 - r).abs() / r.abs().max(1.0));
        }
        // The terms from the reference's depth normals.
        let normals = regularise::depth_normals(&frame.camera, &depth);
        let terms: Vec<f64> = (0..px)
            .map(|p| {
                let n = normals[p];
                let r = raster.normal[p];
                1.0 - raster.alpha[p] * (r[0] * n[0] + r[1] * n[1] + r[2] * n[2])
            })
            .collect();
        compare(
            &format!("{label} normal terms"),
            &got_terms,
            &terms,
            1e-4,
            2e-4,
        );
        for (g, r) in got_terms.iter().zip(&terms) {
            worst_term = worst_term.max((*g as f64 - r).abs());
        }
        // The losses: the GPU's terms and distortion map summed on the host, as a report would.
        let (want_normal, _) = regularise::normal_consistency(
            raster,
            &frame.camera,
            w.depth_ratio as f64,
            w.normal as f64,
        );
        let got_normal =
            w.normal as f64 * got_terms.iter().map(|&t| t as f64).sum::<f64>() / px as f64;
        let (want_dist, _) = regularise::distortion_loss(raster, w.distortion as f64);
        let got_dist = w.distortion as f64
            * (0..px)
                .map(|p| maps[p * MAPS_STRIDE + 5] as f64)
                .sum::<f64>()
            / px as f64;
        for (what, g, r) in [
            ("normal consistency", got_normal, want_normal),
            ("distortion", got_dist, want_dist),
        ] {
            let err = (g - r).abs() / r.abs().max(1e-6);
            worst_loss = worst_loss.max(err);
            assert!(err < 1e-3, "{label}: {what} loss {g:e} vs reference {r:e}");
        }
        if normals.iter().any(|n| *n != [0.0; 3]) {
            with_normals += 1;
        }
        compared += 1;
    }
    eprintln!(
        "{compared} scenes: surface depth within {worst_depth:.1e} (relative), terms within \
         {worst_term:.1e}, losses within {worst_loss:.1e} (relative)"
    );
    assert!(compared >= 12, "only {compared} of 16 scenes comparable");
    assert!(
        with_normals >= 10,
        "only {with_normals} scenes had surface normals"
    );
    ctx.check_validation().unwrap();
}
