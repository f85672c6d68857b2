//! Sort throughput: GPU radix sort (keys/s) against the host's `sort_unstable` on the same keys,
//! 1k … 16M pairs (set LPMSPLAT_BENCH_MAX to cap the size; default 4M, lavapipe is slow).
//! Run: `cargo bench --bench sort`. GPU time is from timestamps (sort only, no transfers).

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder, TimestampPool};
use lpmsplat::render::sort::{Digits, RadixSort};
use rand::{Rng, SeedableRng};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let ctx = GpuContext::new(&GpuOptions::for_benches())?;
    println!("{}", ctx.info.summary());
    let max: usize = std::env::var("LPMSPLAT_BENCH_MAX")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4 << 20);
    // The renderer's two sorts at 1352x1014: depths (32 bits) and tile ids (13 bits).
    println!(
        "{:>10} {:>6} {:>7} {:>8} {:>12} {:>14} {:>14} {:>8}",
        "pairs", "bits", "digits", "passes", "gpu ms", "gpu Mkeys/s", "host Mkeys/s", "ratio"
    );
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    for (n, bits, digits) in std::iter::successors(Some(1024usize), |n| Some(n * 4))
        .take_while(|&n| n <= max)
        .flat_map(|n| [(n, 32u32), (n, 31), (n, 13)])
        .flat_map(|(n, bits)| [Digits::Narrow, Digits::Wide, Digits::Byte].map(|d| (n, bits, d)))
        // 5-bit digits only where they change the passes.
        .filter(|&(_, bits, digits)| {
            digits != Digits::Wide
                || RadixSort::pass_widths(bits, Digits::Wide)
                    != RadixSort::pass_widths(bits, Digits::Narrow)
        })
    {
        let keys: Vec<u32> = (0..n)
            .map(|_| rng.gen::<u32>() & (u32::MAX >> (32 - bits)))
            .collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let shape = RadixSort::shape_for(&ctx, digits);
        let sorter = match RadixSort::with_options(&ctx, n as u64, shape, digits, false) {
            Ok(s) => s,
            Err(e) => {
                println!("{n:>10} {bits:>6} {digits:?}: {e}");
                continue;
            }
        };
        let kb = GpuBuffer::from_slice(&ctx, "keys", &keys)?;
        let vb = GpuBuffer::from_slice(&ctx, "vals", &vals)?;
        let sk = GpuBuffer::<u32>::new(&ctx, "sk", n, BufferKind::DeviceLocal)?;
        let sv = GpuBuffer::<u32>::new(&ctx, "sv", n, BufferKind::DeviceLocal)?;
        let counts = GpuBuffer::from_slice(&ctx, "counts", &[n as u32, 0])?;
        let mut pool = TimestampPool::new(&ctx, 4)?;
        let reps = (4_000_000 / n).clamp(3, 50);
        let mut gpu_ms = Vec::new();
        for _ in 0..reps {
            // Re-upload is outside the timed region: sorting sorted keys would flatter nobody,
            // but keep the input identical every repetition.
            kb.upload(&keys)?;
            let mut rec = Recorder::new(&ctx)?;
            rec.start_timestamps(&mut pool);
            sorter.record(&mut rec, &kb, &vb, &sk, &sv, &counts, 0, 1, bits);
            rec.timestamp(&mut pool, "sort");
            rec.submit_and_wait()?;
            gpu_ms.push(pool.read()?.total_ms());
        }
        gpu_ms.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let gpu = gpu_ms[gpu_ms.len() / 2];
        let mut host_ms = Vec::new();
        for _ in 0..reps {
            let mut pairs: Vec<(u32, u32)> =
                keys.iter().copied().zip(vals.iter().copied()).collect();
            let t = Instant::now();
            pairs.sort_unstable();
            host_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        host_ms.sort_by(|a, b| a.partial_cmp(b).unwrap());
        let host = host_ms[host_ms.len() / 2];
        println!(
            "{:>10} {:>6} {:>7} {:>8} {:>12.3} {:>14.1} {:>14.1} {:>8.2}",
            n,
            bits,
            digits.max_bits(),
            RadixSort::pass_widths(bits, digits).len(),
            gpu,
            n as f64 / gpu / 1e3,
            n as f64 / host / 1e3,
            host / gpu
        );
    }
    Ok(())
}
