//! LPM correspondences on synthetic scenes: COLMAP-style tracks built by hand, the classical
//! feature matcher on ray-cast renders of a textured plane, and the on-disk cache.

use glam::DVec3;
use lpmsplat::lpm::cache::{read_cache, scene_hash, CacheMiss};
use lpmsplat::lpm::correspondences::TrackIndex;
use lpmsplat::lpm::epipolar::{fundamental, symmetric_epipolar_distance};
use lpmsplat::lpm::features::{detect_and_describe, match_features, FeatureSettings};
use lpmsplat::lpm::{
    extract_correspondences, load_or_build, CacheStatus, MatchSettings, MatchSource,
};
use lpmsplat::scene::{
    CameraModel, Image, Keypoints, PinholeCamera, Pose, Scene, SceneFormat, SfmPoints, View,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn look_at(eye: DVec3, target: DVec3) -> Pose {
    let z = (target - eye).normalize();
    let up = if z.z.abs() > 0.99 { DVec3::Y } else { DVec3::Z };
    let x = z.cross(up).normalize();
    let y = z.cross(x);
    let r = glam::DMat3::from_cols(x, y, z).transpose();
    Pose {
        rotation: [x.to_array(), y.to_array(), z.to_array()],
        translation: (-(r * eye)).to_array(),
    }
}

fn view(name: &str, cam: PinholeCamera, pose: Pose) -> View {
    View {
        name: name.into(),
        stem: name.into(),
        image_path: format!("images/{name}.png").into(),
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

fn scene(views: Vec<View>, points: Option<SfmPoints>) -> Scene {
    let train = (0..views.len()).collect();
    Scene {
        root: "synthetic".into(),
        format: SceneFormat::Colmap {
            sparse_dir: "synthetic/sparse/0".into(),
            binary: true,
        },
        views,
        train,
        test: vec![],
        points,
        center: [0.0; 3],
        extent: 1.0,
        background: None,
        has_alpha: false,
        view_times: None,
        time_base: None,
        frame: lpmsplat::scene::SceneFrame::IDENTITY,
    }
}

fn project(v: &View, p: DVec3) -> Option<[f64; 2]> {
    let c = v.pose.transform(p.to_array());
    let uv = v.camera.project(c);
    (c[2] > 1e-6
        && uv[0] >= 0.0
        && uv[1] >= 0.0
        && uv[0] < v.camera.width as f64
        && uv[1] < v.camera.height as f64)
        .then_some(uv)
}

/// A ring of `n` cameras at 12° steps looking at the origin, and SfM points with tracks: each
/// keypoint is the exact projection; keypoint order is shuffled per view, plus unmatched
/// keypoints (point3d = -1), so the test checks the bookkeeping, not an ordering coincidence.
fn track_scene(rng: &mut Pcg64, n: usize, npts: usize) -> (Scene, Vec<DVec3>) {
    let cam = PinholeCamera {
        fx: 400.0,
        fy: 400.0,
        cx: 200.0,
        cy: 150.0,
        width: 400,
        height: 300,
    };
    let mut views: Vec<View> = (0..n)
        .map(|i| {
            let a = (i as f64 * 12.0).to_radians();
            view(
                &format!("v{i:02}"),
                cam,
                look_at(DVec3::new(6.0 * a.cos(), 6.0 * a.sin(), 1.0), DVec3::ZERO),
            )
        })
        .collect();
    let pts: Vec<DVec3> = (0..npts)
        .map(|_| {
            DVec3::new(
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
                rng.gen_range(-1.0..1.0),
            )
        })
        .collect();
    let mut tracks = vec![Vec::new(); npts];
    for (vi, v) in views.iter_mut().enumerate() {
        let mut kps: Vec<([f64; 2], i64)> = Vec::new();
        for (pi, p) in pts.iter().enumerate() {
            // Each point is observed by a random subset of the views that see it.
            if let Some(uv) = project(v, *p) {
                if rng.gen_bool(0.7) {
                    kps.push((uv, pi as i64));
                }
            }
        }
        for _ in 0..20 {
            kps.push(([rng.gen_range(0.0..400.0), rng.gen_range(0.0..300.0)], -1));
        }
        let mut order: Vec<usize> = (0..kps.len()).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, rng.gen_range(0..=i));
        }
        let mut k = Keypoints::default();
        for (ki, &o) in order.iter().enumerate() {
            k.xy.push(kps[o].0);
            k.point3d.push(kps[o].1);
            if kps[o].1 >= 0 {
                tracks[kps[o].1 as usize].push((vi as u32, ki as u32));
            }
        }
        v.keypoints = Some(k);
    }
    let points = SfmPoints {
        ids: (0..npts as u64).collect(),
        positions: pts.iter().map(|p| p.to_array()).collect(),
        colors: vec![[128; 3]; npts],
        errors: vec![0.5; npts],
        tracks,
    };
    (scene(views, Some(points)), pts)
}

fn no_images(_: usize) -> anyhow::Result<Image> {
    anyhow::bail!("no images in this test")
}

#[test]
fn track_matches_on_hand_built_tracks() {
    let mut rng = Pcg64::seed_from_u64(10);
    let (sc, pts) = track_scene(&mut rng, 8, 300);
    let index = TrackIndex::new(&sc).unwrap();
    for a in 0..8 {
        for b in 0..8 {
            let m = index.matches(&sc, a, b);
            if a == b {
                assert!(m.is_empty());
                continue;
            }
            // Expected: points whose track holds both views.
            let tracks = &sc.points.as_ref().unwrap().tracks;
            let shared = tracks
                .iter()
                .filter(|t| t.iter().any(|e| e.0 == a as u32) && t.iter().any(|e| e.0 == b as u32));
            assert_eq!(m.len(), shared.count());
            assert_eq!((m.a as usize, m.b as usize), (a.min(b), a.max(b)));
            // Each match is the projection pair of one true point.
            let (va, vb) = (&sc.views[m.a as usize], &sc.views[m.b as usize]);
            for (xa, xb) in m.xy_a.iter().zip(&m.xy_b) {
                let hit = pts.iter().any(|p| {
                    let (pa, pb) = (project(va, *p), project(vb, *p));
                    matches!((pa, pb), (Some(pa), Some(pb))
                        if (pa[0] - xa[0] as f64).hypot(pa[1] - xa[1] as f64) < 1e-3
                        && (pb[0] - xb[0] as f64).hypot(pb[1] - xb[1] as f64) < 1e-3)
                });
                assert!(hit, "match {xa:?} ↔ {xb:?} is not a projection pair");
            }
        }
    }
    // Through the extraction API: every neighbour pair, epipolar error ~0, all inliers.
    let settings = MatchSettings {
        source: MatchSource::Auto,
        ..Default::default()
    };
    let (corr, summary) = extract_correspondences(&sc, &settings, &no_images, None).unwrap();
    assert_eq!(summary.source, MatchSource::Tracks);
    assert_eq!(summary.pairs, corr.neighbours.pairs().len());
    assert!(summary.pairs > 0 && summary.candidates > 0);
    assert_eq!(summary.inliers, summary.candidates);
    assert!(summary.epipolar_p95_px < 1e-3, "{summary}");
    for (a, ns) in corr.neighbours.of.iter().enumerate() {
        for &b in ns {
            let (xa, xb) = corr.oriented(a, b).unwrap();
            assert_eq!(xa.len(), xb.len());
        }
    }
    println!("{summary}");
}

#[test]
fn track_index_rejects_bad_tracks() {
    let mut rng = Pcg64::seed_from_u64(11);
    let (mut sc, _) = track_scene(&mut rng, 3, 40);
    // A track naming the same view twice keeps one keypoint.
    let t0 = sc
        .points
        .as_ref()
        .unwrap()
        .tracks
        .iter()
        .position(|t| !t.is_empty())
        .unwrap();
    let first = sc.points.as_ref().unwrap().tracks[t0][0];
    sc.points.as_mut().unwrap().tracks[t0].push((first.0, first.1));
    assert!(TrackIndex::new(&sc).is_ok());
    // Out-of-range keypoint and view: errors that name the model and the track.
    let mut bad = sc.clone();
    bad.points.as_mut().unwrap().tracks[t0].push((1, 1_000_000));
    let e = TrackIndex::new(&bad).unwrap_err().to_string();
    assert!(
        e.contains("points3D") && e.contains("keypoint 1000000"),
        "{e}"
    );
    let mut bad = sc.clone();
    bad.points.as_mut().unwrap().tracks[t0].push((7, 0));
    let e = TrackIndex::new(&bad).unwrap_err().to_string();
    assert!(e.contains("view index 7"), "{e}");
}

#[test]
fn one_view_scene_has_no_pairs() {
    let mut rng = Pcg64::seed_from_u64(12);
    let (mut sc, _) = track_scene(&mut rng, 3, 20);
    sc.train = vec![1];
    let (corr, summary) =
        extract_correspondences(&sc, &MatchSettings::default(), &no_images, None).unwrap();
    assert!(corr.pairs.is_empty());
    assert_eq!(summary.pairs, 0);
    assert_eq!(summary.views_without_neighbours, 1);
    assert!(summary.epipolar_median_px.is_nan());
    let _ = format!("{summary}");
}

// ---------------------------------------------------------------- features

/// A procedural texture on the plane z = 0: cells of 0.06 units with hashed grey levels, with
/// random colour tints, plus a few large-scale blobs.
fn texture(x: f64, y: f64) -> [f32; 3] {
    let (i, j) = ((x / 0.06).floor() as i64, (y / 0.06).floor() as i64);
    let mut h = (i.wrapping_mul(73856093) ^ j.wrapping_mul(19349663)) as u64;
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1e995);
    h ^= h >> 15;
    let g = (h & 0xff) as f32 / 255.0;
    let t = ((h >> 8) & 0xff) as f32 / 255.0;
    let blob = (0.5 + 0.5 * (3.0 * x).sin() * (2.0 * y).cos()) as f32;
    [
        0.6 * g + 0.2 * blob + 0.1 * t,
        0.6 * g + 0.2 * blob,
        0.6 * g + 0.2 * (1.0 - blob),
    ]
}

