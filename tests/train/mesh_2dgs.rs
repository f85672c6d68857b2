//! 2DGS's geometry outputs on a constructed scene of known geometry: a sphere of radius
//! [`RADIUS`] tiled with opaque surfels lying in its tangent planes, seen by 14 cameras all
//! around it (a COLMAP text model on disk, 128×96 images). The `mesh` command with every flag
//! that shapes the fusion, read back from its binary PLY; object masks found by the image's stem
//! and by DTU's numbering, resized at `-r 2`, and a missing one named; and the whole chain in
//! process (surfel render → surface depth and normals → TSDF → mesh) measured against the
//! sphere: depth error, normal angle error, mesh-to-surface distance. Validation layer on.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::cli_support::{lpmsplat, run, run_ok};
use crate::sphere_rig::{is_closed, ring_poses};

use lpmsplat::gpu::{GpuBuffer, GpuContext, GpuOptions};
use lpmsplat::mesh::extract::extract;
use lpmsplat::mesh::tsdf::{DepthView, Tsdf};
use lpmsplat::models::BaseModel;
use lpmsplat::reference::project::rotation_to_quat;
use lpmsplat::render::layout::CameraGpu;
use lpmsplat::scene::colmap::{self, ColmapCamera, ColmapImage, ColmapModel};
use lpmsplat::scene::{CameraModel, PinholeCamera, Pose};
use lpmsplat::splats::gpu::GpuSplats;
use lpmsplat::splats::GaussianParams;
use lpmsplat::train::passes::surfels::UNUSED_LOG_SCALE;

/// The sphere's radius; it is centred at the origin.
const RADIUS: f64 = 0.6;
/// Full-size images (the COLMAP cameras').
const W: u32 = 128;
const H: u32 = 96;

fn camera() -> PinholeCamera {
    PinholeCamera {
        fx: 120.0,
        fy: 120.0,
        cx: 64.0,
        cy: 48.0,
        width: W,
        height: H,
    }
}

/// The rotation (w, x, y, z) whose third column is the unit vector `n` (the quaternion between
/// e_z and n; half a turn about x for n = −e_z).
fn facing(n: [f64; 3]) -> [f32; 4] {
    if n[2] < -1.0 + 1e-9 {
        return [0.0, 1.0, 0.0, 0.0];
    }
    let q = [1.0 + n[2], -n[1], n[0], 0.0];
    let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| (v / len) as f32)
}

/// `n` surfels on a Fibonacci lattice of the sphere, each in the sphere's tangent plane at its
/// centre, both scales `sigma`, opacity sigmoid(5), grey.
fn sphere_surfels(n: usize, sigma: f32) -> GaussianParams {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut p = GaussianParams::empty(0);
    for i in 0..n {
        let y = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let ring = (1.0 - y * y).sqrt();
        let a = i as f64 * golden;
        let dir = [ring * a.cos(), y, ring * a.sin()];
        p.positions.push(dir.map(|v| (v * RADIUS) as f32));
        p.log_scales
            .push([sigma.ln(), sigma.ln(), UNUSED_LOG_SCALE]);
        p.rotations.push(facing(dir));
        p.opacity_logits.push(5.0);
        p.sh_dc.push([0.0; 3]);
    }
    p
}

/// The sphere along the ray through pixel centre `(x + 0.5, y + 0.5)`: the near hit's camera z
/// and world point, or None when the ray misses.
fn sphere_hit(cam: &PinholeCamera, pose: &Pose, x: f64, y: f64) -> Option<(f64, [f64; 3])> {
    let rc = [
        (x + 0.5 - cam.cx) / cam.fx,
        (y + 0.5 - cam.cy) / cam.fy,
        1.0,
    ];
    let w = pose.rotation;
    // World direction of the ray with camera z = 1: Rᵀ rc.
    let d = [0, 1, 2].map(|k| w[0][k] * rc[0] + w[1][k] * rc[1] + w[2][k] * rc[2]);
    let o = pose.center();
    let a: f64 = d.iter().map(|v| v * v).sum();
    let b: f64 = 2.0 * (0..3).map(|k| d[k] * o[k]).sum::<f64>();
    let c: f64 = o.iter().map(|v| v * v).sum::<f64>() - RADIUS * RADIUS;
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return None;
    }
    let t = (-b - disc.sqrt()) / (2.0 * a);
    Some((t, [0, 1, 2].map(|k| o[k] + t * d[k])))
}

