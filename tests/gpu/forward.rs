//! The GPU forward renderer against the CPU f64 reference: random scenes (hundreds of seeds,
//! image sizes that are not multiples of 16, SH degrees 0–3, random backgrounds), the sorted
//! tile lists, the per-pixel state the backward needs, and the extremes. Validation layer on.
#![allow(clippy::too_many_arguments, clippy::needless_range_loop)]

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::reference::{
    self, alpha_min_edges, mip, scenes, Footprint, RefGaussians, RenderSettings,
};
use lpmsplat::render::forward::{Capacity, FrameSettings, Renderer};
use lpmsplat::render::layout::{CameraGpu, ProjectedGpu, RenderConstants};
use lpmsplat::scene::{PinholeCamera, Pose};
use lpmsplat::splats::gpu::GpuSplats;
use rand::{Rng, SeedableRng};
use std::sync::Arc;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

struct Frame {
    image: Vec<f32>,
    final_t: Vec<f32>,
    last_index: Vec<u32>,
    projected: Vec<ProjectedGpu>,
    tile_lists: Vec<Vec<u32>>,
    /// The Gaussians the depth sort kept (the renderer's count).
    visible: u64,
}

/// Renders `g` (rounded to f32) on the GPU; returns the frame and the f32-exact reference input.
#[allow(clippy::too_many_arguments)]
fn render_gpu(
    ctx: &Arc<GpuContext>,
    renderer: &mut Renderer,
    g: &RefGaussians,
    sh_degree: u32,
    camera: &PinholeCamera,
    pose: &Pose,
    background: [f32; 3],
    settings: &RenderSettings,
) -> (Frame, RefGaussians) {
    render_gpu_filtered(
        ctx, renderer, g, None, sh_degree, camera, pose, background, settings,
    )
}

/// As `render_gpu`, with Mip-Splatting's 3D filter `filter` (rounded to f32) given to the GPU;
/// the reference input returned then has the filter folded in (`mip::fuse`).
#[allow(clippy::too_many_arguments)]
fn render_gpu_filtered(
    ctx: &Arc<GpuContext>,
    renderer: &mut Renderer,
    g: &RefGaussians,
    filter: Option<&[f64]>,
    sh_degree: u32,
    camera: &PinholeCamera,
    pose: &Pose,
    background: [f32; 3],
    settings: &RenderSettings,
) -> (Frame, RefGaussians) {
    let params = g.to_params(3);
    let filter32: Option<Vec<f32>> = filter.map(|f| f.iter().map(|&v| v as f32).collect());
    let exact = RefGaussians::from_params(&params);
    let exact = match &filter32 {
        Some(f) => mip::fuse(&exact, &f.iter().map(|&v| v as f64).collect::<Vec<_>>()).unwrap(),
        None => exact,
    };
    let filter_buf = filter32
        .as_ref()
        .map(|f| GpuBuffer::from_slice(ctx, "filter3d", f).unwrap());
    let splats = GpuSplats::upload(ctx, &params, params.len().max(1)).unwrap();
    let cam = CameraGpu::new(camera, pose);
    // A decoy camera at index 0 checks that the kernels use the index they are given.
    let mut decoy = cam;
    decoy.r0[3] += 1.0;
    let cameras = GpuBuffer::from_slice(ctx, "cameras", &[decoy, cam]).unwrap();
    // Poison the per-pixel outputs: every pixel must be written.
    let f = &renderer.frame;
    f.image.upload(&vec![f32::NAN; f.image.len()]).unwrap();
    f.final_t.upload(&vec![f32::NAN; f.final_t.len()]).unwrap();
    f.last_index
        .upload(&vec![u32::MAX; f.last_index.len()])
        .unwrap();
    renderer
        .render_blocking(
            &splats,
            &cameras,
            1,
            &cam,
            &FrameSettings {
                sh_degree,
                background,
                constants: RenderConstants::from_settings(settings),
                filter3d: filter_buf.as_ref(),
                features: None,
            },
        )
        .unwrap();
    let px = (camera.width * camera.height) as usize;
    let f = &renderer.frame;
    let ranges = f
        .tile_ranges
        .read_range(0, cam.tile_count() as usize)
        .unwrap();
    let ids = renderer.sorted_ids().read().unwrap();
    let tile_lists = ranges
        .iter()
        .map(|r| ids[r[0] as usize..r[1] as usize].to_vec())
        .collect();
    let frame = Frame {
        image: renderer.read_image().unwrap(),
        final_t: f.final_t.read_range(0, px).unwrap(),
        last_index: f.last_index.read_range(0, px).unwrap(),
        projected: f.projected.read_range(0, params.len()).unwrap(),
        tile_lists,
        visible: renderer.last_visible().unwrap(),
    };
    (frame, exact)
}

fn renderer(ctx: &Arc<GpuContext>) -> Renderer {
    Renderer::new(
        ctx,
        Capacity {
            gaussians: 16,
            intersections: 16,
            pixels: 16,
            tiles: 1,
        },
    )
    .unwrap()
}

