//! LPM's GPU passes against their CPU twins on random inputs, validation on: zone membership and
//! per-zone counts (exact), the opacity reset (exact), error blocks (exact given the GPU's error
//! map, and within the f32-vs-f64 error-map tolerance against regions.rs).

use crate::child_run;

use lpmsplat::gpu::{BufferKind, GpuBuffer, GpuContext, GpuOptions, Recorder};
use lpmsplat::lpm::enclosing_sphere::Sphere;
use lpmsplat::lpm::gpu::{
    block_grid, error_block_counts, unpack_ground_truth, ErrorImages, FilteredOpacity, LpmGpu,
};
use lpmsplat::lpm::record::{ZONE_NO_RESET, ZONE_SLAB};
use lpmsplat::lpm::regions::{block_mask, error_map, quantile, BlockMask};
use lpmsplat::lpm::reset_settings::{
    OpacityResetSettings, FLAG_INSIDE, FLAG_IN_BALL, FLAG_IN_FRONT,
};
use lpmsplat::lpm::{ConeRadius, RegionSettings, Zone, ZoneRecord};
use lpmsplat::reference::lpm_membership::{apply_opacity_reset, membership, ZoneTest};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::sync::Arc;

const POISON: u32 = 0xDEAD_BEEF;
const TAIL: usize = 7;

fn ctx() -> Arc<GpuContext> {
    GpuContext::new(&GpuOptions::for_tests()).expect("a Vulkan device with the validation layer")
}

fn v3(rng: &mut Pcg64, lo: f64, hi: f64) -> [f64; 3] {
    [
        rng.gen_range(lo..hi),
        rng.gen_range(lo..hi),
        rng.gen_range(lo..hi),
    ]
}

fn f32s(v: [f64; 3]) -> [f32; 3] {
    v.map(|x| x as f32)
}

fn sphere(center: [f64; 3], radius: f64, cam: [f64; 3]) -> ZoneRecord {
    ZoneRecord::new(&Zone::Sphere(Sphere { center, radius }), cam, [0.5; 3])
}

/// Zones of every kind the membership pass must handle.
fn random_zones(rng: &mut Pcg64, n: usize) -> Vec<ZoneRecord> {
    let mut zones = vec![
        // Dyadic values: the boundary points below are exactly on the sphere / box.
        sphere([0.5, 0.25, -0.75], 0.5, [4.0, 0.25, -0.75]),
        // The authors' cone: its ball (radius 0.5) leaves the box's corners out.
        ZoneRecord::with_cone(
            &Zone::Box {
                min: [-1.5, -0.5, 0.25],
                max: [-0.5, 0.5, 1.25],
            },
            [-1.0, 0.0, 5.0],
            [0.1; 3],
            ConeRadius::SmallestHalfExtent,
        ),
        // Camera inside its zone (h < r), camera at the centre (h = 0), zero radius.
        sphere([0.0, 0.0, 0.0], 1.5, [0.3, -0.2, 0.1]),
        sphere([1.0, 1.0, 1.0], 0.7, [1.0, 1.0, 1.0]),
        sphere([-1.0, 1.0, 0.5], 0.0, [-1.0, 4.0, 0.5]),
    ];
    while zones.len() < n {
        let c = v3(rng, -2.0, 2.0);
        let dir = v3(rng, -1.0, 1.0);
        let dist = rng.gen_range(0.5..6.0);
        let cam = [
            c[0] + dist * dir[0],
            c[1] + dist * dir[1],
            c[2] + dist * dir[2],
        ];
        let r = match rng.gen_range(0..10) {
            0 => 0.0,
            1 => rng.gen_range(1.0..3.0), // often contains its camera
            _ => rng.gen_range(0.05..0.9),
        };
        if rng.gen_bool(0.3) {
            let h = v3(rng, 0.0, 0.6);
            let z = Zone::Box {
                min: [c[0] - h[0], c[1] - h[1], c[2] - h[2]],
                max: [c[0] + h[0], c[1] + h[1], c[2] + h[2]],
            };
            // Half the boxes take the authors' cone (smallest half-extent), which also makes
            // FLAG_IN_BALL differ from FLAG_INSIDE.
            let cone = if rng.gen_bool(0.5) {
                ConeRadius::SmallestHalfExtent
            } else {
                ConeRadius::Bounding
            };
            zones.push(ZoneRecord::with_cone(&z, cam, [0.2; 3], cone));
        } else if rng.gen_bool(0.25) {
            // A slab: the view's cone through its region cut to a band of distances; a band
            // deeper than the camera's distance reaches the apex.
            let half_depth = if rng.gen_bool(0.15) {
                dist * 1.2
            } else {
                rng.gen_range(0.02..1.0)
            };
            let z = Zone::Slab {
                apex: cam,
                center: c,
                tan_half_angle: rng.gen_range(0.01..0.4),
                half_depth,
            };
            zones.push(ZoneRecord::with_cone(&z, cam, [0.4; 3], ConeRadius::Region));
        } else if rng.gen_bool(0.3) {
            // The view's cone through its error region (`ConeRadius::Region`): narrower than
            // the bounding sphere, while "in front" still ends at the sphere's near side.
            let z = Zone::Sphere(Sphere {
                center: c,
                radius: r,
            });
            let rec = ZoneRecord::with_cone(&z, cam, [0.3; 3], ConeRadius::Region);
            zones.push(rec.narrow_cone(rng.gen_range(0.0..0.3)));
        } else {
            zones.push(sphere(c, r, cam));
        }
    }
    zones
}

