//! LPM geometry on synthetic inputs: minimum enclosing sphere, cone zones, epipolar distance,
//! neighbour views, error regions.

use glam::DVec3;
use lpmsplat::lpm::enclosing_sphere::minimum_enclosing_sphere;
use lpmsplat::lpm::epipolar::{fundamental, symmetric_epipolar_distance};
use lpmsplat::lpm::neighbours::{
    optical_axis_angle, select_neighbours, Covisibility, NeighbourChoice, NeighbourKind,
    NeighbourSettings,
};
use lpmsplat::lpm::pairing::RegionPair;
use lpmsplat::lpm::pairing::{
    pair_regions, pair_regions_on, pair_regions_whole, PixelBox, RegionKeypoints,
};
use lpmsplat::lpm::regions::RegionSettings;
use lpmsplat::lpm::regions::{
    block_mask, error_map, quantile, regions_and_owners, regions_from_blocks, BlockMask, Region,
};
use lpmsplat::lpm::zones::{triangulated_zone, zone_for_pair};
use lpmsplat::lpm::zones::{zone_from_boxes, CameraView, Zone, ZoneGeometry, ZoneSettings};
use lpmsplat::lpm::{zones_for_step, ConeRadius, ZoneRecord};
use lpmsplat::scene::{CameraModel, Image, PinholeCamera, Pose, View};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

// ---------------------------------------------------------------- helpers

fn look_at(eye: DVec3, target: DVec3) -> Pose {
    let z = (target - eye).normalize();
    let up = if z.z.abs() > 0.99 { DVec3::Y } else { DVec3::Z };
    let x = z.cross(up).normalize();
    let y = z.cross(x);
    let rotation = [x.to_array(), y.to_array(), z.to_array()];
    let r = glam::DMat3::from_cols(x, y, z).transpose();
    Pose {
        rotation,
        translation: (-(r * eye)).to_array(),
    }
}

fn camera(w: u32, h: u32, f: f64) -> PinholeCamera {
    PinholeCamera {
        fx: f,
        fy: f * 1.05,
        cx: w as f64 / 2.0 + 3.0,
        cy: h as f64 / 2.0 - 2.0,
        width: w,
        height: h,
    }
}

fn view(name: &str, cam: PinholeCamera, pose: Pose) -> View {
    View {
        name: name.into(),
        stem: name.into(),
        image_path: format!("{name}.png").into(),
        source_model: CameraModel::Pinhole {
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
        },
        source_width: cam.width,
        source_height: cam.height,
        camera: cam,
        pose,
        colmap_image_id: None,
        keypoints: None,
    }
}

fn project(cam: &PinholeCamera, pose: &Pose, p: DVec3) -> Option<[f64; 2]> {
    let c = pose.transform(p.to_array());
    (c[2] > 1e-9).then(|| cam.project(c))
}

fn random_unit(rng: &mut Pcg64) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
            rng.gen_range(-1.0..1.0),
        );
        if v.length_squared() > 1e-3 && v.length_squared() <= 1.0 {
            return v.normalize();
        }
    }
}

// ---------------------------------------------------------------- minimum enclosing sphere

/// Smallest sphere through 1–4 points within their affine hull (independent of the library:
/// closed forms for 2 and 3 points, Cramer's rule for 4).
fn sphere_through(s: &[DVec3]) -> Option<(DVec3, f64)> {
    match s.len() {
        1 => Some((s[0], 0.0)),
        2 => Some(((s[0] + s[1]) * 0.5, 0.5 * s[0].distance(s[1]))),
        3 => {
            let (u, v) = (s[1] - s[0], s[2] - s[0]);
            let n = u.cross(v);
            let n2 = n.length_squared();
            if n2 <= 1e-20 * u.length_squared() * v.length_squared() {
                return None;
            }
            let c = s[0]
                + (v.length_squared() * n.cross(u) + u.length_squared() * v.cross(n)) / (2.0 * n2);
            Some((c, c.distance(s[0])))
        }
        4 => {
            let (a, b, c) = (s[1] - s[0], s[2] - s[0], s[3] - s[0]);
            let det = a.dot(b.cross(c));
            if det.abs() <= 1e-12 * a.length() * b.length() * c.length() {
                return None;
            }
            let rhs = DVec3::new(a.length_squared(), b.length_squared(), c.length_squared()) * 0.5;
            // Solve [a; b; c] x = rhs by Cramer's rule.
            let x = (rhs.x * b.cross(c) + rhs.y * c.cross(a) + rhs.z * a.cross(b)) / det;
            Some((s[0] + x, x.length()))
        }
        _ => None,
    }
}

fn brute_force_radius(p: &[DVec3]) -> f64 {
    let n = p.len();
    let scale = p
        .iter()
        .map(|q| q.distance(p[0]))
        .fold(0.0, f64::max)
        .max(1e-300);
    let mut best = f64::INFINITY;
    let mut consider = |s: &[DVec3]| {
        if let Some((c, r)) = sphere_through(s) {
            if r < best && p.iter().all(|q| q.distance(c) <= r + 1e-9 * scale) {
                best = r;
            }
        }
    };
    for i in 0..n {
        consider(&[p[i]]);
        for j in i + 1..n {
            consider(&[p[i], p[j]]);
            for k in j + 1..n {
                consider(&[p[i], p[j], p[k]]);
                for l in k + 1..n {
                    consider(&[p[i], p[j], p[k], p[l]]);
                }
            }
        }
    }
    best
}

/// Optimality certificate: the centre lies in the convex hull of the points on the sphere
/// (Frank–Wolfe on min |Σ λ_i p_i − c| over the simplex).
fn centre_in_hull_of_boundary(p: &[DVec3], c: DVec3, r: f64) -> f64 {
    let s: Vec<DVec3> = p
        .iter()
        .copied()
        .filter(|q| q.distance(c) >= r * (1.0 - 1e-7) - 1e-12)
        .collect();
    assert!(!s.is_empty());
    let mut x = s[0];
    for k in 0..20000 {
        let g = x - c;
        let best = s
            .iter()
            .copied()
            .min_by(|a, b| a.dot(g).total_cmp(&b.dot(g)))
            .unwrap();
        let step = 2.0 / (k as f64 + 2.0);
        x += step * (best - x);
    }
    x.distance(c)
}

fn check_mes(points: &[DVec3], brute: bool) {
    let arr: Vec<[f64; 3]> = points.iter().map(|p| p.to_array()).collect();
    let s = minimum_enclosing_sphere(&arr).expect("non-empty");
    let c = DVec3::from(s.center);
    assert!(s.radius.is_finite() && c.is_finite());
    let scale = points
        .iter()
        .map(|q| q.distance(points[0]))
        .fold(0.0, f64::max);
    for p in points {
        assert!(
            p.distance(c) <= s.radius + 1e-9 * scale.max(1.0),
            "point outside"
        );
    }
    if s.radius > 0.0 {
        let gap = centre_in_hull_of_boundary(points, c, s.radius);
        assert!(
            gap <= 2e-3 * s.radius,
            "centre not in the hull of the boundary points: gap {gap} r {}",
            s.radius
        );
    }
    if brute {
        let b = brute_force_radius(points);
        assert!(
            (s.radius - b).abs() <= 1e-7 * b.max(1e-12),
            "radius {} vs brute force {}",
            s.radius,
            b
        );
    }
}

#[test]
fn enclosing_sphere_matches_brute_force_on_random_sets() {
    let mut rng = Pcg64::seed_from_u64(1);
    for n in 1..=22 {
        for _ in 0..3 {
            let pts: Vec<DVec3> = (0..n)
                .map(|_| {
                    DVec3::new(
                        rng.gen_range(-5.0..5.0),
                        rng.gen_range(-1.0..3.0),
                        rng.gen_range(10.0..11.0),
                    )
                })
                .collect();
            check_mes(&pts, true);
        }
    }
    for n in [30, 50, 100, 150, 200] {
        let pts: Vec<DVec3> = (0..n)
            .map(|_| random_unit(&mut rng) * rng.gen_range(0.0..2.0f64).sqrt())
            .collect();
        check_mes(&pts, false);
        // Points on a sphere: many near-boundary points.
        let pts: Vec<DVec3> = (0..n)
            .map(|_| DVec3::new(1.0, -2.0, 0.5) + 3.0 * random_unit(&mut rng))
            .collect();
        check_mes(&pts, false);
    }
    assert!(minimum_enclosing_sphere(&[]).is_none());
    assert!(minimum_enclosing_sphere(&[[f64::NAN, 0.0, 0.0]]).is_none());
}

