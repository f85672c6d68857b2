//! The 2DGS rasterizer's constants.

/// The 2DGS rasterizer's constants. [`Default`] gives the official code's values
/// (diff-surfel-rasterization `auxiliary.h`, `forward.cu`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfelSettings {
    /// Surfels whose centre has camera z ≤ near are culled, and a (surfel, pixel) hit with
    /// depth < near is skipped; also the near plane of the distortion's depth mapping. The
    /// official 0.2 world units, in scenes whose cameras' extent is about 4 (DTU as the
    /// official code normalises it, Mip-NeRF 360's COLMAP models), is 0.05 of the extent:
    /// the default here, in the unit-extent training frame (`crate::scene::frame`).
    pub near: f64,
    /// The far plane of the distortion's depth mapping (100 extents).
    pub far: f64,
    /// Tile side in pixels.
    pub tile_size: u32,
    /// Hits with alpha below this are skipped (1/255).
    pub alpha_min: f64,
    /// alpha = min(alpha_max, opacity·G) (0.99).
    pub alpha_max: f64,
    /// A pixel stops before the surfel that would take its transmittance below this (1e-4).
    pub t_min: f64,
    /// The low-pass filter's `rho2d = filter_inv_square·|m − x|²` (2: variance 1/2 px²).
    pub filter_inv_square: f64,
    /// The bounding box is taken at this many sigmas (3).
    pub cutoff: f64,
    /// Test-only: no alpha_min skip, no t_min stop, no alpha_max clamp.
    pub smooth: bool,
}

impl Default for SurfelSettings {
    fn default() -> Self {
        Self {
            near: 0.05,
            far: 100.0,
            tile_size: 16,
            alpha_min: 1.0 / 255.0,
            alpha_max: 0.99,
            t_min: 1e-4,
            filter_inv_square: 2.0,
            cutoff: 3.0,
            smooth: false,
        }
    }
}

impl SurfelSettings {
    /// The same settings in smooth (finite-difference friendly) mode.
    pub fn smooth() -> Self {
        Self {
            smooth: true,
            ..Self::default()
        }
    }

    /// Number of tiles across and down for an image of `width` × `height`.
    pub fn tile_grid(&self, width: u32, height: u32) -> (u32, u32) {
        (
            width.div_ceil(self.tile_size),
            height.div_ceil(self.tile_size),
        )
    }

    /// The smallest box radius, px: `cutoff` standard deviations of the low-pass filter.
    pub fn min_radius(&self) -> f64 {
        self.cutoff / self.filter_inv_square.sqrt()
    }

    /// The distortion's mapped depth `m(z) = far/(far − near)·(1 − near/z)` (0 at `near`,
    /// 1 at `far`).
    pub fn mapped_depth(&self, z: f64) -> f64 {
        self.far / (self.far - self.near) * (1.0 - self.near / z)
    }
}