/// Gaussians spread over the scene, plus points on the camera-to-zone segments, inside zones, on
/// exact boundaries and at the apexes.
fn random_positions(rng: &mut Pcg64, zones: &[ZoneRecord], n: usize) -> Vec<f32> {
    let mut p: Vec<[f32; 3]> = vec![
        [1.0, 0.25, -0.75],  // on sphere 0, +x
        [0.5, -0.25, -0.75], // on sphere 0, −y
        [0.5, 0.25, -0.25],  // on sphere 0, +z
        [-1.5, 0.5, 1.25],   // box 1 corner
        [-0.5, 0.0, 0.75],   // box 1 face
        [0.3, -0.2, 0.1],    // apex of zone 2
        [1.0, 1.0, 1.0],     // apex and centre of zone 3
        [-1.0, 1.0, 0.5],    // the zero-radius zone's centre
    ];
    for z in zones.iter().take(60) {
        let (c, o) = (z.center, z.camera_center);
        for _ in 0..12 {
            let t: f32 = rng.gen_range(-0.2..1.2);
            let j = 0.05 * z.radius.max(0.05);
            p.push([0, 1, 2].map(|k| o[k] + t * (c[k] - o[k]) + rng.gen_range(-j..j)));
        }
        for _ in 0..6 {
            let r = z.radius;
            p.push([0, 1, 2].map(|k| c[k] + rng.gen_range(-r..=r)));
        }
    }
    while p.len() < n {
        p.push(f32s(v3(rng, -3.0, 3.0)));
    }
    p.truncate(n);
    p.into_iter().flatten().collect()
}

/// The sqrt-free f32 tests implement docs/algorithms/lpm.md's definition: check against acos/atan in f64 where
/// the point is not within rounding distance of a boundary.
fn check_against_f64_definition(positions: &[f32], zones: &[ZoneRecord]) -> (usize, usize) {
    let (mut checked, mut front, mut slab_checked) = (0, 0, 0);
    for z in zones {
        let t = ZoneTest::new(z);
        let c = f32s(z.center.map(|x| x as f64)).map(|x| x as f64);
        let o = z.camera_center.map(|x| x as f64);
        // The in-front cone's base is the zone's cone radius (its bounding radius unless the
        // authors' smallest half-extent or the region's cone was asked for); "in front" ends at
        // the near side of the ball of its front radius.
        let r = z.cone_radius as f64;
        let f = z.front_radius as f64;
        let a = [c[0] - o[0], c[1] - o[1], c[2] - o[2]];
        let h = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        for p in positions.chunks_exact(3) {
            let x = [p[0] as f64, p[1] as f64, p[2] as f64];
            let v = [x[0] - o[0], x[1] - o[1], x[2] - o[2]];
            let vl = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if vl < 1e-6 || h < 1e-6 {
                continue;
            }
            let cos = (v[0] * a[0] + v[1] * a[1] + v[2] * a[2]) / (vl * h);
            let angle = cos.clamp(-1.0, 1.0).acos();
            let half = (r / h).atan();
            let limit = if h > f { h - f } else { h };
            if (angle - half).abs() < 1e-3 || (vl - limit).abs() < 1e-4 {
                continue;
            }
            let expect = angle <= half && vl <= limit;
            let got = t.in_front([p[0], p[1], p[2]]);
            assert_eq!(got, expect, "in front: zone {z:?}, point {x:?}");
            checked += 1;
            front += got as usize;
            let d = ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2)).sqrt();
            if (d - r).abs() > 1e-5 {
                assert_eq!(
                    t.in_ball([p[0], p[1], p[2]]),
                    d <= r,
                    "in ball: {z:?} {x:?}"
                );
            }
            if z.shape == ZONE_SLAB
                && (angle - half).abs() > 1e-3
                && ((vl - h).abs() - f).abs() > 1e-4
            {
                assert_eq!(
                    t.contains([p[0], p[1], p[2]]),
                    angle <= half && (vl - h).abs() <= f,
                    "inside slab: {z:?} {x:?}"
                );
                slab_checked += 1;
            }
            if z.shape == 0 {
                let r = z.radius as f64;
                if (d - r).abs() > 1e-5 {
                    assert_eq!(
                        t.contains([p[0], p[1], p[2]]),
                        d <= r,
                        "inside: {z:?} {x:?}"
                    );
                }
            }
        }
    }
    if zones.iter().any(|z| z.shape == ZONE_SLAB) {
        assert!(slab_checked > 0, "no slab point was checked");
    }
    (checked, front)
}

