//! The CPU reference of the 2DGS (surfel) forward pass against independent computations: a
//! plain per-ray renderer written here in world space (ray–plane intersection, tangent-axis
//! coordinates, a sampled screen box), analytic planes and ellipses, numerical extremes, and
//! hand-computed median/expected depth and distortion.

use lpmsplat::reference::scenes::{look_at, random_view};
use lpmsplat::reference::sh;
use lpmsplat::reference::surfel::{
    self, random_surfels, RefSurfels, SurfelCull, SurfelRenderOutput, SurfelSettings, SurfelSkip,
};
use lpmsplat::scene::{PinholeCamera, Pose};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

type V3 = [f64; 3];

/// The near plane of the default settings (0.05 of the unit-extent training frame), which the
/// independent per-ray renderer below applies the same way.
const NEAR: f64 = 0.05;

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn mul(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `W v` for the pose's row-major rotation.
fn rot(pose: &Pose, v: V3) -> V3 {
    [0, 1, 2].map(|r| dot(pose.rotation[r], v))
}

/// `Wᵀ v`.
fn rot_t(pose: &Pose, v: V3) -> V3 {
    let w = &pose.rotation;
    [0, 1, 2].map(|c| w[0][c] * v[0] + w[1][c] * v[1] + w[2][c] * v[2])
}

/// Columns of the rotation of quaternion (w, x, y, z), normalised here; tiny ones are the
/// identity.
fn axes(q: [f64; 4]) -> [V3; 3] {
    let n2: f64 = q.iter().map(|v| v * v).sum();
    let [w, x, y, z] = if n2 < 1e-24 {
        [1.0, 0.0, 0.0, 0.0]
    } else {
        q.map(|v| v / n2.sqrt())
    };
    // The images of e_x, e_y, e_z under v ↦ q v q*.
    [
        [
            w * w + x * x - y * y - z * z,
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ],
        [
            2.0 * (x * y - w * z),
            w * w - x * x + y * y - z * z,
            2.0 * (y * z + w * x),
        ],
        [
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            w * w - x * x - y * y + z * z,
        ],
    ]
}

fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

fn logit(a: f64) -> f64 {
    (a / (1.0 - a)).ln()
}

fn pixel_of(camera: &PinholeCamera, c: V3) -> [f64; 2] {
    [
        camera.fx * c[0] / c[2] + camera.cx,
        camera.fy * c[1] / c[2] + camera.cy,
    ]
}

/// The extreme (`sign` = +1 max, −1 min) of `f` over the circle, by dense sampling then golden
/// section around the best sample (f is smooth with one maximum and one minimum).
fn circle_extreme(f: &dyn Fn(f64) -> f64, sign: f64) -> f64 {
    let n = 720;
    let step = std::f64::consts::TAU / n as f64;
    let best = (0..n)
        .map(|k| k as f64 * step)
        .max_by(|&a, &b| (sign * f(a)).total_cmp(&(sign * f(b))))
        .unwrap();
    let g = |t: f64| sign * f(t);
    let (mut lo, mut hi) = (best - step, best + step);
    let r = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..200 {
        let a = hi - r * (hi - lo);
        let b = lo + r * (hi - lo);
        if g(a) < g(b) {
            lo = a;
        } else {
            hi = b;
        }
    }
    f(0.5 * (lo + hi))
}

/// One surfel as the per-ray renderer sees it.
struct Brute {
    depth: f64,
    mu: V3,
    axes: [V3; 3],
    scale: [f64; 2],
    opacity: f64,
    rgb: V3,
    normal_cam: V3,
    center: [f64; 2],
    extent: [f64; 2],
    tile_min: [i64; 2],
    tile_max: [i64; 2],
}

/// Per-surfel setup without the transform matrix: the screen box is measured on the projected
/// 3σ circle (it must lie in front of the camera), the normal is flipped towards the camera.
fn brute_setup(
    s: &RefSurfels,
    i: usize,
    camera: &PinholeCamera,
    pose: &Pose,
    sh_degree: usize,
) -> Option<Brute> {
    let to_cam = |p: V3| add(rot(pose, p), pose.translation);
    let mu = s.positions[i];
    let t = to_cam(mu);
    if t[2] <= NEAR {
        return None;
    }
    let ax = axes(s.rotations[i]);
    let scale = s.log_scales[i].map(f64::exp);
    let mut n = rot(pose, ax[2]);
    let facing = dot(n, t);
    if facing == 0.0 {
        return None;
    }
    if facing > 0.0 {
        n = mul(n, -1.0);
    }
    let k = 3.0;
    let point = |th: f64| {
        let p = add(
            mu,
            add(
                mul(ax[0], k * scale[0] * th.cos()),
                mul(ax[1], k * scale[1] * th.sin()),
            ),
        );
        let c = to_cam(p);
        assert!(c[2] > 0.0, "the 3σ circle must lie in front of the camera");
        pixel_of(camera, c)
    };
    let mut center = [0.0; 2];
    let mut extent = [0.0; 2];
    for axis in 0..2 {
        let f = |th: f64| point(th)[axis];
        let (hi, lo) = (circle_extreme(&f, 1.0), circle_extreme(&f, -1.0));
        center[axis] = 0.5 * (hi + lo);
        extent[axis] = 0.5 * (hi - lo);
    }
    let radius = extent[0].max(extent[1]).max(3.0 / 2f64.sqrt()).ceil();
    let tile = 16.0;
    let (tiles_x, tiles_y) = (
        camera.width.div_ceil(16) as i64,
        camera.height.div_ceil(16) as i64,
    );
    let tile_min = [
        (((center[0] - radius) / tile).floor() as i64).clamp(0, tiles_x),
        (((center[1] - radius) / tile).floor() as i64).clamp(0, tiles_y),
    ];
    let tile_max = [
        (((center[0] + radius) / tile).ceil() as i64).clamp(0, tiles_x),
        (((center[1] + radius) / tile).ceil() as i64).clamp(0, tiles_y),
    ];
    let o = mul(rot_t(pose, pose.translation), -1.0);
    let dir = sub(mu, o);
    let dir = mul(dir, 1.0 / dot(dir, dir).sqrt());
    let raw = sh::eval(sh_degree, &s.sh[i], dir);
    Some(Brute {
        depth: t[2],
        mu,
        axes: ax,
        scale,
        opacity: sigmoid(s.opacity_logits[i]),
        rgb: raw.map(|v| (v + 0.5).max(0.0)),
        normal_cam: n,
        center,
        extent,
        tile_min,
        tile_max,
    })
}

#[derive(Debug, Clone, Copy, Default)]
struct BrutePixel {
    color: V3,
    alpha: f64,
    depth: f64,
    normal: V3,
    median: f64,
    median_contributor: u32,
    last_contributor: u32,
    distortion: f64,
}

/// Renders one pixel by intersecting its world-space ray with every surfel's plane.
fn brute_pixel(
    surfels: &[Option<Brute>],
    camera: &PinholeCamera,
    pose: &Pose,
    i: u32,
    j: u32,
    background: V3,
) -> BrutePixel {
    let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
    let (tx, ty) = ((i / 16) as i64, (j / 16) as i64);
    let origin = mul(rot_t(pose, pose.translation), -1.0);
    // Camera-space direction with z = 1, so the ray parameter is the camera depth.
    let dir = rot_t(
        pose,
        [
            (x - camera.cx) / camera.fx,
            (y - camera.cy) / camera.fy,
            1.0,
        ],
    );
    let mut list: Vec<usize> = (0..surfels.len())
        .filter(|&g| {
            surfels[g].as_ref().is_some_and(|b| {
                (b.tile_min[0]..b.tile_max[0]).contains(&tx)
                    && (b.tile_min[1]..b.tile_max[1]).contains(&ty)
            })
        })
        .collect();
    list.sort_by(|&a, &b| {
        let (da, db) = (surfels[a].as_ref().unwrap(), surfels[b].as_ref().unwrap());
        da.depth.total_cmp(&db.depth).then(a.cmp(&b))
    });
    let mut out = BrutePixel::default();
    let mut t = 1.0;
    let mut blended: Vec<(f64, f64)> = Vec::new(); // (weight, mapped depth)
    for (k, &g) in list.iter().enumerate() {
        let b = surfels[g].as_ref().unwrap();
        let nrm = b.axes[2];
        let denom = dot(nrm, dir);
        if denom == 0.0 {
            continue;
        }
        let z = dot(nrm, sub(b.mu, origin)) / denom;
        if !z.is_finite() || z < NEAR {
            continue;
        }
        let hit = add(origin, mul(dir, z));
        let local = sub(hit, b.mu);
        let u = dot(b.axes[0], local) / b.scale[0];
        let v = dot(b.axes[1], local) / b.scale[1];
        let rho3d = u * u + v * v;
        let rho2d = 2.0 * ((b.center[0] - x).powi(2) + (b.center[1] - y).powi(2));
        let alpha = (b.opacity * (-0.5 * rho3d.min(rho2d)).exp()).min(0.99);
        if alpha < 1.0 / 255.0 {
            continue;
        }
        if t * (1.0 - alpha) < 1e-4 {
            break;
        }
        let w = alpha * t;
        for ch in 0..3 {
            out.color[ch] += w * b.rgb[ch];
            out.normal[ch] += w * b.normal_cam[ch];
        }
        out.depth += w * z;
        if t > 0.5 {
            out.median = z;
            out.median_contributor = k as u32 + 1;
        }
        blended.push((w, 100.0 / (100.0 - NEAR) * (1.0 - NEAR / z)));
        t *= 1.0 - alpha;
        out.last_contributor = k as u32 + 1;
    }
    // The distortion as the plain double sum over pairs.
    for (a, &(wa, ma)) in blended.iter().enumerate() {
        for &(wb, mb) in &blended[..a] {
            out.distortion += wa * wb * (ma - mb) * (ma - mb);
        }
    }
    for (c, bg) in out.color.iter_mut().zip(background) {
        *c += t * bg;
    }
    out.alpha = 1.0 - t;
    out
}

fn render(s: &RefSurfels, camera: &PinholeCamera, pose: &Pose, sh: usize) -> SurfelRenderOutput {
    surfel::render(
        s,
        camera,
        pose,
        sh,
        [0.2, 0.1, 0.3],
        &SurfelSettings::default(),
    )
    .unwrap()
}

fn all_finite(out: &SurfelRenderOutput) -> bool {
    let r = &out.raster;
    r.image.iter().flatten().all(|v| v.is_finite())
        && r.normal.iter().flatten().all(|v| v.is_finite())
        && r.alpha
            .iter()
            .chain(&r.depth)
            .chain(&r.median_depth)
            .chain(&r.distortion)
            .chain(&r.m1)
            .chain(&r.m2)
            .all(|v| v.is_finite())
}

fn camera(w: u32, h: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> PinholeCamera {
    PinholeCamera {
        fx,
        fy,
        cx,
        cy,
        width: w,
        height: h,
    }
}

fn one(pos: V3, log_scale: [f64; 2], q: [f64; 4], logit: f64) -> RefSurfels {
    let mut s = RefSurfels::default();
    s.push(pos, log_scale, q, logit, [0.4, 0.1, -0.2]);
    s
}

/// Tolerance of the cross-check: both sides are exact formulas in f64 whose differences are
/// rounding (about 1e-14 here); the box centre of the per-ray side is found by golden section
/// to ~1e-14 px, which enters only through the low-pass term.
const TOL: f64 = 1e-9;

#[test]
fn matches_a_plain_per_ray_renderer_on_random_scenes() {
    let mut lowpass_hits = 0;
    let mut max_err = 0.0f64;
    let mut max_box = 0.0f64;
    let mut object_hits = 0;
    let mut multi = 0;
    for seed in 0..8u64 {
        let mut rng = Pcg64::seed_from_u64(100 + seed);
        let s = random_surfels(&mut rng, 40);
        let (cam, pose) = random_view(&mut rng, 40, 30);
        let sh_degree = rng.gen_range(0..=3);
        let bg = [0.2, 0.1, 0.3];
        let out = render(&s, &cam, &pose, sh_degree);
        let brute: Vec<Option<Brute>> = (0..s.len())
            .map(|i| brute_setup(&s, i, &cam, &pose, sh_degree))
            .collect();
        // Per surfel: the same culling, box, radius, normal and colour.
        for (i, (p, b)) in out.projected.iter().zip(&brute).enumerate() {
            assert_eq!(p.culled(), b.is_none(), "seed {seed} surfel {i}");
            let Some(b) = b else { continue };
            for k in 0..2 {
                assert!(
                    (p.center2d[k] - b.center[k]).abs() < TOL,
                    "seed {seed} surfel {i}: box centre {:?} vs sampled {:?}",
                    p.center2d,
                    b.center
                );
                assert!((p.extent[k] - b.extent[k]).abs() < TOL);
                max_box = max_box.max((p.center2d[k] - b.center[k]).abs());
                max_box = max_box.max((p.extent[k] - b.extent[k]).abs());
            }
            assert!(p.box_denominator < 0.0);
            assert_eq!(
                [p.tile_min, p.tile_max].map(|t| t.map(i64::from)),
                [b.tile_min, b.tile_max]
            );
            for k in 0..3 {
                assert!((p.normal[k] - b.normal_cam[k]).abs() < 1e-14);
                assert!((p.rgb[k] - b.rgb[k]).abs() < 1e-14);
            }
        }
        let r = &out.raster;
        for j in 0..cam.height {
            for i in 0..cam.width {
                let pix = (j * cam.width + i) as usize;
                let e = brute_pixel(&brute, &cam, &pose, i, j, bg);
                let ctx = format!("seed {seed} pixel ({i}, {j})");
                let mut close = |a: f64, b: f64, what: &str| {
                    let err = (a - b).abs();
                    assert!(err < TOL, "{ctx} {what}: {a} vs {b}");
                    max_err = max_err.max(err);
                };
                for ch in 0..3 {
                    close(r.image[pix][ch], e.color[ch], "colour");
                    close(r.normal[pix][ch], e.normal[ch], "normal");
                }
                close(r.alpha[pix], e.alpha, "alpha");
                close(r.depth[pix], e.depth, "depth");
                close(r.median_depth[pix], e.median, "median depth");
                close(r.distortion[pix], e.distortion, "distortion");
                assert_eq!(r.last_contributor[pix], e.last_contributor, "{ctx}");
                assert_eq!(r.median_contributor[pix], e.median_contributor, "{ctx}");
                if r.contributors[pix] > 1 {
                    multi += 1;
                }
                // Which branch of the kernel the contributing hits took.
                let list = &out.bins.lists[out.bins.tile_of_pixel(i, j)];
                for &g in &list[..r.last_contributor[pix] as usize] {
                    let p = &out.projected[g as usize];
                    let st = SurfelSettings::default();
                    if let Ok(smp) = surfel::sample_surfel(p, i as f64 + 0.5, j as f64 + 0.5, &st) {
                        if smp.lowpass {
                            lowpass_hits += 1;
                        } else {
                            object_hits += 1;
                        }
                    }
                }
            }
        }
    }
    // The scenes exercise both kernel branches and real compositing.
    println!(
        "largest difference {max_err:e} (box {max_box:e} px); hits: {lowpass_hits} low-pass, {object_hits} \
         object-space; {multi} pixels with several contributors"
    );
    assert!(lowpass_hits > 20, "low-pass hits: {lowpass_hits}");
    assert!(object_hits > 1000, "object-space hits: {object_hits}");
    assert!(multi > 500, "pixels with several contributors: {multi}");
}

#[test]
fn fronto_parallel_plane_has_its_depth_normal_and_full_alpha() {
    let cam = camera(40, 30, 30.0, 33.0, 18.3, 13.7);
    let d = 3.0;
    // Scale 2 (3σ = 6 world units at depth 3): the plane fills the image.
    let s = one(
        [0.1, -0.05, d],
        [2f64.ln(), 2f64.ln()],
        [1.0, 0.0, 0.0, 0.0],
        10.0,
    );
    let out = render(&s, &cam, &Pose::IDENTITY, 0);
    let r = &out.raster;
    for pix in 0..r.alpha.len() {
        assert!(r.alpha[pix] > 0.0, "pixel {pix} not covered");
        assert!((r.depth[pix] / r.alpha[pix] - d).abs() < 1e-12);
        assert!((r.expected_depth()[pix] - d).abs() < 1e-12);
        assert_eq!(r.median_depth[pix], d);
        let n = r.normal[pix].map(|v| v / r.alpha[pix]);
        assert!(n[0].abs() < 1e-15 && n[1].abs() < 1e-15 && (n[2] + 1.0).abs() < 1e-12);
        assert_eq!(r.distortion[pix], 0.0);
    }
    // The centre projects to (cx + 30·0.1/3, cy − 33·0.05/3) = (19.3, 13.15): pixel (19, 13)
    // has its centre 0.4 px away, about 0.04 world units, u² + v² ≈ 4e-4: G ≈ 1, alpha at its
    // 0.99 clamp.
    let centre = 13 * 40 + 19;
    assert_eq!(r.alpha[centre], 0.99);
    let smp =
        surfel::sample_surfel(&out.projected[0], 19.5, 13.5, &SurfelSettings::default()).unwrap();
    assert!(smp.alpha_clamped);
}

#[test]
fn tilted_plane_has_the_analytic_ray_plane_depth() {
    let cam = camera(40, 30, 30.0, 32.0, 21.7, 14.2);
    // 45° about the camera y axis: normal (sin 45°, 0, cos 45°), the plane through (0, 0, 3):
    // the ray (x̂, ŷ, 1)·z meets it at z = 3 / (1 + x̂).
    let h = std::f64::consts::FRAC_PI_8;
    let s = one(
        [0.0, 0.0, 3.0],
        [0.0, 0.0],
        [h.cos(), 0.0, h.sin(), 0.0],
        8.0,
    );
    let out = render(&s, &cam, &Pose::IDENTITY, 0);
    let p = &out.projected[0];
    assert!(p.cull.is_none() && p.box_denominator < 0.0);
    let r = &out.raster;
    let mut covered = 0;
    for j in 0..cam.height {
        for i in 0..cam.width {
            let pix = (j * cam.width + i) as usize;
            if r.alpha[pix] == 0.0 {
                continue;
            }
            covered += 1;
            let xh = (i as f64 + 0.5 - cam.cx) / cam.fx;
            let z = 3.0 / (1.0 + xh);
            let got = r.depth[pix] / r.alpha[pix];
            assert!(
                (got - z).abs() < 1e-12 * z,
                "pixel ({i}, {j}): {got} vs {z}"
            );
            assert!((r.median_depth[pix] - z).abs() < 1e-12 * z);
            let n = r.normal[pix].map(|v| v / r.alpha[pix]);
            let c = std::f64::consts::FRAC_1_SQRT_2;
            for (k, want) in [-c, 0.0, -c].into_iter().enumerate() {
                assert!((n[k] - want).abs() < 1e-12, "normal {n:?}");
            }
        }
    }
    assert!(covered > 600, "covered {covered} of 1200");
    // The image centre row near the surfel centre is opaque.
    let centre = 14 * 40 + 21;
    assert_eq!(r.alpha[centre], 0.99);
}

#[test]
fn fronto_parallel_footprint_is_the_analytic_ellipse() {
    let cam = camera(40, 30, 36.0, 30.0, 19.1, 16.4);
    let (d, mu) = (2.5, [0.12, -0.07]);
    let (su, sv) = (0.6f64, 0.35f64);
    let phi = 0.7f64; // rotation about the optical axis
    let q = [(phi / 2.0).cos(), 0.0, 0.0, (phi / 2.0).sin()];
    let s = one([mu[0], mu[1], d], [su.ln(), sv.ln()], q, 0.0);
    let out = render(&s, &cam, &Pose::IDENTITY, 0);
    let p = &out.projected[0];
    // Analytic image of the disk: x = c0 + A (u, v), A = diag(fx, fy)/d · R(φ) · diag(su, sv).
    let c0 = [cam.fx * mu[0] / d + cam.cx, cam.fy * mu[1] / d + cam.cy];
    let (c, sn) = (phi.cos(), phi.sin());
    let a = [
        [cam.fx / d * c * su, -cam.fx / d * sn * sv],
        [cam.fy / d * sn * su, cam.fy / d * c * sv],
    ];
    let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    let st = SurfelSettings::default();
    let (mut inside, mut agree) = (0, 0);
    for j in 0..cam.height {
        for i in 0..cam.width {
            let (x, y) = (i as f64 + 0.5 - c0[0], j as f64 + 0.5 - c0[1]);
            let u = (a[1][1] * x - a[0][1] * y) / det;
            let v = (-a[1][0] * x + a[0][0] * y) / det;
            let analytic = u * u + v * v;
            let smp = surfel::sample_surfel(p, i as f64 + 0.5, j as f64 + 0.5, &st);
            let rho3d = match smp {
                Ok(smp) => smp.rho3d,
                Err(SurfelSkip::Faint) => f64::INFINITY,
                Err(e) => panic!("unexpected skip {e:?}"),
            };
            if analytic < 1.0 {
                inside += 1;
                assert!((rho3d - analytic).abs() < 1e-12, "{rho3d} vs {analytic}");
            }
            if (analytic < 1.0) == (rho3d < 1.0) {
                agree += 1;
            }
        }
    }
    assert_eq!(agree, 1200);
    // Sanity of the count: the ellipse area π·|det A| ≈ 114 px².
    let area = std::f64::consts::PI * det.abs();
    assert!(
        (inside as f64 - area).abs() < 0.15 * area,
        "{inside} vs {area}"
    );
}

#[test]
fn edge_on_surfels_give_finite_outputs() {
    // Camera at the origin looking along world +x (a permutation matrix: exact), principal
    // point on a pixel-centre row, so the row y = 15.5 sees the surfel plane y_cam = ε exactly
    // parallel.
    let cam = camera(40, 30, 40.0, 40.0, 20.3, 15.5);
    let side = Pose {
        rotation: [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
        translation: [0.0; 3],
    };
    let st = SurfelSettings::default();
    let identity = [1.0, 0.0, 0.0, 0.0];
    // World plane z = 0 through the camera centre: culled exactly edge-on in preprocess.
    let out = render(
        &one([2.0, 0.3, 0.0], [-1.0, -1.0], identity, 3.0),
        &cam,
        &side,
        0,
    );
    assert_eq!(out.projected[0].cull, Some(SurfelCull::EdgeOn));
    assert!(out.raster.alpha.iter().all(|&a| a == 0.0));
    // Nearly edge-on: the plane z = ε (camera y = ε).
    for eps in [1e-300, 1e-12, 1e-6, 1e-3, 0.05] {
        let s = one([2.0, 0.3, eps], [-1.0, -1.0], identity, 3.0);
        let out = render(&s, &cam, &side, 0);
        let p = &out.projected[0];
        assert!(p.cull.is_none(), "ε = {eps}");
        assert!(all_finite(&out), "ε = {eps}");
        let mut reasons = std::collections::BTreeMap::new();
        for j in 0..cam.height {
            for i in 0..cam.width {
                let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                let key = match surfel::sample_surfel(p, x, y, &st) {
                    Ok(_) => "hit".to_string(),
                    Err(e) => format!("{e:?}"),
                };
                *reasons.entry(key).or_insert(0) += 1;
                let pix = (j * cam.width + i) as usize;
                if j == 15 {
                    // The ray is parallel to the plane: the p₃ == 0 guard.
                    assert_eq!(
                        surfel::sample_surfel(p, x, y, &st).unwrap_err(),
                        SurfelSkip::Parallel
                    );
                }
                let a = out.raster.alpha[pix];
                if a > 0.0 {
                    // The depth stays the ray–plane hit ε / ŷ even where the low-pass filter
                    // carries the splat.
                    let z = eps * cam.fy / (y - cam.cy);
                    let got = out.raster.depth[pix] / a;
                    assert!((got - z).abs() < 1e-12 * z, "ε = {eps}: {got} vs {z}");
                }
            }
        }
        println!("ε = {eps}: {reasons:?}");
        assert_eq!(reasons.get("Parallel"), Some(&40));
        if eps <= 1e-3 {
            // Every non-parallel ray meets the plane behind the camera or closer than near.
            assert_eq!(reasons.get("Near"), Some(&1160), "ε = {eps}");
        } else if eps == 0.05 {
            assert!(reasons.get("hit").is_some_and(|&n| n > 0));
        }
    }
    // A generic camera and surfel planes tilted δ away from holding the camera centre.
    let mut rng = Pcg64::seed_from_u64(5);
    for delta in [0.0f64, 1e-15, 1e-10, 1e-5, 1e-2] {
        for _ in 0..5 {
            let (cam, pose) = random_view(&mut rng, 40, 30);
            let o = pose.center();
            let mu: V3 = [0; 3].map(|_| rng.gen_range(-0.3..0.3));
            // r1 = a direction across the view, r2 = the view direction tilted by δ about r1,
            // so the normal r3 = r1 × r2 is δ away from perpendicular to the view direction.
            let view = sub(mu, o);
            let view = mul(view, 1.0 / dot(view, view).sqrt());
            let up = rot_t(&pose, [0.0, 1.0, 0.0]);
            let r1 = sub(up, mul(view, dot(up, view)));
            let r1 = mul(r1, 1.0 / dot(r1, r1).sqrt());
            let r3 = cross(r1, view);
            let r2 = add(mul(view, delta.cos()), mul(r3, delta.sin()));
            let q = quat_from_axes(r1, r2, cross(r1, r2));
            let s = one(mu, [-1.2, -1.5], q, 2.0);
            let out = render(&s, &cam, &pose, 2);
            assert!(all_finite(&out), "δ = {delta}");
        }
    }
}

fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The quaternion (w, x, y, z) of the rotation with columns `c1, c2, c3`.
fn quat_from_axes(c1: V3, c2: V3, c3: V3) -> [f64; 4] {
    lpmsplat::reference::project::rotation_to_quat(&[
        [c1[0], c2[0], c3[0]],
        [c1[1], c2[1], c3[1]],
        [c1[2], c2[2], c3[2]],
    ])
}

#[test]
fn quat_from_axes_round_trips() {
    let mut rng = Pcg64::seed_from_u64(3);
    for _ in 0..50 {
        let q: [f64; 4] = [0; 4].map(|_| rng.gen_range(-1.0..1.0));
        round_trip(q);
    }
    // Every branch of Shepperd's method: half turns about x, y and z (trace −1) and near them.
    for q in [
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
        [0.05, 0.3, 0.2, 0.9],
    ] {
        round_trip(q);
    }
}

/// The axes of `q` back through [`quat_from_axes`] (the library's `rotation_to_quat`).
fn round_trip(q: [f64; 4]) {
    let [c1, c2, c3] = axes(q);
    let back = axes(quat_from_axes(c1, c2, c3));
    for (a, b) in back.iter().zip([c1, c2, c3]) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() < 1e-12, "{q:?}");
        }
    }
}

