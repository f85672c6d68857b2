//! Surfel preprocess: one surfel in world space → its transform matrix to pixels, camera-facing
//! normal, screen box (low-pass centre, radius, tile rectangle), opacity and colour. The
//! numbered steps are those of the module docs of [`crate::reference::surfel`].

use anyhow::Result;

use super::{check_inputs, RefSurfels, SurfelSettings};
use crate::reference::linalg::{self, Mat3, Vec3};
use crate::reference::project::{rotation_of, sigmoid, view_direction};
use crate::reference::sh;
use crate::scene::{PinholeCamera, Pose};

/// Why a surfel was culled in preprocess.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfelCull {
    /// Step 1: centre camera z ≤ near (or NaN).
    Near,
    /// Step 4: the surfel's plane holds the camera centre exactly (`t·n == 0`).
    EdgeOn,
    /// Step 5: the box denominator `d` is exactly 0.
    DegenerateBox,
    /// Step 7: a non-finite transform, normal, box, colour or opacity.
    NonFinite,
}

/// The per-surfel result of preprocessing, field by field what a GPU preprocess kernel
/// produces. For a culled surfel only `cull`, `cam_mean` and `depth` are meaningful (plus
/// whatever the steps before the cull computed); the tile rectangle is empty.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SurfelProjected {
    /// `Some(reason)` when culled.
    pub cull: Option<SurfelCull>,
    /// Centre in camera space `t = W μ + b`.
    pub cam_mean: Vec3,
    /// `t_z`: the sort key within a tile.
    pub depth: f64,
    /// World rotation `R` (columns r1, r2, r3) from the normalised quaternion.
    pub rotation: Mat3,
    /// `(s_u, s_v) = exp(log_scales)`.
    pub scale: [f64; 2],
    /// `M`, row-major: row k is `h_{k+1}`; `M (u, v, 1)ᵀ = (x·z, y·z, z)`.
    pub transform: Mat3,
    /// Camera-space unit normal, facing the camera (`n·t < 0`).
    pub normal: Vec3,
    /// `+1` or `−1`: `normal = normal_sign · W r3`.
    pub normal_sign: f64,
    /// The box denominator `d = Σ τ_j h₃ⱼ²` (< 0 when the cutoff disk is fully in front).
    pub box_denominator: f64,
    /// Box centre `m` in pixels: the low-pass filter's centre and the tile square's centre.
    pub center2d: [f64; 2],
    /// Box half-extents `e` (after the clamp of the radicand at 1e-4).
    pub extent: [f64; 2],
    /// Per axis: the radicand was below 1e-4 and clamped (no gradient through it).
    pub extent_clamped: [bool; 2],
    /// `ceil(max(e_x, e_y, min_radius))`, px (an integer value, kept as f64).
    pub radius: f64,
    /// sigmoid(opacity logit).
    pub opacity: f64,
    /// Colour after `+0.5` and the clamp at 0.
    pub rgb: [f64; 3],
    /// Per channel: the clamp at 0 was active.
    pub rgb_clamped: [bool; 3],
    /// Tile rectangle `[tile_min, tile_max)` in tile units, clamped to the grid.
    pub tile_min: [u32; 2],
    pub tile_max: [u32; 2],
}

impl SurfelProjected {
    pub fn culled(&self) -> bool {
        self.cull.is_some()
    }

    /// Number of tiles the rectangle covers (0 when culled or off-screen).
    pub fn tiles_touched(&self) -> u64 {
        let w = self.tile_max[0].saturating_sub(self.tile_min[0]) as u64;
        let h = self.tile_max[1].saturating_sub(self.tile_min[1]) as u64;
        w * h
    }

    /// True when tile (tx, ty) lies in the rectangle.
    pub fn touches_tile(&self, tx: u32, ty: u32) -> bool {
        (self.tile_min[0]..self.tile_max[0]).contains(&tx)
            && (self.tile_min[1]..self.tile_max[1]).contains(&ty)
    }

    /// The projection of the centre μ, `(h₁₃, h₂₃)/h₃₃` (not the box centre).
    pub fn projected_center(&self) -> [f64; 2] {
        let m = &self.transform;
        [m[0][2] / m[2][2], m[1][2] / m[2][2]]
    }
}