fn run_membership(
    ctx: &Arc<GpuContext>,
    lpm: &LpmGpu,
    positions: &[f32],
    zones: &[ZoneRecord],
) -> (Vec<u32>, Vec<u32>) {
    let n = positions.len() / 3;
    let pos = GpuBuffer::from_slice(ctx, "positions", positions).unwrap();
    let zbuf = if zones.is_empty() {
        GpuBuffer::<ZoneRecord>::new(ctx, "zones", 1, BufferKind::DeviceLocal).unwrap()
    } else {
        GpuBuffer::from_slice(ctx, "zones", zones).unwrap()
    };
    let flags = GpuBuffer::<u32>::new(ctx, "flags", n + TAIL, BufferKind::DeviceLocal).unwrap();
    let counts =
        GpuBuffer::<u32>::new(ctx, "zone counts", zones.len() + 1, BufferKind::DeviceLocal)
            .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    rec.fill(&flags, POISON);
    rec.fill(&counts, POISON);
    lpm.record_membership(
        &mut rec,
        &pos,
        n as u32,
        &zbuf,
        zones.len() as u32,
        &flags,
        &counts,
    )
    .unwrap();
    rec.submit_and_wait().unwrap();
    let f = flags.read().unwrap();
    assert!(
        f[n..].iter().all(|&v| v == POISON),
        "flags written past count"
    );
    let c = counts.read().unwrap();
    (f[..n].to_vec(), c[..zones.len()].to_vec())
}

#[test]
fn membership_matches_cpu_exactly() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(71);
    // 300 zones span three shared-memory batches; 0 zones must give all-zero flags.
    for &(nz, ng) in &[(40usize, 30_011usize), (300, 6_007), (0, 1_000), (7, 1)] {
        let zones = random_zones(&mut rng, nz.max(5));
        let zones = &zones[..nz];
        let positions = random_positions(&mut rng, zones, ng);
        let cpu = membership(&positions, zones);
        let (flags, counts) = run_membership(&ctx, &lpm, &positions, zones);
        for (i, (g, c)) in flags.iter().zip(&cpu.flags).enumerate() {
            assert_eq!(g, c, "flags of Gaussian {i} ({} zones)", nz);
        }
        assert_eq!(counts, cpu.inside_counts, "per-zone counts ({nz} zones)");
        if nz >= 40 {
            // The inputs exercise both bits, and the exact boundary points count as inside.
            let inside = flags.iter().filter(|&&f| f & FLAG_INSIDE != 0).count();
            let front = flags.iter().filter(|&&f| f & FLAG_IN_FRONT != 0).count();
            assert!(
                inside > 100 && front > 100,
                "inside {inside}, in front {front}"
            );
            assert!(flags[..5].iter().all(|&f| f & FLAG_INSIDE != 0));
            // The authors' cone makes the ball a strict subset of its box (zone 1's corner).
            let ball = flags.iter().filter(|&&f| f & FLAG_IN_BALL != 0).count();
            let t = ZoneTest::new(&zones[1]);
            let corner = [-1.5, 0.5, 1.25];
            let box_not_ball = (t.contains(corner) && !t.in_ball(corner)) as usize;
            assert!(
                ball > 100 && box_not_ball > 0,
                "ball {ball}, {box_not_ball}"
            );
            let (checked, front) = check_against_f64_definition(&positions[..3 * 2000], zones);
            assert!(
                checked > 10_000 && front > 50,
                "{checked} checked, {front} in front"
            );
        }
        if nz == 0 {
            assert!(flags.iter().all(|&f| f == 0));
        }
    }
    ctx.check_validation().unwrap();
}