#[test]
fn enclosing_sphere_degenerate_sets() {
    let mut rng = Pcg64::seed_from_u64(2);
    // Duplicates: every point repeated, plus one point repeated many times.
    let base: Vec<DVec3> = (0..8).map(|_| random_unit(&mut rng) * 2.0).collect();
    let mut dup: Vec<DVec3> = base.iter().chain(base.iter()).copied().collect();
    dup.extend(std::iter::repeat_n(base[3], 10));
    check_mes(&dup, dup.len() <= 22);
    check_mes(
        &base.iter().chain(base.iter()).copied().collect::<Vec<_>>(),
        true,
    );
    let same = vec![DVec3::new(1.0, 2.0, 3.0); 17];
    let s =
        minimum_enclosing_sphere(&same.iter().map(|p| p.to_array()).collect::<Vec<_>>()).unwrap();
    assert_eq!(s.radius, 0.0);

    for trial in 0..10 {
        // Collinear.
        let o = DVec3::new(rng.gen_range(-3.0..3.0), 1.0, 2.0);
        let d = random_unit(&mut rng);
        let n = 5 + trial * 20;
        let line: Vec<DVec3> = (0..n).map(|_| o + rng.gen_range(-4.0..4.0) * d).collect();
        check_mes(&line, n <= 22);
        let ts: Vec<f64> = line.iter().map(|p| (*p - o).dot(d)).collect();
        let want = 0.5
            * (ts.iter().copied().fold(f64::MIN, f64::max)
                - ts.iter().copied().fold(f64::MAX, f64::min));
        let got = minimum_enclosing_sphere(&line.iter().map(|p| p.to_array()).collect::<Vec<_>>())
            .unwrap();
        assert!((got.radius - want).abs() <= 1e-9 * want);

        // Coplanar (in a tilted plane), including grid-aligned points with many cocircular ones.
        let (u, v) = (random_unit(&mut rng), random_unit(&mut rng));
        let plane: Vec<DVec3> = (0..n)
            .map(|_| {
                o + rng.gen_range(-2.0..2.0) * u + rng.gen_range(-2.0..2.0) * (v - v.dot(u) * u)
            })
            .collect();
        check_mes(&plane, n <= 22);
    }
    // Cocircular and cospherical configurations (many support candidates).
    let square: Vec<DVec3> = [(-1., -1.), (1., -1.), (1., 1.), (-1., 1.), (0., 0.)]
        .iter()
        .map(|&(x, y)| DVec3::new(x, y, 5.0))
        .collect();
    check_mes(&square, true);
    let cube: Vec<DVec3> = (0..8)
        .map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64))
        .collect();
    check_mes(&cube, true);
}

// ---------------------------------------------------------------- zones

/// A random scene: a ball of radius `rho` near the origin and two cameras looking at it, their
/// viewing directions `sep_deg` apart.
struct Rig {
    centre: DVec3,
    rho: f64,
    cams: [(PinholeCamera, Pose); 2],
}

fn rig(rng: &mut Pcg64, sep_deg: f64) -> Rig {
    let centre = DVec3::new(
        rng.gen_range(-0.3..0.3),
        rng.gen_range(-0.3..0.3),
        rng.gen_range(-0.3..0.3),
    );
    let rho = rng.gen_range(0.1..0.3);
    let d0 = random_unit(rng);
    let axis = d0.any_orthonormal_vector();
    let d1 = glam::DQuat::from_axis_angle(axis, sep_deg.to_radians()) * d0;
    let mk = |d: DVec3, dist: f64, rng: &mut Pcg64| {
        // Aim slightly off the ball so regions are off-centre in the image.
        let jitter = DVec3::new(
            rng.gen_range(-0.2..0.2),
            rng.gen_range(-0.2..0.2),
            rng.gen_range(-0.2..0.2),
        );
        (
            camera(640, 480, 500.0),
            look_at(centre + d * dist, centre + jitter),
        )
    };
    let c0 = mk(d0, rng.gen_range(3.0..5.0), rng);
    let c1 = mk(d1, rng.gen_range(3.0..5.0), rng);
    Rig {
        centre,
        rho,
        cams: [c0, c1],
    }
}

fn silhouette_box(
    cam: &PinholeCamera,
    pose: &Pose,
    centre: DVec3,
    rho: f64,
    rng: &mut Pcg64,
) -> PixelBox {
    let pts: Vec<[f64; 2]> = (0..4000)
        .map(|_| project(cam, pose, centre + rho * random_unit(rng)).unwrap())
        .collect();
    PixelBox::bounding(pts).unwrap()
}

/// Inside the cone of `cam` through the circumscribed circle of `b` (independent formulation:
/// project, then compare the pixel distance with the circle radius).
fn in_cone(cam: &PinholeCamera, pose: &Pose, b: &PixelBox, p: DVec3) -> bool {
    match project(cam, pose, p) {
        Some(uv) => {
            let c = b.center();
            (uv[0] - c[0]).hypot(uv[1] - c[1]) <= b.circumradius()
        }
        None => false,
    }
}

/// Oracle for the exact zone: grid points inside both cones, their enclosing sphere.
fn grid_zone_radius(r: &Rig, boxes: &[PixelBox; 2], half: f64, n: usize) -> Option<f64> {
    let mut pts = Vec::new();
    let h = 2.0 * half / n as f64;
    for i in 0..=n {
        for j in 0..=n {
            for k in 0..=n {
                let p = r.centre
                    + DVec3::new(
                        -half + i as f64 * h,
                        -half + j as f64 * h,
                        -half + k as f64 * h,
                    );
                if (0..2).all(|v| in_cone(&r.cams[v].0, &r.cams[v].1, &boxes[v], p)) {
                    if i == 0 || j == 0 || k == 0 || i == n || j == n || k == n {
                        return None; // the grid does not hold the whole intersection
                    }
                    pts.push(p.to_array());
                }
            }
        }
    }
    Some(minimum_enclosing_sphere(&pts)?.radius)
}

#[test]
fn sphere_zone_contains_the_ball_and_matches_the_exact_cone_intersection() {
    let mut rng = Pcg64::seed_from_u64(3);
    let s = ZoneSettings {
        geometry: ZoneGeometry::Sphere,
        ..Default::default()
    };
    let mut checked = 0;
    for trial in 0..12 {
        let sep = [25.0, 40.0, 60.0, 90.0][trial % 4];
        let r = rig(&mut rng, sep);
        let boxes =
            [0, 1].map(|v| silhouette_box(&r.cams[v].0, &r.cams[v].1, r.centre, r.rho, &mut rng));
        let cv = |v: usize| CameraView {
            camera: &r.cams[v].0,
            pose: &r.cams[v].1,
        };
        let out = zone_from_boxes(cv(0), &boxes[0], cv(1), &boxes[1], &s);
        let Some(Zone::Sphere(z)) = out.zone else {
            panic!("no zone: {out:?}")
        };
        assert_eq!(out.unbounded_rays, 0, "cones close at {sep}°");
        // Contains the ball (the cones circumscribe its silhouettes), to 1 % of the radius.
        let c = DVec3::from(z.center);
        assert!(
            c.distance(r.centre) + r.rho <= z.radius * 1.01,
            "ball not inside zone: |c - s| = {}, rho {}, R {}",
            c.distance(r.centre),
            r.rho,
            z.radius
        );
        // Radius against the grid oracle of the exact intersection: within 3 % + 2 grid cells.
        let half = 1.6 * z.radius;
        let n = 70;
        if let Some(oracle) = grid_zone_radius(&r, &boxes, half, n) {
            let cell = 2.0 * half / n as f64 * 3f64.sqrt();
            assert!(
                (z.radius - oracle).abs() <= 0.03 * oracle + cell,
                "sep {sep}: radius {} vs oracle {oracle} (cell {cell})",
                z.radius
            );
            checked += 1;
        }
        // The ray-pair reading encloses the exact zone's sample points' sphere only loosely, but
        // must still be finite and contain the ball.
        let rp = zone_from_boxes(
            cv(0),
            &boxes[0],
            cv(1),
            &boxes[1],
            &ZoneSettings {
                geometry: ZoneGeometry::SphereRayPairs,
                ..s
            },
        );
        let Some(Zone::Sphere(zp)) = rp.zone else {
            panic!("no ray-pair zone")
        };
        assert!(DVec3::from(zp.center).distance(r.centre) + r.rho <= zp.radius * 1.01);
        // The authors' box holds the ball's centre.
        let ab = zone_from_boxes(
            cv(0),
            &boxes[0],
            cv(1),
            &boxes[1],
            &ZoneSettings {
                geometry: ZoneGeometry::AuthorsBox,
                ..s
            },
        );
        let zb = ab.zone.expect("box zone");
        assert!(
            zb.contains(r.centre.to_array(), 1e-9),
            "authors' box misses the centre: {zb:?}"
        );
    }
    assert!(
        checked >= 8,
        "oracle grid too small too often ({checked} checked)"
    );
}

#[test]
fn sphere_zone_degrades_gracefully_with_match_noise() {
    let mut rng = Pcg64::seed_from_u64(4);
    for _ in 0..4 {
        let r = rig(&mut rng, 35.0);
        // Matches: projections of random surface points seen by both cameras.
        let surf: Vec<DVec3> = (0..300)
            .map(|_| r.centre + r.rho * random_unit(&mut rng))
            .collect();
        let clean: Vec<[[f64; 2]; 2]> = surf
            .iter()
            .map(|p| [0, 1].map(|v| project(&r.cams[v].0, &r.cams[v].1, *p).unwrap()))
            .collect();
        let region = Region {
            x0: 0,
            y0: 0,
            x1: 640,
            y1: 480,
        };
        let cv = |v: usize| CameraView {
            camera: &r.cams[v].0,
            pose: &r.cams[v].1,
        };
        let mut radii = Vec::new();
        let sigmas = [0.0, 0.25, 0.5, 1.0, 2.0, 4.0];
        let box_px = {
            let b = PixelBox::bounding(clean.iter().map(|m| m[0])).unwrap();
            b.circumradius()
        };
        for &sigma in &sigmas {
            let mut noisy_rng = Pcg64::seed_from_u64(99);
            let mut noise = || {
                let (a, b): (f64, f64) = (noisy_rng.gen_range(1e-12..1.0), noisy_rng.gen());
                sigma * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
            };
            let xy_v: Vec<[f32; 2]> = clean
                .iter()
                .map(|m| [(m[0][0] + noise()) as f32, (m[0][1] + noise()) as f32])
                .collect();
            let xy_r: Vec<[f32; 2]> = clean
                .iter()
                .map(|m| [(m[1][0] + noise()) as f32, (m[1][1] + noise()) as f32])
                .collect();
            let (pairs, stats) = pair_regions(&[region], &xy_v, &xy_r);
            assert_eq!(stats.paired, 1);
            let out = zone_from_boxes(
                cv(0),
                &pairs[0].in_view,
                cv(1),
                &pairs[0].in_reference,
                &ZoneSettings {
                    geometry: ZoneGeometry::Sphere,
                    ..Default::default()
                },
            );
            let Some(Zone::Sphere(z)) = out.zone else {
                panic!("no zone at sigma {sigma}")
            };
            assert!(z.radius.is_finite() && z.center.iter().all(|c| c.is_finite()));
            radii.push(z.radius);
        }
        // Stated tolerance: the radius moves by at most 3·σ/ρ_px of itself (ρ_px: the region's
        // circumradius in pixels; the extreme matches move by about 2σ), plus 1 % for sampling.
        for (k, &sigma) in sigmas.iter().enumerate() {
            let rel = (radii[k] - radii[0]).abs() / radii[0];
            assert!(
                rel <= 3.0 * sigma / box_px + 0.01,
                "sigma {sigma}: radius {} vs {} (rel {rel})",
                radii[k],
                radii[0]
            );
        }
    }
}

