//! A picture of a mesh from a camera, to look at a [`Mesh`] without a mesh viewer: a CPU
//! z-buffer rasterizer (pixel centres, barycentric depth) with grey headlight shading
//! `0.15 + 0.85·|n·v|` (flat per triangle, both sides lit) on black.

use super::Mesh;
use crate::scene::{Image, PinholeCamera, Pose};

pub fn render_preview(mesh: &Mesh, camera: &PinholeCamera, pose: &Pose) -> Image {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let mut depth = vec![f64::INFINITY; w * h];
    let mut shade = vec![0.0f32; w * h];
    let cam_pts: Vec<[f64; 3]> = mesh
        .vertices
        .iter()
        .map(|v| pose.transform(v.map(f64::from)))
        .collect();
    for t in &mesh.triangles {
        let p = t.map(|i| cam_pts[i as usize]);
        if p.iter().any(|q| q[2] <= 1e-6) {
            continue;
        }
        let s = p.map(|q| {
            [
                camera.fx * q[0] / q[2] + camera.cx,
                camera.fy * q[1] / q[2] + camera.cy,
            ]
        });
        let u = [0, 1, 2].map(|c| p[1][c] - p[0][c]);
        let v = [0, 1, 2].map(|c| p[2][c] - p[0][c]);
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let c = [0, 1, 2].map(|k| (p[0][k] + p[1][k] + p[2][k]) / 3.0);
        let (nl, cl) = (
            (n.iter().map(|x| x * x).sum::<f64>()).sqrt(),
            (c.iter().map(|x| x * x).sum::<f64>()).sqrt(),
        );
        if nl <= 0.0 {
            continue;
        }
        let lit =
            (0.15 + 0.85 * ((n[0] * c[0] + n[1] * c[1] + n[2] * c[2]) / (nl * cl)).abs()) as f32;
        let area =
            (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[2][0] - s[0][0]) * (s[1][1] - s[0][1]);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = s
            .iter()
            .map(|q| q[0])
            .fold(f64::INFINITY, f64::min)
            .floor()
            .max(0.0) as usize;
        let x1 = (s
            .iter()
            .map(|q| q[0])
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil() as isize)
            .clamp(0, w as isize) as usize;
        let y0 = s
            .iter()
            .map(|q| q[1])
            .fold(f64::INFINITY, f64::min)
            .floor()
            .max(0.0) as usize;
        let y1 = (s
            .iter()
            .map(|q| q[1])
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil() as isize)
            .clamp(0, h as isize) as usize;
        for y in y0..y1 {
            for x in x0..x1 {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let e = |a: [f64; 2], b: [f64; 2]| {
                    (b[0] - a[0]) * (py - a[1]) - (px - a[0]) * (b[1] - a[1])
                };
                let b0 = e(s[1], s[2]) / area;
                let b1 = e(s[2], s[0]) / area;
                let b2 = 1.0 - b0 - b1;
                if b0 < 0.0 || b1 < 0.0 || b2 < 0.0 {
                    continue;
                }
                // Perspective-correct depth: 1/z is affine in screen space.
                let inv_z = b0 / p[0][2] + b1 / p[1][2] + b2 / p[2][2];
                let z = 1.0 / inv_z;
                let q = y * w + x;
                if z < depth[q] {
                    depth[q] = z;
                    shade[q] = lit;
                }
            }
        }
    }
    Image {
        width: camera.width,
        height: camera.height,
        rgb: shade.iter().flat_map(|&s| [s; 3]).collect(),
        alpha: None,
    }
}