/// The cosine between the sphere's outward normal at its point `p` and the direction from `p`
/// to the camera.
fn facing_cos(pose: &Pose, p: [f64; 3]) -> f64 {
    let o = pose.center();
    let d = [0, 1, 2].map(|c| o[c] - p[c]);
    let l = d.iter().map(|v| v * v).sum::<f64>().sqrt();
    (0..3).map(|c| p[c] / RADIUS * d[c] / l).sum()
}

/// Whether a ray within two pixels of pixel `(x, y)`'s meets the sphere.
fn near_sphere(cam: &PinholeCamera, pose: &Pose, x: u32, y: u32) -> bool {
    (-2..=2).any(|dy: i32| {
        (-2..=2).any(|dx: i32| {
            sphere_hit(cam, pose, (x as i32 + dx) as f64, (y as i32 + dy) as f64).is_some()
        })
    })
}

fn stem(k: usize) -> String {
    format!("{k:06}")
}

/// The scene on disk: a COLMAP text model (no SfM points) and a PNG per view named like DTU's
/// (`000000.png`, …). COLMAP's split holds out views 0 and 8; the other 12 are `train`.
fn write_scene(root: &Path) -> PathBuf {
    let cam = camera();
    let model = ColmapModel {
        cameras: vec![ColmapCamera::from_model(
            1,
            &CameraModel::Pinhole {
                fx: cam.fx,
                fy: cam.fy,
                cx: cam.cx,
                cy: cam.cy,
            },
            W as u64,
            H as u64,
        )],
        images: ring_poses()
            .iter()
            .enumerate()
            .map(|(k, pose)| ColmapImage {
                id: k as u32 + 1,
                qvec: rotation_to_quat(&pose.rotation),
                tvec: pose.translation,
                camera_id: 1,
                name: format!("{}.png", stem(k)),
                points2d: Vec::new(),
                point3d_ids: Vec::new(),
            })
            .collect(),
        points: Vec::new(),
    };
    colmap::write_text(&root.join("sparse/0"), &model).unwrap();
    std::fs::create_dir_all(root.join("images")).unwrap();
    for im in &model.images {
        image::RgbImage::from_fn(W, H, |x, y| image::Rgb([(x * 2) as u8, (y * 2) as u8, 90]))
            .save(root.join("images").join(&im.name))
            .unwrap();
    }
    root.to_path_buf()
}

/// The object mask of view `k` at `factor` times below full size, the object being the
/// sphere's lower half (world y > 0; the cameras' "up" is −y): white where the pixel's centre
/// ray and all its full-size sub-pixels' rays meet the sphere there, black elsewhere. No pixel
/// that sees the upper half is white, nor one whose ray passes the sphere (where the discs'
/// overhang past the silhouette can reach from the upper half), so nothing above the equator
/// is fused.
fn mask(k: usize, factor: u32) -> image::GrayImage {
    let pose = ring_poses()[k];
    let full = camera();
    let cam = full.resized(W / factor, H / factor);
    let upper =
        |c: &PinholeCamera, x: f64, y: f64| sphere_hit(c, &pose, x, y).is_none_or(|h| h.1[1] < 0.0);
    image::GrayImage::from_fn(cam.width, cam.height, |x, y| {
        let mut hidden = upper(&cam, x as f64, y as f64);
        for sy in 0..factor {
            for sx in 0..factor {
                hidden |= upper(&full, (x * factor + sx) as f64, (y * factor + sy) as f64);
            }
        }
        image::Luma([if hidden { 0 } else { 255 }])
    })
}

/// Every view's mask, `factor` times below full size and then scaled back up by `up` (pixel
/// replication, so an area-average back down by `up` gives it exactly), named by `name`.
fn write_masks(dir: &Path, factor: u32, up: u32, name: impl Fn(usize) -> String) {
    std::fs::create_dir_all(dir).unwrap();
    for k in 0..ring_poses().len() {
        let m = mask(k, factor);
        let big = image::GrayImage::from_fn(m.width() * up, m.height() * up, |x, y| {
            *m.get_pixel(x / up, y / up)
        });
        big.save(dir.join(name(k))).unwrap();
    }
}

