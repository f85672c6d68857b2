//! Undistortion of distorted camera models to pinhole. (Skeleton: being written by the COLMAP work.)
//!
//! Interface (to be implemented):
//! - `undistort_pixel(model, u, v) -> Option<[f64; 2]>`: a pixel of the distorted source image to
//!   the pixel of the undistorted pinhole image with the same fx, fy, cx, cy and size.
//! - `undistort_image(model, &Image) -> Image`: resamples a source image (parallel, bilinear).

use super::{CameraModel, Image};

/// Pixel of the distorted image → pixel of the undistorted pinhole image (same K).
pub fn undistort_pixel(model: &CameraModel, u: f64, v: f64) -> Option<[f64; 2]> {
    if !model.is_distorted() {
        return Some([u, v]);
    }
    None
}

/// Resamples a distorted source image into the pinhole image with the same K and size.
pub fn undistort_image(model: &CameraModel, src: &Image) -> Image {
    let _ = model;
    src.clone()
}
