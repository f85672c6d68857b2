//! Image loading (parallel), undistortion, resizing. (Skeleton: being written.)

/// An RGB(A) image with f32 channels in [0, 1], row-major, pixel (x, y) at `(y * width + x)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// 3 floats per pixel.
    pub rgb: Vec<f32>,
    /// 1 float per pixel when the source had alpha.
    pub alpha: Option<Vec<f32>>,
}
