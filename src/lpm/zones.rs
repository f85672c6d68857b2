//! Cones and error zones (docs/algorithms/lpm.md step 6).
//!
//! A *cone* is the set of points seen by a camera inside a circle on its image plane: apex at the
//! camera centre, through the circumscribed circle of the region's pixel box. In pixels, a point
//! with camera coordinates (x, y, z) is inside the cone of circle (cu, cv, ρ) iff z > 0 and
//! `(fx x + (cx − cu) z)² + (fy y + (cy − cv) z)² ≤ ρ² z²` — a quadric cone, exact also for
//! fx ≠ fy and for off-centre regions (where the 3D cone is oblique, not circular).
//!
//! Five geometries:
//!
//! * [`ZoneGeometry::Triangulated`] (default, ours): the zone is bounded by the surface the
//!   region explains. Every matched keypoint pair inside the region pair is triangulated (the
//!   midpoint of the two rays' common perpendicular, kept when both ray parameters are positive,
//!   the rays are not near-parallel and the point is finite); points far from the rest (more
//!   than `outlier_factor` times the median distance to the coordinate-wise median: a mismatch
//!   along the epipolar line lands at a wrong depth) are dropped; the zone is their minimum
//!   enclosing sphere, grown by `margin` of its radius and to at least `min_radius_px` pixels
//!   seen from V at its centre's depth. The cone geometries below bound where the surface *may*
//!   be: with a small baseline their intersection is a long lens along the viewing direction
//!   whose enclosing sphere covers much of the scene (measured: one region on lund_door at
//!   162×242 lowered the threshold of 6,285 Gaussians with `Sphere`, 5 with `AuthorsBox`). The
//!   matches say where the surface *is*, so this zone stays as local as the region.
//! * [`ZoneGeometry::Slab`] (ours, 2026-11-27): V's cone through the region's circumcircle, cut
//!   to the band of distances from V's centre that the same kept triangulated points span (grown
//!   by `margin`, at least `min_radius_px` pixels of V deep). The sphere above must be as wide as
//!   the points are deep: a region of the far background whose matches spread from 16 to 30
//!   units away (Truck at `-r 4`, scene extent 5.3) gave a sphere of radius 8, holding Gaussians
//!   far outside the region's pixels, and at full size such zones made 84 % of LPM's resets.
//!   The slab holds only what is drawn over the region, at the depths the matches found; "in
//!   front" is the same cone nearer than the band.
//! * [`ZoneGeometry::Local`] (ours, 2026-12-02): a slab made local by construction. Only
//!   matches whose two rays meet at `min_parallax_deg` or more are triangulated (below that a
//!   pixel of error moves the point along the ray by more than the zone is deep), and the band
//!   is the `band_quantiles` of their distances from V's centre, each end moved out by
//!   `band_margin` of its distance, instead of their whole span: one mismatch no longer
//!   stretches the zone to the far background. Used with one zone per error block
//!   ([`crate::lpm::region_units::RegionUnit::Blocks`]) and a cap on the share of the model a
//!   zone may hold (`LpmConfig::max_zone_share`), as `LpmConfig::with_local_zones` sets them.
//! * [`ZoneGeometry::Sphere`] (the paper read literally): the zone is the minimum enclosing sphere of
//!   the intersection of the two cones. The intersection is convex and its extreme points lie on
//!   both cone surfaces, so we sample `circle_rays` rays on each cone's surface (plus its axis
//!   ray), clip every ray of one cone exactly against the other cone (a quadratic in the ray
//!   parameter t, restricted to t > 0 and to the forward nappe) and keep the entry and exit
//!   points. Those points lie exactly on the intersection's boundary, so their enclosing sphere
//!   converges to the true one from inside as `circle_rays` grows (32 rays: within about 1 %).
//!   A ray that stays inside the other cone to infinity (the cones do not close: rays nearly
//!   parallel) contributes only its finite entry point; such rays are counted in
//!   [`ZoneOutcome::unbounded_rays`]. Non-finite points are dropped.
//! * [`ZoneGeometry::SphereRayPairs`]: the literal reading "intersect the rays of the two cones":
//!   every sampled ray of V against every sampled ray of V', the midpoint of their common
//!   perpendicular, kept when both ray parameters are > 0, the rays are not near-parallel and the
//!   point is finite; zone = minimum enclosing sphere. Skew ray pairs far from the intersection
//!   also give points, so this sphere is larger than the exact one.
//! * [`ZoneGeometry::AuthorsBox`]: the authors' code: rays through the perimeter pixels of both
//!   boxes, the k-th ray of V paired with the k-th of V' (as Python's `zip`, up to the shorter
//!   perimeter), both closest points of each pair kept, negative t allowed; zone = axis-aligned
//!   box. The one change: non-finite points (exactly parallel rays) are dropped, as one NaN would
//!   poison the box.