/// Zones marked `ZONE_NO_RESET` (wider than `--lpm-reset-max-zone-radius`) hold their
/// Gaussians as before, but put nothing in front of them or in their ball: the GPU matches the
/// CPU mirror bit for bit, the inside bits and counts are those of the unmarked zones, and the
/// in-front and ball bits are exactly those of the zones left unmarked.
#[test]
fn zones_marked_no_reset_keep_their_inside_and_lose_their_front() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(72);
    let zones = random_zones(&mut rng, 40);
    let positions = random_positions(&mut rng, &zones, 20_011);
    let mut marked = zones.clone();
    for z in marked.iter_mut().step_by(3) {
        z.shape |= ZONE_NO_RESET;
    }
    assert!(marked.iter().any(|z| z.shape == ZONE_SLAB | ZONE_NO_RESET));
    let cpu = membership(&positions, &marked);
    let (flags, counts) = run_membership(&ctx, &lpm, &positions, &marked);
    assert_eq!(flags, cpu.flags, "GPU and CPU flags");
    assert_eq!(counts, cpu.inside_counts);
    let all = membership(&positions, &zones);
    let kept: Vec<ZoneRecord> = zones.iter().skip(1).step_by(3).copied().collect();
    let kept2: Vec<ZoneRecord> = zones.iter().skip(2).step_by(3).copied().collect();
    let resetting = membership(&positions, &[kept, kept2].concat());
    assert_eq!(
        counts, all.inside_counts,
        "marked zones hold what they held"
    );
    let (front_ball, mut lost) = (FLAG_IN_FRONT | FLAG_IN_BALL, 0);
    for (i, &f) in flags.iter().enumerate() {
        assert_eq!(
            f & FLAG_INSIDE,
            all.flags[i] & FLAG_INSIDE,
            "inside bit of {i}"
        );
        assert_eq!(
            f & front_ball,
            resetting.flags[i] & front_ball,
            "front bits of {i}"
        );
        lost += (all.flags[i] & FLAG_IN_FRONT != 0 && f & FLAG_IN_FRONT == 0) as usize;
    }
    assert!(
        lost > 100,
        "the marked zones took only {lost} Gaussians out of the front"
    );
    ctx.check_validation().unwrap();
}

fn run_reset(
    ctx: &Arc<GpuContext>,
    lpm: &LpmGpu,
    flags: &[u32],
    logits: &[f32],
    count: usize,
    s: &OpacityResetSettings,
) -> Vec<f32> {
    let fb = GpuBuffer::from_slice(ctx, "flags", flags).unwrap();
    let lb = GpuBuffer::from_slice(ctx, "logits", logits).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    lpm.record_opacity_reset(&mut rec, &fb, &lb, count as u32, s, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    lb.read().unwrap()
}

#[test]
fn opacity_reset_matches_cpu_exactly() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(72);
    let paper = OpacityResetSettings::default();
    let authors = OpacityResetSettings {
        quantile: 0.3,
        threshold_set: FLAG_IN_BALL,
        ..paper
    };
    // (Gaussians, P(inside), quantised logits with ties, settings)
    let cases = [
        (50_003usize, 0.3, false, paper),
        (50_003, 0.3, true, paper),
        (20_000, 0.6, true, authors),
        (1_000, 0.0, false, paper), // nothing inside: no reset
        (3, 1.0, false, paper),     // n = 3: k = ⌊0.9⌋ = 0, no reset
        (4, 1.0, false, paper),     // n = 4: k = 1
        (300_017, 0.05, false, paper),
    ];
    let mut some_reset = false;
    for (n, p_in, ties, s) in cases {
        let total = n + TAIL;
        let flags: Vec<u32> = (0..total)
            .map(|_| {
                ((rng.gen_bool(p_in) as u32) * FLAG_INSIDE)
                    | ((rng.gen_bool(0.4) as u32) * FLAG_IN_FRONT)
                    | ((rng.gen_bool(p_in) as u32) * FLAG_IN_BALL)
            })
            .collect();
        let logits: Vec<f32> = (0..total)
            .map(|_| {
                let x: f32 = rng.gen_range(-8.0..8.0);
                if ties {
                    match rng.gen_range(0..20) {
                        0 => 0.0,
                        1 => -0.0,
                        _ => (x * 4.0).round() / 4.0,
                    }
                } else {
                    x
                }
            })
            .collect();
        let mut expect = logits[..n].to_vec();
        let stats = apply_opacity_reset(&mut expect, &flags[..n], &s).unwrap();
        expect.extend_from_slice(&logits[n..]);
        let got = run_reset(&ctx, &lpm, &flags, &logits, n, &s);
        for (i, (g, e)) in got.iter().zip(&expect).enumerate() {
            assert_eq!(g.to_bits(), e.to_bits(), "logit {i} of {n}");
        }
        let gpu_stats = lpm.read_opacity_reset_stats().unwrap();
        assert_eq!(gpu_stats, stats, "n = {n}");
        some_reset |= stats.reset > 0;
        if p_in == 0.0 || n == 3 {
            assert_eq!(stats.threshold_logit, None);
        }
        if n == 4 {
            assert!(stats.threshold_logit.is_some());
        }
    }
    assert!(some_reset);
    ctx.check_validation().unwrap();
}