/// `K v` for a camera-space vector.
fn apply_k(camera: &PinholeCamera, v: Vec3) -> Vec3 {
    [
        camera.fx * v[0] + camera.cx * v[2],
        camera.fy * v[1] + camera.cy * v[2],
        v[2],
    ]
}

/// Step 3: `M = [K W (s_u r1) | K W (s_v r2) | K t]` as rows `h₁, h₂, h₃`, for world rotation
/// `rotation` (columns r1, r2, r3), scales `scale` and camera-space centre `t`.
pub fn transform_matrix(
    camera: &PinholeCamera,
    pose: &Pose,
    rotation: &Mat3,
    scale: [f64; 2],
    t: Vec3,
) -> Mat3 {
    let column = |k: usize| [rotation[0][k], rotation[1][k], rotation[2][k]];
    let cols = [
        apply_k(
            camera,
            linalg::mat_vec(&pose.rotation, linalg::scale(column(0), scale[0])),
        ),
        apply_k(
            camera,
            linalg::mat_vec(&pose.rotation, linalg::scale(column(1), scale[1])),
        ),
        apply_k(camera, t),
    ];
    let mut m = [[0.0; 3]; 3];
    for (k, col) in cols.iter().enumerate() {
        for row in 0..3 {
            m[row][k] = col[row];
        }
    }
    m
}

/// The screen box of step 5.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfelBox {
    /// `d = Σ τ_j h₃ⱼ²`.
    pub denominator: f64,
    /// Centre `m`.
    pub center: [f64; 2],
    /// `sqrt(max(1e-4, radicand))` per axis.
    pub extent: [f64; 2],
    /// Per axis: the radicand was below 1e-4.
    pub clamped: [bool; 2],
}

/// The smallest radicand of the box half-extents (official `compute_aabb`).
pub const EXTENT_RADICAND_MIN: f64 = 1e-4;

/// Step 5: the box around the image of the circle `u² + v² = cutoff²` through the dual conic
/// `M diag(cutoff², cutoff², −1) Mᵀ`; `None` when its denominator is exactly 0.
pub fn bounding_box(m: &Mat3, cutoff: f64) -> Option<SurfelBox> {
    let tau = [cutoff * cutoff, cutoff * cutoff, -1.0];
    let (h1, h2, h3) = (m[0], m[1], m[2]);
    let d: f64 = (0..3).map(|j| tau[j] * h3[j] * h3[j]).sum();
    if d == 0.0 {
        return None;
    }
    let f = tau.map(|t| t / d);
    let center = [
        (0..3).map(|j| f[j] * h1[j] * h3[j]).sum::<f64>(),
        (0..3).map(|j| f[j] * h2[j] * h3[j]).sum::<f64>(),
    ];
    let quad = [
        (0..3).map(|j| f[j] * h1[j] * h1[j]).sum::<f64>(),
        (0..3).map(|j| f[j] * h2[j] * h2[j]).sum::<f64>(),
    ];
    let mut extent = [0.0; 2];
    let mut clamped = [false; 2];
    for k in 0..2 {
        let radicand = center[k] * center[k] - quad[k];
        // A NaN radicand is clamped too; it comes with a non-finite centre, which step 7
        // culls anyway.
        clamped[k] = radicand.is_nan() || radicand < EXTENT_RADICAND_MIN;
        extent[k] = if clamped[k] {
            EXTENT_RADICAND_MIN.sqrt()
        } else {
            radicand.sqrt()
        };
    }
    Some(SurfelBox {
        denominator: d,
        center,
        extent,
        clamped,
    })
}

/// Preprocesses every surfel for one camera.
pub fn preprocess(
    surfels: &RefSurfels,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    settings: &SurfelSettings,
) -> Result<Vec<SurfelProjected>> {
    check_inputs(surfels, camera, sh_degree, settings)?;
    Ok((0..surfels.len())
        .map(|i| project_surfel(surfels, i, camera, pose, sh_degree, settings))
        .collect())
}