#[test]
fn zones_reject_degenerate_pairs_without_nan() {
    let mut rng = Pcg64::seed_from_u64(5);
    let cam = camera(320, 240, 300.0);
    let pose = look_at(DVec3::new(0.0, -4.0, 0.0), DVec3::ZERO);
    let b = PixelBox {
        x0: 100.0,
        y0: 80.0,
        x1: 140.0,
        y1: 120.0,
    };
    let cv = CameraView {
        camera: &cam,
        pose: &pose,
    };
    for geometry in [
        ZoneGeometry::Sphere,
        ZoneGeometry::SphereRayPairs,
        ZoneGeometry::AuthorsBox,
    ] {
        let s = ZoneSettings {
            geometry,
            ..Default::default()
        };
        // Same camera twice: every ray pair is parallel or identical.
        let out = zone_from_boxes(cv, &b, cv, &b, &s);
        if let Some(z) = out.zone {
            let sp = z.bounding_sphere();
            assert!(
                sp.radius.is_finite() && sp.center.iter().all(|c| c.is_finite()),
                "{geometry:?}: {z:?}"
            );
        }
        // Tiny baseline, same direction: cones do not close.
        let pose2 = look_at(DVec3::new(0.01, -4.0, 0.0), DVec3::new(0.01, 0.0, 0.0));
        let out = zone_from_boxes(
            cv,
            &b,
            CameraView {
                camera: &cam,
                pose: &pose2,
            },
            &b,
            &s,
        );
        if geometry == ZoneGeometry::Sphere {
            assert!(out.unbounded_rays > 0);
        }
        if let Some(z) = out.zone {
            let sp = z.bounding_sphere();
            assert!(
                sp.radius.is_finite() && sp.center.iter().all(|c| c.is_finite()),
                "{geometry:?}: {z:?}"
            );
        }
        // Cameras facing away from each other: no point in front of both.
        let pose3 = look_at(DVec3::new(0.0, -8.0, 0.0), DVec3::new(0.0, -12.0, 0.0));
        let out = zone_from_boxes(
            cv,
            &b,
            CameraView {
                camera: &cam,
                pose: &pose3,
            },
            &b,
            &s,
        );
        if geometry != ZoneGeometry::AuthorsBox {
            assert!(out.zone.is_none(), "{geometry:?}: {out:?}");
        }
    }
    let _ = rng.gen::<u8>();
}

#[test]
fn zone_records_layout_and_step() {
    assert_eq!(std::mem::size_of::<ZoneRecord>(), 64);
    assert_eq!(std::mem::align_of::<ZoneRecord>(), 4);
    let mut rng = Pcg64::seed_from_u64(6);
    let r = rig(&mut rng, 40.0);
    let v0 = view("a", r.cams[0].0, r.cams[0].1);
    let v1 = view("b", r.cams[1].0, r.cams[1].1);
    let surf: Vec<DVec3> = (0..200)
        .map(|_| r.centre + r.rho * random_unit(&mut rng))
        .collect();
    let xy0: Vec<[f32; 2]> = surf
        .iter()
        .map(|p| project(&v0.camera, &v0.pose, *p).unwrap().map(|x| x as f32))
        .collect();
    let xy1: Vec<[f32; 2]> = surf
        .iter()
        .map(|p| project(&v1.camera, &v1.pose, *p).unwrap().map(|x| x as f32))
        .collect();
    let (w, h) = (640u32, 480u32);
    let rgb: Vec<f32> = (0..w * h)
        .flat_map(|i| [(i % w) as f32 / w as f32, 0.25, 0.75])
        .collect();
    let gt = Image {
        width: w,
        height: h,
        rgb,
        alpha: None,
    };
    let regions = [
        Region {
            x0: 0,
            y0: 0,
            x1: 640,
            y1: 480,
        }, // holds every match
        Region {
            x0: 0,
            y0: 0,
            x1: 16,
            y1: 16,
        }, // corner: no matches (ball is near the centre)
    ];
    let out = zones_for_step(
        &v0,
        &v1,
        &regions,
        None,
        &xy0,
        &xy1,
        &gt,
        [0.0; 3],
        &ZoneSettings {
            geometry: ZoneGeometry::Sphere,
            ..Default::default()
        },
        ConeRadius::Bounding,
    );
    assert_eq!(out.pairing.regions, 2);
    assert_eq!(out.pairing.no_matches, 1);
    assert_eq!(out.records.len(), 1);
    let rec = out.records[0];
    let bytes: &[u8] = bytemuck::bytes_of(&rec);
    assert_eq!(bytes.len(), 64);
    assert!(
        (DVec3::from(rec.camera_center.map(|x| x as f64)) - DVec3::from(v0.pose.center())).length()
            < 1e-4
    );
    assert_eq!(rec.shape, 0);
    assert!(
        DVec3::from(rec.center.map(|x| x as f64)).distance(r.centre) + r.rho
            <= rec.radius as f64 * 1.01
    );
    // Colour: mean over the keypoints' box; red channel = mean x / w over its pixel columns.
    let b = PixelBox::bounding(xy0.iter().map(|p| [p[0] as f64, p[1] as f64])).unwrap();
    let (x0, x1) = ((b.x0 - 0.5).ceil(), (b.x1 - 0.5).floor());
    let want_r = (0.5 * (x0 + x1)) / w as f64;
    assert!(
        (rec.color[0] as f64 - want_r).abs() < 1e-4,
        "{} vs {want_r}",
        rec.color[0]
    );
    assert!((rec.color[1] - 0.25).abs() < 1e-6 && (rec.color[2] - 0.75).abs() < 1e-6);
}

// ---------------------------------------------------------------- epipolar

#[test]
fn epipolar_distance_zero_for_true_matches_and_grows_with_corruption() {
    let mut rng = Pcg64::seed_from_u64(7);
    for _ in 0..20 {
        let sep = rng.gen_range(10.0..80.0);
        let r = rig(&mut rng, sep);
        let [(ca, pa), (cb, pb)] = r.cams;
        let f = fundamental(&ca, &pa, &cb, &pb);
        for _ in 0..50 {
            let p = r.centre + random_unit(&mut rng) * rng.gen_range(0.0..1.0);
            let (xa, xb) = (project(&ca, &pa, p).unwrap(), project(&cb, &pb, p).unwrap());
            assert!(symmetric_epipolar_distance(&f, xa, xb) < 1e-6);
            // Move xb off its epipolar line by d pixels along the line's normal.
            let l = [
                f[0][0] * xa[0] + f[0][1] * xa[1] + f[0][2],
                f[1][0] * xa[0] + f[1][1] * xa[1] + f[1][2],
                f[2][0] * xa[0] + f[2][1] * xa[1] + f[2][2],
            ];
            let n = l[0].hypot(l[1]);
            let d = rng.gen_range(5.0..50.0);
            let moved = [xb[0] + d * l[0] / n, xb[1] + d * l[1] / n];
            let e = symmetric_epipolar_distance(&f, xa, moved);
            assert!(e >= d * (1.0 - 1e-6), "corrupted by {d} px, distance {e}");
        }
    }
    // Zero baseline: undefined lines are infinitely far (so a filter rejects, never NaN).
    let cam = camera(100, 100, 80.0);
    let p = look_at(DVec3::new(1.0, 2.0, 3.0), DVec3::ZERO);
    let f = fundamental(&cam, &p, &cam, &p);
    assert!(symmetric_epipolar_distance(&f, [10.0, 10.0], [10.0, 10.0]).is_infinite());
}

// ---------------------------------------------------------------- neighbours

/// 36 cameras on a ring of radius 5, every 10°, all looking at the centre: axis angle = ring
/// angle.
fn ring_views() -> Vec<View> {
    let cam = camera(100, 100, 80.0);
    (0..36)
        .map(|i| {
            let a = (i as f64 * 10.0).to_radians();
            view(
                &format!("r{i}"),
                cam,
                look_at(DVec3::new(5.0 * a.cos(), 5.0 * a.sin(), 0.0), DVec3::ZERO),
            )
        })
        .collect()
}