#[test]
fn membership_then_reset_in_one_submission() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(73);
    let zones = random_zones(&mut rng, 25);
    let positions = random_positions(&mut rng, &zones, 12_345);
    let n = positions.len() / 3;
    let logits: Vec<f32> = (0..n).map(|_| rng.gen_range(-5.0..5.0)).collect();
    let s = OpacityResetSettings::default();
    let cpu = membership(&positions, &zones);
    let mut expect = logits.clone();
    let stats = apply_opacity_reset(&mut expect, &cpu.flags, &s).unwrap();
    assert!(stats.reset > 0);

    let pos = GpuBuffer::from_slice(&ctx, "positions", &positions).unwrap();
    let zbuf = GpuBuffer::from_slice(&ctx, "zones", &zones).unwrap();
    let flags = GpuBuffer::<u32>::new(&ctx, "flags", n, BufferKind::DeviceLocal).unwrap();
    let counts =
        GpuBuffer::<u32>::new(&ctx, "counts", zones.len(), BufferKind::DeviceLocal).unwrap();
    let lb = GpuBuffer::from_slice(&ctx, "logits", &logits).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    rec.fill(&flags, POISON);
    let (nn, nz) = (n as u32, zones.len() as u32);
    lpm.record_membership(&mut rec, &pos, nn, &zbuf, nz, &flags, &counts)
        .unwrap();
    lpm.record_opacity_reset(&mut rec, &flags, &lb, nn, &s, None)
        .unwrap();
    rec.submit_and_wait().unwrap();
    assert_eq!(counts.read().unwrap(), cpu.inside_counts);
    let got = lb.read().unwrap();
    assert!(got
        .iter()
        .zip(&expect)
        .all(|(g, e)| g.to_bits() == e.to_bits()));
    assert_eq!(lpm.read_opacity_reset_stats().unwrap(), stats);
    ctx.check_validation().unwrap();
}

/// Random images made of flat rectangles (many equal errors) over noise, with large-error
/// rectangles; ground truth with partial alpha.
fn random_images(rng: &mut Pcg64, w: u32, h: u32, bg: [f32; 3]) -> (Vec<f32>, Vec<u32>) {
    let n = (w * h) as usize;
    let mut gt: Vec<u32> = (0..n)
        .map(|_| {
            let a = if rng.gen_bool(0.2) { rng.gen() } else { 255u8 };
            u32::from_le_bytes([rng.gen(), rng.gen(), rng.gen(), a])
        })
        .collect();
    let rect = |rng: &mut Pcg64| {
        let x0 = rng.gen_range(0..w);
        let y0 = rng.gen_range(0..h);
        let x1 = rng.gen_range(x0 + 1..=w.min(x0 + 80));
        let y1 = rng.gen_range(y0 + 1..=h.min(y0 + 80));
        (x0, y0, x1, y1)
    };
    for _ in 0..4 {
        let (x0, y0, x1, y1) = rect(rng);
        let v = u32::from_le_bytes([rng.gen(), rng.gen(), rng.gen(), 255]);
        for y in y0..y1 {
            for x in x0..x1 {
                gt[(y * w + x) as usize] = v;
            }
        }
    }
    let composited = unpack_ground_truth(&gt, bg);
    let mut render: Vec<f32> = composited
        .iter()
        .map(|&g| (g + rng.gen_range(-0.03..0.03f32)).clamp(0.0, 1.0))
        .collect();
    for _ in 0..5 {
        let (x0, y0, x1, y1) = rect(rng);
        let flat = rng.gen_bool(0.5);
        let v: [f32; 3] = [rng.gen(), rng.gen(), rng.gen()];
        for y in y0..y1 {
            for x in x0..x1 {
                let i = 3 * (y * w + x) as usize;
                for c in 0..3 {
                    render[i + c] = if flat { v[c] } else { rng.gen() };
                }
            }
        }
    }
    (render, gt)
}