use super::enclosing_sphere::{minimum_enclosing_sphere, Sphere};
use super::epipolar::rotation;
use super::pairing::{PixelBox, RegionPair};
use crate::scene::{PinholeCamera, Pose};
use glam::DVec3;

/// Which zone geometry to compute (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum ZoneGeometry {
    #[default]
    Triangulated,
    Slab,
    Local,
    Sphere,
    SphereRayPairs,
    AuthorsBox,
}

/// Settings of step 6.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZoneSettings {
    pub geometry: ZoneGeometry,
    /// Rays sampled on each circumscribed circle (the axis ray is added).
    pub circle_rays: usize,
    /// Ray pairs closer to parallel than this angle (degrees) are skipped (`SphereRayPairs`,
    /// `Triangulated`).
    pub min_ray_angle_deg: f64,
    /// `Triangulated`: the sphere's radius grows by this fraction (the keypoints sample the
    /// region's surface; the Gaussians explaining it sit around them).
    pub margin: f64,
    /// `Triangulated`: the smallest radius, in pixels of V at the zone centre's depth (two
    /// matches at almost the same place would give a zone no Gaussian fits in).
    pub min_radius_px: f64,
    /// `Triangulated`: a point farther from the points' coordinate-wise median than this many
    /// times their median distance to it is dropped as a mismatch.
    pub outlier_factor: f64,
    /// `Local`: matches whose rays meet at a smaller angle (degrees) are not triangulated.
    pub min_parallax_deg: f64,
    /// `Local`: the band of distances from V's centre runs from this lower to this upper
    /// quantile of the kept points' distances ...
    pub band_quantiles: (f64, f64),
    /// ... each end moved outwards by this fraction of its own distance.
    pub band_margin: f64,
}

impl Default for ZoneSettings {
    fn default() -> Self {
        Self {
            geometry: ZoneGeometry::Triangulated,
            circle_rays: 32,
            min_ray_angle_deg: 0.5,
            margin: 0.1,
            min_radius_px: 4.0,
            outlier_factor: 3.0,
            min_parallax_deg: 2.0,
            band_quantiles: (0.2, 0.8),
            band_margin: 0.05,
        }
    }
}

/// An error zone in world units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Zone {
    Sphere(Sphere),
    Box {
        min: [f64; 3],
        max: [f64; 3],
    },
    /// [`ZoneGeometry::Slab`]: the points x with angle(x − apex, center − apex) ≤
    /// atan(`tan_half_angle`) and | |x − apex| − |center − apex| | ≤ `half_depth`.
    Slab {
        apex: [f64; 3],
        center: [f64; 3],
        tan_half_angle: f64,
        half_depth: f64,
    },
}