/// The GPU's sorted tile lists against the reference's: the same, except that a splat whose
/// ellipse reaches a tile only within f32 rounding of its margin (badly conditioned conics)
/// may be paired with the tile on one side only; such a splat must stay below alpha_min over
/// that whole tile in both footprints (so it is blended in neither), and the splats both
/// lists hold must come in the same order.
fn compare_tile_lists(
    frame: &Frame,
    r: &reference::RenderOutput,
    gpu: &[Footprint],
    camera: &PinholeCamera,
    settings: &RenderSettings,
    label: &str,
) {
    let below = settings.alpha_min * (1.0 - 1e-4);
    let tile = r.bins.tile_size;
    for (t, (a, b)) in frame.tile_lists.iter().zip(&r.bins.lists).enumerate() {
        if a == b {
            continue;
        }
        let in_a: std::collections::HashSet<u32> = a.iter().copied().collect();
        let in_b: std::collections::HashSet<u32> = b.iter().copied().collect();
        let common_a: Vec<u32> = a.iter().copied().filter(|g| in_b.contains(g)).collect();
        let common_b: Vec<u32> = b.iter().copied().filter(|g| in_a.contains(g)).collect();
        assert_eq!(
            common_a, common_b,
            "{label}: tile {t}: order of the sorted list"
        );
        let (tx, ty) = (t as u32 % r.bins.tiles_x, t as u32 / r.bins.tiles_x);
        for &g in in_a.symmetric_difference(&in_b) {
            for j in ty * tile..((ty + 1) * tile).min(camera.height) {
                for i in tx * tile..((tx + 1) * tile).min(camera.width) {
                    let (px, py) = (i as f64 + 0.5, j as f64 + 0.5);
                    let ours = gpu[g as usize].raw_alpha(px, py);
                    let exact = Footprint::of(&r.projected[g as usize]).raw_alpha(px, py);
                    assert!(
                        ours < below && exact < below,
                        "{label}: tile {t}: Gaussian {g} is paired on one side only (GPU {}) but \
                         reaches alpha {ours} (GPU) / {exact} at pixel ({i}, {j})",
                        in_a.contains(&g)
                    );
                }
            }
        }
    }
}

/// The condition number λmax / λmin of a symmetric 2×2 matrix [a, b, c] (∞ when singular).
fn condition([a, b, c]: [f64; 3]) -> f64 {
    let (m, r) = (0.5 * (a + c), (0.25 * (a - c) * (a - c) + b * b).sqrt());
    (m.abs() + r) / (m.abs() - r).max(0.0)
}

/// Compares one GPU frame with the reference; returns the max abs image difference.
fn compare(
    frame: &Frame,
    exact: &RefGaussians,
    sh_degree: u32,
    camera: &PinholeCamera,
    pose: &Pose,
    background: [f32; 3],
    settings: &RenderSettings,
    label: &str,
) -> f64 {
    let bg = background.map(|v| v as f64);
    let r = reference::render(exact, camera, pose, sh_degree as usize, bg, settings).unwrap();
    assert!(
        frame.image.iter().all(|v| v.is_finite()),
        "{label}: non-finite pixel"
    );
    // The depth sort keeps exactly the splats whose tile rectangle is not empty.
    let touching = frame.projected.iter().filter(|p| p.tiles_touched() > 0);
    assert_eq!(
        frame.visible,
        touching.count() as u64,
        "{label}: visible count"
    );
    // Tile rectangles decide which lists a Gaussian joins; a rectangle can only differ where
    // 3·sqrt(λmax) sits within f32 rounding of an integer. Those seeds are reported, not hidden.
    let mut rect_mismatch = 0;
    for (i, (p, q)) in frame.projected.iter().zip(&r.projected).enumerate() {
        // Visible (radius > 0) means on screen by the 3σ square; the tile rectangle may
        // still be empty for a splat too faint to reach alpha_min anywhere.
        let gpu_rect = (p.tile_min, p.tile_max);
        let ref_rect = (q.tile_min, q.tile_max);
        let ref_touches = !q.culled && q.tiles_touched() > 0;
        if (p.is_visible() && q.culled)
            || (ref_touches && !p.is_visible())
            || ((p.tiles_touched() > 0 || ref_touches) && gpu_rect != ref_rect)
        {
            rect_mismatch += 1;
            continue;
        }
        if p.is_visible() {
            let close = |a: f32, b: f64, tol: f64| (a as f64 - b).abs() <= tol * (1.0 + b.abs());
            assert!(
                close(p.mean_x, q.mean2d[0], 1e-4) && close(p.mean_y, q.mean2d[1], 1e-4),
                "{label}: Gaussian {i} mean2d"
            );
            assert!(close(p.depth, q.depth, 1e-5), "{label}: Gaussian {i} depth");
            // Inverting a 2×2 covariance of condition κ in f32 loses about κ·ε of the largest
            // entry (elongated splats reach κ ~ 1e4 here).
            let conic_tol = 1e-3 + 4.0 * f32::EPSILON as f64 * condition(q.conic);
            for (a, b) in [p.conic_a, p.conic_b, p.conic_c].iter().zip(q.conic) {
                let scale = q.conic.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                assert!(
                    (*a as f64 - b).abs() <= conic_tol * scale + 1e-7,
                    "{label}: Gaussian {i} conic {a} vs {b} (condition {})",
                    condition(q.conic)
                );
            }
            for c in 0..3 {
                assert!(
                    close(p.rgb[c], q.rgb[c], 1e-4),
                    "{label}: Gaussian {i} rgb {:?} vs {:?}",
                    p.rgb,
                    q.rgb
                );
            }
        }
    }
    if rect_mismatch > 0 {
        eprintln!(
            "{label}: {rect_mismatch} tile rectangles differ by rounding; image not compared"
        );
        return 0.0;
    }
    let gpu_footprints: Vec<Footprint> = frame.projected.iter().map(Footprint::of_gpu).collect();
    compare_tile_lists(frame, &r, &gpu_footprints, camera, settings, label);
    // A splat whose alpha at a pixel lands within f32 rounding of alpha_min may be blended on
    // one side and skipped on the other (seed 547 of 3,000 below; elongated splats, whose
    // conics carry more rounding, more often): the GPU's own footprints say where. Such pixels
    // get a bound from their count of those splats, each worth at most alpha_min of the
    // transmittance (T) and twice that times the largest colour (the colour behind it is scaled
    // by 1 − alpha). Every other pixel must match to 1e-3, and such pixels must stay rare.
    let edges = alpha_min_edges(
        &r.projected,
        &gpu_footprints,
        &r.bins,
        camera,
        settings,
        1e-4,
    );
    let colour_scale = r
        .projected
        .iter()
        .flat_map(|p| p.rgb)
        .chain(bg)
        .fold(1.0f64, |m, v| m.max(v.abs()));
    let toggle = settings.alpha_min * (1.0 + 1e-4);
    let mut max_diff = 0.0f64;
    for (pix, rgb) in r.raster.image.iter().enumerate() {
        let e = edges[pix] as f64;
        let tol_colour = 1e-3 + e * 2.0 * toggle * colour_scale;
        for c in 0..3 {
            let d = (frame.image[pix * 3 + c] as f64 - rgb[c]).abs();
            assert!(
                d < tol_colour,
                "{label}: pixel {pix} channel {c}: {} vs {} ({e} splats at the alpha_min edge)",
                frame.image[pix * 3 + c],
                rgb[c]
            );
            if e == 0.0 {
                max_diff = max_diff.max(d);
            }
        }
        let t = r.raster.final_transmittance[pix];
        assert!(
            (frame.final_t[pix] as f64 - t).abs() <= 1e-3 + e * toggle,
            "{label}: pixel {pix} final T {} vs {t} ({e} splats at the alpha_min edge)",
            frame.final_t[pix]
        );
    }
    let edge_pixels = edges.iter().filter(|&&e| e > 0).count();
    assert!(
        edge_pixels <= edges.len() / 100 + 1,
        "{label}: {edge_pixels} of {} pixels have a splat at the alpha_min edge",
        edges.len()
    );
    // The stop rule compares T against 1e-4 in f32 vs f64: a pixel whose transmittance lands
    // right on it may stop one splat earlier or later (as may an edge pixel); anything else
    // must match exactly.
    // Compared as Gaussians (a list may hold a splat the other lacks, compare_tile_lists).
    let last_of = |lists: &[Vec<u32>], pix: usize, last: u32| {
        let tile = r
            .bins
            .tile_of_pixel(pix as u32 % camera.width, pix as u32 / camera.width);
        (last > 0).then(|| lists[tile][last as usize - 1])
    };
    let last_mismatch = (0..frame.last_index.len())
        .filter(|&pix| {
            last_of(&frame.tile_lists, pix, frame.last_index[pix])
                != last_of(&r.bins.lists, pix, r.raster.last_contributor[pix])
        })
        .count();
    assert!(
        last_mismatch <= frame.last_index.len() / 500 + 1 + edge_pixels,
        "{label}: {last_mismatch} pixels disagree on the last contributor"
    );
    max_diff
}