#[test]
fn error_blocks_match_cpu() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 300 * 200).unwrap();
    let mut rng = Pcg64::seed_from_u64(74);
    let mut kept_total = (0usize, 0usize);
    for &(w, h, block, q) in &[
        (37u32, 29u32, 16u32, 0.4f32),
        (100, 75, 16, 0.4),
        (257, 130, 16, 0.4),
        (300, 200, 16, 0.4),
        (64, 48, 8, 0.7),
        (1, 1, 16, 0.4),
        (5, 3, 16, 1.0),
    ] {
        let n = (w * h) as usize;
        let bg: [f32; 3] = [rng.gen(), rng.gen(), rng.gen()];
        let (render, gt) = random_images(&mut rng, w, h, bg);
        // The image sits at an offset inside a larger ground-truth buffer.
        let offset = rng.gen_range(0..500u32);
        let mut gt_all: Vec<u32> = (0..offset).map(|_| rng.gen()).collect();
        gt_all.extend_from_slice(&gt);
        gt_all.extend((0..33).map(|_| rng.gen::<u32>()));
        let rbuf = GpuBuffer::from_slice(&ctx, "render", &render).unwrap();
        let gbuf = GpuBuffer::from_slice(&ctx, "gt", &gt_all).unwrap();
        let (bx, by) = block_grid(w, h, block);
        let nb = (bx * by) as usize;
        let counts =
            GpuBuffer::<u32>::new(&ctx, "counts", nb + TAIL, BufferKind::DeviceLocal).unwrap();
        let s = RegionSettings {
            quantile: q,
            block,
            keep_fraction: 0.85,
        };
        let img = ErrorImages {
            render: &rbuf,
            gt: &gbuf,
            gt_offset: offset,
            width: w,
            height: h,
            background: bg,
        };
        let mut rec = Recorder::new(&ctx).unwrap();
        rec.fill(&counts, POISON);
        rec.fill(lpm.error_map_buffer(), 0x7FC0_0000);
        assert_eq!(
            lpm.record_error_blocks(&mut rec, &img, &s, &counts)
                .unwrap(),
            (bx, by)
        );
        rec.submit_and_wait().unwrap();
        let all = counts.read().unwrap();
        assert!(
            all[nb..].iter().all(|&c| c == POISON),
            "counts past the grid"
        );
        let gpu_counts = &all[..nb];
        let gpu_map = lpm.error_map_buffer().read_range(0, n).unwrap();
        let gpu_thr = lpm.read_error_threshold().unwrap();

        // Exact, given the GPU's own map: the quantile (up to the interpolation's last ulp) and
        // every count.
        let thr_on_gpu_map = quantile(&gpu_map, q);
        assert!(
            gpu_thr == thr_on_gpu_map
                || (gpu_thr.to_bits() as i64 - thr_on_gpu_map.to_bits() as i64).abs() <= 1,
            "{w}×{h}: threshold {gpu_thr} vs {thr_on_gpu_map}"
        );
        let expect = error_block_counts(&gpu_map, w, h, block, thr_on_gpu_map).unwrap();
        assert_eq!(gpu_counts, &expect[..], "{w}×{h} counts on the GPU's map");

        // Against regions.rs in f64: the map within f32 rounding; counts may differ only by
        // pixels whose error is within that rounding of the threshold.
        let gt_rgb = unpack_ground_truth(&gt, bg);
        let cpu_map = error_map(&render, &gt_rgb, w, h).unwrap();
        for (i, (g, c)) in gpu_map.iter().zip(&cpu_map).enumerate() {
            assert!(g.is_finite(), "pixel {i}: {g}");
            assert!(
                (g - c).abs() <= 2e-5 * (1.0 + c.abs()),
                "pixel {i}: {g} vs {c}"
            );
        }
        let cpu_thr = quantile(&cpu_map, q);
        let cpu_counts = error_block_counts(&cpu_map, w, h, block, cpu_thr).unwrap();
        let cpu_mask = block_mask(&cpu_map, w, h, q, block, 0.85).unwrap();
        let mask_from_cpu_counts = BlockMask::from_error_counts(w, h, block, &cpu_counts, 0.85);
        assert_eq!(mask_from_cpu_counts.unwrap(), cpu_mask);
        let gpu_mask = BlockMask::from_error_counts(w, h, block, gpu_counts, 0.85).unwrap();
        let tol = 4e-5 * (1.0 + cpu_thr.abs());
        let mut near = vec![0u32; nb];
        for (i, &e) in cpu_map.iter().enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            if (e - cpu_thr).abs() <= tol {
                near[((y / block) * bx + x / block) as usize] += 1;
            }
        }
        for b in 0..nb {
            let d = (gpu_counts[b] as i64 - cpu_counts[b] as i64).unsigned_abs();
            assert!(
                d <= near[b] as u64,
                "{w}×{h} block {b}: {} vs {}",
                gpu_counts[b],
                cpu_counts[b]
            );
            if near[b] == 0 {
                assert_eq!(gpu_mask.kept[b], cpu_mask.kept[b], "{w}×{h} block {b}");
            }
        }
        kept_total.0 += gpu_mask.kept.iter().filter(|&&k| k).count();
        kept_total.1 += nb;
    }
    assert!(
        kept_total.0 > 0 && kept_total.0 < kept_total.1,
        "kept {} of {} blocks",
        kept_total.0,
        kept_total.1
    );
    ctx.check_validation().unwrap();
}

