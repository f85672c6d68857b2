//! Undistortion of distorted camera models to pinhole.
//!
//! The undistorted camera keeps the source's fx, fy, cx, cy and image size. COLMAP's
//! `image_undistorter` instead grows or crops the image to keep every source pixel; keeping K
//! means keypoints, poses and the training resolution stay exactly those of the model, and a
//! pinhole model passes through untouched. The price: with pincushion distortion (k > 0) the
//! corners of the pinhole image fall outside the source and stay black; with barrel distortion
//! (k < 0) a thin band of the source's border is not used.

use rayon::prelude::*;

use super::{CameraModel, Image};

/// Newton iterations allowed before giving up on a pixel.
const MAX_ITERS: usize = 50;
/// Convergence threshold on the distortion residual, in normalised coordinates (≈1e-9 px at
/// focal lengths in the thousands).
const TOLERANCE: f64 = 1e-12;

/// Jacobian of the model's distortion at normalised (x, y), by central differences: the
/// distortion formulas then live only in [`CameraModel::distort_normalized`].
fn distortion_jacobian(model: &CameraModel, x: f64, y: f64) -> [[f64; 2]; 2] {
    let hx = 1e-7 * (1.0 + x.abs());
    let hy = 1e-7 * (1.0 + y.abs());
    let (ax, ay) = model.distort_normalized(x + hx, y);
    let (bx, by) = model.distort_normalized(x - hx, y);
    let (cx, cy) = model.distort_normalized(x, y + hy);
    let (dx, dy) = model.distort_normalized(x, y - hy);
    [
        [(ax - bx) / (2.0 * hx), (cx - dx) / (2.0 * hy)],
        [(ay - by) / (2.0 * hx), (cy - dy) / (2.0 * hy)],
    ]
}

fn det(j: &[[f64; 2]; 2]) -> f64 {
    j[0][0] * j[1][1] - j[0][1] * j[1][0]
}

/// True where the distortion still maps the plane one-to-one around normalised (x, y). Past the
/// fold of a strong barrel distortion the mapping turns back on itself, and a pinhole pixel
/// there would repeat content from nearer the centre.
fn is_unfolded(model: &CameraModel, x: f64, y: f64) -> bool {
    det(&distortion_jacobian(model, x, y)) > 0.0
}

/// Inverts the distortion: distorted normalised coordinates → undistorted ones, by Newton's
/// method from the distorted point. `None` when it does not converge or lands past the fold.
pub fn undistort_normalized(model: &CameraModel, xd: f64, yd: f64) -> Option<[f64; 2]> {
    if !model.is_distorted() {
        return Some([xd, yd]);
    }
    if !xd.is_finite() || !yd.is_finite() {
        return None;
    }
    let (mut x, mut y) = (xd, yd);
    for _ in 0..MAX_ITERS {
        let (fx, fy) = model.distort_normalized(x, y);
        let (rx, ry) = (fx - xd, fy - yd);
        if rx.abs().max(ry.abs()) < TOLERANCE {
            return is_unfolded(model, x, y).then_some([x, y]);
        }
        let j = distortion_jacobian(model, x, y);
        let d = det(&j);
        if d.is_nan() || d.abs() <= 1e-12 {
            return None;
        }
        x -= (j[1][1] * rx - j[0][1] * ry) / d;
        y -= (j[0][0] * ry - j[1][0] * rx) / d;
        if !x.is_finite() || !y.is_finite() {
            return None;
        }
    }
    None
}

/// Pixel of the distorted source image → pixel of the undistorted pinhole image (same K).
/// `None` when the distortion cannot be inverted there.
pub fn undistort_pixel(model: &CameraModel, u: f64, v: f64) -> Option<[f64; 2]> {
    if !model.is_distorted() {
        return Some([u, v]);
    }
    let (fx, fy, cx, cy) = model.pinhole_part();
    let [x, y] = undistort_normalized(model, (u - cx) / fx, (v - cy) / fy)?;
    Some([fx * x + cx, fy * y + cy])
}

