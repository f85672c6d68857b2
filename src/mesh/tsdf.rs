//! A dense truncated signed distance volume fused from depth maps (the bounded TSDF of 2DGS's
//! `extract_mesh_bounded`, which uses Open3D's): per voxel the running weighted mean of
//! `clamp((d − z) / sdf_trunc, ·, 1)` over the views that see it, where `z` is the voxel
//! centre's camera depth and `d` the rendered depth where it projects, interpolated bilinearly
//! between the four nearest pixel centres when all four have depth (as 2DGS's unbounded
//! extraction samples it), else the nearest pixel's (Open3D's choice); views where the voxel is more than `sdf_trunc` behind the surface, outside the
//! image, beyond `depth_trunc`, masked out or without depth do not vote. Colours are fused the
//! same way. Voxel centres sit at `origin + (i + 0.5)·voxel`.

use rayon::prelude::*;

use crate::scene::{PinholeCamera, Pose};

#[derive(Debug, Clone)]
pub struct Tsdf {
    pub origin: [f64; 3],
    pub voxel: f64,
    /// Voxels along x, y, z; index `(k·ny + j)·nx + i`.
    pub dims: [usize; 3],
    pub sdf_trunc: f64,
    pub tsdf: Vec<f32>,
    pub weight: Vec<f32>,
    pub color: Vec<[f32; 3]>,
}

/// One view to fuse: surface depth (camera z, 0 = none) and colour per pixel, row-major, and an
/// optional object mask (pixels outside it do not vote).
pub struct DepthView<'a> {
    pub camera: &'a PinholeCamera,
    pub pose: &'a Pose,
    pub depth: &'a [f32],
    pub rgb: &'a [f32],
    pub mask: Option<&'a [bool]>,
}

impl Tsdf {
    /// An empty volume covering `[lo, hi]` with cubic voxels of side `voxel`.
    pub fn new(lo: [f64; 3], hi: [f64; 3], voxel: f64, sdf_trunc: f64) -> anyhow::Result<Tsdf> {
        anyhow::ensure!(
            voxel > 0.0 && voxel.is_finite() && sdf_trunc > 0.0,
            "TSDF: voxel size {voxel} and truncation {sdf_trunc} must be positive"
        );
        let dims = [0, 1, 2].map(|a| (((hi[a] - lo[a]) / voxel).ceil() as usize).max(1));
        let n = dims[0]
            .checked_mul(dims[1])
            .and_then(|v| v.checked_mul(dims[2]))
            .filter(|&n| n <= 1 << 30)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "TSDF: {}×{}×{} voxels is too many (at most 2^30). Fix: pass a larger \
                     --voxel or a smaller --mesh-res",
                    dims[0],
                    dims[1],
                    dims[2]
                )
            })?;
        Ok(Tsdf {
            origin: lo,
            voxel,
            dims,
            sdf_trunc,
            tsdf: vec![1.0; n],
            weight: vec![0.0; n],
            color: vec![[0.0; 3]; n],
        })
    }

    pub fn center(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        [
            self.origin[0] + (i as f64 + 0.5) * self.voxel,
            self.origin[1] + (j as f64 + 0.5) * self.voxel,
            self.origin[2] + (k as f64 + 0.5) * self.voxel,
        ]
    }

    /// Fuses one view (voxels in parallel, one z slice per task).
    pub fn integrate(&mut self, view: &DepthView, depth_trunc: f64) {
        let [nx, ny, _] = self.dims;
        let (origin, voxel, trunc) = (self.origin, self.voxel, self.sdf_trunc);
        let cam = view.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        self.tsdf
            .par_chunks_mut(nx * ny)
            .zip(self.weight.par_chunks_mut(nx * ny))
            .zip(self.color.par_chunks_mut(nx * ny))
            .enumerate()
            .for_each(|(k, ((tsdf, weight), color))| {
                for j in 0..ny {
                    for i in 0..nx {
                        let p = [
                            origin[0] + (i as f64 + 0.5) * voxel,
                            origin[1] + (j as f64 + 0.5) * voxel,
                            origin[2] + (k as f64 + 0.5) * voxel,
                        ];
                        let c = view.pose.transform(p);
                        if c[2] <= 0.0 {
                            continue;
                        }
                        let u = cam.fx * c[0] / c[2] + cam.cx;
                        let v = cam.fy * c[1] / c[2] + cam.cy;
                        if !(u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64) {
                            continue;
                        }
                        let pix = v as usize * w + u as usize;
                        if view.mask.is_some_and(|m| !m[pix]) {
                            continue;
                        }
                        let d = sample_depth(view.depth, w, h, u, v);
                        if !(d > 0.0 && d <= depth_trunc && d.is_finite()) {
                            continue;
                        }
                        let sdf = d - c[2];
                        if sdf < -trunc {
                            continue;
                        }
                        let t = (sdf / trunc).min(1.0) as f32;
                        let q = j * nx + i;
                        let wq = weight[q];
                        tsdf[q] = (tsdf[q] * wq + t) / (wq + 1.0);
                        for (ch, c) in color[q].iter_mut().enumerate() {
                            *c = (*c * wq + view.rgb[3 * pix + ch]) / (wq + 1.0);
                        }
                        weight[q] = wq + 1.0;
                    }
                }
            });
    }

    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.dims[1] + j) * self.dims[0] + i
    }
}

/// The depth at image point `(u, v)` (pixel centres at `i + 0.5`): bilinear between the four
/// nearest centres when all have depth (> 0), else the nearest pixel's.
fn sample_depth(depth: &[f32], w: usize, h: usize, u: f64, v: f64) -> f64 {
    let nearest = depth[v as usize * w + u as usize] as f64;
    let (x, y) = (u - 0.5, v - 0.5);
    if x < 0.0 || y < 0.0 || x >= (w - 1) as f64 || y >= (h - 1) as f64 {
        return nearest;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |i: usize, j: usize| depth[j * w + i] as f64;
    let q = [
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    ];
    // NaN depths count as missing.
    if q.iter().any(|&d| d.is_nan() || d <= 0.0) {
        return nearest;
    }
    (q[0] * (1.0 - fx) + q[1] * fx) * (1.0 - fy) + (q[2] * (1.0 - fx) + q[3] * fx) * fy
}
