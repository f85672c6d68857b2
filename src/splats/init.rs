//! Initial Gaussians: one per SfM point, or random points in a box for scenes without points.
//!
//! Each Gaussian starts isotropic, with a standard deviation equal to the root of the mean
//! squared distance to its 3 nearest neighbours (so the splats roughly tile the cloud), opacity
//! 0.1, identity rotation, the point's colour in the SH DC term and zero higher bands.

use anyhow::bail;
use rand::{Rng, SeedableRng};

use super::knn::mean_sq_dist_knn;
use super::model::{inverse_sigmoid, rgb_to_sh_dc, sh_rest_coeffs, GaussianParams, MAX_SH_DEGREE};
use crate::scene::SfmPoints;

/// Opacity (after the sigmoid) of every initial Gaussian.
pub const INIT_OPACITY: f32 = 0.1;

/// Neighbours whose distances set the initial scale.
pub const INIT_NEIGHBOURS: usize = 3;

/// Lower clamp on the mean squared neighbour distance: duplicate points (distance 0) would
/// otherwise get a log scale of −inf. √1e-7 ≈ 3.2e-4 scene units.
pub const MIN_MEAN_SQ_DIST: f64 = 1e-7;

/// Mean squared distance used when the cloud is a single point and there is no neighbour to
/// measure: a Gaussian of standard deviation 0.1 scene units.
pub const LONE_POINT_MEAN_SQ_DIST: f64 = 0.01;

/// Number of random points the reference uses for scenes without SfM points (NeRF-synthetic).
pub const RANDOM_INIT_POINTS: usize = 100_000;

/// The initial log scale for a mean squared neighbour distance: `ln √max(d², MIN_MEAN_SQ_DIST)`.
pub fn init_log_scale(mean_sq_dist: f64) -> f32 {
    (0.5 * mean_sq_dist.max(MIN_MEAN_SQ_DIST).ln()) as f32
}

/// One Gaussian per point. `colors` are 8-bit RGB. Fails on mismatched lengths, non-finite
/// positions (or ones beyond the f32 range) and an SH degree above 3.
pub fn from_sfm_points(
    positions: &[[f64; 3]],
    colors: &[[u8; 3]],
    sh_degree: u32,
) -> anyhow::Result<GaussianParams> {
    if sh_degree > MAX_SH_DEGREE {
        bail!("SH degree {sh_degree} requested; the engine supports 0..={MAX_SH_DEGREE}");
    }
    if positions.len() != colors.len() {
        bail!(
            "initialisation: {} point positions but {} colours",
            positions.len(),
            colors.len()
        );
    }
    if let Some(i) = positions
        .iter()
        .position(|p| p.iter().any(|&v| !(v as f32).is_finite()))
    {
        bail!(
            "initialisation: point {i} has position {:?}, which is not finite in f32",
            positions[i]
        );
    }
    let n = positions.len();
    let mean_sq = if n == 1 {
        vec![LONE_POINT_MEAN_SQ_DIST]
    } else {
        mean_sq_dist_knn(positions, INIT_NEIGHBOURS)
    };
    let opacity = inverse_sigmoid(INIT_OPACITY);
    Ok(GaussianParams {
        sh_degree,
        positions: positions.iter().map(|p| p.map(|v| v as f32)).collect(),
        log_scales: mean_sq.iter().map(|&d| [init_log_scale(d); 3]).collect(),
        rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
        opacity_logits: vec![opacity; n],
        sh_dc: colors
            .iter()
            .map(|c| c.map(|v| rgb_to_sh_dc(v as f32 / 255.0)))
            .collect(),
        sh_rest: vec![0.0; n * sh_rest_coeffs(sh_degree) * 3],
        extra: Vec::new(),
    })
}

/// [`from_sfm_points`] for a scene's SfM points.
pub fn from_sfm(points: &SfmPoints, sh_degree: u32) -> anyhow::Result<GaussianParams> {
    from_sfm_points(&points.positions, &points.colors, sh_degree)
}

/// `n` Gaussians at uniformly random positions in the axis-aligned box `center ± half_extent`,
/// sized as in [`from_sfm_points`], with the reference's nearly grey colours: each SH DC
/// coefficient uniform in [0, 1/255), so every colour starts within 0.0012 of 0.5 (C0/255).
/// The same seed gives the same model. (The reference uses 100k points in ±1.3 for
/// NeRF-synthetic; see `Scene::random_init_box`.)
pub fn random_init(
    n: usize,
    center: [f64; 3],
    half_extent: [f64; 3],
    seed: u64,
    sh_degree: u32,
) -> anyhow::Result<GaussianParams> {
    if center.iter().chain(&half_extent).any(|v| !v.is_finite()) {
        bail!("random initialisation: box centre {center:?} / half extent {half_extent:?} must be finite");
    }
    if half_extent.iter().any(|&h| h < 0.0) {
        bail!("random initialisation: half extent {half_extent:?} must not be negative");
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let mut positions = Vec::with_capacity(n);
    let mut sh_dc = Vec::with_capacity(n);
    for _ in 0..n {
        let u: [f64; 3] = rng.gen();
        positions.push([0, 1, 2].map(|a| center[a] + (2.0 * u[a] - 1.0) * half_extent[a]));
        sh_dc.push(rng.gen::<[f32; 3]>().map(|v| v / 255.0));
    }
    let mut params = from_sfm_points(&positions, &vec![[0u8; 3]; n], sh_degree)?;
    params.sh_dc = sh_dc;
    Ok(params)
}

// A start above a Gaussian budget is drawn down to it in `super::budget_draw`.