fn mesh_cmd(scene: &Path, ply: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut c = lpmsplat();
    c.args([
        "mesh",
        scene.to_str().unwrap(),
        "--ply",
        ply.to_str().unwrap(),
        "-o",
    ])
    .arg(out)
    .args(extra);
    c
}

/// A mesh read back from the binary PLY `mesh` writes.
struct PlyMesh {
    vertices: Vec<[f32; 3]>,
    colors: Vec<[u8; 3]>,
    faces: Vec<[u32; 3]>,
}

/// Parses the file strictly: the header `mesh` promises (binary little-endian; float x, y, z and
/// uchar red, green, blue per vertex; a uchar-counted int list per face), then exactly the
/// bytes that header announces, every face a triangle of in-range indices.
fn read_mesh_ply(path: &Path) -> PlyMesh {
    let bytes = std::fs::read(path).unwrap();
    let end = b"end_header\n";
    let at = bytes
        .windows(end.len())
        .position(|w| w == end)
        .expect("no end_header")
        + end.len();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    let lines: Vec<&str> = header
        .lines()
        .filter(|l| !l.starts_with("comment"))
        .collect();
    let count = |element: &str| -> usize {
        lines
            .iter()
            .find_map(|l| l.strip_prefix(&format!("element {element} ")))
            .unwrap_or_else(|| panic!("no {element} element in\n{header}"))
            .parse()
            .unwrap()
    };
    let (nv, nf) = (count("vertex"), count("face"));
    assert_eq!(
        lines,
        [
            "ply",
            "format binary_little_endian 1.0",
            &format!("element vertex {nv}"),
            "property float x",
            "property float y",
            "property float z",
            "property uchar red",
            "property uchar green",
            "property uchar blue",
            &format!("element face {nf}"),
            "property list uchar int vertex_indices",
            "end_header",
        ],
        "header of {}",
        path.display()
    );
    let body = &bytes[at..];
    assert_eq!(
        body.len(),
        nv * 15 + nf * 13,
        "body size of {}",
        path.display()
    );
    let f32_at = |o: usize| f32::from_le_bytes(body[o..o + 4].try_into().unwrap());
    let mut vertices = Vec::with_capacity(nv);
    let mut colors = Vec::with_capacity(nv);
    for v in 0..nv {
        let o = 15 * v;
        vertices.push([f32_at(o), f32_at(o + 4), f32_at(o + 8)]);
        colors.push([body[o + 12], body[o + 13], body[o + 14]]);
    }
    let mut faces = Vec::with_capacity(nf);
    for f in 0..nf {
        let o = 15 * nv + 13 * f;
        assert_eq!(body[o], 3, "face {f} is not a triangle");
        let idx = [0, 1, 2].map(|k| {
            let i = i32::from_le_bytes(body[o + 1 + 4 * k..o + 5 + 4 * k].try_into().unwrap());
            assert!(
                i >= 0 && (i as usize) < nv,
                "face {f}: index {i} of {nv} vertices"
            );
            i as u32
        });
        faces.push(idx);
    }
    PlyMesh {
        vertices,
        colors,
        faces,
    }
}

/// The surfels are grey (SH DC 0: colour 0.5, byte 128), rendered on black: most vertices are
/// 128, none brighter (a pixel the surfels cover only partly, near a silhouette, is darker).
fn check_grey(m: &PlyMesh) {
    let grey = m
        .colors
        .iter()
        .filter(|c| c.iter().all(|&v| v.abs_diff(128) <= 1))
        .count();
    assert!(
        grey * 4 >= m.colors.len() * 3 && m.colors.iter().flatten().all(|&v| v <= 129),
        "{grey} of {} vertices grey",
        m.colors.len()
    );
}

/// Mean and largest distance of the vertices from the sphere.
fn sphere_distance(vertices: &[[f32; 3]]) -> (f64, f64) {
    let d: Vec<f64> = vertices
        .iter()
        .map(|v| (v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt() - RADIUS).abs())
        .collect();
    (
        d.iter().sum::<f64>() / d.len() as f64,
        d.iter().copied().fold(0.0, f64::max),
    )
}