impl Zone {
    /// The zone's enclosing sphere (the box's circumscribed sphere for a box).
    pub fn bounding_sphere(&self) -> Sphere {
        match *self {
            Zone::Sphere(s) => s,
            Zone::Box { min, max } => {
                let (a, b) = (DVec3::from(min), DVec3::from(max));
                Sphere {
                    center: ((a + b) * 0.5).to_array(),
                    radius: 0.5 * a.distance(b),
                }
            }
            Zone::Slab {
                apex,
                center,
                tan_half_angle,
                half_depth,
            } => {
                // The farthest slab point from the centre lies on the cone's surface (angle θ)
                // at the nearest or the farthest distance s from the apex: |x − c|² =
                // s² − 2ds·cos θ + d², convex in s.
                let d = DVec3::from(center).distance(DVec3::from(apex));
                let cos = 1.0 / (1.0 + tan_half_angle * tan_half_angle).sqrt();
                let at = |s: f64| (s * s - 2.0 * d * s * cos + d * d).max(0.0);
                let r2 = at((d - half_depth).max(0.0)).max(at(d + half_depth));
                Sphere {
                    center,
                    radius: r2.sqrt(),
                }
            }
        }
    }
    pub fn contains(&self, p: [f64; 3], tol: f64) -> bool {
        match *self {
            Zone::Sphere(s) => s.contains(p, tol),
            Zone::Box { min, max } => (0..3).all(|i| p[i] >= min[i] - tol && p[i] <= max[i] + tol),
            Zone::Slab {
                apex,
                center,
                tan_half_angle,
                half_depth,
            } => {
                let (o, a) = (DVec3::from(apex), DVec3::from(center) - DVec3::from(apex));
                let v = DVec3::from(p) - o;
                let (d, s) = (a.length(), v.length());
                if s <= tol {
                    return d <= half_depth + tol;
                }
                // Distance from the cone's surface, by the angle, and from the band's faces.
                let beyond = (v.angle_between(a) - tan_half_angle.atan()).max(0.0);
                let off_cone = if beyond >= std::f64::consts::FRAC_PI_2 {
                    s
                } else {
                    s * beyond.sin()
                };
                off_cone <= tol && (s - d).abs() <= half_depth + tol
            }
        }
    }
}

/// The result of one zone computation.
#[derive(Debug, Clone, PartialEq)]
pub struct ZoneOutcome {
    /// `None` when no intersection point survived.
    pub zone: Option<Zone>,
    /// Points the zone was built from.
    pub points: usize,
    /// Candidate points rejected (t ≤ 0, near-parallel, non-finite).
    pub rejected: usize,
    /// `Sphere` only: rays that stayed inside the other cone to infinity.
    pub unbounded_rays: usize,
}

impl ZoneOutcome {
    /// No zone, `rejected` candidate points.
    fn none(rejected: usize) -> ZoneOutcome {
        ZoneOutcome {
            zone: None,
            points: 0,
            rejected,
            unbounded_rays: 0,
        }
    }
}

/// A camera with its pose, as the zone code sees it.
#[derive(Debug, Clone, Copy)]
pub struct CameraView<'a> {
    pub camera: &'a PinholeCamera,
    pub pose: &'a Pose,
}

impl CameraView<'_> {
    fn center(&self) -> DVec3 {
        DVec3::from(self.pose.center())
    }
    /// World direction of the ray through pixel (u, v) (not normalised; camera z component 1).
    fn ray(&self, u: f64, v: f64) -> DVec3 {
        let c = self.camera;
        let d = DVec3::new((u - c.cx) / c.fx, (v - c.cy) / c.fy, 1.0);
        rotation(self.pose).transpose() * d
    }
}

/// The tangent of the largest angle between the ray through the centre of `b` and the rays
/// through its circumcircle (16 points on it), in `camera`: the half-angle of the view's cone
/// through the region.
pub fn region_tan_half_angle(camera: &PinholeCamera, b: &PixelBox) -> f64 {
    let ray = |[u, v]: [f64; 2]| {
        DVec3::new(
            (u - camera.cx) / camera.fx,
            (v - camera.cy) / camera.fy,
            1.0,
        )
    };
    let samples = circle_samples(b, 16);
    let d0 = ray(samples[0]);
    let largest = samples[1..]
        .iter()
        .map(|&p| d0.angle_between(ray(p)))
        .fold(0.0f64, f64::max);
    largest.tan()
}