/// The number of random scenes a test draws: `default`, or LPMSPLAT_FORWARD_SEEDS for a deeper
/// run (the same scenes first, then more).
fn seed_count(default: usize) -> usize {
    match std::env::var("LPMSPLAT_FORWARD_SEEDS") {
        Ok(v) => v.trim().parse().unwrap_or_else(|_| {
            panic!("LPMSPLAT_FORWARD_SEEDS={v:?} is not a count. Fix: a whole number, e.g. 3000")
        }),
        Err(_) => default,
    }
}

#[test]
fn random_scenes_match_the_reference() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2024);
    let mut worst = 0.0f64;
    let seeds = seed_count(200);
    for seed in 0..seeds {
        let n = rng.gen_range(1..160);
        let g = scenes::random_gaussians(&mut rng, n);
        let w = rng.gen_range(1..90);
        let h = rng.gen_range(1..90);
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let sh_degree = rng.gen_range(0..=3);
        let bg = [rng.gen(), rng.gen(), rng.gen()];
        let (frame, exact) = render_gpu(
            &ctx,
            &mut renderer,
            &g,
            sh_degree,
            &camera,
            &pose,
            bg,
            &settings,
        );
        let label = format!("seed {seed} ({n} Gaussians, {w}×{h}, SH {sh_degree})");
        worst = worst.max(compare(
            &frame, &exact, sh_degree, &camera, &pose, bg, &settings, &label,
        ));
    }
    eprintln!("worst max abs difference over {seeds} scenes: {worst:.2e}");
    ctx.check_validation().unwrap();
}