/// Preprocesses surfel `i` (steps 1–8). The arguments are assumed checked (see
/// [`preprocess`]).
pub fn project_surfel(
    s: &RefSurfels,
    i: usize,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
    settings: &SurfelSettings,
) -> SurfelProjected {
    // Step 1: near cull on the centre; a NaN depth is culled too.
    let t = pose.transform(s.positions[i]);
    let mut out = SurfelProjected {
        cam_mean: t,
        depth: t[2],
        ..SurfelProjected::default()
    };
    if t[2].is_nan() || t[2] <= settings.near {
        out.cull = Some(SurfelCull::Near);
        return out;
    }

    // Steps 2–3: rotation, scales, transform matrix.
    let rotation = rotation_of(s.rotations[i]);
    let scale = s.log_scales[i].map(f64::exp);
    let transform = transform_matrix(camera, pose, &rotation, scale, t);
    out.rotation = rotation;
    out.scale = scale;
    out.transform = transform;

    // Step 4: normal facing the camera. `cos == 0` exactly is the only cull (official); a NaN
    // cos fails the finiteness test below.
    let r3 = [rotation[0][2], rotation[1][2], rotation[2][2]];
    let n = linalg::mat_vec(&pose.rotation, r3);
    let cos = -linalg::dot(t, n);
    if cos == 0.0 {
        out.cull = Some(SurfelCull::EdgeOn);
        return out;
    }
    out.normal_sign = if cos > 0.0 { 1.0 } else { -1.0 };
    out.normal = linalg::scale(n, out.normal_sign);

    // Step 5: screen box, radius.
    let Some(bbox) = bounding_box(&transform, settings.cutoff) else {
        out.cull = Some(SurfelCull::DegenerateBox);
        return out;
    };
    out.box_denominator = bbox.denominator;
    out.center2d = bbox.center;
    out.extent = bbox.extent;
    out.extent_clamped = bbox.clamped;
    out.radius = bbox.extent[0]
        .max(bbox.extent[1])
        .max(settings.min_radius())
        .ceil();

    // Step 6: colour.
    let (dir, _) = view_direction(s.positions[i], pose.center());
    let raw_rgb = sh::eval(sh_degree, &s.sh[i], dir);
    for (ch, raw) in raw_rgb.iter().enumerate() {
        let v = raw + 0.5;
        out.rgb_clamped[ch] = v < 0.0;
        out.rgb[ch] = v.max(0.0);
    }
    out.opacity = sigmoid(s.opacity_logits[i]);

    // Step 7: nothing non-finite reaches the rasterizer. The box denominator is checked too:
    // for astronomically large scales `d` overflows to inf, `f = τ/d` to 0 and the box
    // collapses, finite but meaningless, onto pixel (0, 0).
    let finite = transform
        .iter()
        .flatten()
        .chain(&[bbox.denominator])
        .chain(&out.normal)
        .chain(&out.center2d)
        .chain(&out.extent)
        .chain(&raw_rgb)
        .all(|v| v.is_finite())
        && out.radius.is_finite()
        && out.opacity.is_finite();
    if !finite {
        out.cull = Some(SurfelCull::NonFinite);
        return out;
    }

    // Step 8: tile rectangle, clamped to the grid in f64 before converting.
    let (tiles_x, tiles_y) = settings.tile_grid(camera.width, camera.height);
    let ts = settings.tile_size as f64;
    let to_tile = |v: f64, n: u32| v.max(0.0).min(n as f64) as u32;
    let (m, r) = (out.center2d, out.radius);
    out.tile_min = [
        to_tile(((m[0] - r) / ts).floor(), tiles_x),
        to_tile(((m[1] - r) / ts).floor(), tiles_y),
    ];
    out.tile_max = [
        to_tile(((m[0] + r) / ts).ceil(), tiles_x),
        to_tile(((m[1] + r) / ts).ceil(), tiles_y),
    ];
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera {
            fx: 50.0,
            fy: 55.0,
            cx: 21.0,
            cy: 14.5,
            width: 40,
            height: 30,
        }
    }

    fn one(pos: Vec3, log_scale: [f64; 2], q: [f64; 4]) -> RefSurfels {
        let mut s = RefSurfels::default();
        s.push(pos, log_scale, q, 0.0, [0.3, 0.2, 0.1]);
        s
    }

    #[test]
    fn transform_maps_disk_points_to_their_projections() {
        let cam = camera();
        let pose = crate::reference::scenes::look_at([0.4, -0.3, -3.0], [0.0; 3], [0.0, 1.0, 0.1]);
        let s = one([0.1, 0.2, -0.3], [-1.5, -0.7], [0.9, 0.2, -0.3, 0.4]);
        let p = project_surfel(&s, 0, &cam, &pose, 0, &SurfelSettings::default());
        assert!(p.cull.is_none());
        let r = p.rotation;
        for (u, v) in [(0.0, 0.0), (1.0, 0.0), (0.3, -2.0), (-1.7, 0.9)] {
            let world: Vec3 = [0, 1, 2]
                .map(|k| s.positions[0][k] + p.scale[0] * u * r[k][0] + p.scale[1] * v * r[k][1]);
            let c = pose.transform(world);
            let h = linalg::mat_vec(&p.transform, [u, v, 1.0]);
            let expect = [
                cam.fx * c[0] / c[2] + cam.cx,
                cam.fy * c[1] / c[2] + cam.cy,
                c[2],
            ];
            let got = [h[0] / h[2], h[1] / h[2], h[2]];
            for k in 0..3 {
                assert!((got[k] - expect[k]).abs() < 1e-12, "{got:?} vs {expect:?}");
            }
        }
        assert!(linalg::dot(p.normal, p.cam_mean) < 0.0);
    }

    #[test]
    fn culls_behind_near_edge_on_and_non_finite() {
        let cam = camera();
        let st = SurfelSettings::default();
        let pose = Pose::IDENTITY;
        // At the near plane itself: culled (z ≤ near).
        let behind = one([0.0, 0.0, st.near], [-1.0, -1.0], [1.0, 0.0, 0.0, 0.0]);
        let p = project_surfel(&behind, 0, &cam, &pose, 0, &st);
        assert_eq!(p.cull, Some(SurfelCull::Near));
        // Exactly edge-on: a camera at the origin looking along world +x (a permutation
        // matrix, so no rounding) and an unrotated surfel, i.e. the world plane z = 0, which
        // holds the camera centre.
        let pose_side = Pose {
            rotation: [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
            translation: [0.0; 3],
        };
        let edge = one([2.0, 0.3, 0.0], [-1.0, -1.0], [1.0, 0.0, 0.0, 0.0]);
        let p = project_surfel(&edge, 0, &cam, &pose_side, 0, &st);
        assert_eq!(p.cull, Some(SurfelCull::EdgeOn));
        let huge = one([0.0, 0.0, 2.0], [800.0, 0.0], [1.0, 0.0, 0.0, 0.0]);
        let p = project_surfel(&huge, 0, &cam, &pose, 0, &st);
        assert_eq!(p.cull, Some(SurfelCull::NonFinite));
    }

    #[test]
    fn fronto_parallel_box_is_the_projected_ellipse_box() {
        // Facing the camera: the image is the ellipse of the affine map diag(f)/z, so the box
        // centre is the projected centre and the half-extents are 3σ along each axis.
        let cam = camera();
        let (c, sn) = (0.3f64.cos(), 0.3f64.sin());
        // Rotation by 0.6 rad about z: q = (cos 0.3, 0, 0, sin 0.3).
        let s = one([0.2, -0.1, 2.5], [-2.0, -1.2], [c, 0.0, 0.0, sn]);
        let p = project_surfel(&s, 0, &cam, &Pose::IDENTITY, 0, &SurfelSettings::default());
        let z = 2.5;
        let proj = [cam.fx * 0.2 / z + cam.cx, cam.fy * -0.1 / z + cam.cy];
        let (su, sv) = ((-2.0f64).exp(), (-1.2f64).exp());
        let (c2, s2) = (0.6f64.cos(), 0.6f64.sin());
        let ex = 3.0 * cam.fx / z * ((su * c2).powi(2) + (sv * s2).powi(2)).sqrt();
        let ey = 3.0 * cam.fy / z * ((su * s2).powi(2) + (sv * c2).powi(2)).sqrt();
        for (k, want) in proj.iter().enumerate() {
            assert!((p.center2d[k] - want).abs() < 1e-12);
            assert!((p.projected_center()[k] - want).abs() < 1e-12);
        }
        assert!((p.extent[0] - ex).abs() < 1e-12, "{} vs {ex}", p.extent[0]);
        assert!((p.extent[1] - ey).abs() < 1e-12, "{} vs {ey}", p.extent[1]);
        assert_eq!(p.radius, ex.max(ey).ceil());
        assert_eq!(p.normal, [0.0, 0.0, -1.0]);
        assert_eq!(p.normal_sign, -1.0);
    }
}
