//! Initial points triangulated from feature matches (`triangulated_init`) on a constructed
//! scene of known geometry: a textured plane rendered by the f64 reference from three posed
//! cameras. Every kept point must lie on the plane, inside its extent; as a video scene (two
//! times), every point carries the time of the frame it came from.

use glam::DVec3;
use lpmsplat::reference::{render, RefGaussians, RenderSettings};
use lpmsplat::scene::images::save_png;
use lpmsplat::scene::orbit::look_at;
use lpmsplat::scene::{CameraModel, Image, PinholeCamera, Scene, SceneFormat, View};
use lpmsplat::triangulated_init::{source_views, topped_up_model, triangulate_scene};
use rand::{Rng, SeedableRng};

const PLANE_Z: f64 = 0.0;
const HALF: f64 = 1.5;

/// A plane z = PLANE_Z textured with separate round Gaussians of random colours and sizes on
/// a jittered grid (texture to match; blobs that overlapped would occlude each other in an
/// order that changes with the view, which no real surface does).
fn textured_plane() -> RefGaussians {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x7E47);
    let cells = 36;
    let step = 2.0 * HALF / cells as f64;
    let mut g = RefGaussians::default();
    for gx in 0..cells {
        for gy in 0..cells {
            let at = |k: usize, rng: &mut rand_pcg::Pcg64| {
                -HALF + step * (k as f64 + 0.5) + rng.gen_range(-0.15..0.15) * step
            };
            g.positions
                .push([at(gx, &mut rng), at(gy, &mut rng), PLANE_Z]);
            let s = (step * rng.gen_range(0.15..0.28)).ln();
            g.log_scales.push([s; 3]);
            g.rotations.push([1.0, 0.0, 0.0, 0.0]);
            g.opacity_logits.push(6.0);
            let mut sh = [[0.0; 3]; 16];
            sh[0] = [0; 3].map(|_| rng.gen_range(-1.6..1.6));
            g.sh.push(sh);
        }
    }
    g
}

/// Three cameras 4 units in front of the plane, rendered to PNGs in `dir`, as a scene (with
/// `times`, each camera's image reused at every time, as a video of a still plane).
fn plane_scene(dir: &std::path::Path, times: &[f64]) -> Scene {
    let (w, h) = (320u32, 240u32);
    let camera = PinholeCamera {
        fx: 300.0,
        fy: 300.0,
        cx: w as f64 / 2.0,
        cy: h as f64 / 2.0,
        width: w,
        height: h,
    };
    let eyes = [[0.0, 0.0, -4.0], [-0.7, 0.1, -3.9], [0.6, -0.3, -4.1]];
    let g = textured_plane();
    let mut views = Vec::new();
    let mut view_times = Vec::new();
    for (c, eye) in eyes.iter().enumerate() {
        let pose = look_at(
            DVec3::from(*eye),
            DVec3::new(0.0, 0.0, PLANE_Z),
            DVec3::NEG_Y,
        );
        let out = render(&g, &camera, &pose, 0, [0.0; 3], &RenderSettings::default()).unwrap();
        let mut img = Image::new(w, h);
        for (i, p) in out.raster.image.iter().enumerate() {
            img.set_pixel(i as u32 % w, i as u32 / w, p.map(|v| v as f32));
        }
        let path = dir.join(format!("cam{c}.png"));
        save_png(&path, &img).unwrap();
        for &t in times {
            views.push(View {
                name: format!("cam{c}/{t}"),
                stem: format!("cam{c}_{t}"),
                image_path: path.clone(),
                source_model: CameraModel::Pinhole {
                    fx: camera.fx,
                    fy: camera.fy,
                    cx: camera.cx,
                    cy: camera.cy,
                },
                source_width: w,
                source_height: h,
                camera,
                pose,
                colmap_image_id: None,
                keypoints: None,
            });
            view_times.push(t);
        }
    }
    let train: Vec<usize> = (0..views.len()).collect();
    Scene {
        root: dir.to_path_buf(),
        format: SceneFormat::Video,
        views,
        train,
        test: Vec::new(),
        points: None,
        center: [0.0, 0.0, -4.0],
        extent: 1.0,
        background: None,
        has_alpha: false,
        view_times: (times.len() > 1).then_some(view_times),
        time_base: None,
        frame: lpmsplat::scene::SceneFrame::IDENTITY,
    }
}

#[test]
fn triangulated_points_lie_on_the_plane() {
    let dir = tempfile::tempdir().unwrap();
    let scene = plane_scene(dir.path(), &[0.0]);
    let tri = triangulate_scene(&scene, 100_000, 0).unwrap();
    let n = tri.positions.len();
    assert!(n >= 200, "only {n} points from {} matches", tri.matches);
    // Depth from a 0.6–0.7 unit baseline at 4 units and f = 300 px moves ~0.08 units per pixel
    // of keypoint error. Two views cannot reject a wrong match that lies along its epipolar
    // line, so a few points may be far off: at least 97 % within 0.1 of the plane (inside its
    // extent), half of them within 0.04, and no bias (signed median within 0.005).
    let mut dz: Vec<f64> = tri
        .positions
        .iter()
        .map(|p| (p[2] - PLANE_Z).abs())
        .collect();
    let near = tri
        .positions
        .iter()
        .zip(&dz)
        .filter(|(p, &d)| d < 0.1 && p[0].abs() < HALF + 0.1 && p[1].abs() < HALF + 0.1)
        .count();
    assert!(near * 100 >= n * 97, "{near} of {n} points near the plane");
    dz.sort_by(f64::total_cmp);
    let median = dz[n / 2];
    let mut signed: Vec<f64> = tri.positions.iter().map(|p| p[2] - PLANE_Z).collect();
    signed.sort_by(f64::total_cmp);
    let bias = signed[n / 2];
    assert!(
        bias.abs() < 0.005,
        "median signed distance to the plane {bias}"
    );
    assert!(median < 0.04, "median distance to the plane {median}");
    eprintln!("{n} points, {near} near the plane, median distance {median:.4}");
    // Colours come from the images (not all black or white).
    assert!(tri
        .colors
        .iter()
        .any(|c| c.iter().any(|&v| v > 20 && v < 235)));
    // The cap keeps a seeded subset.
    let capped = triangulate_scene(&scene, 50, 0).unwrap();
    assert_eq!(capped.positions.len(), 50);
    assert!(capped.positions.iter().all(|p| tri.positions.contains(p)));
    // Topped up with random points to the asked total, the triangulated ones first.
    let model = topped_up_model(&capped, &scene, 80, 0, 0).unwrap();
    assert_eq!(model.len(), 80);
    for (m, p) in model.positions.iter().zip(&capped.positions) {
        assert_eq!(*m, p.map(|v| v as f32));
    }
    assert_eq!(topped_up_model(&tri, &scene, 10, 0, 0).unwrap().len(), n);
}

#[test]
fn video_points_carry_their_frame_time() {
    let dir = tempfile::tempdir().unwrap();
    let times = [0.0, 0.25, 0.5, 0.75];
    let scene = plane_scene(dir.path(), &times);
    // Every distinct time is a source frame here (fewer than VIDEO_FRAMES of them), and a
    // view is only matched with views of its own time.
    assert_eq!(source_views(&scene).len(), scene.views.len());
    let tri = triangulate_scene(&scene, 100_000, 0).unwrap();
    assert_eq!(tri.times.len(), tri.positions.len());
    for t in times {
        let k = tri.times.iter().filter(|&&x| x == t).count();
        assert!(k >= 100, "time {t}: {k} points");
    }
    assert!(tri.times.iter().all(|t| times.contains(t)));
}