#[test]
fn behind_the_camera_is_culled() {
    let cam = camera(40, 30, 40.0, 40.0, 20.3, 15.1);
    let q = [0.9, 0.1, -0.2, 0.3];
    for (z, culled) in [
        (-1.0, true),
        (0.0, true),
        (NEAR, true),
        (NEAR + 1e-9, false),
    ] {
        let out = render(
            &one([0.0, 0.0, z], [-2.0, -2.0], q, 1.0),
            &cam,
            &Pose::IDENTITY,
            0,
        );
        let p = &out.projected[0];
        assert_eq!(p.cull == Some(SurfelCull::Near), culled, "z = {z}");
        assert!(all_finite(&out));
        if culled {
            assert!(out.raster.alpha.iter().all(|&a| a == 0.0));
            assert_eq!(p.tiles_touched(), 0);
        }
    }
    // A large surfel whose centre is behind the camera is culled even where its plane would
    // be in front (the cull is on the centre only).
    let out = render(
        &one([0.0, 0.0, -0.5], [1.0, 1.0], q, 1.0),
        &cam,
        &Pose::IDENTITY,
        0,
    );
    assert!(out.raster.alpha.iter().all(|&a| a == 0.0));
}

#[test]
fn degenerate_quaternions_read_as_identity() {
    let mut rng = Pcg64::seed_from_u64(9);
    let (cam, pose) = random_view(&mut rng, 40, 30);
    let render_q = |q: [f64; 4]| {
        let mut s = random_surfels(&mut Pcg64::seed_from_u64(4), 12);
        for r in &mut s.rotations {
            *r = q;
        }
        render(&s, &cam, &pose, 1)
    };
    let identity = render_q([1.0, 0.0, 0.0, 0.0]);
    assert!(identity.raster.alpha.iter().any(|&a| a > 0.1));
    for q in [
        [0.0; 4],
        [1e-300, 0.0, 0.0, 0.0],
        [5e-324, 5e-324, 0.0, 5e-324],
        [1e-13, 0.0, 0.0, 0.0],
    ] {
        let out = render_q(q);
        assert_eq!(out.raster, identity.raster, "q = {q:?}");
        assert!(all_finite(&out));
    }
}

