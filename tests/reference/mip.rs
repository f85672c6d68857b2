//! Mip-Splatting's filters in the f64 reference: the 3D filter's value from the training
//! cameras, what folding it into the parameters preserves, and the 2D filter's compensation
//! floor. (Their gradients are checked against finite differences in reference_backward.rs.)

use lpmsplat::reference::mip::{filter3d, fuse, FILTER_SCALE};
use lpmsplat::reference::project::{mip_compensation, sigmoid};
use lpmsplat::reference::scenes::random_gaussians;
use lpmsplat::reference::MIP_MIN_COMPENSATION;
use lpmsplat::scene::{PinholeCamera, Pose};
use rand::SeedableRng;
use rand_pcg::Pcg64;

fn camera(f: f64) -> PinholeCamera {
    PinholeCamera {
        fx: f,
        fy: f,
        cx: 50.0,
        cy: 40.0,
        width: 100,
        height: 80,
    }
}

/// A camera looking down +z from (0, 0, −d): a point at the origin has depth d.
fn at_distance(d: f64) -> Pose {
    Pose {
        translation: [0.0, 0.0, d],
        ..Pose::IDENTITY
    }
}

#[test]
fn filter_is_the_nearest_seeing_depth_over_the_largest_focal() {
    let cams = [
        (camera(100.0), at_distance(2.0)),
        (camera(200.0), at_distance(5.0)),
    ];
    let k = FILTER_SCALE.sqrt();
    let points = [
        // Seen by both: the nearer depth (2) over the largest focal (200).
        [0.0, 0.0, 0.0],
        // 1.9 in front of the near camera's centre: depth 0.1 < 0.2 does not count, so the
        // far camera's 3.1 does.
        [0.0, 0.0, -1.9],
        // Off to the side: at u = 125 in the near camera (past the 15 % margin of a 100-px
        // image), u = 110 in the far one: depth 5.
        [1.5, 0.0, 0.0],
        // Behind both cameras: unseen, gets the largest value of the others.
        [0.0, 0.0, -10.0],
    ];
    let f = filter3d(&points, &cams).unwrap();
    let want = [2.0, 3.1, 5.0, 5.0].map(|d: f64| d / 200.0 * k);
    for (got, want) in f.iter().zip(want) {
        assert!((got - want).abs() < 1e-12, "{f:?} vs {want:?}");
    }
    // 15 % past the edge still counts, 16 % does not (u = 100·x/2 + 50).
    let edge = |u: f64| [(u - 50.0) * 2.0 / 100.0, 0.0, 0.0];
    let only_near = [(camera(100.0), at_distance(2.0))];
    let seen = filter3d(&[edge(114.9), [0.0, 0.0, 1.0]], &only_near).unwrap();
    assert!((seen[0] - 2.0 / 100.0 * k).abs() < 1e-12);
    let unseen = filter3d(&[edge(116.1), [0.0, 0.0, 1.0]], &only_near).unwrap();
    assert!((unseen[0] - 3.0 / 100.0 * k).abs() < 1e-12, "{unseen:?}");
    // Nothing seen at all: no smoothing. No camera: an error naming the fix.
    assert_eq!(
        filter3d(&[[0.0, 0.0, -10.0]], &only_near).unwrap(),
        vec![0.0]
    );
    let e = filter3d(&points, &[]).unwrap_err().to_string();
    assert!(e.contains("training cameras"), "{e}");
}

#[test]
fn fusing_keeps_each_gaussians_integral_and_zero_filter_changes_nothing() {
    let mut rng = Pcg64::seed_from_u64(5);
    let g = random_gaussians(&mut rng, 50);
    let filter: Vec<f64> = (0..g.len()).map(|i| 0.002 * (i as f64 + 1.0)).collect();
    let fused = fuse(&g, &filter).unwrap();
    for (i, &f) in filter.iter().enumerate() {
        // opacity × volume (Π scales) is what the filter must not change.
        let integral = |logit: f64, ls: [f64; 3]| sigmoid(logit) * ls.iter().sum::<f64>().exp();
        let before = integral(g.opacity_logits[i], g.log_scales[i]);
        let after = integral(fused.opacity_logits[i], fused.log_scales[i]);
        assert!(
            (after / before - 1.0).abs() < 1e-9,
            "{i}: {before} → {after}"
        );
        for k in 0..3 {
            let (s, s2) = (g.log_scales[i][k].exp(), fused.log_scales[i][k].exp());
            assert!((s2 * s2 - s * s - f * f).abs() < 1e-12 * (1.0 + s2 * s2));
        }
        assert!(fused.opacity_logits[i] < g.opacity_logits[i]);
        assert_eq!(fused.positions[i], g.positions[i]);
        assert_eq!(fused.rotations[i], g.rotations[i]);
    }
    let same = fuse(&g, &vec![0.0; g.len()]).unwrap();
    for i in 0..g.len() {
        assert!((same.opacity_logits[i] - g.opacity_logits[i]).abs() < 1e-9);
        assert!((same.log_scales[i][0] - g.log_scales[i][0]).abs() < 1e-12);
    }
    assert!(fuse(&g, &filter[1..]).is_err());
}

#[test]
fn compensation_is_the_determinant_ratio_with_a_floor() {
    let eps = 0.1;
    let with = |raw: [f64; 3]| {
        let det1 = (raw[0] + eps) * (raw[2] + eps) - raw[1] * raw[1];
        mip_compensation(raw, det1)
    };
    // Isotropic σ² = 0.9 px²: ρ = 0.9 / (0.9 + 0.1).
    let (r, floored) = with([0.9, 0.0, 0.9]);
    assert!((r - 0.9).abs() < 1e-12 && !floored);
    // Degenerate (a line: det0 = 0), or a NaN: the floor, flagged (no gradient through it).
    assert_eq!(with([2.0, 2.0, 2.0]), (MIP_MIN_COMPENSATION, true));
    assert_eq!(with([f64::NAN, 0.0, 1.0]), (MIP_MIN_COMPENSATION, true));
    // Large splats are barely changed.
    assert!(with([400.0, 0.0, 900.0]).0 > 0.999);
}