#[test]
fn neighbours_on_a_ring_rig() {
    let cam = camera(100, 100, 80.0);
    let mut views = ring_views();
    // A camera with the same axis as r0 (further back): angle 0, never a neighbour of r0.
    views.push(view(
        "twin",
        cam,
        look_at(DVec3::new(9.0, 0.0, 0.0), DVec3::ZERO),
    ));
    // A camera looking straight up from far away: no axis within 45° → nearest centre.
    views.push(view(
        "up",
        cam,
        look_at(DVec3::new(5.3, 0.2, 0.0), DVec3::new(5.3, 0.2, 10.0)),
    ));
    let train: Vec<usize> = (0..views.len()).collect();
    let s = NeighbourSettings {
        choice: NeighbourChoice::Random,
        ..NeighbourSettings::default()
    };
    let n = select_neighbours(&views, &train, None, &s);
    for v in 0..36 {
        assert_eq!(n.kind[v], NeighbourKind::ByAngle);
        assert_eq!(n.of[v].len(), 3);
        for &o in &n.of[v] {
            assert_ne!(o, v);
            let a = optical_axis_angle(&views[v].pose, &views[o].pose).to_degrees();
            assert!(
                a > 0.0 && a <= 45.0 + 1e-9,
                "view {v} neighbour {o} at {a}°"
            );
        }
    }
    assert!(!n.of[0].contains(&36), "angle 0 must not qualify");
    assert_eq!(n.kind[37], NeighbourKind::NearestCentre);
    assert_eq!(n.of[37], vec![0], "r0 at (5,0,0) is nearest to (5.3,0.2,0)");
    // Deterministic for a seed; the pick is always among the neighbours.
    assert_eq!(n, select_neighbours(&views, &train, None, &s));
    let other = select_neighbours(&views, &train, None, &NeighbourSettings { seed: 1234, ..s });
    assert_ne!(
        n.of, other.of,
        "another seed should pick differently somewhere"
    );
    let mut rng = Pcg64::seed_from_u64(0);
    for _ in 0..20 {
        assert!(n.of[5].contains(&n.pick(5, &mut rng).unwrap()));
    }
    // A 90° limit lets more views qualify; a tiny one falls back everywhere.
    let wide = select_neighbours(
        &views,
        &train,
        None,
        &NeighbourSettings {
            max_angle_deg: 90.0,
            ..s
        },
    );
    assert!(wide.of[0]
        .iter()
        .all(|&o| optical_axis_angle(&views[0].pose, &views[o].pose).to_degrees() <= 90.0 + 1e-9));
    let narrow = select_neighbours(
        &views,
        &train,
        None,
        &NeighbourSettings {
            max_angle_deg: 5.0,
            ..s
        },
    );
    assert_eq!(narrow.kind[3], NeighbourKind::NearestCentre);
    // Only training views count; one training view has no neighbour.
    let one = select_neighbours(&views, &[4], None, &s);
    assert_eq!(one.kind[4], NeighbourKind::None);
    assert!(one.of.iter().all(|o| o.is_empty()));
    assert!(one.pairs().is_empty());
    // Pairs are unordered and unique.
    let pairs = n.pairs();
    assert!(pairs.windows(2).all(|w| w[0] < w[1]) && pairs.iter().all(|p| p.0 < p.1));
}

/// The overlap choice keeps, among the views within the angle, those sharing the most SfM
/// tracks, ties by the nearest camera centre; the random pick ignores both.
#[test]
fn overlap_neighbours_follow_shared_tracks_then_centres() {
    let views = ring_views();
    let train: Vec<usize> = (0..36).collect();
    assert_eq!(
        NeighbourSettings::default().choice,
        NeighbourChoice::Random,
        "the paper's pick is the default"
    );
    let s = NeighbourSettings {
        choice: NeighbourChoice::Overlap,
        ..NeighbourSettings::default()
    };
    // Without tracks: the nearest centres, ±10° and one of the two at ±20°.
    let n = select_neighbours(&views, &train, None, &s);
    for v in 0..36usize {
        let (next, prev) = ((v + 1) % 36, (v + 35) % 36);
        let (next2, prev2) = ((v + 2) % 36, (v + 34) % 36);
        let of = &n.of[v];
        assert_eq!(n.kind[v], NeighbourKind::ByAngle);
        assert_eq!(of.len(), 3, "view {v}: {of:?}");
        assert!(of.contains(&next) && of.contains(&prev), "view {v}: {of:?}");
        assert!(
            of.contains(&next2) || of.contains(&prev2),
            "view {v}: {of:?}"
        );
    }
    // Tracks: view 0 shares 5 points with r4 (40°), 3 with r33 (30°), 1 with r1, none with the
    // rest; r5 (50°) shares 9 but is outside the 45° limit. A view listed twice in one track
    // counts once; views outside the angle never qualify whatever they share.
    let mut tracks: Vec<Vec<(u32, u32)>> = Vec::new();
    for k in 0..5 {
        tracks.push(vec![(0, k), (4, k), (4, k + 100)]);
    }
    for k in 0..3 {
        tracks.push(vec![(33, k), (0, 10 + k)]);
    }
    tracks.push(vec![(0, 20), (1, 0)]);
    for k in 0..9 {
        tracks.push(vec![(0, 30 + k), (5, k)]);
    }
    let cv = Covisibility::from_tracks(&tracks);
    assert_eq!(
        (cv.shared(0, 4), cv.shared(4, 0), cv.shared(0, 2)),
        (5, 5, 0)
    );
    let n = select_neighbours(&views, &train, Some(&cv), &s);
    assert_eq!(
        n.of[0],
        vec![1, 4, 33],
        "most shared tracks first, within 45°"
    );
    // Two neighbours: the two that share most.
    let two = select_neighbours(
        &views,
        &train,
        Some(&cv),
        &NeighbourSettings {
            max_neighbours: 2,
            ..s
        },
    );
    assert_eq!(two.of[0], vec![4, 33]);
    // The seed does not change an overlap choice; it does change a random one.
    let seeded = NeighbourSettings { seed: 99, ..s };
    assert_eq!(n, select_neighbours(&views, &train, Some(&cv), &seeded));
    let random = |seed| {
        select_neighbours(
            &views,
            &train,
            Some(&cv),
            &NeighbourSettings {
                choice: NeighbourChoice::Random,
                seed,
                ..s
            },
        )
    };
    assert!(
        (0..8).any(|seed| random(seed).of[0] != n.of[0]),
        "the random pick does not follow the tracks"
    );
    // The choice's names round-trip; an unknown one is refused with the choices.
    for c in [NeighbourChoice::Overlap, NeighbourChoice::Random] {
        assert_eq!(NeighbourChoice::parse(c.name()).unwrap(), c);
    }
    let err = NeighbourChoice::parse("nearest").unwrap_err().to_string();
    assert!(err.contains("overlap or random"), "{err}");
}

// ---------------------------------------------------------------- regions

#[test]
fn error_map_and_quantile_match_their_definitions() {
    let mut rng = Pcg64::seed_from_u64(8);
    let (w, h) = (37u32, 23u32);
    let n = (w * h) as usize;
    let render: Vec<f32> = (0..3 * n).map(|_| rng.gen()).collect();
    let gt: Vec<f32> = (0..3 * n).map(|_| rng.gen::<f32>() * 0.5).collect();
    let e = error_map(&render, &gt, w, h).unwrap();
    let mr = render.iter().map(|&x| x as f64).sum::<f64>() / (3 * n) as f64;
    let mg = gt.iter().map(|&x| x as f64).sum::<f64>() / (3 * n) as f64;
    for i in 0..n {
        let want: f64 = (0..3)
            .map(|c| {
                (render[3 * i + c] as f64 / (mr + 0.01) - gt[3 * i + c] as f64 / (mg + 0.01)).abs()
            })
            .sum();
        assert!((e[i] as f64 - want).abs() < 1e-5);
    }
    let mut sorted = e.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    for q in [0.0f32, 0.1, 0.4, 0.5, 0.77, 1.0] {
        let pos = q as f64 * (n - 1) as f64;
        let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
        let want = sorted[lo] as f64 + (pos - lo as f64) * (sorted[hi] as f64 - sorted[lo] as f64);
        assert!((quantile(&e, q) as f64 - want).abs() < 1e-6, "q {q}");
    }
    assert!(error_map(&render, &gt[..10], w, h).is_err());
    assert!(block_mask(&e, w + 1, h, 0.4, 16, 0.85).is_err());
}

fn map_with(w: u32, h: u32, on: impl Fn(u32, u32) -> bool) -> Vec<f32> {
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| if on(x, y) { 1.0 } else { 0.0 })
        .collect()
}

#[test]
fn regions_on_constructed_error_maps() {
    // 128×96 image (8×6 blocks). Blocks (1,1) and (2,2) touch diagonally → one region;
    // block (6,1) alone; block (4,4) has exactly 218 error pixels (kept: > 217.6), block (0,4)
    // has 217 (dropped).
    let (w, h) = (128u32, 96u32);
    let full = |bx: u32, by: u32, x: u32, y: u32| x / 16 == bx && y / 16 == by;
    let count_in =
        |bx: u32, by: u32, k: u32, x: u32, y: u32| full(bx, by, x, y) && (y % 16) * 16 + x % 16 < k;
    let e = map_with(w, h, |x, y| {
        full(1, 1, x, y)
            || full(2, 2, x, y)
            || full(6, 1, x, y)
            || count_in(4, 4, 218, x, y)
            || count_in(0, 4, 217, x, y)
    });
    let m = block_mask(&e, w, h, 0.4, 16, 0.85).unwrap();
    let kept: Vec<(u32, u32)> = (0..6)
        .flat_map(|y| (0..8).map(move |x| (x, y)))
        .filter(|&(x, y)| m.is_kept(x, y))
        .collect();
    assert_eq!(kept, vec![(1, 1), (6, 1), (2, 2), (4, 4)]);
    let mut regions = regions_from_blocks(&m);
    regions.sort_by_key(|r| (r.y0, r.x0));
    assert_eq!(
        regions,
        vec![
            Region {
                x0: 16,
                y0: 16,
                x1: 48,
                y1: 48
            },
            Region {
                x0: 96,
                y0: 16,
                x1: 112,
                y1: 32
            },
            Region {
                x0: 64,
                y0: 64,
                x1: 80,
                y1: 80
            },
        ]
    );
    // The same through precomputed counts (as from a GPU pass).
    let mut counts = vec![0u32; 48];
    for y in 0..h {
        for x in 0..w {
            if e[(y * w + x) as usize] > 0.0 {
                counts[((y / 16) * 8 + x / 16) as usize] += 1;
            }
        }
    }
    assert_eq!(
        BlockMask::from_error_counts(w, h, 16, &counts, 0.85).unwrap(),
        m
    );
    assert!(BlockMask::from_error_counts(w, h, 16, &counts[1..], 0.85).is_err());
}

