//! Times the 3-nearest-neighbour scale computation used by initialisation.
//! Run with `cargo bench --bench knn` (release profile).

use std::time::Instant;

use lpmsplat::splats::knn::mean_sq_dist_knn;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn main() {
    println!("threads: {}", rayon::current_num_threads());
    for n in [10_000usize, 100_000, 1_000_000] {
        let mut rng = Pcg64::seed_from_u64(n as u64);
        let uniform: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                [
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                ]
            })
            .collect();
        // SfM-like: points on a few thin surfaces plus sparse outliers.
        let surfaces: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                if i % 50 == 0 {
                    [
                        rng.gen_range(-50.0..50.0),
                        rng.gen_range(-50.0..50.0),
                        rng.gen_range(-50.0..50.0),
                    ]
                } else {
                    let plane = (i % 7) as f64;
                    [
                        rng.gen_range(-1.0..1.0),
                        rng.gen_range(-1.0..1.0),
                        plane + rng.gen_range(-1e-3..1e-3),
                    ]
                }
            })
            .collect();
        for (name, points) in [("uniform", &uniform), ("surfaces", &surfaces)] {
            let reps = if n <= 10_000 { 10 } else { 1 };
            // One untimed run warms the thread pool and the allocator.
            let mut sink = mean_sq_dist_knn(points, 3)[0];
            let t = Instant::now();
            for _ in 0..reps {
                sink += mean_sq_dist_knn(points, 3)[n / 2];
            }
            let s = t.elapsed().as_secs_f64() / reps as f64;
            println!(
                "knn3 {name:>8} n={n:>8}: {:8.1} ms, {:6.2} M points/s (checksum {sink:.3e})",
                s * 1e3,
                n as f64 / s / 1e6
            );
        }
    }
}
