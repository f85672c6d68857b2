//! Preprocess: one Gaussian in world space → its screen-space footprint (mean, conic, radius,
//! tile rectangle), depth, opacity and view-dependent colour. See the module docs of
//! [`crate::reference`] for the numbered steps this file follows.

use anyhow::Result;

use super::linalg::{self, Mat23, Mat3, Vec3};
use super::{sh, RefGaussians, RenderSettings, QUAT_NORM2_MIN};
use crate::scene::{PinholeCamera, Pose};

/// The per-Gaussian result of preprocessing, field by field what a GPU preprocess kernel
/// produces. For a culled Gaussian only `culled`, `cam_mean` and `depth` are meaningful;
/// the rest is zero and the tile rectangle is empty.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Projected {
    /// Culled: behind the near plane, degenerate 2D covariance, or non-finite projection.
    pub culled: bool,
    /// Mean in camera space.
    pub cam_mean: [f64; 3],
    /// Camera z: the sort key within a tile.
    pub depth: f64,
    /// Projected mean in pixels (pixel centres at +0.5).
    pub mean2d: [f64; 2],
    /// Dilated 2D covariance `[a, b, c]` = `[[a, b], [b, c]]`, px².
    pub cov2d: [f64; 3],
    /// Inverse of `cov2d`, `[a, b, c]` = `[[a, b], [b, c]]`.
    pub conic: [f64; 3],
    /// `ceil(3·sqrt(λmax))` in pixels (an integer value, kept as f64).
    pub radius: f64,
    /// sigmoid(opacity logit), times `compensation`.
    pub opacity: f64,
    /// The 2D Mip filter's opacity factor ρ (1 without `mip_2d`).
    pub compensation: f64,
    /// ρ sits at its floor (passes no gradient).
    pub compensation_floored: bool,
    /// Colour after `+0.5` and the clamp at 0.
    pub rgb: [f64; 3],
    /// Per channel: the clamp at 0 was active (this channel passes no gradient).
    pub rgb_clamped: [bool; 3],
    /// Tile rectangle `[tile_min, tile_max)` in tile units, clamped to the grid.
    pub tile_min: [u32; 2],
    pub tile_max: [u32; 2],
}

impl Projected {
    /// Number of tiles the rectangle covers (0 when culled or off-screen).
    pub fn tiles_touched(&self) -> u64 {
        let w = self.tile_max[0].saturating_sub(self.tile_min[0]) as u64;
        let h = self.tile_max[1].saturating_sub(self.tile_min[1]) as u64;
        w * h
    }

    /// The tile columns `[x0, x1)` of tile row `ty` that this splat is paired with: those of
    /// the rectangle where a pixel centre may get alpha ≥ `alpha_min` ([`ellipse_row_span`]).
    /// The rest of the rectangle's tiles would skip the splat at every pixel, so leaving them
    /// out changes no pixel and no gradient. Empty outside the rectangle's rows.
    pub fn row_tiles(&self, ty: u32, s: &RenderSettings) -> std::ops::Range<u32> {
        let (x0, x1) = (self.tile_min[0], self.tile_max[0]);
        if self.culled || !(self.tile_min[1]..self.tile_max[1]).contains(&ty) || x0 >= x1 {
            return 0..0;
        }
        let ts = s.tile_size as f64;
        let q_cut = splat_q_cut(self.opacity, s);
        let band = [ty as f64 * ts + 0.5, (ty + 1) as f64 * ts - 0.5];
        match ellipse_row_span(self.mean2d, self.conic, q_cut, band) {
            RowSpan::Empty => 0..0,
            RowSpan::Whole => x0..x1,
            RowSpan::Pixels(lo, hi) => {
                // Tile tx holds the pixel centres tx·ts + 0.5 ..= (tx + 1)·ts − 0.5.
                let first = ((lo - (ts - 0.5)) / ts).ceil().clamp(x0 as f64, x1 as f64) as u32;
                let end = (((hi - 0.5) / ts).floor() + 1.0).clamp(x0 as f64, x1 as f64) as u32;
                first..end.max(first)
            }
        }
    }

    /// The number of (tile, splat) pairs: the tiles of [`Projected::row_tiles`] over its rows.
    pub fn pairs(&self, s: &RenderSettings) -> u64 {
        (self.tile_min[1]..self.tile_max[1])
            .map(|ty| self.row_tiles(ty, s).len() as u64)
            .sum()
    }

    /// True when tile (tx, ty) lies in the rectangle.
    pub fn touches_tile(&self, tx: u32, ty: u32) -> bool {
        (self.tile_min[0]..self.tile_max[0]).contains(&tx)
            && (self.tile_min[1]..self.tile_max[1]).contains(&ty)
    }
}