/// A region's own error blocks, not its box: an L-shaped component's box also covers a block
/// that is no error and a block of another component, and only the error-blocks rule keeps the
/// matches there out of its zone.
#[test]
fn pairing_on_error_blocks_keeps_only_the_regions_own_matches() {
    // 64×64, 16-px blocks (4×4). Component A: blocks (0,0), (0,1), (0,2), (1,2), (2,2) — an L
    // whose box is blocks x 0..3, y 0..3. Component B: block (2,0) alone, inside A's box (its
    // corner touches no block of A: (1,1) is not kept). Block (1,1) is inside A's box, no error.
    let (w, h) = (64u32, 64u32);
    let a = [(0, 0), (0, 1), (0, 2), (1, 2), (2, 2)];
    let b = [(2, 0)];
    let e = map_with(w, h, |x, y| {
        let blk = (x / 16, y / 16);
        a.contains(&blk) || b.contains(&blk)
    });
    let m = block_mask(&e, w, h, 0.4, 16, 0.85).unwrap();
    let (regions, owners) = regions_and_owners(&m);
    assert_eq!(regions, regions_from_blocks(&m));
    assert_eq!(regions.len(), 2);
    let ra = regions
        .iter()
        .position(|r| r.x1 == 48 && r.y1 == 48)
        .unwrap();
    let rb = 1 - ra;
    assert_eq!(
        regions[rb],
        Region {
            x0: 32,
            y0: 0,
            x1: 48,
            y1: 16
        }
    );
    // Owners by pixel: A's blocks, B's block, nothing elsewhere or outside.
    assert_eq!(owners.owner(8.0, 40.0), Some(ra));
    assert_eq!(owners.owner(40.0, 8.0), Some(rb));
    assert_eq!(
        owners.owner(24.0, 24.0),
        None,
        "block (1,1) is no error block"
    );
    assert_eq!(owners.owner(-1.0, 8.0), None);
    assert_eq!(owners.owner(64.5, 8.0), None);
    assert_eq!(owners.owner(f64::NAN, 8.0), None);
    // Matches (V → V' shifted by 100 px): two on A's blocks, one on the no-error block (1,1),
    // one on B's block, one outside every box.
    let xy_v: Vec<[f32; 2]> = vec![
        [4.0, 4.0],
        [40.0, 40.0],
        [24.0, 24.0],
        [40.0, 4.0],
        [60.0, 60.0],
    ];
    let xy_r: Vec<[f32; 2]> = xy_v.iter().map(|p| [p[0] + 100.0, p[1]]).collect();
    // The paper's box rule: A gets the four inside its box (B's and the no-error one included).
    let (boxed, _) = pair_regions(&regions, &xy_v, &xy_r);
    let a_box = boxed.iter().find(|p| p.region == regions[ra]).unwrap();
    assert_eq!(a_box.matched, vec![0, 1, 2, 3]);
    // Ours: A keeps its own two; B has one match only (a zero-area box: not paired).
    let (own, stats) = pair_regions_on(&regions, Some(&owners), &xy_v, &xy_r);
    assert_eq!(own.len(), 1);
    assert_eq!(own[0].region, regions[ra]);
    assert_eq!(own[0].matched, vec![0, 1]);
    assert_eq!(
        (
            own[0].in_view.x0,
            own[0].in_view.y0,
            own[0].in_view.x1,
            own[0].in_view.y1
        ),
        (4.0, 4.0, 40.0, 40.0)
    );
    assert_eq!((stats.regions, stats.paired, stats.zero_area), (2, 1, 1));
    // The rule's names round-trip; an unknown one is refused with the choices.
    for k in [RegionKeypoints::ErrorBlocks, RegionKeypoints::Box] {
        assert_eq!(RegionKeypoints::parse(k.name()).unwrap(), k);
    }
    let err = RegionKeypoints::parse("blocks").unwrap_err().to_string();
    assert!(err.contains("error-blocks or box"), "{err}");
    assert_eq!(
        RegionKeypoints::default(),
        RegionKeypoints::Box,
        "the paper's rule"
    );
}

#[test]
fn regions_with_padding() {
    // 40×30: blocks 3×2, the last column 8 px wide, the last row 14 px high. Padding pixels count
    // as non-error, so the 8-wide column can never be kept (128 < 217.6), while a 14-row block
    // can (224 > 217.6) and its box is clipped to the image.
    let (w, h) = (40u32, 30u32);
    let e = map_with(w, h, |x, y| (x >= 32) || (x < 16 && y >= 16));
    let m = block_mask(&e, w, h, 0.4, 16, 0.85).unwrap();
    assert_eq!((m.blocks_x, m.blocks_y), (3, 2));
    assert!(!m.is_kept(2, 0) && !m.is_kept(2, 1));
    assert!(m.is_kept(0, 1));
    assert_eq!(
        regions_from_blocks(&m),
        vec![Region {
            x0: 0,
            y0: 16,
            x1: 16,
            y1: 30
        }]
    );
    // Uniform error: nothing is above the 0.4 quantile, so no region.
    let flat = vec![0.5f32; (w * h) as usize];
    assert!(regions_from_blocks(&block_mask(&flat, w, h, 0.4, 16, 0.85).unwrap()).is_empty());
    // Tiny images (smaller than a block) work.
    let tiny = map_with(5, 3, |_, _| true);
    assert!(regions_from_blocks(&block_mask(&tiny, 5, 3, 0.4, 16, 0.85).unwrap()).is_empty());
}

/// One step's host work over 12 regions tiling the image: every region the pairing keeps gets
/// a zone. The time is printed for the report (`--nocapture`), not asserted.
#[test]
fn zone_step_finds_a_zone_per_matched_region() {
    let mut rng = Pcg64::seed_from_u64(9);
    let r = rig(&mut rng, 30.0);
    let v0 = view("a", r.cams[0].0, r.cams[0].1);
    let v1 = view("b", r.cams[1].0, r.cams[1].1);
    let surf: Vec<DVec3> = (0..2000)
        .map(|_| r.centre + r.rho * random_unit(&mut rng))
        .collect();
    let xy0: Vec<[f32; 2]> = surf
        .iter()
        .map(|p| project(&v0.camera, &v0.pose, *p).unwrap().map(|x| x as f32))
        .collect();
    let xy1: Vec<[f32; 2]> = surf
        .iter()
        .map(|p| project(&v1.camera, &v1.pose, *p).unwrap().map(|x| x as f32))
        .collect();
    let gt = Image {
        width: 640,
        height: 480,
        rgb: vec![0.5; 640 * 480 * 3],
        alpha: None,
    };
    // 12 regions tiling the image; those the matches fall in are paired.
    let regions: Vec<Region> = (0..12)
        .map(|k| Region {
            x0: (k % 4) * 160,
            y0: (k / 4) * 160,
            x1: (k % 4 + 1) * 160,
            y1: ((k / 4 + 1) * 160).min(480),
        })
        .collect();
    let step = || {
        zones_for_step(
            &v0,
            &v1,
            &regions,
            None,
            &xy0,
            &xy1,
            &gt,
            [0.0; 3],
            &ZoneSettings::default(),
            ConeRadius::Bounding,
        )
    };
    let t = std::time::Instant::now();
    let reps = 20;
    let mut zones = 0;
    for _ in 0..reps {
        zones += step().records.len();
    }
    let per_step = t.elapsed().as_secs_f64() / reps as f64;
    println!(
        "zones_for_step: {:.3} ms per step, {} zones per step",
        1e3 * per_step,
        zones / reps
    );
    // Every region the pairing kept gets its zone (exact matches leave no pair without one).
    let step = step();
    assert!(
        step.pairing.paired >= 1 && step.no_zone == 0,
        "{:?}",
        step.pairing
    );
    assert_eq!(step.records.len(), step.pairing.paired);
    assert_eq!(
        zones,
        reps * step.pairing.paired,
        "every repetition finds the same zones"
    );
}

// ---------------------------------------------------------------- triangulated (local) zones

/// Two cameras 4 units from a plane patch, `sep_deg` apart around it (a small baseline).
fn small_baseline(sep_deg: f64) -> [(PinholeCamera, Pose); 2] {
    let cam = camera(640, 480, 500.0);
    let half = 0.5 * sep_deg.to_radians();
    [-half, half].map(|a| {
        let eye = DVec3::new(4.0 * a.sin(), -4.0 * a.cos(), 0.3);
        (cam, look_at(eye, DVec3::ZERO))
    })
}

/// The pixel box of `xy` grown by 2 pixels on every side.
fn region_around(xy: &[[f32; 2]]) -> Region {
    let (lo, hi) = xy
        .iter()
        .fold(([f32::MAX; 2], [f32::MIN; 2]), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1])],
                [hi[0].max(p[0]), hi[1].max(p[1])],
            )
        });
    Region {
        x0: lo[0].floor() as u32 - 2,
        y0: lo[1].floor() as u32 - 2,
        x1: hi[0].ceil() as u32 + 2,
        y1: hi[1].ceil() as u32 + 2,
    }
}

/// The two sides of f64 matches as the f32 pixel lists the pairing reads.
fn f32_pixels(matches: &[([f64; 2], [f64; 2])]) -> (Vec<[f32; 2]>, Vec<[f32; 2]>) {
    let f = |p: [f64; 2]| [p[0] as f32, p[1] as f32];
    matches.iter().map(|&(v, r)| (f(v), f(r))).unzip()
}

/// Matches of points on a disc of radius `rho` in the plane y = 0 around the origin.
fn disc_matches(
    cams: &[(PinholeCamera, Pose); 2],
    rho: f64,
    n: usize,
) -> Vec<([f64; 2], [f64; 2])> {
    let mut rng = Pcg64::seed_from_u64(17);
    (0..n)
        .map(|_| {
            let (r, a): (f64, f64) = (rho * rng.gen::<f64>().sqrt(), rng.gen_range(0.0..6.3));
            let p = DVec3::new(r * a.cos(), 0.0, r * a.sin());
            let m = [0, 1].map(|v| project(&cams[v].0, &cams[v].1, p).unwrap());
            (m[0], m[1])
        })
        .collect()
}

