//! The 2DGS regularisers (docs/algorithms/base-models.md §1.4) on the reference's per-pixel outputs, with their
//! gradients as [`SurfelOutputGrads`] for [`super::backward()`]:
//!
//! - **Normal consistency** `mean_pixels(1 − N · N_surf·alpha)`: `N` is the accumulated
//!   (unnormalised) rendered normal, `N_surf` the unit normal of the surface-depth map (each
//!   pixel back-projected along its ray, central differences two rows and two columns apart,
//!   `normalize(rows × columns)`, 0 on the one-pixel border and where the cross product
//!   vanishes), times the accumulated alpha, which is detached (no gradient through it), as in
//!   the official code. The mean runs over every pixel, the border included. Camera space: the
//!   official code compares both in world space, and a dot product does not see the rotation.
//!   Pixel centres are `(i + 0.5, j + 0.5)` through `K⁻¹`, the rasterizer's convention (the
//!   official depth-to-normal puts the principal point half a pixel off its rasterizer's).
//! - **Depth distortion** `mean_pixels(distortion)`.
//!
//! The surface depth is `(1 − depth_ratio)·D/alpha + depth_ratio·median` (0 where `D/alpha`
//! is not finite, with no gradient there), so the normal term's gradient reaches the depth
//! numerator, the alpha map and the median depth.

use super::backward::SurfelOutputGrads;
use super::raster::SurfelRasterOutput;
use crate::reference::linalg::{self, Vec3};
use crate::scene::PinholeCamera;

/// Below this length a cross product of depth differences gives no normal (the official
/// `torch.nn.functional.normalize` eps).
pub const NORMAL_EPS: f64 = 1e-12;

/// The ray through pixel `(i, j)`'s centre with camera z = 1: `K⁻¹ (i + 0.5, j + 0.5, 1)`.
pub fn pixel_ray(camera: &PinholeCamera, i: u32, j: u32) -> Vec3 {
    [
        (i as f64 + 0.5 - camera.cx) / camera.fx,
        (j as f64 + 0.5 - camera.cy) / camera.fy,
        1.0,
    ]
}

/// The surface depth per pixel and, per pixel, whether `D/alpha` was finite (the expected
/// depth's gradient flows only there).
pub fn surface_depth(raster: &SurfelRasterOutput, depth_ratio: f64) -> (Vec<f64>, Vec<bool>) {
    let mut depth = Vec::with_capacity(raster.depth.len());
    let mut finite = Vec::with_capacity(raster.depth.len());
    for (pix, (&d, &a)) in raster.depth.iter().zip(&raster.alpha).enumerate() {
        let e = d / a;
        let ok = e.is_finite();
        let expected = if ok { e } else { 0.0 };
        depth.push((1.0 - depth_ratio) * expected + depth_ratio * raster.median_depth[pix]);
        finite.push(ok);
    }
    (depth, finite)
}

/// The two differences and the unnormalised normal at an interior pixel: `a` = point below −
/// point above, `c` = point right − point left, `a × c`.
fn differences(camera: &PinholeCamera, depth: &[f64], i: u32, j: u32) -> (Vec3, Vec3, Vec3) {
    let w = camera.width as usize;
    let point =
        |x: u32, y: u32| linalg::scale(pixel_ray(camera, x, y), depth[y as usize * w + x as usize]);
    let a = linalg::sub(point(i, j + 1), point(i, j - 1));
    let c = linalg::sub(point(i + 1, j), point(i - 1, j));
    (a, c, cross(a, c))
}

fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn interior(camera: &PinholeCamera, i: u32, j: u32) -> bool {
    i >= 1 && j >= 1 && i + 1 < camera.width && j + 1 < camera.height
}

/// The unit normal of a depth map per pixel (camera space, facing the camera for a surface in
/// front of it), 0 on the border and where the cross product is shorter than [`NORMAL_EPS`].
pub fn depth_normals(camera: &PinholeCamera, depth: &[f64]) -> Vec<Vec3> {
    let mut out = vec![[0.0; 3]; depth.len()];
    for j in 0..camera.height {
        for i in 0..camera.width {
            if !interior(camera, i, j) {
                continue;
            }
            let (_, _, n) = differences(camera, depth, i, j);
            let len = linalg::dot(n, n).sqrt();
            if len > NORMAL_EPS {
                out[(j * camera.width + i) as usize] = linalg::scale(n, 1.0 / len);
            }
        }
    }
    out
}