fn y_range(vertices: &[[f32; 3]]) -> (f64, f64) {
    vertices.iter().fold((f64::MAX, f64::MIN), |(lo, hi), v| {
        (lo.min(v[1] as f64), hi.max(v[1] as f64))
    })
}

/// `mesh` with an explicit voxel, truncation and depth cut, object masks and a preview: a
/// well-formed binary PLY whose vertices lie on the sphere, only on the part the masks leave in
/// (the lower half); without masks the whole sphere, closed; a depth cut in front of the sphere
/// leaves nothing to fuse and says so.
#[test]
fn mesh_cli_fuses_a_surfel_sphere_with_every_flag() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(&dir.path().join("scene"));
    let ply = dir.path().join("sphere.ply");
    lpmsplat::splats::write_ply(&ply, &sphere_surfels(3000, 0.03)).unwrap();
    let masks = dir.path().join("masks");
    write_masks(&masks, 1, 1, |k| format!("{}.png", stem(k)));
    let (voxel, trunc) = (0.03, 0.09);
    let out = dir.path().join("mesh.ply");
    let preview = dir.path().join("preview.png");
    let text = run_ok(&mut mesh_cmd(
        &scene,
        &ply,
        &out,
        &[
            "--voxel",
            "0.03",
            "--sdf-trunc",
            "0.09",
            "--depth-trunc",
            "10",
            "--masks",
            masks.to_str().unwrap(),
            "--preview",
            preview.to_str().unwrap(),
        ],
    ));
    eprintln!("{text}");
    assert!(
        text.contains("12 views, voxel 0.03000") && text.contains("sdf truncation 0.09000"),
        "{text}"
    );
    let m = read_mesh_ply(&out);
    assert!(
        m.faces.len() > 500 && m.vertices.len() > 250,
        "{} faces",
        m.faces.len()
    );
    let (mean, worst) = sphere_distance(&m.vertices);
    let (lo, hi) = y_range(&m.vertices);
    eprintln!(
        "masked: {} vertices, {} faces; distance to the sphere mean {mean:.4}, worst {worst:.4}; \
         y in [{lo:.3}, {hi:.3}]",
        m.vertices.len(),
        m.faces.len()
    );
    assert!(mean < 0.25 * voxel && worst < 1.5 * voxel, "{mean} {worst}");
    // Nothing above the equator was fused: a surface needs voxels that voted "inside", which
    // lie within the truncation behind a seen surface point (y ≥ 0), give or take a voxel and
    // the depth interpolated across the mask's edge.
    assert!(lo > -(trunc + 2.0 * voxel), "a vertex at y = {lo}");
    assert!(hi > 0.9 * RADIUS, "{hi}");
    check_grey(&m);
    // The preview from the first fused view (view 1, the first training view, which looks
    // down on the sphere): the kept lower half is drawn wherever the view sees it face on
    // (shaded 0.15 + 0.85·|cos| per triangle: bright on average, never black), and black
    // where its rays pass the sphere by more than two pixels.
    let img = image::open(&preview).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (W, H));
    let pose = ring_poses()[1];
    let (mut lit, mut sum, mut black) = (0, 0.0, 0);
    for y in 0..H {
        for x in 0..W {
            let v = img.get_pixel(x, y)[0];
            match sphere_hit(&camera(), &pose, x as f64, y as f64) {
                Some((_, p)) if p[1] > 0.06 && facing_cos(&pose, p) > 0.6 => {
                    assert!(v >= 38, "preview ({x}, {y}) = {v}");
                    lit += 1;
                    sum += v as f64;
                }
                Some(_) => {}
                None if !near_sphere(&camera(), &pose, x, y) => {
                    assert_eq!(v, 0, "preview ({x}, {y})");
                    black += 1;
                }
                None => {}
            }
        }
    }
    eprintln!(
        "preview: {lit} pixels of the lower half, mean {:.0}; {black} black",
        sum / lit as f64
    );
    assert!(
        lit > 100 && sum / lit as f64 > 150.0 && black > 5000,
        "{lit} lit, {black} black"
    );

    // Without masks: the whole sphere, one closed piece.
    let whole = dir.path().join("whole.ply");
    run_ok(&mut mesh_cmd(
        &scene,
        &ply,
        &whole,
        &["--voxel", "0.03", "--sdf-trunc", "0.09"],
    ));
    let m = read_mesh_ply(&whole);
    let (mean, worst) = sphere_distance(&m.vertices);
    let (lo, hi) = y_range(&m.vertices);
    eprintln!(
        "whole: {} vertices, {} faces; distance to the sphere mean {mean:.4}, worst {worst:.4}; \
         y in [{lo:.3}, {hi:.3}]",
        m.vertices.len(),
        m.faces.len()
    );
    assert!(mean < 0.25 * voxel && worst < 1.5 * voxel, "{mean} {worst}");
    assert!(lo < -0.9 * RADIUS && hi > 0.9 * RADIUS, "{lo} {hi}");
    check_grey(&m);
    assert!(is_closed(&m.faces), "open or non-manifold edges");

    // The sphere's nearest point is 2.4 from every camera: a depth cut at 2 leaves nothing.
    let (ok, text) = run(&mut mesh_cmd(
        &scene,
        &ply,
        &dir.path().join("cut.ply"),
        &["--voxel", "0.03", "--depth-trunc", "2"],
    ));
    assert!(
        !ok && text.contains("covers no pixel") && text.contains("--depth-trunc"),
        "{text}"
    );
}