/// The median-depth pass (`glsl/render/median_depth.comp`, SpacetimeGaussians' guided sampling
/// reads it) against the reference's median depth on random scenes: the camera depth of the
/// splat that takes a pixel's transmittance below ½, 0 where none does. The output is poisoned
/// before each frame. A pixel whose transmittance lands within f32 rounding of ½ (or that has
/// a splat at the alpha_min edge) may take the splat before or after; such pixels must be rare.
#[test]
fn the_median_depth_pass_matches_the_reference() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx).with_median_depth().unwrap();
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x3ED1);
    let (mut pixels, mut with_depth, mut differ) = (0usize, 0usize, 0usize);
    for seed in 0..seed_count(120) {
        let n = rng.gen_range(1..200);
        let g = scenes::random_gaussians(&mut rng, n);
        let (w, h) = (rng.gen_range(1..70), rng.gen_range(1..70));
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let label = format!("seed {seed} ({n} Gaussians, {w}×{h})");
        // Once to size the output, then poisoned and drawn again.
        render_gpu(
            &ctx,
            &mut renderer,
            &g,
            0,
            &camera,
            &pose,
            [0.0; 3],
            &settings,
        );
        let out = renderer.median_depth_buffer().unwrap();
        out.upload(&vec![f32::NAN; out.len()]).unwrap();
        let (frame, exact) = render_gpu(
            &ctx,
            &mut renderer,
            &g,
            0,
            &camera,
            &pose,
            [0.0; 3],
            &settings,
        );
        let gpu = renderer.read_median_depth().unwrap();
        let r = reference::render(&exact, &camera, &pose, 0, [0.0; 3], &settings).unwrap();
        let footprints: Vec<Footprint> = frame.projected.iter().map(Footprint::of_gpu).collect();
        let edges = alpha_min_edges(&r.projected, &footprints, &r.bins, &camera, &settings, 1e-4);
        let mut here = 0;
        for (pix, (&d, want)) in gpu.iter().zip(&r.raster.median_depth).enumerate() {
            assert!(d.is_finite() && d >= 0.0, "{label}: pixel {pix} wrote {d}");
            let same = match want {
                Some(z) => d > 0.0 && (d as f64 - z).abs() <= 1e-5 * (1.0 + z.abs()),
                None => d == 0.0,
            };
            if !same {
                // Only where a choice within rounding exists: T at the pixel's end near ½ or
                // below it (the crossing lies somewhere in the list), or an alpha_min edge.
                assert!(
                    edges[pix] > 0 || r.raster.final_transmittance[pix] < 0.5 + 1e-4,
                    "{label}: pixel {pix} median {d} vs {want:?}"
                );
                here += 1;
            }
        }
        assert!(
            here <= gpu.len() / 200 + 1,
            "{label}: {here} of {} pixels disagree on the median depth",
            gpu.len()
        );
        pixels += gpu.len();
        with_depth += r.raster.median_depth.iter().flatten().count();
        differ += here;
    }
    eprintln!("{pixels} pixels, {with_depth} with a median depth, {differ} within rounding");
    assert!(with_depth > pixels / 10, "the scenes must cover pixels");
    ctx.check_validation().unwrap();
}

/// The contributions pass (each Gaussian's sums over the pixels it was blended into: their
/// weights, their number, T·alpha and the distance to its centre) against the reference's walk
/// of the same lists, on random scenes with random pixel weights. A pixel where a choice within
/// rounding exists (an alpha_min edge, or a stop near t_min) may count a Gaussian once more or
/// less; everywhere else the sums agree to float rounding.
#[test]
fn the_contributions_pass_matches_the_reference() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx).with_contributions().unwrap();
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0xC047);
    let (mut gaussians, mut blended, mut differ) = (0usize, 0usize, 0usize);
    for seed in 0..seed_count(80) {
        let n = rng.gen_range(1..200);
        let g = scenes::random_gaussians(&mut rng, n);
        let (w, h) = (rng.gen_range(1..70), rng.gen_range(1..70));
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let label = format!("seed {seed} ({n} Gaussians, {w}×{h})");
        // Once to size the buffers, then weights uploaded, sums poisoned, drawn again.
        render_gpu(
            &ctx,
            &mut renderer,
            &g,
            0,
            &camera,
            &pose,
            [0.0; 3],
            &settings,
        );
        let weights: Vec<f32> = (0..w * h).map(|_| rng.gen_range(0.0..2.0)).collect();
        renderer
            .pixel_weights_buffer()
            .unwrap()
            .upload(&weights)
            .unwrap();
        for b in renderer.contribution_buffers().unwrap() {
            b.upload(&vec![f32::NAN; b.len()]).unwrap();
        }
        let (frame, exact) = render_gpu(
            &ctx,
            &mut renderer,
            &g,
            0,
            &camera,
            &pose,
            [0.0; 3],
            &settings,
        );
        let gpu = renderer.read_contributions(n).unwrap();
        let r = reference::render(&exact, &camera, &pose, 0, [0.0; 3], &settings).unwrap();
        let wide: Vec<f64> = weights.iter().map(|&v| v as f64).collect();
        let want =
            reference::raster::contributions(&r.projected, &r.bins, &camera, &settings, &wide)
                .unwrap();
        let footprints: Vec<Footprint> = frame.projected.iter().map(Footprint::of_gpu).collect();
        let edges = alpha_min_edges(&r.projected, &footprints, &r.bins, &camera, &settings, 1e-4);
        let unsure = edges.iter().filter(|&&e| e > 0).count()
            + r.raster
                .final_transmittance
                .iter()
                .filter(|&&t| t < 2.0 * settings.t_min)
                .count();
        let mut here = 0;
        for i in 0..n {
            let got = [gpu.weight[i], gpu.pixels[i], gpu.blend[i], gpu.distance[i]];
            let exp = [
                want.weight[i],
                want.pixels[i],
                want.blend[i],
                want.distance[i],
            ];
            assert!(
                got.iter().all(|v| v.is_finite()),
                "{label}: Gaussian {i} summed {got:?}"
            );
            let same = got
                .iter()
                .zip(exp)
                .all(|(&a, b)| (a as f64 - b).abs() <= 1e-4 * (1.0 + b.abs()));
            if !same {
                // A pixel more or less, and only where some pixel's walk is unsure.
                assert!(
                    unsure > 0 && (got[1] as f64 - exp[1]).abs() <= unsure as f64,
                    "{label}: Gaussian {i} summed {got:?}, the reference {exp:?}"
                );
                here += 1;
            }
        }
        assert!(
            here <= n / 20 + 1,
            "{label}: {here} of {n} Gaussians disagree"
        );
        gaussians += n;
        blended += want.pixels.iter().filter(|&&p| p > 0.0).count();
        differ += here;
    }
    eprintln!("{gaussians} Gaussians, {blended} blended somewhere, {differ} within rounding");
    assert!(blended > gaussians / 4, "the scenes must blend Gaussians");
    ctx.check_validation().unwrap();
}