/// Pixel positions: the circle's centre, then `n` points on the circle.
pub(crate) fn circle_samples(b: &PixelBox, n: usize) -> Vec<[f64; 2]> {
    let [cu, cv] = b.center();
    let r = b.circumradius();
    let mut out = vec![[cu, cv]];
    out.extend((0..n).map(|k| {
        let a = std::f64::consts::TAU * k as f64 / n as f64;
        [cu + r * a.cos(), cv + r * a.sin()]
    }));
    out
}

/// The zone of one region pair: `pair.matched` indexes the matches `xy_view[i]` (in `v`) ↔
/// `xy_ref[i]` (in `r`) inside it. Every geometry goes through here; only `Triangulated` reads
/// the matches, the others the pair's boxes.
pub fn zone_for_pair(
    v: CameraView,
    r: CameraView,
    pair: &RegionPair,
    xy_view: &[[f32; 2]],
    xy_ref: &[[f32; 2]],
    s: &ZoneSettings,
) -> ZoneOutcome {
    if !matches!(
        s.geometry,
        ZoneGeometry::Triangulated | ZoneGeometry::Slab | ZoneGeometry::Local
    ) {
        return zone_from_boxes(v, &pair.in_view, r, &pair.in_reference, s);
    }
    let pts: Vec<([f64; 2], [f64; 2])> = pair
        .matched
        .iter()
        .filter_map(|&i| {
            let (a, b) = (xy_view.get(i as usize)?, xy_ref.get(i as usize)?);
            Some(([a[0] as f64, a[1] as f64], [b[0] as f64, b[1] as f64]))
        })
        .collect();
    match s.geometry {
        ZoneGeometry::Slab => slab_zone(v, r, &pair.in_view, &pts, s),
        ZoneGeometry::Local => local_zone(v, r, &pair.in_view, &pts, s),
        _ => triangulated_zone(v, r, &pts, s),
    }
}

/// The zone of one region pair from its boxes alone: `box_v` (R_e) in view `v`, `box_r` (R_e')
/// in view `r`. `Triangulated` and `Slab` need the matches themselves ([`zone_for_pair`]);
/// given boxes only they find no zone.
pub fn zone_from_boxes(
    v: CameraView,
    box_v: &PixelBox,
    r: CameraView,
    box_r: &PixelBox,
    s: &ZoneSettings,
) -> ZoneOutcome {
    match s.geometry {
        ZoneGeometry::Triangulated | ZoneGeometry::Slab | ZoneGeometry::Local => {
            ZoneOutcome::none(0)
        }
        ZoneGeometry::Sphere => cone_clip_zone(v, box_v, r, box_r, s),
        ZoneGeometry::SphereRayPairs => ray_pair_zone(v, box_v, r, box_r, s),
        ZoneGeometry::AuthorsBox => authors_box_zone(v, box_v, r, box_r),
    }
}

