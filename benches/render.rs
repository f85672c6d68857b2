//! Per-stage GPU time of one training-style frame (forward stages + rasterizer/preprocess
//! backward) against the Gaussian count and the resolution, on `render::synthetic` scenes.
//! Run: `cargo bench --bench render`. The default run is short (2 sizes × 2 resolutions);
//! `LPMSPLAT_BENCH_SIZES=1000,10000,100000` and `LPMSPLAT_BENCH_RES=162x242,648x968` widen it,
//! `LPMSPLAT_BENCH_VARIANTS=1` adds backward variants ("c/P": compare-and-swap, "a/1" … "a/16":
//! 1 … 16 pixels per invocation; the default is "a/P": float atomics, P pixels per invocation);
//! `LPMSPLAT_BENCH_FRAMES` sets the timed frames (median reported). Times come from timestamps.

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder, TimestampPool};
use lpmsplat::render::backward::{
    backward_pixels_per_invocation, AtomicMode, Backward, BackwardArgs,
};
use lpmsplat::render::forward::{FrameSettings, Renderer};
use lpmsplat::render::layout::{CameraGpu, RenderConstants};
use lpmsplat::render::synthetic;
use lpmsplat::splats::gpu::GpuSplats;
use rand::{Rng, SeedableRng};

fn env_list<T: std::str::FromStr>(name: &str, default: &str) -> Vec<T> {
    std::env::var(name)
        .unwrap_or_else(|_| default.to_string())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect()
}

fn main() -> anyhow::Result<()> {
    let ctx = GpuContext::new(&GpuOptions::for_benches())?;
    println!("{}", ctx.info.summary());
    let sizes: Vec<usize> = env_list("LPMSPLAT_BENCH_SIZES", "3000,12000");
    let res: Vec<String> = env_list("LPMSPLAT_BENCH_RES", "162x242,324x484");
    let frames: usize = std::env::var("LPMSPLAT_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5);
    // Backward variants: (label, atomics, pixels per invocation). LPMSPLAT_BENCH_VARIANTS=1
    // adds compare-and-swap and one pixel per invocation next to the device default.
    let px = backward_pixels_per_invocation(&ctx.info);
    let mut modes: Vec<(String, AtomicMode, u32)> = vec![(format!("a/{px}"), AtomicMode::Auto, px)];
    if std::env::var("LPMSPLAT_BENCH_VARIANTS").is_ok() {
        modes.push((format!("c/{px}"), AtomicMode::CompareSwap, px));
        for p in [1, 2, 4, 8, 16] {
            if p != px && (256 / p) % ctx.info.subgroup_size == 0 {
                modes.push((format!("a/{p}"), AtomicMode::Auto, p));
            }
        }
    }
    println!(
        "{:>8} {:>10} {:>8} {:>5} {:>8} {:>8} {:>8} {:>8} {:>9} {:>9} {:>8}",
        "gauss",
        "res",
        "pairs",
        "bwd",
        "preproc",
        "dsort",
        "binning",
        "tsort",
        "raster",
        "backward",
        "total"
    );
    for &n in &sizes {
        let params = synthetic::random_scene(n, 7);
        let splats = GpuSplats::upload(&ctx, &params, n)?;
        let grads = GpuSplats::zeroed(&ctx, "grad_", params.sh_degree, n, n)?;
        let vgn = GpuBuffer::<f32>::new(&ctx, "view grad norm", n, BufferKind::DeviceLocal)?;
        for r in &res {
            let Some((w, h)) = r.split_once('x') else {
                continue;
            };
            let (w, h): (u32, u32) = (w.parse()?, h.parse()?);
            let (camera, pose) = synthetic::bench_camera(w, h);
            let cam = CameraGpu::new(&camera, &pose);
            let cameras = GpuBuffer::from_slice(&ctx, "cameras", &[cam])?;
            let settings = FrameSettings {
                sh_degree: params.sh_degree,
                background: [0.1, 0.2, 0.3],
                constants: RenderConstants::default(),
                filter3d: None,
                features: None,
            };
            let mut renderer = Renderer::for_camera(&ctx, n, &cam)?;
            renderer.render_blocking(&splats, &cameras, 0, &cam, &settings)?;
            let pairs = renderer.last_intersections()?;
            let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
            let dl: Vec<f32> = (0..(w * h * 3) as usize)
                .map(|_| rng.gen_range(-1e-3..1e-3))
                .collect();
            let dl_dimage = GpuBuffer::from_slice(&ctx, "dl_dimage", &dl)?;
            for (mode_name, mode, pixels) in &modes {
                let backward = Backward::with_pixels(&ctx, n, *mode, *pixels)?;
                let mut pool = TimestampPool::new(&ctx, 16)?;
                let mut rec = Recorder::new(&ctx)?;
                let mut rows: Vec<Vec<f64>> = Vec::new();
                for _ in 0..frames + 1 {
                    rec.begin()?;
                    rec.start_timestamps(&mut pool);
                    renderer.record(
                        &mut rec,
                        &splats,
                        &cameras,
                        0,
                        &cam,
                        &settings,
                        Some(&mut pool),
                    )?;
                    let f = &renderer.frame;
                    backward.record(
                        &ctx,
                        &mut rec,
                        &BackwardArgs {
                            cameras: &cameras,
                            camera_index: 0,
                            camera: &cam,
                            projected: &f.projected,
                            tile_ranges: &f.tile_ranges,
                            sorted_ids: renderer.sorted_ids(),
                            final_t: &f.final_t,
                            last_index: &f.last_index,
                            dl_dimage: &dl_dimage,
                            splats: &splats,
                            grads: &grads,
                            view_grad_norm: &vgn,
                            pixel_count: None,
                            abs_grad: None,
                            count: n,
                            sh_degree: params.sh_degree,
                            constants: settings.constants,
                            background: settings.background,
                            filter3d: None,
                            features: None,
                        },
                    )?;
                    rec.barrier();
                    rec.timestamp(&mut pool, "backward");
                    rec.submit_and_wait()?;
                    let t = pool.read()?;
                    rows.push(t.stages.iter().map(|s| s.1).collect());
                }
                rows.remove(0); // warm-up
                let median = |k: usize| {
                    let mut v: Vec<f64> = rows.iter().map(|r| r[k]).collect();
                    v.sort_by(|a, b| a.total_cmp(b));
                    v[v.len() / 2]
                };
                let st: Vec<f64> = (0..rows[0].len()).map(median).collect();
                println!(
                    "{:>8} {:>10} {:>8} {:>5} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>9.2} {:>9.2} {:>8.2}",
                    n, r, pairs, mode_name, st[0], st[1], st[2], st[3], st[4], st[5],
                    st.iter().sum::<f64>()
                );
            }
        }
    }
    Ok(())
}
