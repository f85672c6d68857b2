//! The TSDF fusion and marching-tetrahedra extraction against known geometry: exact depth maps
//! of a sphere seen from several cameras give a closed mesh whose vertices lie on the surface
//! (mesh-to-surface distance a fraction of a voxel), facing outwards, with the fused colours;
//! masks and the depth cut keep pixels out; small pieces are dropped; the preview shows it.
//! `tests/train/mesh_2dgs.rs` fuses depths rendered from surfels, in process and through `mesh`.

use crate::sphere_rig::{is_closed, ring_poses};
use lpmsplat::mesh::extract::extract;
use lpmsplat::mesh::tsdf::{DepthView, Tsdf};
use lpmsplat::mesh::Mesh;
use lpmsplat::scene::{PinholeCamera, Pose};

fn camera() -> PinholeCamera {
    PinholeCamera {
        fx: 120.0,
        fy: 120.0,
        cx: 64.0,
        cy: 48.0,
        width: 128,
        height: 96,
    }
}

/// Depth (camera z) of the sphere |x − c| = r along every pixel ray, 0 where it misses.
fn sphere_depth(cam: &PinholeCamera, pose: &Pose, c: [f64; 3], r: f64) -> Vec<f32> {
    let o = pose.center();
    let mut out = Vec::new();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let rc = [
                (x as f64 + 0.5 - cam.cx) / cam.fx,
                (y as f64 + 0.5 - cam.cy) / cam.fy,
                1.0,
            ];
            // World direction of the ray with camera z = 1: Rᵀ rc.
            let w = pose.rotation;
            let d = [0, 1, 2].map(|k| w[0][k] * rc[0] + w[1][k] * rc[1] + w[2][k] * rc[2]);
            let oc = [0, 1, 2].map(|k| o[k] - c[k]);
            let a: f64 = d.iter().map(|v| v * v).sum();
            let b: f64 = 2.0 * (0..3).map(|k| d[k] * oc[k]).sum::<f64>();
            let cc: f64 = oc.iter().map(|v| v * v).sum::<f64>() - r * r;
            let disc = b * b - 4.0 * a * cc;
            out.push(if disc < 0.0 {
                0.0
            } else {
                ((-b - disc.sqrt()) / (2.0 * a)) as f32
            });
        }
    }
    out
}

fn fuse_sphere(voxel: f64, mask: bool, depth_trunc: f64) -> (Mesh, f64) {
    let cam = camera();
    let r = 0.7;
    let mut tsdf = Tsdf::new([-1.0; 3], [1.0; 3], voxel, 4.0 * voxel).unwrap();
    let rgb = vec![0.25f32; (cam.width * cam.height * 3) as usize];
    for pose in ring_poses() {
        let depth = sphere_depth(&cam, &pose, [0.0; 3], r);
        // A mask that hides the left half of every image.
        let m: Vec<bool> = (0..depth.len())
            .map(|p| !mask || (p as u32 % cam.width) >= cam.width / 2)
            .collect();
        tsdf.integrate(
            &DepthView {
                camera: &cam,
                pose: &pose,
                depth: &depth,
                rgb: &rgb,
                mask: Some(&m),
            },
            depth_trunc,
        );
    }
    (extract(&tsdf), r)
}

#[test]
fn a_fused_sphere_is_a_closed_outward_mesh_on_the_sphere() {
    let voxel = 0.04;
    let (mesh, r) = fuse_sphere(voxel, false, f64::INFINITY);
    assert!(mesh.triangles.len() > 1000, "{}", mesh.triangles.len());
    let (mut worst, mut sum) = (0.0f64, 0.0);
    for v in &mesh.vertices {
        let d = (v.iter().map(|&x| (x as f64).powi(2)).sum::<f64>()).sqrt();
        worst = worst.max((d - r).abs());
        sum += (d - r).abs();
    }
    let mean = sum / mesh.vertices.len() as f64;
    eprintln!(
        "{} triangles, distance to the sphere: mean {mean:.5}, worst {worst:.4} (voxel {voxel})",
        mesh.triangles.len()
    );
    // A projective TSDF (depth differences along each view's z) is exact on the rays, but near
    // a view's silhouette a voxel just outside the far side lies within the truncation behind
    // the near side and votes "inside": the fused zero crossing moves inwards by a fraction of a
    // voxel there (Open3D's fusion does the same). Measured: mean 0.11 voxel, worst 0.63.
    assert!(mean < 0.15 * voxel, "{mean}");
    assert!(worst < voxel, "{worst}");
    // Closed: every edge is shared by exactly two triangles.
    assert!(
        is_closed(&mesh.triangles),
        "the mesh has open or non-manifold edges"
    );
    // Outward: each face normal points away from the centre.
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.vertices[i as usize].map(f64::from));
        let u = [0, 1, 2].map(|c| p[1][c] - p[0][c]);
        let w = [0, 1, 2].map(|c| p[2][c] - p[0][c]);
        let n = [
            u[1] * w[2] - u[2] * w[1],
            u[2] * w[0] - u[0] * w[2],
            u[0] * w[1] - u[1] * w[0],
        ];
        let c = [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0);
        assert!(
            n[0] * c[0] + n[1] * c[1] + n[2] * c[2] > 0.0,
            "an inward face"
        );
    }
    assert!(mesh
        .colors
        .iter()
        .all(|c| c.iter().all(|&v| (v - 0.25).abs() < 1e-5)));
    // One piece; a threshold above its size drops it.
    assert_eq!(
        mesh.keep_large_pieces(50, 50).triangles.len(),
        mesh.triangles.len()
    );
    assert!(mesh
        .keep_large_pieces(mesh.triangles.len() + 1, 50)
        .triangles
        .is_empty());
}

#[test]
fn masks_and_the_depth_cut_keep_pixels_out() {
    let (all, _) = fuse_sphere(0.05, false, f64::INFINITY);
    let (masked, _) = fuse_sphere(0.05, true, f64::INFINITY);
    // Hiding half of every image leaves parts of the sphere unseen or only partly carved.
    assert_ne!(masked.triangles.len(), all.triangles.len());
    // Nothing is nearer than 2.2 (cameras at distance ~3, sphere radius 0.7): no surface.
    let (cut, _) = fuse_sphere(0.05, false, 1.5);
    assert!(cut.triangles.is_empty());
}

#[test]
fn a_tsdf_too_large_is_refused_with_a_fix() {
    let err = Tsdf::new([0.0; 3], [1000.0; 3], 0.01, 0.05)
        .unwrap_err()
        .to_string();
    assert!(err.contains("--voxel"), "{err}");
}

/// The preview of the fused sphere from one of the fusing views: lit where the sphere faces
/// the camera, darker towards its silhouette, black around it.
#[test]
fn the_preview_shows_the_sphere_lit_from_the_camera() {
    let (mesh, _) = fuse_sphere(0.04, false, f64::INFINITY);
    let cam = camera();
    let pose = ring_poses()[0];
    let img = lpmsplat::mesh::preview::render_preview(&mesh, &cam, &pose);
    let at = |x: u32, y: u32| img.rgb[3 * (y * cam.width + x) as usize];
    // The sphere's centre projects to the principal point (the view looks at the origin).
    assert!(at(64, 48) > 0.95, "{}", at(64, 48));
    assert_eq!(at(2, 2), 0.0);
    // Radius 0.7 at distance ~3.23: ~26 px; 22 px out the surface is seen at a grazing angle.
    assert!(
        at(64 + 22, 48) < at(64 + 5, 48),
        "{} vs {}",
        at(86, 48),
        at(69, 48)
    );
}