/// Long thin splats at every angle, faint and opaque: the GPU pairs each with the tiles its
/// ellipse reaches (glsl/common/tile_rows.glsl), the same lists as the reference's
/// `Projected::row_tiles`, the same image, and far fewer pairs than the rectangles hold.
#[test]
fn elongated_splats_pair_with_the_tiles_their_ellipse_reaches() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x7115);
    let (mut pairs, mut rect_pairs) = (0usize, 0u64);
    for seed in 0..seed_count(40) {
        let n = rng.gen_range(1..120);
        let mut g = scenes::random_gaussians(&mut rng, n);
        for (s, o) in g.log_scales.iter_mut().zip(&mut g.opacity_logits) {
            s[0] += rng.gen_range(0.0..3.0);
            s[1] -= rng.gen_range(0.0..1.0);
            *o = rng.gen_range(-4.0..3.0);
        }
        let (w, h) = (rng.gen_range(16..120), rng.gen_range(16..120));
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let bg = [rng.gen(), rng.gen(), rng.gen()];
        let (frame, exact) = render_gpu(&ctx, &mut renderer, &g, 3, &camera, &pose, bg, &settings);
        let label = format!("elongated seed {seed} ({n} Gaussians, {w}×{h})");
        compare(&frame, &exact, 3, &camera, &pose, bg, &settings, &label);
        pairs += frame.tile_lists.iter().map(Vec::len).sum::<usize>();
        rect_pairs += frame
            .projected
            .iter()
            .map(|p| p.tiles_touched())
            .sum::<u64>();
    }
    assert!(
        (pairs as f64) < 0.8 * rect_pairs as f64,
        "{pairs} pairs of the rectangles' {rect_pairs}"
    );
    eprintln!("GPU pairs: {pairs} of the rectangles' {rect_pairs}");
    ctx.check_validation().unwrap();
}

/// Every pixels-per-invocation layout of the rasterizer against the reference: 1 is what GPUs
/// run (a shared-memory load per splat), more take each splat from its lane by shuffles (CPU
/// drivers); the default layout is covered above.
#[test]
fn every_rasterizer_layout_matches_the_reference() {
    let ctx = ctx();
    let settings = RenderSettings::default();
    for pixels in [1u32, 2, 4, 8] {
        let wg = 256 / pixels;
        if wg % ctx.info.subgroup_size != 0 {
            continue;
        }
        let mut renderer = renderer(&ctx).with_raster_pixels(pixels).unwrap();
        let mut rng = rand_pcg::Pcg64::seed_from_u64(77 + pixels as u64);
        for seed in 0..25 {
            let n = rng.gen_range(1..200);
            let g = scenes::random_gaussians(&mut rng, n);
            let w = rng.gen_range(1..70);
            let h = rng.gen_range(1..70);
            let (camera, pose) = scenes::random_view(&mut rng, w, h);
            let bg = [rng.gen(), rng.gen(), rng.gen()];
            let (frame, exact) =
                render_gpu(&ctx, &mut renderer, &g, 1, &camera, &pose, bg, &settings);
            let label = format!("{pixels} px/invocation, seed {seed} ({n} Gaussians, {w}×{h})");
            compare(&frame, &exact, 1, &camera, &pose, bg, &settings, &label);
        }
    }
    assert!(renderer(&ctx).with_raster_pixels(3).is_err());
    ctx.check_validation().unwrap();
}

/// Smooth mode, Mip-Splatting's 2D filter (eps2d 0.1 and the opacity compensation) and
/// larger images.
#[test]
fn mip_splatting_3d_filter_matches_the_fused_reference() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x3D);
    for (seed, (w, h)) in [(120u32, 90u32), (64, 150)].into_iter().enumerate() {
        let g = scenes::random_gaussians(&mut rng, 500);
        // Filters from a tenth of a Gaussian's largest scale to several times it.
        let filter: Vec<f64> = g
            .log_scales
            .iter()
            .map(|l| l.iter().copied().fold(f64::MIN, f64::max).exp() * rng.gen_range(0.1..3.0))
            .collect();
        let (camera, pose) = scenes::random_view(&mut rng, w, h);
        let bg = [0.2, 0.1, 0.9];
        let settings = RenderSettings::mip_splatting();
        let (frame, exact) = render_gpu_filtered(
            &ctx,
            &mut renderer,
            &g,
            Some(&filter),
            2,
            &camera,
            &pose,
            bg,
            &settings,
        );
        compare(
            &frame,
            &exact,
            2,
            &camera,
            &pose,
            bg,
            &settings,
            &format!("3D filter {seed} {w}×{h}"),
        );
    }
    ctx.check_validation().unwrap();
}

#[test]
fn smooth_mode_and_larger_images_match() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(99);
    for (seed, (w, h)) in [(300u32, 200u32), (161, 243), (17, 300)]
        .into_iter()
        .enumerate()
    {
        let mip = RenderSettings::mip_splatting();
        for settings in [RenderSettings::default(), RenderSettings::smooth(), mip] {
            let mut g = scenes::random_gaussians(&mut rng, 800);
            if settings.smooth {
                // Smooth mode needs alpha < 1 (no clamp): keep opacities moderate.
                g.opacity_logits.iter_mut().for_each(|o| *o = o.min(1.5));
            }
            let (camera, pose) = scenes::random_view(&mut rng, w, h);
            let bg = [0.0, 1.0, 0.5];
            let (frame, exact) =
                render_gpu(&ctx, &mut renderer, &g, 3, &camera, &pose, bg, &settings);
            compare(
                &frame,
                &exact,
                3,
                &camera,
                &pose,
                bg,
                &settings,
                &format!(
                    "image {seed} {w}×{h} smooth={} mip={}",
                    settings.smooth, settings.mip_2d
                ),
            );
        }
    }
    ctx.check_validation().unwrap();
}