#[test]
fn bad_inputs_are_errors() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 100).unwrap();
    let small = GpuBuffer::<f32>::new(&ctx, "small", 30, BufferKind::DeviceLocal).unwrap();
    let gt = GpuBuffer::<u32>::new(&ctx, "gt", 10, BufferKind::DeviceLocal).unwrap();
    let flags = GpuBuffer::<u32>::new(&ctx, "flags", 10, BufferKind::DeviceLocal).unwrap();
    let zones = GpuBuffer::<ZoneRecord>::new(&ctx, "zones", 2, BufferKind::DeviceLocal).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let img = |w, h| ErrorImages {
        render: &small,
        gt: &gt,
        gt_offset: 0,
        width: w,
        height: h,
        background: [0.0; 3],
    };
    let s = RegionSettings::default();
    assert!(lpm
        .record_error_blocks(&mut rec, &img(20, 20), &s, &flags)
        .is_err());
    assert!(lpm
        .record_error_blocks(&mut rec, &img(0, 5), &s, &flags)
        .is_err());
    assert!(lpm
        .record_error_blocks(&mut rec, &img(5, 5), &s, &flags)
        .is_err());
    assert!(lpm
        .record_membership(&mut rec, &small, 11, &zones, 2, &flags, &flags)
        .is_err());
    assert!(lpm
        .record_membership(&mut rec, &small, 10, &zones, 3, &flags, &flags)
        .is_err());
    let bad = OpacityResetSettings {
        quantile: 1.5,
        ..Default::default()
    };
    assert!(lpm
        .record_opacity_reset(&mut rec, &flags, &small, 10, &bad, None)
        .is_err());
    assert!(lpm
        .record_opacity_reset(&mut rec, &flags, &small, 11, &Default::default(), None)
        .is_err());
    rec.submit_and_wait().unwrap();
    ctx.check_validation().unwrap();
}

#[test]
fn lpm_passes_under_subgroup_size_16() {
    // lavapipe runs with subgroup size 16 when LP_NATIVE_VECTOR_WIDTH=512 (set before the driver
    // loads, hence a child process); the subgroup reductions must not assume a size.
    child_run::rerun_under_subgroup_size_16(
        module_path!(),
        &[
            "membership_matches_cpu_exactly",
            "opacity_reset_matches_cpu_exactly",
            "error_blocks_match_cpu",
        ],
    );
}

/// The weighted rank selection (the authors' density-aware pruning ranks the model after
/// densification, where a cloned or split Gaussian's opacity appears twice) against a CPU sort
/// of the expanded multiset; unweighted with the same flags as a control.
#[test]
fn weighted_rank_selection_matches_the_expanded_multiset() {
    use lpmsplat::reference::lpm_membership::float_key;
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(73);
    for &(n, ties) in &[(20_011usize, false), (5_003, true), (3, false)] {
        let weights: Vec<u32> = (0..n + TAIL).map(|_| rng.gen_range(0..3u32)).collect();
        let values: Vec<f32> = (0..n + TAIL)
            .map(|_| {
                let x: f32 = rng.gen_range(-8.0..8.0);
                if ties {
                    (x * 4.0).round() / 4.0
                } else {
                    x
                }
            })
            .collect();
        let vb = GpuBuffer::from_slice(&ctx, "values", &values).unwrap();
        let wb = GpuBuffer::from_slice(&ctx, "weights", &weights).unwrap();
        for weighted in [true, false] {
            let mut keys: Vec<u32> = (0..n)
                .flat_map(|i| {
                    let w = if weighted {
                        weights[i]
                    } else {
                        (weights[i] != 0) as u32
                    };
                    std::iter::repeat_n(float_key(values[i]), w as usize)
                })
                .collect();
            keys.sort_unstable();
            if keys.is_empty() {
                continue;
            }
            let total = keys.len() as u32;
            for rank in [0, total / 3, total - 1] {
                let mut rec = Recorder::new(&ctx).unwrap();
                lpm.record_rank_selection(&mut rec, &vb, &wb, 3, weighted, n as u32, total, rank)
                    .unwrap();
                rec.submit_and_wait().unwrap();
                let st = lpm.rank_selection_state().read().unwrap();
                assert_eq!(st[1], 1, "selection valid");
                assert_eq!(
                    st[4], keys[rank as usize],
                    "rank {rank} of {total} (weighted {weighted}, n {n})"
                );
            }
        }
    }
    ctx.check_validation().unwrap();
}

/// LPM in time marks a Gaussian absent from the frame with a NaN centre: it must be inside no
/// zone, in front of none, in no ball, and counted in no zone, while the present ones keep
/// exactly the flags and counts they have without the absent ones.
#[test]
fn absent_gaussians_are_in_no_zone() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(79);
    let zones = random_zones(&mut rng, 60);
    let mut positions = random_positions(&mut rng, &zones, 20_000);
    let n = positions.len() / 3;
    let absent: Vec<bool> = (0..n).map(|_| rng.gen_bool(0.4)).collect();
    let mut present_positions = Vec::new();
    for (i, &a) in absent.iter().enumerate() {
        if a {
            positions[3 * i..3 * i + 3].fill(f32::NAN);
        } else {
            present_positions.extend_from_slice(&positions[3 * i..3 * i + 3]);
        }
    }
    let cpu = membership(&present_positions, &zones);
    let (flags, counts) = run_membership(&ctx, &lpm, &positions, &zones);
    let mut k = 0;
    for (i, &a) in absent.iter().enumerate() {
        if a {
            assert_eq!(flags[i], 0, "absent Gaussian {i}");
        } else {
            assert_eq!(flags[i], cpu.flags[k], "present Gaussian {i}");
            k += 1;
        }
    }
    assert_eq!(counts, cpu.inside_counts);
    // The case is not vacuous: some present Gaussians are inside, in front and in balls.
    for bit in [FLAG_INSIDE, FLAG_IN_FRONT, FLAG_IN_BALL] {
        assert!(cpu.flags.iter().any(|f| f & bit != 0), "flag {bit}");
    }
    ctx.check_validation().unwrap();
}