/// Ray-casts the plane z = 0 (2×2 supersampling; grey 0.5 where the ray misses).
fn render_plane(v: &View) -> Image {
    let c = &v.camera;
    let r = v.pose.rotation;
    let o = DVec3::from(v.pose.center());
    let mut rgb = Vec::with_capacity((c.width * c.height * 3) as usize);
    for py in 0..c.height {
        for px in 0..c.width {
            let mut acc = [0.0f32; 3];
            for (sx, sy) in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)] {
                let d = DVec3::new(
                    (px as f64 + sx - c.cx) / c.fx,
                    (py as f64 + sy - c.cy) / c.fy,
                    1.0,
                );
                // World direction Rᵀ d.
                let w = DVec3::new(
                    r[0][0] * d.x + r[1][0] * d.y + r[2][0] * d.z,
                    r[0][1] * d.x + r[1][1] * d.y + r[2][1] * d.z,
                    r[0][2] * d.x + r[1][2] * d.y + r[2][2] * d.z,
                );
                let t = -o.z / w.z;
                let col = if t > 0.0 {
                    texture(o.x + t * w.x, o.y + t * w.y)
                } else {
                    [0.5; 3]
                };
                for k in 0..3 {
                    acc[k] += 0.25 * col[k];
                }
            }
            rgb.extend_from_slice(&acc);
        }
    }
    Image {
        width: c.width,
        height: c.height,
        rgb,
        alpha: None,
    }
}

