//! The training loss's GPU time (L1 + SSIM, forward and backward: `train::loss::Loss`) per
//! layout and image size: the training scenes' sizes and 1352×1014.
//! Run: `cargo bench --bench loss` (`LPMSPLAT_BENCH_REPS` repetitions a case, default 20).
//! GPU time is from timestamps around the recorded loss only; the median is printed.

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions, Recorder, TimestampPool};
use lpmsplat::train::loss::{Loss, LossLayout};
use rand::{Rng, SeedableRng};

fn main() -> anyhow::Result<()> {
    let ctx = GpuContext::new(&GpuOptions::for_benches())?;
    println!("{}", ctx.info.summary());
    let reps: usize = std::env::var("LPMSPLAT_BENCH_REPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20)
        .max(1);
    println!(
        "{:>11} {:>9} {:>10} {:>12}",
        "size", "layout", "gpu ms", "ns a pixel"
    );
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    // lund_door -r 2, Truck -r 4, Truck full size, the FPS benchmark's size.
    for (w, h) in [(162u32, 242u32), (245, 137), (979, 546), (1352, 1014)] {
        let px = (w * h) as usize;
        let image: Vec<f32> = (0..3 * px).map(|_| rng.gen::<f32>()).collect();
        let gt: Vec<u32> = (0..px).map(|_| rng.gen::<u32>() | 0xFF00_0000).collect();
        let image = GpuBuffer::from_slice(&ctx, "image", &image)?;
        let gt = GpuBuffer::from_slice(&ctx, "ground truth", &gt)?;
        let grad = GpuBuffer::from_slice(&ctx, "gradient", &vec![0f32; 3 * px])?;
        let out = GpuBuffer::from_slice(&ctx, "loss", &[0f32; 3])?;
        for layout in [LossLayout::Segments, LossLayout::Tiles] {
            let loss = Loss::with_layout(&ctx, w, h, layout)?;
            let mut pool = TimestampPool::new(&ctx, 4)?;
            let mut ms = Vec::with_capacity(reps);
            for _ in 0..reps {
                let mut rec = Recorder::new(&ctx)?;
                rec.start_timestamps(&mut pool);
                loss.record(
                    &mut rec, &image, &gt, 0, w, h, [0.0; 3], &grad, &out, 0, 0.2,
                )?;
                rec.timestamp(&mut pool, "loss");
                rec.submit_and_wait()?;
                ms.push(pool.read()?.total_ms());
            }
            ms.sort_by(|a, b| a.total_cmp(b));
            let median = ms[ms.len() / 2];
            println!(
                "{:>11} {:>9} {:>10.3} {:>12.1}",
                format!("{w}×{h}"),
                layout.name(),
                median,
                median * 1e6 / px as f64
            );
        }
    }
    Ok(())
}