/// Object masks by the image's stem (`000001.png`) and by DTU's number (`001.png` for the
/// image `000001.png`) give the same mesh; full-size masks are resized to a scene loaded at
/// `-r 2` (they give the mesh of half-size masks, pixel for pixel); a view without a mask is an
/// error naming the folder, the view and the file looked for.
#[test]
fn mesh_cli_finds_masks_by_stem_and_dtu_number_and_resizes_them() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(&dir.path().join("scene"));
    let ply = dir.path().join("sphere.ply");
    lpmsplat::splats::write_ply(&ply, &sphere_surfels(3000, 0.03)).unwrap();
    // The half-size masks, and the same masks at full size (each pixel twice in x and y).
    let half = dir.path().join("half");
    write_masks(&half, 2, 1, |k| format!("{}.png", stem(k)));
    let by_stem = dir.path().join("by_stem");
    write_masks(&by_stem, 2, 2, |k| format!("{}.png", stem(k)));
    let dtu = dir.path().join("dtu");
    write_masks(&dtu, 2, 2, |k| format!("{k:03}.png"));
    let mesh = |masks: Option<&Path>, name: &str| -> Vec<u8> {
        let out = dir.path().join(name);
        let mut args = vec!["-r", "2", "--voxel", "0.04"];
        if let Some(m) = masks {
            args.extend(["--masks", m.to_str().unwrap()]);
        }
        run_ok(&mut mesh_cmd(&scene, &ply, &out, &args));
        std::fs::read(out).unwrap()
    };
    let (a, b, c) = (
        mesh(Some(&half), "half.ply"),
        mesh(Some(&by_stem), "stem.ply"),
        mesh(Some(&dtu), "dtu.ply"),
    );
    let none = mesh(None, "none.ply");
    assert!(
        a == b,
        "full-size masks resized to -r 2 differ from half-size ones"
    );
    assert!(b == c, "DTU-numbered masks differ from masks named by stem");
    assert!(a != none, "the masks changed nothing");
    let m = read_mesh_ply(&dir.path().join("dtu.ply"));
    let (lo, _) = y_range(&m.vertices);
    // As in `mesh_cli_fuses_a_surfel_sphere_with_every_flag`, with the default truncation of
    // 5 voxels.
    assert!(lo > -(5.0 * 0.04 + 2.0 * 0.04), "a vertex at y = {lo}");
    assert!(y_range(&read_mesh_ply(&dir.path().join("none.ply")).vertices).0 < -0.9 * RADIUS);

    // A scene with its own `mask/` folder (DTU's layout) is meshed with it by default;
    // --no-masks fuses every pixel.
    let own = scene.join("mask");
    write_masks(&own, 2, 2, |k| format!("{k:03}.png"));
    assert!(
        mesh(None, "own.ply") == c,
        "the scene's mask/ folder was not used"
    );
    let out = dir.path().join("no_masks.ply");
    run_ok(&mut mesh_cmd(
        &scene,
        &ply,
        &out,
        &["-r", "2", "--voxel", "0.04", "--no-masks"],
    ));
    assert!(
        std::fs::read(out).unwrap() == none,
        "--no-masks still masked"
    );
    std::fs::remove_dir_all(&own).unwrap();

    // View 3 (a training view) without its mask.
    std::fs::remove_file(dtu.join("003.png")).unwrap();
    let (ok, text) = run(&mut mesh_cmd(
        &scene,
        &ply,
        &dir.path().join("missing.ply"),
        &[
            "-r",
            "2",
            "--voxel",
            "0.04",
            "--masks",
            dtu.to_str().unwrap(),
        ],
    ));
    assert!(!ok, "{text}");
    assert!(
        text.contains(dtu.to_str().unwrap())
            && text.contains("no mask for view 000003")
            && text.contains("000003.png"),
        "{text}"
    );
}