/// The parameter intervals (t > 0) where `origin + t dir` lies inside the cone of `cam` through
/// the circle (cu, cv, rho). The last interval may end at +∞.
fn clip_ray_to_cone(
    origin: DVec3,
    dir: DVec3,
    cam: CameraView,
    circle: ([f64; 2], f64),
) -> Vec<(f64, f64)> {
    let rot = rotation(cam.pose);
    let y0 = rot * origin + DVec3::from(cam.pose.translation);
    let y1 = rot * dir;
    let c = cam.camera;
    let ([cu, cv], rho) = circle;
    // a(t), b(t), c(t) are linear in t; inside ⇔ a² + b² ≤ c² and z > 0.
    let lin = |p: DVec3| {
        (
            c.fx * p.x + (c.cx - cu) * p.z,
            c.fy * p.y + (c.cy - cv) * p.z,
            rho * p.z,
        )
    };
    let (a0, b0, c0) = lin(y0);
    let (a1, b1, c1) = lin(y1);
    let qa = a1 * a1 + b1 * b1 - c1 * c1;
    let qb = 2.0 * (a0 * a1 + b0 * b1 - c0 * c1);
    let qc = a0 * a0 + b0 * b0 - c0 * c0;
    let g = |t: f64| {
        let (a, b, cc) = (a0 + a1 * t, b0 + b1 * t, c0 + c1 * t);
        a * a + b * b - cc * cc
    };
    let inside = |t: f64| t > 0.0 && y0.z + y1.z * t > 0.0 && g(t) <= 0.0;

    let mut breaks = vec![0.0];
    let scale = qa.abs().max(qb.abs()).max(qc.abs());
    if qa.abs() > 1e-14 * scale {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            // Numerically stable roots.
            let q = -0.5 * (qb + qb.signum() * disc.sqrt());
            if q != 0.0 {
                breaks.push(q / qa);
                breaks.push(qc / q);
            } else {
                breaks.push(0.0);
            }
        }
    } else if qb != 0.0 {
        breaks.push(-qc / qb);
    }
    if y1.z != 0.0 {
        breaks.push(-y0.z / y1.z);
    }
    breaks.retain(|t| t.is_finite() && *t >= 0.0);
    breaks.sort_by(|a, b| a.total_cmp(b));
    breaks.dedup();

    let mut out: Vec<(f64, f64)> = Vec::new();
    for (i, &t0) in breaks.iter().enumerate() {
        let (t1, probe) = match breaks.get(i + 1) {
            Some(&t1) => (t1, 0.5 * (t0 + t1)),
            None => (f64::INFINITY, t0 + t0.abs().max(1.0)),
        };
        if inside(probe) {
            match out.last_mut() {
                Some(last) if last.1 == t0 => last.1 = t1,
                _ => out.push((t0, t1)),
            }
        }
    }
    out
}

fn cone_clip_zone(
    v: CameraView,
    box_v: &PixelBox,
    r: CameraView,
    box_r: &PixelBox,
    s: &ZoneSettings,
) -> ZoneOutcome {
    let n = s.circle_rays.max(3);
    let mut points = Vec::new();
    let (mut rejected, mut unbounded) = (0, 0);
    for (from, bfrom, to, bto) in [(v, box_v, r, box_r), (r, box_r, v, box_v)] {
        let o = from.center();
        let circle = (bto.center(), bto.circumradius());
        for [u, w] in circle_samples(bfrom, n) {
            let d = from.ray(u, w);
            for (t0, t1) in clip_ray_to_cone(o, d, to, circle) {
                for t in [t0, t1] {
                    if t.is_infinite() {
                        unbounded += 1;
                        continue;
                    }
                    let p = o + t * d;
                    if t > 0.0 && p.is_finite() {
                        points.push(p.to_array());
                    } else {
                        // t = 0 is the ray's own apex: the cone starts inside the other cone only
                        // when the apexes coincide, which is no intersection point.
                        rejected += 1;
                    }
                }
            }
        }
    }
    let zone = minimum_enclosing_sphere(&points).map(Zone::Sphere);
    ZoneOutcome {
        zone,
        points: points.len(),
        rejected,
        unbounded_rays: unbounded,
    }
}

/// Closest points of two rays: `(t, s)` with `o1 + t d1` nearest to `o2 + s d2`; `None` when the
/// rays are closer to parallel than `sin_min`.
fn closest_params(o1: DVec3, d1: DVec3, o2: DVec3, d2: DVec3, sin_min: f64) -> Option<(f64, f64)> {
    let w = o1 - o2;
    let (a, b, c) = (d1.dot(d1), d1.dot(d2), d2.dot(d2));
    let (d, e) = (d1.dot(w), d2.dot(w));
    let den = a * c - b * b;
    if den.is_nan() || den <= sin_min * sin_min * a * c {
        return None;
    }
    Some(((b * e - c * d) / den, (a * e - b * d) / den))
}