/// Mip-Splatting's filter-aware LPM reset: the ranking is the CPU reset's on the drawn
/// (effective) logits, the reset Gaussians then draw at the reset opacity, and every other
/// stored logit is untouched.
#[test]
fn filtered_opacity_reset_ranks_and_caps_the_drawn_opacity() {
    let ctx = ctx();
    let lpm = LpmGpu::new(&ctx, 1).unwrap();
    let mut rng = Pcg64::seed_from_u64(2024);
    let s = OpacityResetSettings::default();
    let n = 20_011;
    let flags: Vec<u32> = (0..n)
        .map(|_| {
            ((rng.gen_bool(0.3) as u32) * FLAG_INSIDE)
                | ((rng.gen_bool(0.4) as u32) * FLAG_IN_FRONT)
        })
        .collect();
    let logits: Vec<f32> = (0..n).map(|_| rng.gen_range(-6.0..8.0)).collect();
    let log_scales: Vec<f32> = (0..3 * n).map(|_| rng.gen_range(-6.0f32..-1.0)).collect();
    // Filters from negligible to dominant (ρ from ~1 down to ~1e-6).
    let filter: Vec<f32> = (0..n)
        .map(|_| 10f32.powf(rng.gen_range(-4.0..0.0)))
        .collect();
    let rho = |i: usize| -> f64 {
        let f2 = (filter[i] as f64).powi(2);
        (0..3)
            .map(|k| {
                let s2 = (log_scales[3 * i + k] as f64).exp().powi(2);
                s2 / (s2 + f2)
            })
            .product::<f64>()
            .sqrt()
    };
    let sigmoid = |x: f64| 1.0 / (1.0 + (-x).exp());
    let fb = GpuBuffer::from_slice(&ctx, "flags", &flags).unwrap();
    let lb = GpuBuffer::from_slice(&ctx, "logits", &logits).unwrap();
    let sb = GpuBuffer::from_slice(&ctx, "log scales", &log_scales).unwrap();
    let filt = GpuBuffer::from_slice(&ctx, "filter3d", &filter).unwrap();
    let eff = GpuBuffer::from_slice(&ctx, "effective", &vec![f32::NAN; n]).unwrap();
    let mut rec = Recorder::new(&ctx).unwrap();
    let filtered = FilteredOpacity {
        filter3d: &filt,
        log_scales: &sb,
        effective: &eff,
    };
    lpm.record_opacity_reset(&mut rec, &fb, &lb, n as u32, &s, Some(&filtered))
        .unwrap();
    rec.submit_and_wait().unwrap();
    let got = lb.read().unwrap();
    let effective = eff.read().unwrap();
    let gpu_stats = lpm.read_opacity_reset_stats().unwrap();
    // The GPU's effective logits are the formula's.
    for i in 0..n {
        let p = rho(i) * sigmoid(logits[i] as f64);
        let want = (p / (1.0 - p)).ln();
        assert!(
            (effective[i] as f64 - want).abs() <= 1e-4 * want.abs().max(1.0),
            "effective logit {i}: {} vs {want}",
            effective[i]
        );
    }
    // The ranking: the CPU reset run on those effective logits.
    let mut chosen = effective.clone();
    let stats = apply_opacity_reset(&mut chosen, &flags, &s).unwrap();
    assert_eq!(gpu_stats, stats);
    assert!(stats.reset > 100, "{stats:?}");
    let target = sigmoid(s.reset_logit().unwrap() as f64);
    let mut capped = 0;
    for i in 0..n {
        if chosen[i].to_bits() == effective[i].to_bits() {
            assert_eq!(got[i].to_bits(), logits[i].to_bits(), "logit {i} moved");
            continue;
        }
        let stored = sigmoid(got[i] as f64);
        if target / rho(i) >= 1.0 - 1e-6 {
            capped += 1;
            assert!(stored > 0.999, "{i}: capped at {stored}");
        } else {
            let drawn = stored * rho(i);
            assert!(
                (drawn - target).abs() <= 1e-4 * target,
                "{i}: draws {drawn}, not {target}"
            );
        }
    }
    eprintln!("{stats:?}, {capped} capped at the sigmoid's ceiling");
    ctx.check_validation().unwrap();
}