#[test]
fn huge_and_tiny_scales_stay_finite() {
    let mut rng = Pcg64::seed_from_u64(11);
    let (cam, pose) = random_view(&mut rng, 40, 30);
    for l in [
        -800.0, -400.0, -300.0, -100.0, -30.0, -10.0, 10.0, 30.0, 100.0, 300.0, 400.0, 800.0,
    ] {
        let mut s = random_surfels(&mut Pcg64::seed_from_u64(12), 10);
        for (k, ls) in s.log_scales.iter_mut().enumerate() {
            // Both axes extreme, or one extreme and one ordinary.
            *ls = if k % 2 == 0 { [l, l] } else { [l, -2.0] };
        }
        let out = render(&s, &cam, &pose, 3);
        assert!(all_finite(&out), "log-scale {l}");
        let culls: Vec<_> = out.projected.iter().map(|p| p.cull).collect();
        let hits = out.raster.contributors.iter().filter(|&&c| c > 0).count();
        println!("log-scale {l}: culls {culls:?}, pixels hit {hits}");
        if l >= 400.0 {
            // M overflows (l = 800: s = inf) or its squares in the box denominator do
            // (l = 400: d = inf): culled in preprocess.
            assert!(culls.iter().all(|&c| c == Some(SurfelCull::NonFinite)));
        } else {
            assert!(culls.iter().all(Option::is_none));
        }
        if l == -800.0 {
            // s_u = 0: a column of M is exactly 0, so p₃ = 0 at every pixel (the guard).
            assert_eq!(hits, 0);
        } else if l < 400.0 {
            assert!(hits > 0);
        }
    }
}