fn one(pos: [f64; 3], log_scale: [f64; 3], quat: [f64; 4], logit: f64) -> RefGaussians {
    let mut sh = [[0.0; 3]; 16];
    sh[0] = [0.8, -0.3, 0.1];
    sh[1] = [0.05, 0.02, -0.04];
    RefGaussians {
        positions: vec![pos],
        log_scales: vec![log_scale],
        rotations: vec![quat],
        opacity_logits: vec![logit],
        sh: vec![sh],
    }
}

fn concat(parts: &[RefGaussians]) -> RefGaussians {
    let mut g = RefGaussians::default();
    for p in parts {
        g.positions.extend(&p.positions);
        g.log_scales.extend(&p.log_scales);
        g.rotations.extend(&p.rotations);
        g.opacity_logits.extend(&p.opacity_logits);
        g.sh.extend(&p.sh);
    }
    g
}

#[test]
fn extremes_stay_finite_and_match() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let settings = RenderSettings::default();
    let camera = PinholeCamera {
        fx: 60.0,
        fy: 60.0,
        cx: 31.0,
        cy: 22.0,
        width: 61,
        height: 45,
    };
    let pose = Pose::IDENTITY;
    let id = [1.0, 0.0, 0.0, 0.0];
    let mut parts = Vec::new();
    for ls in [1e-8f64, 1e-4, 1.0, 1e2, 1e4] {
        parts.push(one([0.1, -0.05, 3.0], [ls.ln(); 3], id, 0.5));
    }
    parts.push(one([0.2, 0.1, 2.0], [-3.0, -1.0, -4.0], id, 50.0));
    parts.push(one([-0.2, 0.1, 2.0], [-3.0, -1.0, -4.0], id, -50.0));
    parts.push(one([0.0, 0.2, 2.5], [-2.0; 3], [0.0; 4], 1.0));
    parts.push(one(
        [0.0, -0.2, 2.5],
        [-2.0; 3],
        [1e-30, 0.0, 1e-30, 0.0],
        1.0,
    ));
    parts.push(one([0.3, 0.0, settings.near], [-2.0; 3], id, 1.0));
    parts.push(one([0.3, 0.0, -1.0], [-2.0; 3], id, 1.0));
    parts.push(one([0.0, 0.0, 1e6], [5.0; 3], id, 1.0));
    parts.push(one([1e6, 0.0, 1.0], [-2.0; 3], id, 1.0));
    let g = concat(&parts);
    for bg in [[0.0; 3], [1.0; 3]] {
        let (frame, exact) = render_gpu(&ctx, &mut renderer, &g, 1, &camera, &pose, bg, &settings);
        compare(&frame, &exact, 1, &camera, &pose, bg, &settings, "extremes");
        // Gaussians on or behind the near plane are culled.
        assert_eq!(frame.projected[9].radius, 0.0, "on the near plane");
        assert_eq!(frame.projected[10].radius, 0.0, "behind the camera");
    }
    ctx.check_validation().unwrap();
}

#[test]
fn a_thousand_splats_on_one_pixel_stop_at_the_transmittance_floor() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let settings = RenderSettings::default();
    let camera = PinholeCamera {
        fx: 50.0,
        fy: 50.0,
        cx: 8.0,
        cy: 8.0,
        width: 16,
        height: 16,
    };
    let parts: Vec<_> = (0..1000)
        .map(|k| {
            one(
                [0.0, 0.0, 2.0 + k as f64 * 1e-3],
                [-6.0; 3],
                [1.0, 0.0, 0.0, 0.0],
                0.0,
            )
        })
        .collect();
    let g = concat(&parts);
    let (frame, exact) = render_gpu(
        &ctx,
        &mut renderer,
        &g,
        0,
        &camera,
        &Pose::IDENTITY,
        [0.2; 3],
        &settings,
    );
    compare(
        &frame,
        &exact,
        0,
        &camera,
        &Pose::IDENTITY,
        [0.2; 3],
        &settings,
        "stacked",
    );
    let centre = 8 * 16 + 8;
    assert!(frame.final_t[centre] >= settings.t_min as f32);
    assert!(frame.last_index[centre] > 5 && frame.last_index[centre] < 1000);
    ctx.check_validation().unwrap();
}

#[test]
fn empty_scene_and_one_pixel_image_show_the_background() {
    let ctx = ctx();
    let mut renderer = renderer(&ctx);
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let (camera, pose) = scenes::random_view(&mut rng, 33, 17);
    let (frame, _) = render_gpu(
        &ctx,
        &mut renderer,
        &RefGaussians::default(),
        0,
        &camera,
        &pose,
        [0.25, 0.5, 0.75],
        &settings,
    );
    for px in frame.image.chunks(3) {
        assert_eq!(px, [0.25, 0.5, 0.75]);
    }
    assert!(frame.final_t.iter().all(|&t| t == 1.0));
    assert!(frame.last_index.iter().all(|&l| l == 0));
    let g = scenes::random_gaussians(&mut rng, 50);
    let (camera, pose) = scenes::random_view(&mut rng, 1, 1);
    let (frame, exact) = render_gpu(
        &ctx,
        &mut renderer,
        &g,
        2,
        &camera,
        &pose,
        [0.0; 3],
        &settings,
    );
    compare(
        &frame, &exact, 2, &camera, &pose, [0.0; 3], &settings, "1×1",
    );
    ctx.check_validation().unwrap();
}