/// The unit quaternion and the norm it was divided by, or `None` when `|q|² < QUAT_NORM2_MIN`
/// (or not finite): such a quaternion is read as the identity rotation.
pub fn normalize_quat(q: [f64; 4]) -> Option<([f64; 4], f64)> {
    let n2 = q.iter().map(|v| v * v).sum::<f64>();
    if !n2.is_finite() || n2 < QUAT_NORM2_MIN {
        return None;
    }
    let n = n2.sqrt();
    Some(([q[0] / n, q[1] / n, q[2] / n, q[3] / n], n))
}

/// Rotation matrix of a unit quaternion (w, x, y, z): the formula the COLMAP reader uses for
/// poses, kept once below both (the GPU kernels' own, in GLSL, are what this oracle checks).
pub fn quat_to_rotation(q: [f64; 4]) -> Mat3 {
    crate::scene::camera::rotation_of_unit_quaternion(q)
}

/// The unit quaternion (w, x, y, z; w ≥ 0) of a rotation matrix, the inverse of
/// [`quat_to_rotation`]: kept once below both, with the COLMAP writers.
pub fn rotation_to_quat(m: &Mat3) -> [f64; 4] {
    crate::scene::camera::unit_quaternion_of_rotation(*m)
}

/// The rotation a stored quaternion stands for (identity for a degenerate one).
pub fn rotation_of(q: [f64; 4]) -> Mat3 {
    match normalize_quat(q) {
        Some((unit, _)) => quat_to_rotation(unit),
        None => quat_to_rotation([1.0, 0.0, 0.0, 0.0]),
    }
}

/// `M = R S` with `S = diag(exp(log_scale))`, so that `Σ = M Mᵀ`.
pub fn scaled_rotation(log_scale: [f64; 3], q: [f64; 4]) -> Mat3 {
    let r = rotation_of(q);
    let s = log_scale.map(f64::exp);
    let mut m = r;
    for row in m.iter_mut() {
        for (col, v) in row.iter_mut().enumerate() {
            *v *= s[col];
        }
    }
    m
}

/// World-space 3D covariance `Σ = R S Sᵀ Rᵀ`.
pub fn covariance3d(log_scale: [f64; 3], q: [f64; 4]) -> Mat3 {
    let m = scaled_rotation(log_scale, q);
    linalg::mul(&m, &linalg::transpose(&m))
}

/// Clamp intervals `[lo, hi]` for x/z and y/z in the EWA Jacobian: `fov_clamp` times the
/// tangent from the principal point to each image edge.
pub fn jacobian_limits(camera: &PinholeCamera, settings: &RenderSettings) -> [[f64; 2]; 2] {
    let k = settings.fov_clamp;
    [
        [
            -k * camera.cx / camera.fx,
            k * (camera.width as f64 - camera.cx) / camera.fx,
        ],
        [
            -k * camera.cy / camera.fy,
            k * (camera.height as f64 - camera.cy) / camera.fy,
        ],
    ]
}

/// `min(max(v, lo), hi)`: never panics, even when `lo > hi` (unlike `f64::clamp`), and says
/// whether `v` was moved.
pub fn clamp_flag(v: f64, lo: f64, hi: f64) -> (f64, bool) {
    let c = v.max(lo).min(hi);
    (c, c != v)
}

/// The EWA Jacobian of the projection at camera-space point `t`, with x/z and y/z clamped
/// (step 4), and which of the two were clamped.
pub fn ewa_jacobian(camera: &PinholeCamera, t: Vec3, limits: &[[f64; 2]; 2]) -> (Mat23, [bool; 2]) {
    let z = t[2];
    let (tx, cx) = clamp_flag(t[0] / z, limits[0][0], limits[0][1]);
    let (ty, cy) = clamp_flag(t[1] / z, limits[1][0], limits[1][1]);
    let j = [
        [camera.fx / z, 0.0, -camera.fx * tx / z],
        [0.0, camera.fy / z, -camera.fy * ty / z],
    ];
    (j, [cx, cy])
}

/// Unit view direction from the camera centre to `p`, and the distance it was divided by.
pub fn view_direction(p: Vec3, camera_center: Vec3) -> (Vec3, f64) {
    let v = linalg::sub(p, camera_center);
    let len = linalg::dot(v, v).sqrt();
    (linalg::scale(v, 1.0 / len), len)
}

pub fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Half-size in pixels of the square a Gaussian's tiles are taken from: the 3σ `radius`, or,
/// when smaller, `ceil(sqrt(2·ln(opacity / alpha_min)·λmax))`, the distance beyond which
/// `opacity·exp(power)` is below `alpha_min` in every direction, so the splat is skipped there
/// anyway. The image is unchanged; faint Gaussians just join fewer tile lists. 0 means the
/// Gaussian is too faint to show anywhere. Smooth mode has no `alpha_min` skip: 3σ only.
pub fn footprint_extent(radius: f64, lambda_max: f64, opacity: f64, s: &RenderSettings) -> f64 {
    if s.smooth {
        return radius;
    }
    let p = (opacity / s.alpha_min).ln();
    if p.is_nan() || p <= 0.0 {
        return 0.0;
    }
    radius.min((2.0 * p * lambda_max).sqrt().ceil())
}