fn ray_pair_zone(
    v: CameraView,
    box_v: &PixelBox,
    r: CameraView,
    box_r: &PixelBox,
    s: &ZoneSettings,
) -> ZoneOutcome {
    let n = s.circle_rays.max(3);
    let sin_min = s.min_ray_angle_deg.to_radians().sin();
    let (ov, or) = (v.center(), r.center());
    let rays_v: Vec<DVec3> = circle_samples(box_v, n)
        .into_iter()
        .map(|[a, b]| v.ray(a, b))
        .collect();
    let rays_r: Vec<DVec3> = circle_samples(box_r, n)
        .into_iter()
        .map(|[a, b]| r.ray(a, b))
        .collect();
    let mut points = Vec::new();
    let mut rejected = 0;
    for dv in &rays_v {
        for dr in &rays_r {
            let Some((t, u)) = closest_params(ov, *dv, or, *dr, sin_min) else {
                rejected += 1;
                continue;
            };
            let p = 0.5 * ((ov + t * *dv) + (or + u * *dr));
            if t > 0.0 && u > 0.0 && p.is_finite() {
                points.push(p.to_array());
            } else {
                rejected += 1;
            }
        }
    }
    let zone = minimum_enclosing_sphere(&points).map(Zone::Sphere);
    ZoneOutcome {
        zone,
        points: points.len(),
        rejected,
        unbounded_rays: 0,
    }
}

/// Pixel centres along a box's border, clockwise from the top-left, one per pixel step.
fn perimeter_samples(b: &PixelBox) -> Vec<[f64; 2]> {
    let nx = ((b.x1 - b.x0).ceil() as usize).max(1);
    let ny = ((b.y1 - b.y0).ceil() as usize).max(1);
    let mut out = Vec::with_capacity(2 * (nx + ny));
    let lerp = |a: f64, b: f64, k: usize, n: usize| a + (b - a) * k as f64 / n as f64;
    out.extend((0..nx).map(|k| [lerp(b.x0, b.x1, k, nx), b.y0]));
    out.extend((0..ny).map(|k| [b.x1, lerp(b.y0, b.y1, k, ny)]));
    out.extend((0..nx).map(|k| [lerp(b.x1, b.x0, k, nx), b.y1]));
    out.extend((0..ny).map(|k| [b.x0, lerp(b.y1, b.y0, k, ny)]));
    out
}

fn authors_box_zone(
    v: CameraView,
    box_v: &PixelBox,
    r: CameraView,
    box_r: &PixelBox,
) -> ZoneOutcome {
    let (ov, or) = (v.center(), r.center());
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    let (mut points, mut rejected) = (0, 0);
    for (pv, pr) in perimeter_samples(box_v)
        .into_iter()
        .zip(perimeter_samples(box_r))
    {
        let (dv, dr) = (v.ray(pv[0], pv[1]), r.ray(pr[0], pr[1]));
        let Some((t, u)) = closest_params(ov, dv, or, dr, 0.0) else {
            rejected += 2;
            continue;
        };
        for p in [ov + t * dv, or + u * dr] {
            if p.is_finite() {
                lo = lo.min(p);
                hi = hi.max(p);
                points += 1;
            } else {
                rejected += 1;
            }
        }
    }
    let zone = (points > 0).then(|| Zone::Box {
        min: lo.to_array(),
        max: hi.to_array(),
    });
    ZoneOutcome {
        zone,
        points,
        rejected,
        unbounded_rays: 0,
    }
}