/// Pixel of the undistorted pinhole image → pixel of the distorted source image (same K).
pub fn distort_pixel(model: &CameraModel, u: f64, v: f64) -> [f64; 2] {
    let (fx, fy, cx, cy) = model.pinhole_part();
    let (x, y) = model.distort_normalized((u - cx) / fx, (v - cy) / fy);
    [fx * x + cx, fy * y + cy]
}

/// Bilinear footprint of a sample: two columns, two rows and their weights.
struct Footprint {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    tx: f32,
    ty: f32,
}

impl Footprint {
    /// The footprint at source pixel coordinates (u, v) (pixel centres at +0.5), or `None`
    /// outside the image. Within half a pixel of the border the edge pixel is repeated.
    fn at(u: f64, v: f64, width: u32, height: u32) -> Option<Footprint> {
        if !(u >= 0.0 && v >= 0.0 && u <= width as f64 && v <= height as f64) {
            return None;
        }
        let px = (u - 0.5).clamp(0.0, (width - 1) as f64);
        let py = (v - 0.5).clamp(0.0, (height - 1) as f64);
        let (x0, y0) = (px.floor() as usize, py.floor() as usize);
        Some(Footprint {
            x0,
            y0,
            x1: (x0 + 1).min(width as usize - 1),
            y1: (y0 + 1).min(height as usize - 1),
            tx: (px - x0 as f64) as f32,
            ty: (py - y0 as f64) as f32,
        })
    }

    fn sample(&self, data: &[f32], width: usize, channels: usize, c: usize) -> f32 {
        let at = |x: usize, y: usize| data[(y * width + x) * channels + c];
        let top = at(self.x0, self.y0) * (1.0 - self.tx) + at(self.x1, self.y0) * self.tx;
        let bottom = at(self.x0, self.y1) * (1.0 - self.tx) + at(self.x1, self.y1) * self.tx;
        top * (1.0 - self.ty) + bottom * self.ty
    }
}

/// Resamples a distorted source image into the pinhole image with the same K and size: each
/// output pixel centre is distorted into the source and sampled bilinearly. Pixels that land
/// outside the source (or past the distortion's fold) are 0 in every channel, alpha included.
pub fn undistort_image(model: &CameraModel, src: &Image) -> Image {
    if !model.is_distorted() || src.width == 0 || src.height == 0 {
        return src.clone();
    }
    let (w, h) = (src.width as usize, src.height as usize);
    let (fx, fy, cx, cy) = model.pinhole_part();
    let rows: Vec<(Vec<f32>, Option<Vec<f32>>)> = (0..h)
        .into_par_iter()
        .map(|j| {
            let mut rgb = vec![0.0f32; w * 3];
            let mut alpha = src.alpha.as_ref().map(|_| vec![0.0f32; w]);
            for i in 0..w {
                let x = (i as f64 + 0.5 - cx) / fx;
                let y = (j as f64 + 0.5 - cy) / fy;
                if !is_unfolded(model, x, y) {
                    continue;
                }
                let (xd, yd) = model.distort_normalized(x, y);
                let Some(fp) = Footprint::at(fx * xd + cx, fy * yd + cy, src.width, src.height)
                else {
                    continue;
                };
                for c in 0..3 {
                    rgb[i * 3 + c] = fp.sample(&src.rgb, w, 3, c);
                }
                if let (Some(out), Some(a)) = (alpha.as_mut(), src.alpha.as_ref()) {
                    out[i] = fp.sample(a, w, 1, 0);
                }
            }
            (rgb, alpha)
        })
        .collect();
    let mut rgb = Vec::with_capacity(w * h * 3);
    let mut alpha = src.alpha.as_ref().map(|_| Vec::with_capacity(w * h));
    for (r, a) in rows {
        rgb.extend_from_slice(&r);
        if let (Some(out), Some(a)) = (alpha.as_mut(), a) {
            out.extend_from_slice(&a);
        }
    }
    Image {
        width: src.width,
        height: src.height,
        rgb,
        alpha,
    }
}