#[test]
fn intersections_beyond_capacity_regrow_and_render_the_same() {
    let ctx = ctx();
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(77);
    let g = scenes::random_gaussians(&mut rng, 400);
    let (camera, pose) = scenes::random_view(&mut rng, 120, 90);
    // Start with room for 16 pairs: the first frame overflows and must be redone.
    let mut small = renderer(&ctx);
    let (frame, exact) = render_gpu(&ctx, &mut small, &g, 3, &camera, &pose, [0.0; 3], &settings);
    assert!(small.capacity().intersections > 16);
    compare(
        &frame, &exact, 3, &camera, &pose, [0.0; 3], &settings, "regrown",
    );
    ctx.check_validation().unwrap();
}

#[test]
fn a_4096_square_image_renders_or_is_refused_with_the_binding_limit() {
    let ctx = ctx();
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(4096);
    let g = scenes::random_gaussians(&mut rng, 20);
    let (camera, pose) = scenes::random_view(&mut rng, 4096, 4096);
    let params = g.to_params(0);
    let splats = GpuSplats::upload(&ctx, &params, params.len()).unwrap();
    let cam = CameraGpu::new(&camera, &pose);
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
    let frame = FrameSettings {
        sh_degree: 0,
        background: [0.0; 3],
        constants: RenderConstants::from_settings(&settings),
        filter3d: None,
        features: None,
    };
    // 4096² RGB f32 is 192 MiB: above lavapipe's 128 MiB storage binding limit.
    let need = 4096u64 * 4096 * 12;
    match Renderer::for_camera(&ctx, params.len(), &cam).and_then(|mut r| {
        r.render_blocking(&splats, &cameras, 0, &cam, &frame)
            .map(|_| r)
    }) {
        Ok(r) => {
            assert!(need <= ctx.info.max_storage_buffer_range);
            let img = r.read_image().unwrap();
            assert_eq!(img.len(), 4096 * 4096 * 3);
            assert!(img.iter().all(|v| v.is_finite()));
        }
        Err(e) => {
            let msg = format!("{e:#}");
            assert!(
                need > ctx.info.max_storage_buffer_range,
                "unexpected error: {msg}"
            );
            assert!(
                msg.contains("maxStorageBufferRange"),
                "unclear error: {msg}"
            );
        }
    }
    ctx.check_validation().unwrap();
}

/// `n` Gaussians around the origin, each large and opaque enough (alpha ≥ 1/255 out to the
/// image's corners) to touch every tile of a `size`² view looking at it.
fn tile_covering(rng: &mut impl Rng, n: usize, size: u32) -> (RefGaussians, CameraGpu) {
    let mut g = scenes::random_gaussians(rng, n);
    for i in 0..n {
        g.positions[i] = g.positions[i].map(|x| 0.01 * x);
        g.log_scales[i] = [30f64.ln(); 3];
        g.opacity_logits[i] = -3.0;
    }
    let (camera, pose) = scenes::random_view(rng, size, size);
    (g, CameraGpu::new(&camera, &pose))
}

#[test]
fn intersections_are_counted_in_64_bits_and_drawn_in_bands_past_one_binding() {
    let ctx = ctx();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2031);
    let max = lpmsplat::render::forward::max_intersections(&ctx);
    // 2,100 Gaussians × 16,384 tiles = 34.4 M pairs: past a 128 MiB binding of 4-byte keys
    // (33.5 M pairs), within 4 GiB; a row of 128 tiles holds 268,800, so lavapipe draws it in
    // bands of tile rows. 270,000 × 16,384 = 4.42 G pairs: past 2^32, where the 32-bit scan's
    // total wraps, so only the 64-bit count can tell it from a small frame; one tile row holds
    // 34.6 M pairs, past lavapipe's binding: refused there, row and count named.
    for (n, want) in [(2_100usize, 34_406_400u64), (270_000, 4_423_680_000)] {
        let (g, cam) = tile_covering(&mut rng, n, 2048);
        assert_eq!(cam.tile_count(), 16_384);
        let row = 128 * n as u64;
        let params = g.to_params(0);
        let splats = GpuSplats::upload(&ctx, &params, n).unwrap();
        let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
        // Room for 16 pairs at first: the first frame only counts (and draws next to nothing).
        let mut r = Renderer::new(
            &ctx,
            Capacity {
                gaussians: n,
                intersections: 16,
                pixels: (cam.width() * cam.height()) as usize,
                tiles: cam.tile_count() as usize,
            },
        )
        .unwrap();
        let frame = FrameSettings::plain(0, [0.0; 3]);
        match r.render_blocking(&splats, &cameras, 0, &cam, &frame) {
            Ok(()) => {
                assert!(
                    row <= max,
                    "a row of {row} pairs drawn with a limit of {max}"
                );
                assert_eq!(r.last_intersections().unwrap(), want);
                assert_eq!(r.last_frame_bands() > 1, want > max);
                assert!(r.last_band_totals().unwrap().iter().all(|&t| t <= max));
                // Every pixel is covered by the same splats: one colour over the image.
                let img = r.read_image().unwrap();
                assert!(img.iter().all(|v| v.is_finite() && *v > 0.0));
            }
            Err(e) => {
                let msg = format!("{e:#}");
                if row <= max {
                    // Drawable in bands; a GPU may still lack the memory for 1 G pairs a band.
                    assert!(
                        msg.contains("memory"),
                        "refused within the limit {max}: {msg}"
                    );
                } else {
                    assert!(
                        msg.contains(&format!("{want} (tile, Gaussian) intersections"))
                            && msg.contains(&format!("tiles alone has {row}"))
                            && msg.contains("Fix:"),
                        "{msg}"
                    );
                }
            }
        }
    }
    ctx.check_validation().unwrap();
}