/// The triangulated matches of a region pair with the mismatches dropped (shared by
/// [`ZoneGeometry::Triangulated`] and [`ZoneGeometry::Slab`]): each pair's midpoint of the two
/// rays' common perpendicular, kept when both ray parameters are positive, the rays are not
/// near-parallel and the point is finite; then the points farther from the coordinate-wise
/// median than `outlier_factor` times the median distance to it are dropped. Returns the points
/// and the number rejected.
fn triangulated_points(
    v: CameraView,
    r: CameraView,
    matches: &[([f64; 2], [f64; 2])],
    s: &ZoneSettings,
) -> (Vec<DVec3>, usize) {
    let sin_min = s.min_ray_angle_deg.to_radians().sin();
    let (ov, or) = (v.center(), r.center());
    let mut points: Vec<DVec3> = Vec::with_capacity(matches.len());
    let mut rejected = 0;
    for (pv, pr) in matches {
        let (dv, dr) = (v.ray(pv[0], pv[1]), r.ray(pr[0], pr[1]));
        match closest_params(ov, dv, or, dr, sin_min) {
            Some((t, u)) if t > 0.0 && u > 0.0 => {
                let p = 0.5 * ((ov + t * dv) + (or + u * dr));
                if p.is_finite() {
                    points.push(p);
                } else {
                    rejected += 1;
                }
            }
            _ => rejected += 1,
        }
    }
    if points.is_empty() {
        return (points, rejected);
    }
    // Robust centre: the coordinate-wise median; drop points much farther than the typical one.
    let median = |mut xs: Vec<f64>| {
        xs.sort_by(|a, b| a.total_cmp(b));
        xs[xs.len() / 2]
    };
    let m = DVec3::new(
        median(points.iter().map(|p| p.x).collect()),
        median(points.iter().map(|p| p.y).collect()),
        median(points.iter().map(|p| p.z).collect()),
    );
    let typical = median(points.iter().map(|p| p.distance(m)).collect());
    if typical > 0.0 {
        let before = points.len();
        points.retain(|p| p.distance(m) <= s.outlier_factor * typical);
        rejected += before - points.len();
    }
    (points, rejected)
}

/// `min_radius_px` pixels of `v` at the depth of `p` (z in V's camera frame; 0 behind it).
fn radius_floor(v: CameraView, p: DVec3, s: &ZoneSettings) -> f64 {
    let depth = (rotation(v.pose) * p + DVec3::from(v.pose.translation)).z;
    let focal = v.camera.fx.max(v.camera.fy);
    if depth > 0.0 && focal > 0.0 {
        s.min_radius_px * depth / focal
    } else {
        0.0
    }
}

/// [`ZoneGeometry::Slab`] from the region's box in V (`region`) and the matched pixel pairs
/// (`(in v, in r)`): V's cone through the region's circumcircle, cut to the band of distances
/// from V's centre that the kept triangulated points span, each side grown by `margin` of the
/// band's half-width and the half-width floored at `min_radius_px` pixels of V at the band's
/// middle. The zone's centre is on the ray through the box's centre, at the band's middle.
pub fn slab_zone(
    v: CameraView,
    r: CameraView,
    region: &PixelBox,
    matches: &[([f64; 2], [f64; 2])],
    s: &ZoneSettings,
) -> ZoneOutcome {
    let (points, rejected) = triangulated_points(v, r, matches, s);
    let o = v.center();
    let [cu, cv] = region.center();
    let axis = v.ray(cu, cv).normalize();
    let dist: Vec<f64> = points.iter().map(|p| p.distance(o)).collect();
    let (near, far) = dist.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &d| {
        (lo.min(d), hi.max(d))
    });
    if points.is_empty() || !(far > 0.0 && far.is_finite() && axis.is_finite()) {
        return ZoneOutcome::none(rejected);
    }
    band_slab(
        v,
        region,
        axis,
        (near, far),
        1.0 + s.margin,
        s,
        points.len(),
        rejected,
    )
}

/// The slab of V's cone through `region` (axis `axis`, unit) cut to the distances `near..far`
/// from V's centre, its half-depth `grow` times the band's and at least `min_radius_px` pixels
/// of V at the band's middle.
#[allow(clippy::too_many_arguments)] // the band and the outcome's two counts, each used once
fn band_slab(
    v: CameraView,
    region: &PixelBox,
    axis: DVec3,
    (near, far): (f64, f64),
    grow: f64,
    s: &ZoneSettings,
    points: usize,
    rejected: usize,
) -> ZoneOutcome {
    let o = v.center();
    let middle = 0.5 * (near + far);
    let center = o + middle * axis;
    // The band stops short of the apex: what lies between the camera and the band is what is in
    // front of the zone, and a band reaching the camera would leave nothing there.
    let half_depth = (0.5 * (far - near) * grow)
        .max(radius_floor(v, center, s))
        .min(middle * (1.0 - 1e-6));
    let tan_half_angle = region_tan_half_angle(v.camera, region);
    if !(half_depth > 0.0 && half_depth.is_finite() && tan_half_angle.is_finite()) {
        return ZoneOutcome::none(rejected);
    }
    ZoneOutcome {
        zone: Some(Zone::Slab {
            apex: o.to_array(),
            center: center.to_array(),
            tan_half_angle,
            half_depth,
        }),
        points,
        rejected,
        unbounded_rays: 0,
    }
}