/// Where the pixel of view `a` lands in view `b` (through the plane z = 0).
fn transfer(a: &View, b: &View, uv: [f32; 2]) -> Option<[f64; 2]> {
    let c = &a.camera;
    let r = a.pose.rotation;
    let o = DVec3::from(a.pose.center());
    let d = DVec3::new(
        (uv[0] as f64 - c.cx) / c.fx,
        (uv[1] as f64 - c.cy) / c.fy,
        1.0,
    );
    let w = DVec3::new(
        r[0][0] * d.x + r[1][0] * d.y + r[2][0] * d.z,
        r[0][1] * d.x + r[1][1] * d.y + r[2][1] * d.z,
        r[0][2] * d.x + r[1][2] * d.y + r[2][2] * d.z,
    );
    let t = -o.z / w.z;
    (t > 0.0).then(|| b.camera.project(b.pose.transform((o + t * w).to_array())))
}

fn plane_views() -> Vec<View> {
    let cam = PinholeCamera {
        fx: 300.0,
        fy: 300.0,
        cx: 160.0,
        cy: 120.0,
        width: 320,
        height: 240,
    };
    vec![
        view(
            "p0",
            cam,
            look_at(DVec3::new(0.0, -1.2, 2.2), DVec3::new(0.0, 0.0, 0.0)),
        ),
        // 20° around the vertical and a little roll-free tilt: a real change of perspective.
        view(
            "p1",
            cam,
            look_at(DVec3::new(0.75, -1.0, 2.1), DVec3::new(0.05, 0.05, 0.0)),
        ),
    ]
}

