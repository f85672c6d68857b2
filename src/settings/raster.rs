//! The 3DGS rasterizer's constants, and Mip-Splatting's 2D filter in place of its dilation.

/// Mip-Splatting's 2D filter variance (px²), in place of 3DGS's 0.3 dilation.
pub const MIP_EPS2D: f64 = 0.1;
/// The floor of the 2D filter's opacity compensation (gsplat's `MIN_COMPENSATION`).
pub const MIP_MIN_COMPENSATION: f64 = 0.005;

/// The rasterizer's constants. [`Default`] gives the values the engine uses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Near plane: Gaussians with camera z ≤ near are culled (gsplat: 0.01 in its normalised
    /// frame; Inria: 0.2 world units). In the engine's unit-extent training frame
    /// (`crate::scene::frame`) 0.01 is a hundredth of the scene's extent.
    pub near: f64,
    /// Tile side in pixels.
    pub tile_size: u32,
    /// Splats with alpha below this are skipped (1/255).
    pub alpha_min: f64,
    /// alpha = min(alpha_max, opacity·exp(power)) (0.99).
    pub alpha_max: f64,
    /// A pixel stops before the splat that would take its transmittance below this (1e-4).
    pub t_min: f64,
    /// Low-pass dilation added to the 2D covariance diagonal, px² (0.3).
    pub eps2d: f64,
    /// The EWA Jacobian's x/z, y/z are clamped to this many half-FoV tangents (1.3).
    pub fov_clamp: f64,
    /// The 2D covariance determinant is clamped to at least this (after culling det ≤ 0).
    pub det_min: f64,
    /// Test-only: no alpha_min skip, no t_min stop, no alpha_max clamp (see the module docs).
    pub smooth: bool,
    /// Mip-Splatting's 2D Mip filter: the opacity compensation of step 5.
    pub mip_2d: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            near: 0.01,
            tile_size: 16,
            alpha_min: 1.0 / 255.0,
            alpha_max: 0.99,
            t_min: 1e-4,
            eps2d: 0.3,
            fov_clamp: 1.3,
            det_min: 1e-6,
            smooth: false,
            mip_2d: false,
        }
    }
}

impl RenderSettings {
    /// Mip-Splatting's 2D Mip filter: eps2d = 0.1 px² with the opacity compensation.
    pub fn mip_splatting() -> Self {
        Self {
            eps2d: MIP_EPS2D,
            mip_2d: true,
            ..Self::default()
        }
    }

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
}
