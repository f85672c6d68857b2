//! No per-Gaussian device buffer is wider than 36 bytes a Gaussian, in any model, with LPM
//! (issue 19: one storage binding must not cap the model before device memory does). Lavapipe
//! binds 128 MiB, so 36 bytes allow 3.7 M Gaussians of capacity (the 64-byte projected records
//! and 60-byte SH planes of earlier builds stopped at 2.1 M).
//!
//! Each model trains two iterations from two model sizes with `LPMSPLAT_BUFFER_LOG` set; the
//! growth of every named buffer between the runs, over the growth of the Gaussian capacity, is
//! its width. Buffers of (tile, Gaussian) pairs grow with the intersections instead; their own
//! limit is `max_intersections` (4-byte entries).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The widest per-Gaussian buffer the engine allocates, in bytes a Gaussian.
const MAX_BYTES_PER_GAUSSIAN: f64 = 36.0;

/// Buffers sized by the frame's intersections, not by the model.
const PAIR_BUFFERS: [&str; 5] = [
    "tile keys",
    "tile ids",
    "tile keys (scratch)",
    "tile ids (scratch)",
    "sort histograms",
];

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// The largest allocation under each buffer name of a two-iteration run from `points` random
/// points.
fn allocations(scene: &str, model: &str, points: usize) -> HashMap<String, u64> {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("buffers.tsv");
    let out = Command::new(env!("CARGO_BIN_EXE_lpmsplat"))
        .arg("train")
        .arg(data(scene))
        .args([
            "--model",
            model,
            "--lpm",
            "--iterations",
            "2",
            "--sh-degree",
            "3",
        ])
        .args(["--init-points", &points.to_string(), "-o"])
        .arg(dir.path().join("run"))
        .env("LPMSPLAT_BUFFER_LOG", &log)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{model} on {scene}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut by_name = HashMap::new();
    for line in std::fs::read_to_string(&log).unwrap().lines() {
        let (name, bytes) = line.rsplit_once('\t').unwrap();
        let e = by_name.entry(name.to_string()).or_insert(0u64);
        *e = (*e).max(bytes.parse().unwrap());
    }
    by_name
}

/// The trainer's capacity for `n` initial Gaussians (`splats::gpu::grown_capacity`).
fn capacity(n: usize) -> usize {
    lpmsplat::splats::gpu::grown_capacity(n)
}

#[test]
fn no_per_gaussian_buffer_is_wider_than_36_bytes_in_any_model() {
    let (small, large) = (4000, 8000);
    let grown = (capacity(large) - capacity(small)) as f64;
    let runs = [
        ("lego_small", "3dgs"),
        ("lego_small", "pixel-gs"),
        ("lego_small", "mip-splatting"),
        ("lego_small", "2dgs"),
        ("n3v_tiny", "spacetime-lite"),
        ("n3v_tiny", "spacetime-full"),
    ];
    for (scene, model) in runs {
        let a = allocations(scene, model, small);
        let b = allocations(scene, model, large);
        let mut widths: Vec<(f64, &String)> = b
            .iter()
            .filter(|(name, _)| !PAIR_BUFFERS.contains(&name.as_str()))
            .map(|(name, &bytes)| {
                let before = a.get(name).copied().unwrap_or(0);
                ((bytes as f64 - before as f64) / grown, name)
            })
            .collect();
        widths.sort_by(|x, y| y.0.total_cmp(&x.0));
        let (widest, name) = widths[0];
        eprintln!("{model}: widest per-Gaussian buffer '{name}', {widest} bytes a Gaussian");
        // The model's own buffers are there and scale (so the test sees them at all).
        assert!(
            widest >= 28.0,
            "{model}: nothing grows with the model? {widths:?}"
        );
        let wide: Vec<_> = widths
            .iter()
            .filter(|(w, _)| *w > MAX_BYTES_PER_GAUSSIAN + 1e-9)
            .collect();
        assert!(
            wide.is_empty(),
            "{model}: buffers wider than {MAX_BYTES_PER_GAUSSIAN} bytes a Gaussian: {wide:?}"
        );
    }
}

#[test]
fn an_unwritable_buffer_log_warns_and_the_run_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_lpmsplat"))
        .arg("train")
        .arg(data("lego_small"))
        .args(["--iterations", "1", "--init-points", "500", "-o"])
        .arg(dir.path().join("run"))
        .env(
            "LPMSPLAT_BUFFER_LOG",
            dir.path().join("no/such/folder/log.tsv"),
        )
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("LPMSPLAT_BUFFER_LOG") && err.contains("Fix:"),
        "{err}"
    );
}
