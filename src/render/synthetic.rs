//! Generated scenes for benchmarks: N Gaussians filling a ball with a density like a trained
//! scene's (each covering a handful of tiles at 1352×1014), seen by a camera outside the ball.

use rand::{Rng, SeedableRng};

use crate::scene::{PinholeCamera, Pose};
use crate::splats::GaussianParams;

/// `n` random Gaussians of SH degree 3 in the unit ball. Sizes shrink as n^(-1/3) so the
/// number of tiles each one touches stays about constant as n grows (as in a real scene that is
/// densified); opacities span mostly-transparent to opaque.
pub fn random_scene(n: usize, seed: u64) -> GaussianParams {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut p = GaussianParams::empty(3);
    let base = 0.8 * (n.max(1) as f32).powf(-1.0 / 3.0);
    for _ in 0..n {
        let pos = loop {
            let v: [f32; 3] = [0; 3].map(|_| rng.gen_range(-1.0..1.0));
            if v.iter().map(|x| x * x).sum::<f32>() <= 1.0 {
                break v;
            }
        };
        p.positions.push(pos);
        p.log_scales
            .push([0; 3].map(|_| (base * rng.gen_range(0.2f32..1.5)).ln()));
        let q: [f32; 4] = [0; 4].map(|_| rng.gen_range(-1.0..1.0));
        p.rotations.push(q);
        p.opacity_logits.push(rng.gen_range(-2.0..4.0));
        p.sh_dc.push([0; 3].map(|_| rng.gen_range(-1.5..1.5)));
        for _ in 0..45 {
            p.sh_rest.push(rng.gen_range(-0.2..0.2));
        }
    }
    p
}

/// A `width` × `height` camera 2.6 units from the origin looking at it, 60° horizontal FoV.
pub fn bench_camera(width: u32, height: u32) -> (PinholeCamera, Pose) {
    let fx = width as f64 / (2.0 * (30f64).to_radians().tan());
    let camera = PinholeCamera {
        fx,
        fy: fx,
        cx: width as f64 / 2.0,
        cy: height as f64 / 2.0,
        width,
        height,
    };
    let pose = crate::scene::orbit::look_at(
        glam::DVec3::new(0.3, -0.4, -2.55),
        glam::DVec3::ZERO,
        glam::DVec3::NEG_Y,
    );
    (camera, pose)
}

/// A camera that sees a model's bulk: looking at the centroid from outside its 90 % radius.
pub fn camera_for_model(p: &GaussianParams, width: u32, height: u32) -> (PinholeCamera, Pose) {
    let n = p.len().max(1) as f64;
    let mut c = [0.0f64; 3];
    for q in &p.positions {
        for k in 0..3 {
            c[k] += q[k] as f64 / n;
        }
    }
    let mut d: Vec<f64> = p
        .positions
        .iter()
        .map(|q| {
            (0..3)
                .map(|k| (q[k] as f64 - c[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    d.sort_by(|a, b| a.total_cmp(b));
    let r = d.get(d.len() * 9 / 10).copied().unwrap_or(1.0).max(1e-3);
    let (camera, _) = bench_camera(width, height);
    let eye = [c[0] + 0.3 * r, c[1] - 0.4 * r, c[2] - 2.5 * r];
    let pose = crate::scene::orbit::look_at(eye.into(), c.into(), glam::DVec3::NEG_Y);
    (camera, pose)
}