#[test]
fn triangulated_zone_stays_on_the_surface_where_the_cone_zone_spans_the_depth() {
    let cams = small_baseline(6.0);
    let cv = |v: usize| CameraView {
        camera: &cams[v].0,
        pose: &cams[v].1,
    };
    let rho = 0.1;
    let matches = disc_matches(&cams, rho, 40);
    let s = ZoneSettings::default();
    assert_eq!(s.geometry, ZoneGeometry::Triangulated, "the default zone");
    let out = triangulated_zone(cv(0), cv(1), &matches, &s);
    let Some(Zone::Sphere(z)) = out.zone else {
        panic!("no zone: {out:?}")
    };
    assert_eq!((out.points, out.rejected), (40, 0));
    // Centred on the disc, enclosing it, and no larger than the disc plus the margin.
    assert!(DVec3::from(z.center).length() < 0.2 * rho, "{z:?}");
    assert!(
        z.radius >= 0.9 * rho && z.radius <= (1.0 + s.margin) * rho * 1.001,
        "{z:?}"
    );

    // The same matches through the pair's boxes: the cone intersection's sphere.
    let (xy_v, xy_r) = f32_pixels(&matches);
    let region = Region {
        x0: 0,
        y0: 0,
        x1: 640,
        y1: 480,
    };
    let (pairs, _) = pair_regions(&[region], &xy_v, &xy_r);
    let pair: &RegionPair = &pairs[0];
    assert_eq!(pair.matched.len(), 40);
    let sphere = zone_for_pair(
        cv(0),
        cv(1),
        pair,
        &xy_v,
        &xy_r,
        &ZoneSettings {
            geometry: ZoneGeometry::Sphere,
            ..s
        },
    );
    let Some(Zone::Sphere(big)) = sphere.zone else {
        panic!("no sphere zone")
    };
    // At 6° the cones' lens reaches far along the viewing direction: much larger zone.
    assert!(
        big.radius > 5.0 * z.radius,
        "sphere {} vs triangulated {}",
        big.radius,
        z.radius
    );
    // zone_for_pair with the default geometry is the triangulated zone from the pair's matches.
    let via_pair = zone_for_pair(cv(0), cv(1), pair, &xy_v, &xy_r, &s);
    let Some(Zone::Sphere(zp)) = via_pair.zone else {
        panic!()
    };
    assert!((zp.radius - z.radius).abs() < 1e-5 * z.radius);
}

#[test]
fn triangulated_zone_drops_a_mismatch_and_keeps_a_minimum_size() {
    let cams = small_baseline(10.0);
    let cv = |v: usize| CameraView {
        camera: &cams[v].0,
        pose: &cams[v].1,
    };
    let rho = 0.1;
    let mut matches = disc_matches(&cams, rho, 30);
    // A mismatch along the epipolar line: the view-1 point of something twice as far away.
    let far = DVec3::new(0.02, 4.0, 0.01);
    let m0 = project(&cams[0].0, &cams[0].1, far).unwrap();
    // Move along camera 0's ray to depth 8: same pixel in view 0, another pixel in view 1.
    let o = DVec3::from(cams[0].1.center());
    let d = (far - o).normalize();
    let wrong = o + 8.0 * d;
    let m1 = project(&cams[1].0, &cams[1].1, wrong).unwrap();
    matches.push((m0, m1));
    let s = ZoneSettings::default();
    let out = triangulated_zone(cv(0), cv(1), &matches, &s);
    let Some(Zone::Sphere(z)) = out.zone else {
        panic!("no zone")
    };
    assert_eq!(out.rejected, 1, "{out:?}");
    assert!(z.radius <= (1.0 + s.margin) * rho * 1.001, "{z:?}");

    // Two matches of almost the same point: the zone takes the floor of min_radius_px pixels
    // of view 0 at its depth (about 4 units, f = 500: 4 px ≈ 0.032).
    let p = DVec3::new(0.0, 0.0, 0.0);
    let q = DVec3::new(1e-6, 0.0, 0.0);
    let two: Vec<([f64; 2], [f64; 2])> = [p, q]
        .iter()
        .map(|x| {
            (
                project(&cams[0].0, &cams[0].1, *x).unwrap(),
                project(&cams[1].0, &cams[1].1, *x).unwrap(),
            )
        })
        .collect();
    let Some(Zone::Sphere(small)) = triangulated_zone(cv(0), cv(1), &two, &s).zone else {
        panic!()
    };
    let depth = cams[0].1.transform(small.center)[2];
    let floor = s.min_radius_px * depth / cams[0].0.fx.max(cams[0].0.fy);
    assert!(
        (small.radius - floor).abs() < 1e-9 * floor.max(1.0),
        "{} vs {floor}",
        small.radius
    );

    // The same camera twice: every ray pair is parallel, no point survives, no zone.
    let out = triangulated_zone(cv(0), cv(0), &two, &s);
    assert!(out.zone.is_none() && out.rejected == 2, "{out:?}");
    // Given boxes only, the triangulated geometry finds nothing (it needs the matches).
    let b = PixelBox {
        x0: 1.0,
        y0: 1.0,
        x1: 9.0,
        y1: 9.0,
    };
    assert!(zone_from_boxes(cv(0), &b, cv(1), &b, &s).zone.is_none());
}

#[test]
fn block_size_follows_the_image_size_unless_given() {
    let auto = RegionSettings::default();
    assert_eq!(auto.block, 0);
    assert_eq!(auto.resolved(1000, 1000).block, 16);
    assert_eq!(auto.resolved(1600, 1200).block, 22);
    assert_eq!(auto.resolved(979, 546).block, 12);
    assert_eq!(auto.resolved(800, 533).block, 10);
    assert_eq!(auto.resolved(162, 242).block, 4, "at least 4 px");
    let fixed = RegionSettings { block: 16, ..auto };
    assert_eq!(fixed.resolved(162, 242).block, 16);
    assert_eq!(fixed.resolved(162, 242).keep_fraction, auto.keep_fraction);
}

#[test]
fn authors_cone_radius_is_the_smallest_half_extent() {
    let z = Zone::Box {
        min: [0.0, 0.0, 0.0],
        max: [2.0, 0.5, 1.0],
    };
    let paper = ZoneRecord::with_cone(&z, [5.0, 0.0, 0.0], [0.0; 3], ConeRadius::Bounding);
    let authors = ZoneRecord::with_cone(
        &z,
        [5.0, 0.0, 0.0],
        [0.0; 3],
        ConeRadius::SmallestHalfExtent,
    );
    assert!((paper.cone_radius - paper.radius).abs() < 1e-7);
    assert_eq!(authors.cone_radius, 0.25);
    assert_eq!(authors.radius, paper.radius);
    let sphere = Zone::Sphere(lpmsplat::lpm::enclosing_sphere::Sphere {
        center: [0.0; 3],
        radius: 0.7,
    });
    let s = ZoneRecord::with_cone(
        &sphere,
        [5.0, 0.0, 0.0],
        [0.0; 3],
        ConeRadius::SmallestHalfExtent,
    );
    assert!((s.cone_radius - 0.7).abs() < 1e-7);
}

/// `--lpm-cone region`: the in-front cone is the view's cone through its error region's
/// circumcircle (the tangent of its half-angle read off the camera), never wider than the
/// bounding sphere, and "in front" still ends at the bounding sphere's near side, so a Gaussian
/// inside the zone is never reset as its own occluder while one beside the region's line of
/// sight is left alone.
#[test]
fn region_cone_follows_the_error_region_and_stops_at_the_zone() {
    use lpmsplat::lpm::record::region_tan_half_angle;
    use lpmsplat::reference::lpm_membership::ZoneTest;
    let cam = PinholeCamera {
        fx: 100.0,
        fy: 100.0,
        cx: 50.0,
        cy: 50.0,
        width: 100,
        height: 100,
    };
    let square = |x0: f64, y0: f64, side: f64| PixelBox {
        x0,
        y0,
        x1: x0 + side,
        y1: y0 + side,
    };
    // A 20×20 box on the principal point: circumradius 14.14 px, tan = 14.14 / 100.
    let t = region_tan_half_angle(&cam, &square(40.0, 40.0, 20.0));
    assert!((t - 200f64.sqrt() / 100.0).abs() < 1e-9, "{t}");
    // Off the axis the same box subtends a smaller angle (the rays spread out there).
    let tc = region_tan_half_angle(&cam, &square(80.0, 80.0, 20.0));
    assert!(tc < t && tc > 0.5 * t, "{tc} vs {t}");
    // A unit sphere 10 away from its camera along +z: the region cone of tan 0.05 has radius
    // 0.5 at the centre, the bounding cone 1.
    let z = Zone::Sphere(lpmsplat::lpm::enclosing_sphere::Sphere {
        center: [0.0, 0.0, 10.0],
        radius: 1.0,
    });
    let cam_at = [0.0, 0.0, 0.0];
    let bounding = ZoneRecord::with_cone(&z, cam_at, [0.0; 3], ConeRadius::Bounding);
    let region = ZoneRecord::with_cone(&z, cam_at, [0.0; 3], ConeRadius::Region).narrow_cone(0.05);
    assert_eq!(region.cone_radius, 0.5);
    assert_eq!(region.front_radius, 1.0);
    assert_eq!(bounding.front_radius, 1.0);
    // Never wider than the bounding sphere.
    let wide = ZoneRecord::with_cone(&z, cam_at, [0.0; 3], ConeRadius::Region).narrow_cone(0.5);
    assert_eq!(wide.cone_radius, 1.0);
    let (b, r) = (ZoneTest::new(&bounding), ZoneTest::new(&region));
    // On the axis, in front of the sphere: in front of both.
    assert!(b.in_front([0.0, 0.0, 5.0]) && r.in_front([0.0, 0.0, 5.0]));
    // 0.07 rad off the axis at depth 5 (tan 0.07 > 0.05, < 0.1): only the bounding cone's.
    assert!(b.in_front([0.35, 0.0, 5.0]) && !r.in_front([0.35, 0.0, 5.0]));
    // Inside the sphere, nearer than its centre: in front of neither (the sphere's near side
    // ends "in front" for both, not the narrower ball's).
    assert!(!b.in_front([0.0, 0.0, 9.3]) && !r.in_front([0.0, 0.0, 9.3]));
    assert!(r.contains([0.0, 0.0, 9.3]));
    // The authors' cone keeps its own depth: a ball of the smallest half-extent for both.
    let boxed = Zone::Box {
        min: [-1.0, -1.0, 9.0],
        max: [1.0, 1.0, 11.0],
    };
    let a = ZoneRecord::with_cone(&boxed, cam_at, [0.0; 3], ConeRadius::SmallestHalfExtent);
    assert_eq!((a.cone_radius, a.front_radius), (1.0, 1.0));
    assert!(ConeRadius::parse("region").is_ok());
    let e = ConeRadius::parse("narrow").unwrap_err().to_string();
    assert!(
        e.contains("bounding, smallest-half-extent or region"),
        "{e}"
    );
}