/// The normal-consistency loss and its gradient with respect to the rendered normal, the depth
/// numerator, the alpha map (through the expected depth only: the weighting alpha is detached)
/// and the median depth, all scaled by `weight`.
pub fn normal_consistency(
    raster: &SurfelRasterOutput,
    camera: &PinholeCamera,
    depth_ratio: f64,
    weight: f64,
) -> (f64, SurfelOutputGrads) {
    let n_pix = raster.depth.len();
    let inv_p = 1.0 / n_pix as f64;
    let (depth, finite) = surface_depth(raster, depth_ratio);
    let normals = depth_normals(camera, &depth);
    let mut grads = SurfelOutputGrads::zeros(n_pix);
    let mut loss = 0.0;
    // dL/d(surface depth), gathered from the four neighbours' normals.
    let mut dl_dsurf = vec![0.0; n_pix];
    let w = camera.width as usize;
    for j in 0..camera.height {
        for i in 0..camera.width {
            let pix = j as usize * w + i as usize;
            let alpha = raster.alpha[pix];
            let rendered = raster.normal[pix];
            let target = linalg::scale(normals[pix], alpha);
            loss += 1.0 - linalg::dot(rendered, target);
            grads.normal[pix] = linalg::scale(target, -weight * inv_p);
            if normals[pix] == [0.0; 3] {
                continue;
            }
            // L_pix = −alpha·N·n̂ with n̂ = v/|v|, v = a × c:
            // dL/dv = −alpha (N − n̂ (n̂·N)) / |v|.
            let (a, c, v) = differences(camera, &depth, i, j);
            let len = linalg::dot(v, v).sqrt();
            let nh = normals[pix];
            let radial = linalg::dot(nh, rendered);
            let dl_dv = linalg::scale(
                linalg::sub(rendered, linalg::scale(nh, radial)),
                -weight * inv_p * alpha / len,
            );
            // v = a × c: dL/da = c × dL/dv, dL/dc = dL/dv × a.
            let dl_da = cross(c, dl_dv);
            let dl_dc = cross(dl_dv, a);
            // a = P(i, j+1) − P(i, j−1), c = P(i+1, j) − P(i−1, j), P = depth·ray.
            let mut add = |x: u32, y: u32, g: Vec3, sign: f64| {
                let q = y as usize * w + x as usize;
                dl_dsurf[q] += sign * linalg::dot(g, pixel_ray(camera, x, y));
            };
            add(i, j + 1, dl_da, 1.0);
            add(i, j - 1, dl_da, -1.0);
            add(i + 1, j, dl_dc, 1.0);
            add(i - 1, j, dl_dc, -1.0);
        }
    }
    for pix in 0..n_pix {
        let g = dl_dsurf[pix];
        grads.median_depth[pix] = depth_ratio * g;
        if finite[pix] {
            // expected = D / alpha.
            let alpha = raster.alpha[pix];
            let ge = (1.0 - depth_ratio) * g;
            grads.depth[pix] = ge / alpha;
            grads.alpha[pix] = -ge * raster.depth[pix] / (alpha * alpha);
        }
    }
    (weight * loss * inv_p, grads)
}

/// The depth-distortion loss `weight · mean(distortion)` and its gradient.
pub fn distortion_loss(raster: &SurfelRasterOutput, weight: f64) -> (f64, SurfelOutputGrads) {
    let n_pix = raster.distortion.len();
    let mut grads = SurfelOutputGrads::zeros(n_pix);
    let g = weight / n_pix as f64;
    grads.distortion.iter_mut().for_each(|v| *v = g);
    (g * raster.distortion.iter().sum::<f64>(), grads)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera {
            fx: 30.0,
            fy: 33.0,
            cx: 9.7,
            cy: 8.2,
            width: 20,
            height: 17,
        }
    }

    #[test]
    fn a_tilted_plane_gives_its_normal_everywhere_inside() {
        // The plane n·P = d with n = normalize(0.3, −0.2, −1), d = −2 (in front, facing the
        // camera): depth along the ray r is d / (n·r).
        let cam = camera();
        let n = {
            let v = [0.3, -0.2, -1.0];
            linalg::scale(v, 1.0 / linalg::dot(v, v).sqrt())
        };
        let mut depth = Vec::new();
        for j in 0..cam.height {
            for i in 0..cam.width {
                depth.push(-2.0 / linalg::dot(n, pixel_ray(&cam, i, j)));
            }
        }
        let normals = depth_normals(&cam, &depth);
        for j in 0..cam.height {
            for i in 0..cam.width {
                let got = normals[(j * cam.width + i) as usize];
                if interior(&cam, i, j) {
                    for k in 0..3 {
                        assert!((got[k] - n[k]).abs() < 1e-12, "{got:?} vs {n:?}");
                    }
                } else {
                    assert_eq!(got, [0.0; 3]);
                }
            }
        }
    }
}