/// Beyond which `q(d) = dᵀ·conic·d` (= −2·power) a splat's alpha is below `alpha_min`, with the
/// GPU's margins for f32 rounding (`splat_q_cut` in glsl/common/splat_reach.glsl): 1e-3 on the
/// log, then 2 % and 1e-3 on q. Negative: never above `alpha_min`; infinite in smooth mode
/// (which has no `alpha_min` skip).
pub fn splat_q_cut(opacity: f64, s: &RenderSettings) -> f64 {
    if s.smooth {
        return f64::INFINITY;
    }
    let p = (opacity / s.alpha_min).ln() + 1e-3;
    if p.is_nan() || p < 0.0 {
        -1.0
    } else {
        2.0 * p * 1.02 + 1e-3
    }
}

/// Where, along one horizontal band of pixel centres, an ellipse `q(x − mean) ≤ q_cut` lies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RowSpan {
    /// The band misses the ellipse.
    Empty,
    /// No usable bound (smooth mode, a badly conditioned or non-finite conic): all of it.
    Whole,
    /// The ellipse's x-extent over the band, `[lo, hi]` in pixels, widened by the margin.
    Pixels(f64, f64),
}

/// The x-extent of the ellipse `q(x − mean) ≤ q_cut` over the band `band[0] ≤ y ≤ band[1]`.
/// With `d = x − mean`, `q = a·dx² + 2b·dx·dy + c·dy²` and `det = ac − b²`: the ellipse spans
/// `|dy| ≤ sqrt(a·q_cut / det)`; at a given dy its x-range is
/// `(−b·dy ± sqrt(a·q_cut − det·dy²)) / a`; its leftmost point has `dy = b·sqrt(q_cut / (c·det))`
/// and the rightmost the opposite, and since the left boundary is convex in dy (the right one
/// concave), the band's extremes are at those points clamped into the band. Both the band and
/// the result are widened by `1e-3 + 1e-6·(|mean| + half extents)` pixels, for the f32 rounding
/// of the GPU's copy (glsl/common/tile_rows.glsl) on top of the 2 % of `q_cut`. The same
/// conditioning rule as the rasterizers' ellipse test: `det > 1e-4·ac`, else `Whole`.
pub fn ellipse_row_span(mean: [f64; 2], conic: [f64; 3], q_cut: f64, band: [f64; 2]) -> RowSpan {
    let [a, b, c] = conic;
    if q_cut < 0.0 {
        return RowSpan::Empty;
    }
    let ac = a * c;
    let det = ac - b * b;
    if !(a > 0.0 && c > 0.0 && det > 1e-4 * ac && q_cut.is_finite()) {
        return RowSpan::Whole;
    }
    let hx = (c * q_cut / det).sqrt();
    let hy = (a * q_cut / det).sqrt();
    let m = 1e-3 + 1e-6 * (mean[0].abs() + mean[1].abs() + hx + hy);
    let lo_y = (band[0] - mean[1] - m).max(-hy);
    let hi_y = (band[1] - mean[1] + m).min(hy);
    if lo_y > hi_y {
        return RowSpan::Empty;
    }
    if lo_y.is_nan() || hi_y.is_nan() {
        return RowSpan::Whole;
    }
    let k = b * (q_cut / (c * det)).sqrt();
    let half = |dy: f64| (a * q_cut - det * dy * dy).max(0.0).sqrt();
    let dl = k.clamp(lo_y, hi_y);
    let dr = (-k).clamp(lo_y, hi_y);
    let lo = mean[0] + (-b * dl - half(dl)) / a - m;
    let hi = mean[0] + (-b * dr + half(dr)) / a + m;
    if lo.is_finite() && hi.is_finite() {
        RowSpan::Pixels(lo, hi)
    } else {
        RowSpan::Whole
    }
}

/// The 2D Mip filter's opacity factor `sqrt(max(ρ_min², det0 / det1))` for the undilated
/// covariance `raw` and the dilated determinant `det1`, and whether the floor is active.
pub fn mip_compensation(raw: [f64; 3], det1: f64) -> (f64, bool) {
    let det0 = raw[0] * raw[2] - raw[1] * raw[1];
    let ratio = det0 / det1;
    let floor = super::MIP_MIN_COMPENSATION * super::MIP_MIN_COMPENSATION;
    if ratio.is_nan() || ratio <= floor {
        (super::MIP_MIN_COMPENSATION, true)
    } else {
        (ratio.sqrt(), false)
    }
}