/// LPM's added points: isotropic 3D Gaussians, or surfels facing the camera whose error
/// created them (normal = the rotation's third column, towards that camera), with the unused
/// third log-scale; also when the camera is straight "below" (n = −e_z, the quaternion
/// formula's singular case).
#[test]
fn added_surfels_face_the_camera_that_asked_for_them() {
    use lpmsplat::lpm::strategy::{new_point_shape, NewGaussian};
    use lpmsplat::train::passes::surfels::UNUSED_LOG_SCALE;
    use lpmsplat::train::strategy::Primitive;
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut cases: Vec<([f32; 3], [f32; 3])> = (0..200)
        .map(|_| {
            (
                [0; 3].map(|_| rng.gen_range(-2.0..2.0)),
                [0; 3].map(|_| rng.gen_range(-5.0..5.0)),
            )
        })
        .collect();
    cases.push(([0.5, 0.5, 1.0], [0.5, 0.5, -3.0]));
    cases.push(([0.5, 0.5, 1.0], [0.5, 0.5, 4.0]));
    for (position, camera_center) in cases {
        let row = NewGaussian {
            position,
            scale: 0.03,
            color: [0.5; 3],
            opacity: 0.1,
            camera_center,
        };
        let (l, q) = new_point_shape(Primitive::Gaussian, &row);
        assert_eq!((l, q), ([0.03f32.ln(); 3], [1.0, 0.0, 0.0, 0.0]));
        let (l, q) = new_point_shape(Primitive::Surfel, &row);
        assert_eq!(l, [0.03f32.ln(), 0.03f32.ln(), UNUSED_LOG_SCALE]);
        let [w, x, y, z] = q.map(f64::from);
        assert!(((w * w + x * x + y * y + z * z) - 1.0).abs() < 1e-6);
        // Third column of the rotation matrix of a unit quaternion.
        let normal = [
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ];
        let d: Vec<f64> = (0..3)
            .map(|k| (camera_center[k] - position[k]) as f64)
            .collect();
        let len = d.iter().map(|v| v * v).sum::<f64>().sqrt();
        for k in 0..3 {
            assert!(
                (normal[k] - d[k] / len).abs() < 1e-5,
                "{position:?} → {camera_center:?}: normal {normal:?}"
            );
        }
    }
}

/// `--lpm-zone slab`: a region whose matches lie on two surfaces at different depths (a near
/// disc and one 2 units behind it). The triangulated sphere must be as wide as the two are
/// deep; the slab is V's cone through the region cut to the depths the matches span: it holds
/// both discs, not what lies beside the region's line of sight at those depths, and what lies
/// on that line nearer than the band is in front of it. The f32 test the GPU mirrors agrees
/// with the f64 definition, and the bounding sphere holds the slab.
#[test]
fn slab_zone_holds_what_is_drawn_over_the_region_at_the_matches_depths() {
    use lpmsplat::lpm::record::ZONE_SLAB;
    use lpmsplat::reference::lpm_membership::ZoneTest;
    let cams = small_baseline(10.0);
    let cv = |v: usize| CameraView {
        camera: &cams[v].0,
        pose: &cams[v].1,
    };
    // Two discs of radius 0.1 facing the cameras: one around the origin, one 2 units farther (+y).
    let mut rng = Pcg64::seed_from_u64(5);
    let mut disc = |y: f64| -> Vec<DVec3> {
        (0..20)
            .map(|_| {
                let (r, a): (f64, f64) = (0.1 * rng.gen::<f64>().sqrt(), rng.gen_range(0.0..6.3));
                DVec3::new(r * a.cos(), y, r * a.sin())
            })
            .collect()
    };
    let (near_pts, far_pts) = (disc(0.0), disc(2.0));
    let matches: Vec<([f64; 2], [f64; 2])> = near_pts
        .iter()
        .chain(&far_pts)
        .map(|p| {
            let m = [0, 1].map(|v| project(&cams[v].0, &cams[v].1, *p).unwrap());
            (m[0], m[1])
        })
        .collect();
    let (xy_v, xy_r) = f32_pixels(&matches);
    let region = region_around(&xy_v);
    let (pairs, _) = pair_regions(&[region], &xy_v, &xy_r);
    assert_eq!(pairs[0].matched.len(), 40);
    let s = ZoneSettings {
        geometry: ZoneGeometry::Slab,
        ..ZoneSettings::default()
    };
    let out = zone_for_pair(cv(0), cv(1), &pairs[0], &xy_v, &xy_r, &s);
    assert_eq!((out.points, out.rejected), (40, 0), "{out:?}");
    let Some(
        slab @ Zone::Slab {
            apex,
            center,
            tan_half_angle,
            half_depth,
        },
    ) = out.zone
    else {
        panic!("not a slab: {out:?}")
    };
    let o = DVec3::from(cams[0].1.center());
    assert!(DVec3::from(apex).distance(o) < 1e-12);
    // The band spans the matches' distances from V's centre, grown by the margin.
    let dist = |p: DVec3| p.distance(o);
    // (The matches are f32 pixels: the triangulated points are within a few 1e-4 of the true.)
    let d_near = near_pts.iter().copied().map(dist).fold(f64::MAX, f64::min);
    let d_far = far_pts.iter().copied().map(dist).fold(0.0, f64::max);
    let d = DVec3::from(center).distance(o);
    assert!(
        (d - 0.5 * (d_near + d_far)).abs() < 2e-3,
        "{d} vs {d_near}..{d_far}"
    );
    let want = 0.5 * (d_far - d_near) * (1.0 + s.margin);
    assert!((half_depth - want).abs() < 2e-3, "{half_depth} vs {want}");
    // The region's cone: the same half-angle as the in-front cone of the region.
    let b = &pairs[0].in_view;
    let t = lpmsplat::lpm::record::region_tan_half_angle(&cams[0].0, b);
    assert_eq!(tan_half_angle, t);

    let triangulated = zone_for_pair(
        cv(0),
        cv(1),
        &pairs[0],
        &xy_v,
        &xy_r,
        &ZoneSettings::default(),
    );
    let Some(Zone::Sphere(sphere)) = triangulated.zone else {
        panic!()
    };
    let rec = ZoneRecord::with_cone(&slab, o.to_array(), [0.0; 3], ConeRadius::Region);
    assert_eq!(rec.shape, ZONE_SLAB);
    let test = ZoneTest::new(&rec);
    let f = |p: DVec3| p.as_vec3().to_array();
    // Both discs are inside the slab.
    for &p in near_pts.iter().chain(&far_pts) {
        assert!(
            slab.contains(p.to_array(), 0.0) && test.contains(f(p)),
            "{p}"
        );
    }
    // Beside the line of sight at the middle depth: inside the sphere, not the slab.
    let axis = (DVec3::from(center) - o).normalize();
    let side = axis.cross(DVec3::Z).normalize();
    let beside = DVec3::from(center) + 0.4 * side;
    assert!(sphere.contains(beside.to_array(), 0.0));
    assert!(!slab.contains(beside.to_array(), 0.0) && !test.contains(f(beside)));
    // On the line of sight, half a unit nearer than the band: in front, not inside.
    let before = o + (d - half_depth - 0.5) * axis;
    assert!(test.in_front(f(before)) && !test.contains(f(before)));
    assert!(!test.in_front(f(DVec3::from(center))));

    // Random points: the f32 test agrees with the f64 definition away from the boundary, and
    // every point of the slab lies in its bounding sphere.
    let bound = slab.bounding_sphere();
    assert!((rec.radius as f64 - bound.radius).abs() < 1e-5 * bound.radius);
    let mut rng = Pcg64::seed_from_u64(6);
    let mut inside = 0;
    for _ in 0..20_000 {
        let p = o
            + axis * rng.gen_range(0.0..2.0 * d)
            + random_unit(&mut rng) * rng.gen_range(0.0..1.5);
        let v = p - o;
        let beyond = v.angle_between(axis) - tan_half_angle.atan();
        let band = (v.length() - d).abs() - half_depth;
        let want = beyond <= 0.0 && band <= 0.0;
        if beyond.abs() > 1e-4 && band.abs() > 1e-4 {
            assert_eq!(test.contains(f(p)), want, "{p}");
            assert_eq!(slab.contains(p.to_array(), 0.0), want, "{p}");
        }
        if want {
            inside += 1;
            assert!(bound.contains(p.to_array(), 1e-9), "{p} outside {bound:?}");
        }
    }
    assert!(inside > 100, "{inside}");
}

