//! The surfel kernels' data contract (`glsl/surfel/surfel.glsl` is the GLSL side).
//!
//! - Per surfel, beside the shared [`crate::render::layout::ProjectedGpu`] (whose `mean` is the
//!   box centre `m`, the low-pass filter's centre; its conic is unused):
//!   [`SurfelGeomGpu`], the rows of the transform `M`, and in a second buffer the camera-facing
//!   normal (3 floats): no per-surfel buffer is wider than 36 bytes.
//! - Per pixel, beside the image, `final_t` and `last_index` of 3DGS: [`SurfelMapsGpu`] (depth
//!   numerator, median depth, normal, distortion and the distortion's running sums) and
//!   `median_index` (list position plus one of the median contributor, 0 = none).

use bytemuck::{Pod, Zeroable};

use crate::render::layout::TILE_SIZE;
use crate::settings::surfel::SurfelSettings;

/// Per surfel (36 bytes, `GEOM_STRIDE` floats): `M`'s rows `h₁, h₂, h₃` (`M (u, v, 1)ᵀ =
/// (x·z, y·z, z)`). The camera-space normal facing the camera is a buffer of its own
/// ([`NORMAL_STRIDE`] floats a surfel).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct SurfelGeomGpu {
    pub transform: [[f32; 3]; 3],
}

/// Floats per surfel of [`SurfelGeomGpu`].
pub const GEOM_STRIDE: usize = 9;

/// Floats per surfel of the normal buffer.
pub const NORMAL_STRIDE: usize = 3;

/// Per pixel (32 bytes, `MAPS_STRIDE` floats).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct SurfelMapsGpu {
    /// `Σ w·z` (divide by alpha for the expected depth).
    pub depth: f32,
    /// Hit depth of the last surfel blended while `T > 0.5` (0 = none).
    pub median_depth: f32,
    /// `Σ w·n`, camera space.
    pub normal: [f32; 3],
    pub distortion: f32,
    /// `Σ w·m(z)` and `Σ w·m(z)²`: what the distortion backward reads.
    pub m1: f32,
    pub m2: f32,
}

/// Floats per pixel of [`SurfelMapsGpu`].
pub const MAPS_STRIDE: usize = 8;

/// The surfel rasterizer's constants as pushed to the kernels; mirrors [`SurfelSettings`]
/// (whose `Default` gives the official values).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct SurfelConstants {
    pub near: f32,
    pub far: f32,
    pub alpha_min: f32,
    pub alpha_max: f32,
    pub t_min: f32,
    pub filter_inv_square: f32,
    pub cutoff: f32,
    /// Bits [`SurfelConstants::SMOOTH`], [`SurfelConstants::FULL_LISTS`].
    pub flags: u32,
}

impl SurfelConstants {
    /// Smooth test mode (no alpha_min skip, no t_min stop, no alpha_max clamp).
    pub const SMOOTH: u32 = 1;
    /// Test aid: the rasterizers' subgroups visit every surfel of the tile (no reach bound),
    /// which must give the same results as the culled lists.
    pub const FULL_LISTS: u32 = 2;

    pub fn from_settings(s: &SurfelSettings) -> Self {
        assert_eq!(
            s.tile_size, TILE_SIZE,
            "the GPU rasterizer uses 16×16 tiles"
        );
        Self {
            near: s.near as f32,
            far: s.far as f32,
            alpha_min: s.alpha_min as f32,
            alpha_max: s.alpha_max as f32,
            t_min: s.t_min as f32,
            filter_inv_square: s.filter_inv_square as f32,
            cutoff: s.cutoff as f32,
            flags: if s.smooth { Self::SMOOTH } else { 0 },
        }
    }
}

impl Default for SurfelConstants {
    fn default() -> Self {
        Self::from_settings(&SurfelSettings::default())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strides_match_the_structs() {
        assert_eq!(std::mem::size_of::<SurfelGeomGpu>(), GEOM_STRIDE * 4);
        assert_eq!(std::mem::size_of::<SurfelMapsGpu>(), MAPS_STRIDE * 4);
        assert_eq!(std::mem::size_of::<SurfelConstants>(), 32);
    }
}