/// The chain in process on the GPU renderer `mesh` uses: every view's surface depth (expected
/// and median) against the sphere's depth along each pixel's ray, the rendered normal against
/// the sphere's, and the TSDF mesh of the fused depths against the sphere.
///
/// The tolerances follow from the voxel `v` and the surfels' flatness: a tangent disc of scale
/// σ leaves the sphere by d²/2R at distance d from its centre (0.0068 at 3σ, 0.0135 along a
/// ray 60° off the normal: 0.45 v), and its normal is off the sphere's by d/R (σ/R = 2.9° at
/// 1σ); the expected depth also blends in the far side of the sphere behind the last 1 % of
/// transmittance. The fusion's own error is a fraction of a voxel (`tests/train/mesh_tsdf.rs`); near
/// a silhouette the discs overhang the sphere, and where few views carve that away a few
/// vertices stand out by most of a voxel.
/// Measured (lavapipe, 2026-11-29): expected depth error mean 0.00125 (0.04 v), worst 0.0075
/// (0.25 v); median mean 0.0018, worst 0.0141 (0.47 v); normal angle mean 3.15°, worst 3.53°;
/// mesh-to-sphere distance mean 0.105 v, 99th percentile 0.4 v, worst 0.94 v (v = 0.03).
#[test]
fn a_rendered_surfel_sphere_gives_its_depth_normals_and_mesh() {
    let ctx = GpuContext::new(&GpuOptions::for_tests()).unwrap();
    let sigma = 0.03;
    let params = sphere_surfels(3000, sigma as f32);
    let splats = GpuSplats::upload(&ctx, &params, params.len()).unwrap();
    let cam = camera();
    let poses = ring_poses();
    let cams: Vec<CameraGpu> = poses.iter().map(|p| CameraGpu::new(&cam, p)).collect();
    let cameras = GpuBuffer::from_slice(&ctx, "cameras", &cams).unwrap();
    let mut renderer = BaseModel::Surfels2d
        .view_renderer(&ctx, params.len(), &cams[0], None, None)
        .unwrap();
    let voxel = 0.03;
    let mut tsdf = Tsdf::new([-1.0; 3], [1.0; 3], voxel, 3.0 * voxel).unwrap();
    let (mut expected_err, mut median_err, mut angles) = (Vec::new(), Vec::new(), Vec::new());
    let (mut uncovered, mut stray) = (0usize, 0usize);
    for (k, pose) in poses.iter().enumerate() {
        let rgb = renderer
            .render(&splats, &cameras, k as u32, &cams[k], [0.0; 3])
            .unwrap();
        let maps = renderer.geometry(&cams[k]).unwrap().unwrap();
        let expected = maps.surface_depth(0.0);
        let median = maps.surface_depth(1.0);
        let normals = maps.world_normals(pose);
        for y in 0..H {
            for x in 0..W {
                let pix = (y * W + x) as usize;
                let alpha = maps.alpha[pix];
                let Some((z, p)) = sphere_hit(&cam, pose, x as f64, y as f64) else {
                    // Off the sphere by more than two pixels: nothing drawn.
                    if !near_sphere(&cam, pose, x, y) && alpha > 0.01 {
                        stray += 1;
                    }
                    continue;
                };
                // Only pixels seeing the sphere at least 30° from grazing are measured
                // (towards the silhouette the surfels' discs overhang it).
                if facing_cos(pose, p) < 0.5 {
                    continue;
                }
                if alpha < 0.99 {
                    uncovered += 1;
                    continue;
                }
                expected_err.push((expected[pix] as f64 - z).abs());
                median_err.push((median[pix] as f64 - z).abs());
                let r = normals[pix].map(f64::from);
                let len = r.iter().map(|v| v * v).sum::<f64>().sqrt();
                let cos: f64 = (0..3).map(|c| r[c] * p[c] / RADIUS).sum::<f64>() / len;
                angles.push(cos.clamp(-1.0, 1.0).acos().to_degrees());
            }
        }
        // Fuse as `mesh` does: no depth where the accumulated alpha is below 0.5.
        let depth: Vec<f32> = expected
            .iter()
            .zip(&maps.alpha)
            .map(|(&d, &a)| if a < 0.5 { 0.0 } else { d })
            .collect();
        tsdf.integrate(
            &DepthView {
                camera: &cam,
                pose,
                depth: &depth,
                rgb: &rgb,
                mask: None,
            },
            f64::INFINITY,
        );
    }
    let mesh = extract(&tsdf).keep_large_pieces(50, 50);
    let mut mesh_err: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|v| (v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt() - RADIUS).abs())
        .collect();
    // Mean, 99th percentile and largest.
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        (mean, v[v.len() * 99 / 100], v[v.len() - 1])
    };
    let n = angles.len();
    let (e_mean, e_p99, e_worst) = stats(&mut expected_err);
    let (m_mean, m_p99, m_worst) = stats(&mut median_err);
    let (a_mean, a_p99, a_worst) = stats(&mut angles);
    let (v_mean, v_p99, v_worst) = stats(&mut mesh_err);
    eprintln!(
        "{n} pixels (14 views, {W}×{H}; 3000 surfels of σ {sigma} on a sphere of radius \
         {RADIUS}); voxel v = {voxel}; mean / 99th percentile / worst:\n  \
         expected depth error {e_mean:.5} / {e_p99:.5} / {e_worst:.5} ({:.3} / {:.3} / {:.3} v)\n  \
         median depth error {m_mean:.5} / {m_p99:.5} / {m_worst:.5} ({:.3} / {:.3} / {:.3} v)\n  \
         normal angle error {a_mean:.3}° / {a_p99:.3}° / {a_worst:.3}°\n  \
         mesh ({} vertices, {} triangles) to sphere {v_mean:.5} / {v_p99:.5} / {v_worst:.5} \
         ({:.3} / {:.3} / {:.3} v)\n  \
         {uncovered} measured pixels with alpha < 0.99, {stray} drawn pixels off the sphere",
        e_mean / voxel,
        e_p99 / voxel,
        e_worst / voxel,
        m_mean / voxel,
        m_p99 / voxel,
        m_worst / voxel,
        mesh.vertices.len(),
        mesh.triangles.len(),
        v_mean / voxel,
        v_p99 / voxel,
        v_worst / voxel,
    );
    assert!(n > 15_000, "{n} pixels measured");
    assert_eq!(uncovered, 0, "pixels facing the cameras not covered");
    assert_eq!(stray, 0, "pixels drawn off the sphere");
    assert!(
        e_mean < 0.1 * voxel && e_worst < 0.5 * voxel,
        "expected depth"
    );
    assert!(
        m_mean < 0.1 * voxel && m_worst < 0.7 * voxel,
        "median depth"
    );
    let sigma_deg = (sigma / RADIUS).to_degrees();
    assert!(
        a_mean < 1.5 * sigma_deg && a_worst < 3.0 * sigma_deg,
        "normal angle (σ/R = {sigma_deg:.2}°)"
    );
    assert!(mesh.triangles.len() > 2000, "{}", mesh.triangles.len());
    assert!(
        v_mean < 0.2 * voxel && v_p99 < 0.5 * voxel && v_worst < 1.5 * voxel,
        "mesh distance"
    );
    ctx.check_validation().unwrap();
}
