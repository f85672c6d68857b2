//! Initialisation: the kd-tree kNN against brute force, and the initial Gaussian values.

use lpmsplat::splats::init::{
    init_log_scale, INIT_OPACITY, LONE_POINT_MEAN_SQ_DIST, MIN_MEAN_SQ_DIST,
};
use lpmsplat::splats::knn::{mean_sq_dist_knn, KdTree};
use lpmsplat::splats::model::{sh_dc_to_rgb, sh_rest_coeffs, sigmoid};
use lpmsplat::splats::{from_sfm_points, random_init};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn sq(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

/// Sorted squared distances from point `i` to every other point.
fn brute_sorted(points: &[[f64; 3]], i: usize) -> Vec<f64> {
    let mut d: Vec<f64> = (0..points.len())
        .filter(|&j| j != i)
        .map(|j| sq(&points[i], &points[j]))
        .collect();
    d.sort_by(f64::total_cmp);
    d
}

fn brute_mean(points: &[[f64; 3]], i: usize, k: usize) -> f64 {
    let d = brute_sorted(points, i);
    let m = k.min(d.len());
    if m == 0 {
        return 0.0;
    }
    d[..m].iter().sum::<f64>() / m as f64
}

/// Random clouds of several shapes: uniform box, flat clusters, heavy duplicates, a line, and a
/// grid (many equal distances).
fn clouds(seed: u64) -> Vec<(String, Vec<[f64; 3]>)> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut out = Vec::new();
    let uniform: Vec<[f64; 3]> = (0..700)
        .map(|_| {
            [
                rng.gen_range(-5.0..5.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(0.0..30.0),
            ]
        })
        .collect();
    out.push(("uniform".into(), uniform));
    let mut clustered = Vec::new();
    for _ in 0..6 {
        let c: [f64; 3] = [
            rng.gen_range(-100.0..100.0),
            rng.gen_range(-100.0..100.0),
            0.0,
        ];
        for _ in 0..120 {
            clustered.push([
                c[0] + rng.gen_range(-0.5..0.5),
                c[1] + rng.gen_range(-0.5..0.5),
                c[2] + rng.gen_range(-1e-3..1e-3),
            ]);
        }
    }
    clustered.push([1e4, -1e4, 5e3]); // far outlier
    out.push(("clustered".into(), clustered));
    let mut dup: Vec<[f64; 3]> = (0..200)
        .map(|_| {
            [
                rng.gen_range(0.0..1.0),
                rng.gen_range(0.0..1.0),
                rng.gen_range(0.0..1.0),
            ]
        })
        .collect();
    for _ in 0..300 {
        let p = dup[rng.gen_range(0..dup.len())];
        dup.push(p);
    }
    out.push(("duplicates".into(), dup));
    out.push((
        "line".into(),
        (0..300)
            .map(|_| [rng.gen_range(-1.0..1.0), 2.0, 3.0])
            .collect(),
    ));
    let mut grid = Vec::new();
    for x in 0..8 {
        for y in 0..8 {
            for z in 0..8 {
                grid.push([x as f64 * 0.5, y as f64 * 0.5, z as f64 * 0.5]);
            }
        }
    }
    out.push(("grid".into(), grid));
    out
}

#[test]
fn kdtree_matches_brute_force() {
    for (name, points) in clouds(42) {
        let tree = KdTree::build(&points);
        assert_eq!(tree.len(), points.len());
        let mut got = Vec::new();
        for k in [1, 3, 7] {
            let means = mean_sq_dist_knn(&points, k);
            for i in 0..points.len() {
                tree.nearest_sq_dists(points[i], Some(i), k, &mut got);
                let want = brute_sorted(&points, i);
                assert_eq!(got, want[..k], "{name}: point {i}, k={k}");
                let m = brute_mean(&points, i, k);
                assert!(
                    (means[i] - m).abs() <= 1e-12 * m.max(1e-300),
                    "{name} {i}: {} vs {m}",
                    means[i]
                );
            }
        }
        // Queries at arbitrary locations, nothing excluded.
        let mut rng = Pcg64::seed_from_u64(7);
        for _ in 0..200 {
            let q = [
                rng.gen_range(-10.0..10.0),
                rng.gen_range(-10.0..10.0),
                rng.gen_range(-1.0..30.0),
            ];
            tree.nearest_sq_dists(q, None, 4, &mut got);
            let mut want: Vec<f64> = points.iter().map(|p| sq(p, &q)).collect();
            want.sort_by(f64::total_cmp);
            assert_eq!(got, want[..4], "{name}: query {q:?}");
        }
    }
}

#[test]
fn knn_with_few_points_uses_what_is_there() {
    let mut rng = Pcg64::seed_from_u64(3);
    for n in 0..=5 {
        let points: Vec<[f64; 3]> = (0..n)
            .map(|_| {
                [
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                    rng.gen_range(-1.0..1.0),
                ]
            })
            .collect();
        let means = mean_sq_dist_knn(&points, 3);
        assert_eq!(means.len(), n);
        for (i, &m) in means.iter().enumerate() {
            assert!((m - brute_mean(&points, i, 3)).abs() < 1e-15, "n={n} i={i}");
        }
    }
    // n = 2: each point's only neighbour is the other.
    let two = [[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]];
    assert_eq!(mean_sq_dist_knn(&two, 3), vec![25.0, 25.0]);
    // n = 1: an empty mean.
    assert_eq!(mean_sq_dist_knn(&[[1.0, 2.0, 3.0]], 3), vec![0.0]);
}

#[test]
fn sfm_init_values() {
    let mut rng = Pcg64::seed_from_u64(11);
    let n = 400;
    let mut positions: Vec<[f64; 3]> = (0..n)
        .map(|_| {
            [
                rng.gen_range(-3.0..3.0),
                rng.gen_range(-3.0..3.0),
                rng.gen_range(2.0..9.0),
            ]
        })
        .collect();
    // Three copies of one point: their 3 nearest are each other, at distance 0.
    positions[10] = positions[20];
    positions[30] = positions[20];
    positions[40] = positions[20];
    let colors: Vec<[u8; 3]> = (0..n).map(|_| rng.gen()).collect();
    for degree in 0..=3 {
        let m = from_sfm_points(&positions, &colors, degree).unwrap();
        m.validate().unwrap();
        assert_eq!((m.len(), m.sh_degree), (n, degree));
        assert_eq!(m.sh_rest, vec![0.0; n * sh_rest_coeffs(degree) * 3]);
        for i in 0..n {
            assert_eq!(m.positions[i], positions[i].map(|v| v as f32));
            assert_eq!(m.rotations[i], [1.0, 0.0, 0.0, 0.0]);
            assert!((sigmoid(m.opacity_logits[i]) - INIT_OPACITY).abs() < 1e-6);
            for (&dc, &byte) in m.sh_dc[i].iter().zip(&colors[i]) {
                let rgb = byte as f64 / 255.0;
                let want = (rgb - 0.5) / 0.28209479177387814;
                assert!((dc as f64 - want).abs() < 1e-6);
                assert!((sh_dc_to_rgb(dc) as f64 - rgb).abs() < 1e-6);
            }
            let d2 = brute_mean(&positions, i, 3).max(1e-7);
            let want = d2.sqrt().ln();
            assert!(
                m.log_scales[i]
                    .iter()
                    .all(|&s| (s as f64 - want).abs() < 1e-5),
                "{i}"
            );
        }
        for i in [10, 20, 30, 40] {
            assert_eq!(m.log_scales[i][0], init_log_scale(0.0));
            assert!((m.log_scales[i][0] as f64 - MIN_MEAN_SQ_DIST.sqrt().ln()).abs() < 1e-6);
        }
    }
}

#[test]
fn tiny_clouds_and_bad_input() {
    let c = [[255u8, 0, 128]; 3];
    let one = from_sfm_points(&[[1.0, 2.0, 3.0]], &c[..1], 0).unwrap();
    assert_eq!(
        one.log_scales[0],
        [init_log_scale(LONE_POINT_MEAN_SQ_DIST); 3]
    );
    let two = from_sfm_points(&[[0.0; 3], [0.0, 0.0, 2.0]], &c[..2], 1).unwrap();
    assert_eq!(two.log_scales, vec![[2f64.ln() as f32; 3]; 2]);
    let three = from_sfm_points(&[[0.0; 3], [0.0, 0.0, 2.0], [0.0, 4.0, 0.0]], &c, 0).unwrap();
    // Point 0: neighbours at 4 and 16 → mean 10.
    assert!((three.log_scales[0][0] as f64 - 10f64.sqrt().ln()).abs() < 1e-6);
    assert!(from_sfm_points(&[], &[], 3).unwrap().is_empty());

    assert!(from_sfm_points(&[[0.0; 3]], &[], 0).is_err());
    assert!(from_sfm_points(&[[0.0; 3]], &c[..1], 4).is_err());
    let err = from_sfm_points(&[[0.0; 3], [f64::NAN, 0.0, 0.0]], &c[..2], 0).unwrap_err();
    assert!(err.to_string().contains("point 1"), "{err}");
    assert!(from_sfm_points(&[[1e300, 0.0, 0.0]], &c[..1], 0).is_err());
    assert!(random_init(10, [0.0; 3], [-1.0, 1.0, 1.0], 0, 0).is_err());
    assert!(random_init(10, [f64::NAN, 0.0, 0.0], [1.0; 3], 0, 0).is_err());
}

#[test]
fn random_init_is_deterministic_and_in_bounds() {
    let center = [0.5, -2.0, 10.0];
    let half = [1.3, 0.2, 4.0];
    let a = random_init(100_000, center, half, 1234, 3).unwrap();
    let b = random_init(100_000, center, half, 1234, 3).unwrap();
    let c = random_init(100_000, center, half, 1235, 3).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.positions, c.positions);
    assert_eq!(a.len(), 100_000);
    a.validate().unwrap();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &a.positions {
        for k in 0..3 {
            assert!((p[k] as f64 - center[k]).abs() <= half[k] * (1.0 + 1e-6));
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    // Uniform over the box: the extremes come close to the faces.
    for k in 0..3 {
        assert!((lo[k] as f64 - (center[k] - half[k])).abs() < 0.01 * half[k]);
        assert!((hi[k] as f64 - (center[k] + half[k])).abs() < 0.01 * half[k]);
    }
    // The reference's colours: SH DC uniform in [0, 1/255), so nearly grey but not constant.
    let dc: Vec<f32> = a.sh_dc.iter().flatten().copied().collect();
    assert!(dc.iter().all(|&d| (0.0..1.0 / 255.0).contains(&d)));
    let mean = dc.iter().sum::<f32>() / dc.len() as f32;
    assert!((mean * 255.0 - 0.5).abs() < 0.01, "{mean}");
    assert!(dc.iter().any(|&d| d * 255.0 < 0.01) && dc.iter().any(|&d| d * 255.0 > 0.99));
    assert!(dc.iter().all(|&d| (sh_dc_to_rgb(d) - 0.5).abs() < 1.2e-3));
    // Scales follow the kNN rule: spot-check against brute force.
    let pos64: Vec<[f64; 3]> = a.positions.iter().map(|p| p.map(|v| v as f64)).collect();
    let mut rng = Pcg64::seed_from_u64(5);
    for _ in 0..20 {
        let i = rng.gen_range(0..a.len());
        // Positions were rounded to f32 after the kNN in f64, hence the loose tolerance.
        let want = init_log_scale(brute_mean(&pos64, i, 3));
        assert!((a.log_scales[i][0] - want).abs() < 1e-3, "{i}");
    }
}
