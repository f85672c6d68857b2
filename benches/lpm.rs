//! LPM's per-Gaussian GPU work at scale: the zone-membership pass (inside / in-front flags and
//! per-zone counts) and the opacity reset (exact quantile of the in-zone opacities, then the
//! reset of the in-front Gaussians above it), against the Gaussian count and the zone count.
//! Nothing per Gaussian crosses to the host: the scene is uploaded once and only timestamps are
//! read back.
//!
//! `LPMSPLAT_BENCH_SIZES` (Gaussians, default 100000,1000000,10000000),
//! `LPMSPLAT_BENCH_ZONES` (default 16,256), `LPMSPLAT_BENCH_SHAPES` (sphere, slab or both, the
//! default), `LPMSPLAT_BENCH_FRAMES` (timed runs per case, median reported; default 3). Positions are 12 bytes a Gaussian, so 10M fit the 128 MiB
//! storage-binding limit of lavapipe with room to spare.

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder, TimestampPool};
use lpmsplat::lpm::enclosing_sphere::Sphere;
use lpmsplat::lpm::gpu::LpmGpu;
use lpmsplat::lpm::record::ZoneRecord;
use lpmsplat::lpm::reset_settings::OpacityResetSettings;
use lpmsplat::lpm::{ConeRadius, Zone};
use rand::{Rng, SeedableRng};

fn env_list<T: std::str::FromStr>(name: &str, default: &str) -> Vec<T> {
    std::env::var(name)
        .unwrap_or_else(|_| default.to_string())
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect()
}

/// Zones as a training step makes them: spheres (`--lpm-zone triangulated`) or slabs
/// (`--lpm-zone slab`: the camera's cone through a region of tangent 0.02–0.1, cut to a band
/// of half-depth 0.02–0.2) scattered through the scene's unit cube, seen from cameras on a
/// sphere of radius 3 around it.
fn random_zones(rng: &mut impl Rng, count: usize, slab: bool) -> Vec<ZoneRecord> {
    (0..count)
        .map(|_| {
            let theta = rng.gen_range(0.0..std::f64::consts::TAU);
            let z: f64 = rng.gen_range(-1.0..1.0);
            let r = (1.0 - z * z).sqrt();
            let radius = rng.gen_range(0.02..0.2);
            let center = [
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            ];
            let camera = [3.0 * r * theta.cos(), 3.0 * r * theta.sin(), 3.0 * z];
            let zone = if slab {
                Zone::Slab {
                    apex: camera,
                    center,
                    tan_half_angle: rng.gen_range(0.02..0.1),
                    half_depth: radius,
                }
            } else {
                Zone::Sphere(Sphere { center, radius })
            };
            ZoneRecord::with_cone(&zone, camera, [0.5; 3], ConeRadius::Bounding)
        })
        .collect()
}

fn main() -> anyhow::Result<()> {
    let ctx = GpuContext::new(&GpuOptions::for_benches())?;
    println!("{}", ctx.info.summary());
    let sizes: Vec<usize> = env_list("LPMSPLAT_BENCH_SIZES", "100000,1000000,10000000");
    let zone_counts: Vec<usize> = env_list("LPMSPLAT_BENCH_ZONES", "16,256");
    let shapes: Vec<String> = env_list("LPMSPLAT_BENCH_SHAPES", "sphere,slab");
    let frames: usize = std::env::var("LPMSPLAT_BENCH_FRAMES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3)
        .max(1);
    let lpm = LpmGpu::new(&ctx, 1)?;
    println!(
        "{:>10} {:>6} {:>6} {:>14} {:>11} {:>14} {:>11} {:>10}",
        "gaussians",
        "shape",
        "zones",
        "membership ms",
        "ns/G",
        "ns/(G·zone)",
        "reset ms",
        "inside %"
    );
    for &n in &sizes {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(n as u64);
        let positions: Vec<f32> = (0..3 * n).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let logits: Vec<f32> = (0..n).map(|_| rng.gen_range(-6.0..6.0)).collect();
        let pos = GpuBuffer::from_slice(&ctx, "positions", &positions)?;
        drop(positions);
        let opacity = GpuBuffer::from_slice(&ctx, "opacity logits", &logits)?;
        let flags = GpuBuffer::<u32>::new(&ctx, "flags", n, BufferKind::DeviceLocal)?;
        for (shape, &z) in shapes
            .iter()
            .flat_map(|s| zone_counts.iter().map(move |z| (s, z)))
        {
            let zones = random_zones(&mut rng, z, shape == "slab");
            let zbuf = GpuBuffer::from_slice(&ctx, "zones", &zones)?;
            let counts = GpuBuffer::<u32>::new(&ctx, "zone counts", z, BufferKind::DeviceLocal)?;
            let mut pool = TimestampPool::new(&ctx, 8)?;
            let mut rec = Recorder::new(&ctx)?;
            let mut rows: Vec<(f64, f64)> = Vec::new();
            // One warm-up run, then the timed ones. The reset rewrites the logits, so every
            // run after the first resets fewer: the quantile and the pass still cost the same.
            for _ in 0..frames + 1 {
                rec.begin()?;
                rec.start_timestamps(&mut pool);
                rec.fill(&counts, 0);
                rec.barrier();
                lpm.record_membership(&mut rec, &pos, n as u32, &zbuf, z as u32, &flags, &counts)?;
                rec.timestamp(&mut pool, "membership");
                lpm.record_opacity_reset(
                    &mut rec,
                    &flags,
                    &opacity,
                    n as u32,
                    &OpacityResetSettings::default(),
                    None,
                )?;
                rec.timestamp(&mut pool, "reset");
                rec.submit_and_wait()?;
                let t = pool.read()?;
                let get = |name: &str| {
                    t.stages
                        .iter()
                        .find(|s| s.0 == name)
                        .map_or(f64::NAN, |s| s.1)
                };
                rows.push((get("membership"), get("reset")));
            }
            rows.remove(0);
            let median = |f: fn(&(f64, f64)) -> f64| {
                let mut v: Vec<f64> = rows.iter().map(f).collect();
                v.sort_by(|a, b| a.total_cmp(b));
                v[v.len() / 2]
            };
            let (m, r) = (median(|x| x.0), median(|x| x.1));
            let inside: u64 = flags.read()?.iter().map(|&f| (f & 1) as u64).sum();
            println!(
                "{:>10} {:>6} {:>6} {:>14.2} {:>11.2} {:>14.4} {:>11.2} {:>10.2}",
                n,
                shape,
                z,
                m,
                m * 1e6 / n as f64,
                m * 1e6 / (n as f64 * z as f64),
                r,
                100.0 * inside as f64 / n as f64
            );
        }
    }
    Ok(())
}