#[test]
fn median_and_expected_depth_of_two_stacked_surfels() {
    // Both centres on the ray of pixel (20, 15): (u, v) = (0, 0) exactly there, G = 1, so the
    // alphas are the opacities.
    let cam = camera(40, 30, 40.0, 42.0, 20.5, 15.5);
    let pix = 15 * 40 + 20;
    let st = SurfelSettings::default();
    let m = |z: f64| 100.0 / (100.0 - NEAR) * (1.0 - NEAR / z);
    for (a1, a2, median) in [
        (0.3, 0.6, 3.0), // T before the second = 0.7 > 0.5
        (0.6, 0.3, 2.0), // T before the second = 0.4
        (0.5, 0.8, 2.0), // T before the second = 0.5 exactly: not > 0.5
        (0.2, 0.9, 3.0),
    ] {
        let mut s = RefSurfels::default();
        // Given in back-to-front order: the sort must put depth 2 first.
        s.push(
            [0.0, 0.0, 3.0],
            [0.5f64.ln(); 2],
            [1.0, 0.0, 0.0, 0.0],
            logit(a2),
            [0.0, 1.0, 0.0],
        );
        s.push(
            [0.0, 0.0, 2.0],
            [0.5f64.ln(); 2],
            [1.0, 0.0, 0.0, 0.0],
            logit(a1),
            [1.0, 0.0, 0.0],
        );
        let out = surfel::render(&s, &cam, &Pose::IDENTITY, 0, [0.0; 3], &st).unwrap();
        let r = &out.raster;
        assert_eq!(out.bins.lists[out.bins.tile_of_pixel(20, 15)], [1, 0]);
        let (w1, w2) = (a1, (1.0 - a1) * a2);
        let alpha = 1.0 - (1.0 - a1) * (1.0 - a2);
        let expected = (2.0 * w1 + 3.0 * w2) / alpha;
        let tol = 1e-12;
        assert!((r.alpha[pix] - alpha).abs() < tol);
        assert!((r.depth[pix] - (2.0 * w1 + 3.0 * w2)).abs() < tol);
        assert!((r.expected_depth()[pix] - expected).abs() < tol);
        assert_eq!(r.median_depth[pix], median, "α = ({a1}, {a2})");
        assert_eq!(r.median_contributor[pix], if median == 2.0 { 1 } else { 2 });
        assert_eq!(r.last_contributor[pix], 2);
        let surf = r.surface_depth(0.25)[pix];
        assert!((surf - (0.75 * expected + 0.25 * median)).abs() < tol);
        let dist = w1 * w2 * (m(2.0) - m(3.0)).powi(2);
        assert!(
            (r.distortion[pix] - dist).abs() < tol,
            "{} vs {dist}",
            r.distortion[pix]
        );
        assert!((r.m1[pix] - (w1 * m(2.0) + w2 * m(3.0))).abs() < tol);
        assert!((r.m2[pix] - (w1 * m(2.0).powi(2) + w2 * m(3.0).powi(2))).abs() < tol);
        // Colour: SH DC c gives c·C0 + 0.5 per channel.
        let c = |dc: f64| dc * sh::SH_C0 + 0.5;
        let want = [0, 1, 2].map(|ch| {
            let (d1, d2) = ([1.0, 0.0, 0.0][ch], [0.0, 1.0, 0.0][ch]);
            w1 * c(d1) + w2 * c(d2)
        });
        for (got, want) in r.image[pix].iter().zip(want) {
            assert!((got - want).abs() < tol);
        }
        // The world normal of an identity pose is the camera one, facing the camera.
        let n = r.world_normals(&Pose::IDENTITY)[pix];
        assert!((n[2] + alpha).abs() < tol);
    }
}