#[test]
fn feature_matcher_finds_correct_matches_on_a_textured_plane() {
    let views = plane_views();
    let imgs: Vec<Image> = views.iter().map(render_plane).collect();
    let s = FeatureSettings::default();
    let f: Vec<_> = imgs.iter().map(|i| detect_and_describe(i, &s)).collect();
    assert!(
        f[0].xy.len() > 300 && f[1].xy.len() > 300,
        "keypoints: {} {}",
        f[0].xy.len(),
        f[1].xy.len()
    );
    let m = match_features(&f[0], &f[1], &s);
    let correct = |&(i, j): &(usize, usize)| {
        transfer(&views[0], &views[1], f[0].xy[i]).is_some_and(|t| {
            (t[0] - f[1].xy[j][0] as f64).hypot(t[1] - f[1].xy[j][1] as f64) <= 2.0
        })
    };
    let raw_ok = m.iter().filter(|p| correct(p)).count();
    // Epipolar filter from the known poses.
    let fm = fundamental(
        &views[0].camera,
        &views[0].pose,
        &views[1].camera,
        &views[1].pose,
    );
    let kept: Vec<(usize, usize)> = m
        .iter()
        .copied()
        .filter(|&(i, j)| {
            let (a, b) = (f[0].xy[i], f[1].xy[j]);
            symmetric_epipolar_distance(&fm, [a[0] as f64, a[1] as f64], [b[0] as f64, b[1] as f64])
                <= 3.0
        })
        .collect();
    let kept_ok = kept.iter().filter(|p| correct(p)).count();
    println!(
        "mutual matches {} ({raw_ok} correct); after epipolar {} ({kept_ok} correct)",
        m.len(),
        kept.len()
    );
    // Stated bounds: ≥ 100 matches survive, ≥ 95 % of them within 2 px of the true transfer,
    // and the raw mutual-NN + ratio matches are already ≥ 70 % correct.
    assert!(kept.len() >= 100);
    assert!(kept_ok as f64 >= 0.95 * kept.len() as f64);
    assert!(raw_ok as f64 >= 0.7 * m.len() as f64);

    // Corrupted matches (a wrong partner) are rejected by the epipolar filter; true ones kept.
    let mut rng = Pcg64::seed_from_u64(13);
    let mut rejected_bad = 0;
    let mut total_bad = 0;
    for &(i, j) in kept.iter().filter(|p| correct(p)).take(100) {
        let a = f[0].xy[i];
        let b = f[1].xy[j];
        assert!(
            symmetric_epipolar_distance(
                &fm,
                [a[0] as f64, a[1] as f64],
                [b[0] as f64, b[1] as f64]
            ) <= 3.0
        );
        let wrong = f[1].xy[rng.gen_range(0..f[1].xy.len())];
        if (wrong[0] - b[0]).hypot(wrong[1] - b[1]) > 30.0 {
            total_bad += 1;
            let e = symmetric_epipolar_distance(
                &fm,
                [a[0] as f64, a[1] as f64],
                [wrong[0] as f64, wrong[1] as f64],
            );
            rejected_bad += (e > 3.0) as usize;
        }
    }
    assert!(
        rejected_bad as f64 >= 0.9 * total_bad as f64,
        "{rejected_bad}/{total_bad}"
    );

    // The whole path through the extraction API on a features scene.
    let sc = scene(views.clone(), None);
    let load = |i: usize| Ok(imgs[i].clone());
    let settings = MatchSettings {
        source: MatchSource::Auto,
        ..Default::default()
    };
    let (corr, summary) = extract_correspondences(&sc, &settings, &load, None).unwrap();
    assert_eq!(summary.source, MatchSource::Features);
    assert_eq!(corr.pairs.len(), 1);
    assert!(corr.pairs[0].len() >= 100);
    assert!(summary.inlier_ratio > 0.5 && summary.inlier_ratio <= 1.0);
    println!("{summary}");
}

