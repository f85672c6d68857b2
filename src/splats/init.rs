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

/// How opaque and how large a start from points begins: every Gaussian's opacity set to
/// `opacity` and its scales multiplied by `scale`. 3DGS starts at 0.1 and the neighbours'
/// spacing ([`Look::STANDARD`]); the MCMC recipe as gsplat ships it starts at 0.5 and a tenth of
/// the spacing ([`Look::MCMC`]): small opaque Gaussians that relocation can move without
/// dimming the image, where wide faint ones blur it until they are split.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// Opacity after the sigmoid, in (0, 1).
    pub opacity: f32,
    /// Factor on every scale, > 0.
    pub scale: f32,
}

impl Look {
    /// 3DGS's start: opacity [`INIT_OPACITY`], scales as set from the neighbours.
    pub const STANDARD: Look = Look {
        opacity: INIT_OPACITY,
        scale: 1.0,
    };
    /// MCMC's start (gsplat's MCMC preset): opacity 0.5, a tenth of the neighbours' spacing.
    pub const MCMC: Look = Look {
        opacity: 0.5,
        scale: 0.1,
    };

    /// Refuses an opacity outside (0, 1) (its logit is infinite) and a scale that is not a
    /// finite positive number, naming the flag.
    pub fn validate(&self) -> anyhow::Result<()> {
        if !(self.opacity > 0.0 && self.opacity < 1.0) {
            bail!(
                "--init-opacity {}: an opacity must lie strictly between 0 and 1 (its logit is \
                 the stored value). Fix: pass e.g. 0.1 (3DGS) or 0.5 (MCMC)",
                self.opacity
            );
        }
        if !(self.scale.is_finite() && self.scale > 0.0) {
            bail!(
                "--init-scale {}: the factor on the neighbours' spacing must be a finite number \
                 above 0. Fix: pass e.g. 1 (3DGS) or 0.1 (MCMC)",
                self.scale
            );
        }
        Ok(())
    }

    /// Sets every Gaussian's opacity and multiplies its scales. [`Look::STANDARD`] on a fresh
    /// start from points leaves it bit for bit as it was.
    pub fn apply(&self, params: &mut GaussianParams) {
        let logit = inverse_sigmoid(self.opacity);
        params.opacity_logits.iter_mut().for_each(|o| *o = logit);
        if self.scale != 1.0 {
            let shift = self.scale.ln();
            for s in params.log_scales.iter_mut().flatten() {
                *s += shift;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> GaussianParams {
        let positions: Vec<[f64; 3]> = (0..20)
            .map(|i| [i as f64 * 0.3, (i % 3) as f64, (i % 5) as f64 * 0.1])
            .collect();
        from_sfm_points(&positions, &[[10, 20, 30]; 20], 1).unwrap()
    }

    #[test]
    fn the_standard_look_leaves_a_start_bit_for_bit() {
        let before = cloud();
        let mut after = before.clone();
        Look::STANDARD.apply(&mut after);
        assert_eq!(before.opacity_logits, after.opacity_logits);
        assert_eq!(before.log_scales, after.log_scales);
    }

    #[test]
    fn mcmcs_look_sets_opacity_and_shrinks_every_scale_tenfold() {
        let before = cloud();
        let mut after = before.clone();
        Look::MCMC.apply(&mut after);
        for &o in &after.opacity_logits {
            let p = 1.0 / (1.0 + (-o as f64).exp());
            assert!((p - 0.5).abs() < 1e-6, "{p}");
        }
        for (b, a) in before.log_scales.iter().zip(&after.log_scales) {
            for k in 0..3 {
                let ratio = (a[k] as f64).exp() / (b[k] as f64).exp();
                assert!((ratio - 0.1).abs() < 1e-5, "{ratio}");
            }
        }
        assert_eq!(before.positions, after.positions);
        assert_eq!(before.sh_dc, after.sh_dc);
    }

    #[test]
    fn a_look_without_a_logit_or_a_size_is_refused_by_its_flag() {
        for o in [0.0, 1.0, -0.2, 1.5, f32::NAN] {
            let e = Look {
                opacity: o,
                scale: 1.0,
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("--init-opacity"), "{e}");
        }
        for s in [0.0, -1.0, f32::INFINITY, f32::NAN] {
            let e = Look {
                opacity: 0.5,
                scale: s,
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("--init-scale"), "{e}");
        }
        Look::MCMC.validate().unwrap();
        Look::STANDARD.validate().unwrap();
    }
}