#[test]
fn look_at_scene_renders_like_the_identity_pose_moved() {
    // Moving the camera and the surfels by the same rigid motion leaves every output but the
    // world normals unchanged (up to rounding).
    let mut rng = Pcg64::seed_from_u64(21);
    let s = random_surfels(&mut rng, 30);
    let cam = camera(40, 30, 44.0, 46.0, 18.9, 16.2);
    let pose = look_at([0.5, -0.4, -4.0], [0.0; 3], [0.0, -1.0, 0.0]);
    let moved = {
        let mut m = s.clone();
        for p in &mut m.positions {
            *p = add(rot(&pose, *p), pose.translation);
        }
        // Left-multiply every rotation by W: q ← q_W ⊗ q.
        let [c1, c2, c3] = [0, 1, 2].map(|k| pose.rotation.map(|row| row[k]));
        let qw = quat_from_axes(c1, c2, c3);
        for q in &mut m.rotations {
            *q = qmul(qw, *q);
        }
        m
    };
    // Only SH degree 0: the view directions are the same, but higher bands are expressed in
    // world axes, which the motion changes.
    let a = render(&s, &cam, &pose, 0);
    let b = render(&moved, &cam, &Pose::IDENTITY, 0);
    let (ra, rb) = (&a.raster, &b.raster);
    assert_eq!(ra.last_contributor, rb.last_contributor);
    for pix in 0..ra.alpha.len() {
        for ch in 0..3 {
            assert!((ra.image[pix][ch] - rb.image[pix][ch]).abs() < 1e-9);
            assert!((ra.normal[pix][ch] - rb.normal[pix][ch]).abs() < 1e-9);
        }
        assert!((ra.depth[pix] - rb.depth[pix]).abs() < 1e-9);
        assert!((ra.distortion[pix] - rb.distortion[pix]).abs() < 1e-9);
    }
}

/// Hamilton product of quaternions (w, x, y, z).
fn qmul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}