/// Preprocesses every Gaussian for one camera.
pub fn preprocess(
    gaussians: &RefGaussians,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    settings: &RenderSettings,
) -> Result<Vec<Projected>> {
    super::check_inputs(gaussians, camera, sh_degree, settings)?;
    let limits = jacobian_limits(camera, settings);
    let center = pose.center();
    Ok((0..gaussians.len())
        .map(|i| {
            project_one(
                gaussians, i, camera, pose, center, &limits, sh_degree, settings,
            )
        })
        .collect())
}

#[allow(clippy::too_many_arguments)]
fn project_one(
    g: &RefGaussians,
    i: usize,
    camera: &PinholeCamera,
    pose: &Pose,
    camera_center: Vec3,
    limits: &[[f64; 2]; 2],
    sh_degree: usize,
    settings: &RenderSettings,
) -> Projected {
    let t = pose.transform(g.positions[i]);
    let culled = Projected {
        culled: true,
        cam_mean: t,
        depth: t[2],
        ..Projected::default()
    };
    // Step 1: near plane; a NaN depth is culled too.
    if t[2].is_nan() || t[2] <= settings.near {
        return culled;
    }

    // Steps 2–5: 3D covariance, into the camera, EWA projection, dilation.
    let sigma = covariance3d(g.log_scales[i], g.rotations[i]);
    let (j, _) = ewa_jacobian(camera, t, limits);
    let jw = linalg::mul23(&j, &pose.rotation);
    let raw = linalg::project_sym(&jw, &sigma);
    let cov2d = [raw[0] + settings.eps2d, raw[1], raw[2] + settings.eps2d];

    // Step 6: determinant, culling, clamp, inverse.
    let [a, b, c] = cov2d;
    let det_raw = a * c - b * b;
    if det_raw.is_nan() || det_raw <= 0.0 {
        return culled;
    }
    let det = det_raw.max(settings.det_min);
    let conic = [c / det, -b / det, a / det];

    // Step 7: screen radius from the larger eigenvalue.
    let mid = 0.5 * (a + c);
    let lambda_max = mid + (mid * mid - det).max(0.0).sqrt();
    let radius = (3.0 * lambda_max.sqrt()).ceil();

    let mean2d = [
        camera.fx * t[0] / t[2] + camera.cx,
        camera.fy * t[1] / t[2] + camera.cy,
    ];

    // Step 9: colour from SH along the view direction.
    let (dir, _) = view_direction(g.positions[i], camera_center);
    let raw_rgb = sh::eval(sh_degree, &g.sh[i], dir);
    let mut rgb = [0.0; 3];
    let mut rgb_clamped = [false; 3];
    for ch in 0..3 {
        let v = raw_rgb[ch] + 0.5;
        rgb_clamped[ch] = v < 0.0;
        rgb[ch] = v.max(0.0);
    }

    // Step 5 (Mip): the 2D filter's opacity compensation, from the undilated determinant.
    let (compensation, compensation_floored) = if settings.mip_2d {
        mip_compensation(raw, det_raw)
    } else {
        (1.0, false)
    };

    // Step 10: never let a non-finite footprint or colour reach the rasterizer.
    let opacity = sigmoid(g.opacity_logits[i]) * compensation;
    let finite = mean2d
        .iter()
        .chain(&conic)
        .chain(&raw_rgb)
        .all(|v| v.is_finite())
        && radius.is_finite()
        && opacity.is_finite();
    if !finite {
        return culled;
    }

    // Step 8: tile rectangle, clamped to the grid in f64 before converting. Its half-size is
    // the footprint extent (see `footprint_extent`), not always the 3σ radius.
    let extent = footprint_extent(radius, lambda_max, opacity, settings);
    let (tiles_x, tiles_y) = settings.tile_grid(camera.width, camera.height);
    let ts = settings.tile_size as f64;
    let to_tile = |v: f64, n: u32| v.max(0.0).min(n as f64) as u32;
    let (tile_min, tile_max) = if extent > 0.0 {
        (
            [
                to_tile(((mean2d[0] - extent) / ts).floor(), tiles_x),
                to_tile(((mean2d[1] - extent) / ts).floor(), tiles_y),
            ],
            [
                to_tile(((mean2d[0] + extent) / ts).ceil(), tiles_x),
                to_tile(((mean2d[1] + extent) / ts).ceil(), tiles_y),
            ],
        )
    } else {
        ([0, 0], [0, 0])
    };

    Projected {
        culled: false,
        cam_mean: t,
        depth: t[2],
        mean2d,
        cov2d,
        conic,
        radius,
        opacity,
        compensation,
        compensation_floored,
        rgb,
        rgb_clamped,
        tile_min,
        tile_max,
    }
}