/// [`ZoneGeometry::Local`]: as [`slab_zone`], from the matches whose rays meet at
/// `min_parallax_deg` or more, the band from the `band_quantiles` of their distances from V's
/// centre, each end moved out by `band_margin` of its distance.
pub fn local_zone(
    v: CameraView,
    r: CameraView,
    region: &PixelBox,
    matches: &[([f64; 2], [f64; 2])],
    s: &ZoneSettings,
) -> ZoneOutcome {
    let strict = ZoneSettings {
        min_ray_angle_deg: s.min_ray_angle_deg.max(s.min_parallax_deg),
        ..*s
    };
    let (points, rejected) = triangulated_points(v, r, matches, &strict);
    band_zone(v, region, &points, rejected, s)
}

/// The [`ZoneGeometry::Local`] slab of V's cone through `region` around `points` (world): the
/// band from the `band_quantiles` of their distances from V's centre, each end moved out by
/// `band_margin` of its distance. `rejected` is passed through to the outcome.
pub fn band_zone(
    v: CameraView,
    region: &PixelBox,
    points: &[DVec3],
    rejected: usize,
    s: &ZoneSettings,
) -> ZoneOutcome {
    let o = v.center();
    let [cu, cv] = region.center();
    let axis = v.ray(cu, cv).normalize();
    let mut dist: Vec<f64> = points.iter().map(|p| p.distance(o)).collect();
    dist.sort_by(|a, b| a.total_cmp(b));
    let Some(&last) = dist.last() else {
        return ZoneOutcome::none(rejected);
    };
    if !(last > 0.0 && last.is_finite() && axis.is_finite()) {
        return ZoneOutcome::none(rejected);
    }
    let (ql, qh) = s.band_quantiles;
    let near = quantile_sorted(&dist, ql) * (1.0 - s.band_margin);
    let far = quantile_sorted(&dist, qh) * (1.0 + s.band_margin);
    band_slab(v, region, axis, (near, far), 1.0, s, points.len(), rejected)
}

/// The `q`-quantile of sorted, non-empty `xs`, linear between order statistics.
fn quantile_sorted(xs: &[f64], q: f64) -> f64 {
    let pos = q.clamp(0.0, 1.0) * (xs.len() - 1) as f64;
    let (lo, frac) = (pos.floor() as usize, pos.fract());
    match xs.get(lo + 1) {
        Some(&b) if frac > 0.0 => xs[lo] + frac * (b - xs[lo]),
        _ => xs[lo],
    }
}

/// [`ZoneGeometry::Triangulated`] from the matched pixel pairs (`(in v, in r)`), see the module
/// documentation.
pub fn triangulated_zone(
    v: CameraView,
    r: CameraView,
    matches: &[([f64; 2], [f64; 2])],
    s: &ZoneSettings,
) -> ZoneOutcome {
    let (points, rejected) = triangulated_points(v, r, matches, s);
    if points.is_empty() {
        return ZoneOutcome::none(rejected);
    }
    let kept: Vec<[f64; 3]> = points.iter().map(|p| p.to_array()).collect();
    let Some(mut sphere) = minimum_enclosing_sphere(&kept) else {
        return ZoneOutcome::none(rejected);
    };
    let floor = radius_floor(v, DVec3::from(sphere.center), s);
    sphere.radius = (sphere.radius * (1.0 + s.margin)).max(floor);
    if !(sphere.radius > 0.0 && sphere.radius.is_finite()) {
        return ZoneOutcome::none(rejected);
    }
    ZoneOutcome {
        zone: Some(Zone::Sphere(sphere)),
        points: kept.len(),
        rejected,
        unbounded_rays: 0,
    }
}