/// `--lpm-zone local`: the matches of a region lie on a surface running 4 units in depth. The
/// slab's band spans every depth; the local zone's is the 20–80 % quantiles of the distances,
/// each end moved out by 5 % of its distance: it holds the points inside that band and not the
/// nearest and farthest. A point seen at under 2° of parallax is not triangulated (the slab,
/// at 0.5°, takes it).
#[test]
fn local_zone_is_the_quantile_band_of_the_points_seen_with_parallax() {
    use lpmsplat::reference::lpm_membership::ZoneTest;
    let cams = small_baseline(10.0);
    let cv = |v: usize| CameraView {
        camera: &cams[v].0,
        pose: &cams[v].1,
    };
    let pts: Vec<DVec3> = (0..21)
        .map(|k| {
            let a = k as f64;
            DVec3::new(0.02 * a.sin(), -1.5 + a / 5.0, 0.02 * a.cos())
        })
        .collect();
    let pixels = |ps: &[DVec3]| {
        let m: Vec<([f64; 2], [f64; 2])> = ps
            .iter()
            .map(|p| {
                let m = [0, 1].map(|v| project(&cams[v].0, &cams[v].1, *p).unwrap());
                (m[0], m[1])
            })
            .collect();
        f32_pixels(&m)
    };
    let (xy_v, xy_r) = pixels(&pts);
    let region = region_around(&xy_v);
    let (pairs, _) = pair_regions(&[region], &xy_v, &xy_r);
    assert_eq!(pairs[0].matched.len(), 21);
    // A local zone's cone is the region's own box, and one match pairs it.
    let (whole, _) = pair_regions_whole(&[region], None, &xy_v, &xy_r);
    assert_eq!(whole[0].matched, pairs[0].matched);
    assert_eq!(
        (whole[0].in_view.x0, whole[0].in_view.x1),
        (region.x0 as f64, region.x1 as f64)
    );
    let local = ZoneSettings {
        geometry: ZoneGeometry::Local,
        ..ZoneSettings::default()
    };
    let slab_settings = ZoneSettings {
        geometry: ZoneGeometry::Slab,
        ..ZoneSettings::default()
    };
    let out = zone_for_pair(cv(0), cv(1), &whole[0], &xy_v, &xy_r, &local);
    assert_eq!((out.points, out.rejected), (21, 0), "{out:?}");
    let Some(
        zone @ Zone::Slab {
            center, half_depth, ..
        },
    ) = out.zone
    else {
        panic!("not a slab: {out:?}")
    };
    let o = DVec3::from(cams[0].1.center());
    let mut d: Vec<f64> = pts.iter().map(|p| p.distance(o)).collect();
    d.sort_by(|a, b| a.total_cmp(b));
    // Quantiles with linear interpolation over the 21 distances: positions 4 and 16.
    let (near, far) = (d[4] * 0.95, d[16] * 1.05);
    let dc = DVec3::from(center).distance(o);
    assert!(
        (dc - 0.5 * (near + far)).abs() < 2e-3,
        "{dc} vs {near}..{far}"
    );
    assert!(
        (half_depth - 0.5 * (far - near)).abs() < 2e-3,
        "{half_depth}"
    );
    let rec = ZoneRecord::with_cone(&zone, o.to_array(), [0.0; 3], ConeRadius::Region);
    let test = ZoneTest::new(&rec);
    let f = |p: DVec3| p.as_vec3().to_array();
    let (mut held, mut out_of_band) = (0, 0);
    for &p in &pts {
        let dp = p.distance(o);
        if dp > near + 5e-3 && dp < far - 5e-3 {
            assert!(
                zone.contains(p.to_array(), 0.0) && test.contains(f(p)),
                "{p}"
            );
            held += 1;
        } else if dp < near - 5e-3 || dp > far + 5e-3 {
            assert!(
                !zone.contains(p.to_array(), 0.0) && !test.contains(f(p)),
                "{p}"
            );
            out_of_band += 1;
        }
    }
    assert!(
        held >= 12 && out_of_band >= 2,
        "{held} held, {out_of_band} out"
    );
    // The slab of the same matches holds every point.
    let slab = zone_for_pair(cv(0), cv(1), &pairs[0], &xy_v, &xy_r, &slab_settings);
    let slab = slab.zone.unwrap();
    assert!(pts.iter().all(|p| slab.contains(p.to_array(), 0.0)));
    // One point alone: a band of ± 5 % around it (above the 4-pixel floor at this depth).
    let (xy1, xr1) = pixels(&pts[10..11]);
    assert!(
        pair_regions(&[region], &xy1, &xr1).0.is_empty(),
        "zero area"
    );
    let one = pair_regions_whole(&[region], None, &xy1, &xr1).0;
    let z = zone_for_pair(cv(0), cv(1), &one[0], &xy1, &xr1, &local);
    let Some(Zone::Slab { half_depth, .. }) = z.zone else {
        panic!("{z:?}")
    };
    let d10 = pts[10].distance(o);
    assert!(
        (half_depth - 0.05 * d10).abs() < 1e-3,
        "{half_depth} vs {}",
        0.05 * d10
    );
    // 60 units away the two rays meet at about 0.7 / 64 rad, 0.6°: no local zone; a slab.
    let (xyf, xrf) = pixels(&[DVec3::new(0.0, 60.0, 0.02)]);
    let image = Region {
        x0: 0,
        y0: 0,
        x1: 640,
        y1: 480,
    };
    let far_pair = pair_regions_whole(&[image], None, &xyf, &xrf).0;
    let z = zone_for_pair(cv(0), cv(1), &far_pair[0], &xyf, &xrf, &local);
    assert!(z.zone.is_none() && z.rejected == 1, "{z:?}");
    let z = zone_for_pair(cv(0), cv(1), &far_pair[0], &xyf, &xrf, &slab_settings);
    assert!(z.zone.is_some(), "{z:?}");
}

/// Local zones from the SfM points a view observes: every error block holding points gets the
/// slab of its own cone around their depths (no neighbour needed), a block without a point gets
/// none, and a block whose points' depths spread gets the quantile band, not the whole span.
#[test]
fn local_zones_take_their_depths_from_the_points_the_view_observes() {
    use lpmsplat::lpm::record::local_zones_for_step;
    // A long focal length, so the 4-pixel floor of a band (0.03 units here) does not bite.
    let cam = camera(64, 48, 600.0);
    let pose = look_at(DVec3::new(0.0, -4.0, 0.0), DVec3::ZERO);
    let v = view("v", cam, pose);
    let o = DVec3::from(pose.center());
    // Points on the ray through a pixel, at the given distances from the camera.
    let along = |u: f64, w: f64, d: &[f64]| -> Vec<(DVec3, [f32; 2])> {
        let ray = DVec3::from(pose.rotation[0]) * ((u - cam.cx) / cam.fx)
            + DVec3::from(pose.rotation[1]) * ((w - cam.cy) / cam.fy)
            + DVec3::from(pose.rotation[2]);
        d.iter()
            .map(|&t| (o + t * ray.normalize(), [u as f32, w as f32]))
            .collect()
    };
    // Block (0, 0) of 8 px: one point 4 units away; block (2, 1): eleven from 3 to 5 units.
    let spread: Vec<f64> = (0..11).map(|k| 3.0 + 0.2 * k as f64).collect();
    let pts: Vec<(DVec3, [f32; 2])> = along(3.5, 4.5, &[4.0])
        .into_iter()
        .chain(along(20.5, 12.5, &spread))
        .collect();
    let xy: Vec<[f32; 2]> = pts.iter().map(|p| p.1).collect();
    let world: Vec<[f64; 3]> = pts.iter().map(|p| p.0.to_array()).collect();
    let block = |bx: u32, by: u32| Region {
        x0: 8 * bx,
        y0: 8 * by,
        x1: 8 * bx + 8,
        y1: 8 * by + 8,
    };
    let regions = [block(0, 0), block(2, 1), block(5, 5)];
    let gt = Image {
        width: 64,
        height: 48,
        rgb: vec![0.5; 64 * 48 * 3],
        alpha: None,
    };
    let s = ZoneSettings {
        geometry: ZoneGeometry::Local,
        ..ZoneSettings::default()
    };
    let step = local_zones_for_step(&v, &regions, None, &xy, &world, &gt, [0.0; 3], &s);
    assert_eq!((step.pairing.paired, step.pairing.no_matches), (2, 1));
    assert_eq!(step.zones.len(), 2);
    let band = |z: &Zone| match *z {
        Zone::Slab {
            center, half_depth, ..
        } => {
            let d = DVec3::from(center).distance(o);
            (d - half_depth, d + half_depth)
        }
        _ => panic!("{z:?}"),
    };
    let (near, far) = band(&step.zones[0]);
    assert!(
        (near - 3.8).abs() < 1e-9 && (far - 4.2).abs() < 1e-9,
        "{near}..{far}"
    );
    // Eleven distances 3.0..5.0: quantiles 20 % and 80 % are 3.4 and 4.6.
    let (near, far) = band(&step.zones[1]);
    assert!((near - 3.4 * 0.95).abs() < 1e-9, "{near}");
    assert!((far - 4.6 * 1.05).abs() < 1e-9, "{far}");
    for (k, z) in step.zones.iter().enumerate() {
        let p = &pts[if k == 0 { 0 } else { 6 }].0;
        assert!(
            z.contains(p.to_array(), 1e-9),
            "zone {k} holds its middle point"
        );
    }
    // The nearest and farthest of the spread lie outside the band, on the same ray.
    assert!(!step.zones[1].contains(pts[1].0.to_array(), 0.0));
    assert!(!step.zones[1].contains(pts[11].0.to_array(), 0.0));
    assert_eq!(
        step.records[1].shape & 0xFF,
        lpmsplat::lpm::record::ZONE_SLAB
    );
}