/// Feature channels (SpacetimeGaussians' full model: 6; 48, the most the backward carries)
/// blended beside the colour in every pixels-per-invocation layout, against the reference's
/// feature image; the image is poisoned first, so every pixel must be written.
#[test]
fn feature_channels_match_the_reference_in_every_layout() {
    use lpmsplat::reference::decoder::rasterize_features;
    use lpmsplat::render::forward::FeatureChannels;
    let ctx = ctx();
    let settings = RenderSettings::default();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0xFEA7);
    let mut compared = 0;
    for channels in [6usize, 48] {
        for pixels in [1u32, 2, 4, 8] {
            if (256 / pixels) % ctx.info.subgroup_size != 0 {
                continue;
            }
            let mut renderer = renderer(&ctx).with_raster_pixels(pixels).unwrap();
            for seed in 0..3 {
                let n = rng.gen_range(20..160);
                let g = scenes::random_gaussians(&mut rng, n);
                let (w, h) = (rng.gen_range(8..60), rng.gen_range(8..60));
                let (camera, pose) = scenes::random_view(&mut rng, w, h);
                let values: Vec<f32> = (0..n * channels)
                    .map(|_| rng.gen_range(-1.5f32..1.5))
                    .collect();
                let label = format!("{channels} channels, {pixels} px/invocation, seed {seed}");
                let params = g.to_params(3);
                let exact = RefGaussians::from_params(&params);
                let splats = GpuSplats::upload(&ctx, &params, n).unwrap();
                let cam = CameraGpu::new(&camera, &pose);
                let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam]).unwrap();
                let feature_buf = GpuBuffer::from_slice(&ctx, "features", &values).unwrap();
                let frame = FrameSettings {
                    features: Some(FeatureChannels {
                        values: &feature_buf,
                        channels: channels as u32,
                        decoded_by: None,
                    }),
                    ..FrameSettings::plain(1, [0.3, 0.6, 0.9])
                };
                // The first render sizes the feature image; the second must overwrite poison.
                for pass in 0..2 {
                    if pass == 1 {
                        let img = renderer.feature_image().unwrap();
                        img.upload(&vec![f32::NAN; img.len()]).unwrap();
                    }
                    renderer
                        .render_blocking(&splats, &cameras, 0, &cam, &frame)
                        .unwrap();
                }
                let px = (w * h) as usize;
                let got = renderer
                    .feature_image()
                    .unwrap()
                    .read_range(0, px * channels)
                    .unwrap();
                let r = reference::render(&exact, &camera, &pose, 1, [0.0; 3], &settings).unwrap();
                let f64s: Vec<f64> = values.iter().map(|&v| v as f64).collect();
                let want =
                    rasterize_features(&r.projected, &r.bins, &camera, &f64s, channels, &settings)
                        .unwrap();
                let mut max_diff = 0.0f64;
                for (i, (&a, &b)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        a.is_finite(),
                        "{label}: value {i} not written or not finite"
                    );
                    max_diff = max_diff.max((a as f64 - b).abs());
                }
                assert!(max_diff < 2e-3, "{label}: max abs difference {max_diff}");
                assert!(
                    want.iter().any(|v| v.abs() > 1e-2),
                    "{label}: nothing drawn"
                );
                compared += 1;
            }
        }
    }
    assert!(compared >= 12, "only {compared} frames compared");
    ctx.check_validation().unwrap();
}

/// The renderer with 8-bit sort digits (`--sort-digits 8`, ballot-ranked passes) against the
/// default 4/5-bit passes: both sorts are stable, so the frames must be the same bits, tile
/// lists included, on scenes large enough for several sort blocks (2,048 keys) in both sorts.
#[test]
fn byte_digit_sorts_render_the_same_bits() {
    let settings = RenderSettings::default();
    let frames = |digits: Option<u32>| {
        let ctx = GpuContext::new(&GpuOptions {
            sort_digit_bits: digits,
            ..GpuOptions::for_tests()
        })
        .unwrap();
        let mut renderer = renderer(&ctx);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(88);
        let mut out = Vec::new();
        for _ in 0..6 {
            let n = rng.gen_range(2_500..7_000);
            let g = scenes::random_gaussians(&mut rng, n);
            let (w, h) = (rng.gen_range(64..200), rng.gen_range(64..200));
            let (camera, pose) = scenes::random_view(&mut rng, w, h);
            let (frame, _) = render_gpu(
                &ctx,
                &mut renderer,
                &g,
                3,
                &camera,
                &pose,
                [0.2, 0.3, 0.4],
                &settings,
            );
            let pairs: usize = frame.tile_lists.iter().map(Vec::len).sum();
            out.push((frame.image, frame.tile_lists, frame.visible, pairs));
        }
        ctx.check_validation().unwrap();
        (renderer.sort_digits(), out)
    };
    let (default_digits, want) = frames(None);
    let (byte_digits, got) = frames(Some(8));
    assert_eq!(default_digits, lpmsplat::render::sort::Digits::Wide);
    assert_eq!(byte_digits, lpmsplat::render::sort::Digits::Byte);
    for (k, (a, b)) in want.iter().zip(&got).enumerate() {
        assert!(
            a.2 > 2_048 && a.3 > 4_096,
            "scene {k}: {} visible, {} pairs",
            a.2,
            a.3
        );
        assert_eq!(a.2, b.2, "scene {k}: visible Gaussians");
        assert_eq!(a.1, b.1, "scene {k}: tile lists");
        let same =
            a.0.iter()
                .zip(&b.0)
                .all(|(x, y)| x.to_bits() == y.to_bits());
        assert!(same, "scene {k}: the images differ");
    }
}