#[test]
fn textureless_images_give_no_keypoints_and_no_panic() {
    let views = plane_views();
    let flat = Image {
        width: 320,
        height: 240,
        rgb: vec![0.4; 320 * 240 * 3],
        alpha: None,
    };
    assert!(detect_and_describe(&flat, &FeatureSettings::default())
        .xy
        .is_empty());
    let tiny = Image {
        width: 8,
        height: 8,
        rgb: vec![0.4; 8 * 8 * 3],
        alpha: None,
    };
    assert!(detect_and_describe(&tiny, &FeatureSettings::default())
        .xy
        .is_empty());
    let sc = scene(views, None);
    let load = |_: usize| Ok(flat.clone());
    let (corr, summary) =
        extract_correspondences(&sc, &MatchSettings::default(), &load, None).unwrap();
    assert_eq!(summary.views_without_keypoints, 2);
    assert_eq!(summary.pairs_without_matches, 1);
    assert!(corr.pairs[0].is_empty());
    // A loader error propagates instead of panicking.
    assert!(extract_correspondences(&sc, &MatchSettings::default(), &no_images, None).is_err());
}

// ---------------------------------------------------------------- cache

#[test]
fn cache_round_trip_invalidation_and_corruption() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(lpmsplat::lpm::CACHE_FILE_NAME);
    let mut rng = Pcg64::seed_from_u64(14);
    let (sc, _) = track_scene(&mut rng, 8, 200);
    let s = MatchSettings::default();

    let (c1, s1) = load_or_build(&sc, &s, &path, &no_images, None).unwrap();
    assert_eq!(s1.cache, CacheStatus::Built);
    let (c2, s2) = load_or_build(&sc, &s, &path, &no_images, None).unwrap();
    assert_eq!(s2.cache, CacheStatus::Loaded);
    assert_eq!(c1, c2);
    assert_eq!(s1.candidates, s2.candidates);

    // Settings change → stale → rebuilt.
    let s_other = MatchSettings {
        epipolar_threshold_px: 1.5,
        ..s
    };
    let (_, s3) = load_or_build(&sc, &s_other, &path, &no_images, None).unwrap();
    assert!(
        matches!(&s3.cache, CacheStatus::Rebuilt(why) if why.contains("settings")),
        "{:?}",
        s3.cache
    );
    // Scene change (a pose moves) → stale → rebuilt.
    let mut moved = sc.clone();
    moved.views[3].pose.translation[0] += 1e-3;
    assert_ne!(scene_hash(&moved), scene_hash(&sc));
    let (_, s4) = load_or_build(&moved, &s_other, &path, &no_images, None).unwrap();
    assert!(
        matches!(&s4.cache, CacheStatus::Rebuilt(why) if why.contains("scene")),
        "{:?}",
        s4.cache
    );
    let (_, s5) = load_or_build(&moved, &s_other, &path, &no_images, None).unwrap();
    assert_eq!(s5.cache, CacheStatus::Loaded);

    // Corruption: a flipped byte in the body, a truncated file, a foreign file.
    let (sh, st) = (scene_hash(&moved), s_other.hash());
    let good = std::fs::read(&path).unwrap();
    let mut flipped = good.clone();
    let k = good.len() / 2;
    flipped[k] ^= 0x40;
    std::fs::write(&path, &flipped).unwrap();
    assert!(
        matches!(read_cache(&path, sh, st, moved.views.len()), Err(CacheMiss::Corrupt(m)) if m.contains("checksum"))
    );
    let (c6, s6) = load_or_build(&moved, &s_other, &path, &no_images, None).unwrap();
    assert!(
        matches!(&s6.cache, CacheStatus::Rebuilt(why) if why.contains("corrupt")),
        "{:?}",
        s6.cache
    );
    assert_eq!(
        std::fs::read(&path).unwrap(),
        good,
        "rebuilt file is byte-identical"
    );
    std::fs::write(&path, &good[..good.len() - 20]).unwrap();
    assert!(matches!(
        read_cache(&path, sh, st, moved.views.len()),
        Err(CacheMiss::Corrupt(_))
    ));
    std::fs::write(&path, b"hello, not a cache").unwrap();
    assert!(
        matches!(read_cache(&path, sh, st, moved.views.len()), Err(CacheMiss::Corrupt(m)) if m.contains("magic"))
    );
    std::fs::remove_file(&path).unwrap();
    assert_eq!(
        read_cache(&path, sh, st, moved.views.len()),
        Err(CacheMiss::Missing)
    );
    // Round trip of the values themselves.
    lpmsplat::lpm::cache::write_cache(&path, sh, st, &c6.pairs).unwrap();
    assert_eq!(
        read_cache(&path, sh, st, moved.views.len()).unwrap(),
        c6.pairs
    );
    // No temporary files left behind.
    let names: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
}
