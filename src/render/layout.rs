//! The GPU data contract of the renderer: the structs and per-pixel buffers every forward,
//! backward, loss and density-control kernel agrees on. The GLSL side is
//! `glsl/common/camera.glsl` and `glsl/common/projected.glsl`; both are plain scalars in std430
//! so the `#[repr(C)]` structs here have the same bytes.
//!
//! Per-pixel buffers (width × height, row-major, pixel `(x, y)` at `y·width + x`):
//! - image: `f32 × 3` interleaved RGB (`[(y·width + x)·3 + c]`), the same layout as
//!   [`crate::reference::RasterOutput`] and as the gradient `dL/d(image)`;
//! - `final_t`: f32, the transmittance left after the last splat (before the background);
//! - `last_index`: u32, how many entries of the pixel's tile list were walked up to and
//!   including the last one that contributed (0 = none), the reference's `last_contributor`.
//!
//! Per tile (`tiles_x × tiles_y`, row-major): `tile_ranges: [u32; 2]`, the `[start, end)` range of
//! the tile's entries in `sorted_ids` (the Gaussian index of each intersection, tile-major and
//! front-to-back within a tile).

use bytemuck::{Pod, Zeroable};

use crate::scene::{PinholeCamera, Pose};

/// Tile side in pixels; the rasterizer runs one 16×16 workgroup per tile.
pub const TILE_SIZE: u32 = 16;

/// One camera, world-to-camera rows plus intrinsics (96 bytes, std430 `Camera`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct CameraGpu {
    /// Rows of the world-to-camera rotation; the translation in the fourth column.
    pub r0: [f32; 4],
    pub r1: [f32; 4],
    pub r2: [f32; 4],
    /// Camera centre in world space (xyz), w = 0.
    pub center: [f32; 4],
    /// fx, fy, cx, cy in pixels.
    pub intrinsics: [f32; 4],
    /// width, height, tiles_x, tiles_y.
    pub size: [u32; 4],
}

impl CameraGpu {
    pub fn new(camera: &PinholeCamera, pose: &Pose) -> Self {
        let r = pose.rotation;
        let t = pose.translation;
        let c = pose.center();
        let row = |i: usize| [r[i][0] as f32, r[i][1] as f32, r[i][2] as f32, t[i] as f32];
        Self {
            r0: row(0),
            r1: row(1),
            r2: row(2),
            center: [c[0] as f32, c[1] as f32, c[2] as f32, 0.0],
            intrinsics: [
                camera.fx as f32,
                camera.fy as f32,
                camera.cx as f32,
                camera.cy as f32,
            ],
            size: [
                camera.width,
                camera.height,
                camera.width.div_ceil(TILE_SIZE),
                camera.height.div_ceil(TILE_SIZE),
            ],
        }
    }

    pub fn width(&self) -> u32 {
        self.size[0]
    }
    pub fn height(&self) -> u32 {
        self.size[1]
    }
    pub fn tile_count(&self) -> u32 {
        self.size[2] * self.size[3]
    }
    pub fn tiles_x(&self) -> u32 {
        self.size[2]
    }
    pub fn tiles_y(&self) -> u32 {
        self.size[3]
    }
}

/// Bits of `flags` in [`ProjectedGpu`]: channel c's `+0.5` colour was clamped at 0.
pub const FLAG_CLAMPED_R: u32 = 1;
pub const FLAG_CLAMPED_G: u32 = 2;
pub const FLAG_CLAMPED_B: u32 = 4;

/// What preprocess computes per Gaussian (the host's view, 64 bytes; the GLSL `Projected`). A
/// culled Gaussian has `radius == 0` and an empty tile rectangle; its other fields are
/// unspecified. On the GPU it is stored as two buffers ([`ProjectedSplatGpu`] and
/// [`ProjectedBoundsGpu`], [`crate::render::projected::ProjectedBuffers`]): no per-Gaussian
/// buffer is wider than 36 bytes, so one storage binding does not cap the model first.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct ProjectedGpu {
    pub mean_x: f32,
    pub mean_y: f32,
    /// Camera z.
    pub depth: f32,
    /// sigmoid(opacity logit).
    pub opacity: f32,
    /// Conic (inverse dilated 2D covariance) `[[a, b], [b, c]]`.
    pub conic_a: f32,
    pub conic_b: f32,
    pub conic_c: f32,
    /// `ceil(3·sqrt(λmax))` px; 0 = culled.
    pub radius: f32,
    /// Colour after `+0.5` and the clamp at 0.
    pub rgb: [f32; 3],
    /// `FLAG_CLAMPED_*` bits.
    pub flags: u32,
    /// Tile rectangle `[min, max)` in tiles, clamped to the grid.
    pub tile_min: [u32; 2],
    pub tile_max: [u32; 2],
}

/// What the rasterizers read of a projected Gaussian (36 bytes, std430 `ProjectedSplat`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct ProjectedSplatGpu {
    pub mean_x: f32,
    pub mean_y: f32,
    pub opacity: f32,
    pub conic_a: f32,
    pub conic_b: f32,
    pub conic_c: f32,
    pub rgb: [f32; 3],
}

/// What binning, density statistics and the preprocess backward read of a projected Gaussian
/// (28 bytes, std430 `ProjectedBounds`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct ProjectedBoundsGpu {
    pub depth: f32,
    pub radius: f32,
    pub flags: u32,
    pub tile_min: [u32; 2],
    pub tile_max: [u32; 2],
}

impl ProjectedGpu {
    /// The two stored parts.
    pub fn split(&self) -> (ProjectedSplatGpu, ProjectedBoundsGpu) {
        (
            ProjectedSplatGpu {
                mean_x: self.mean_x,
                mean_y: self.mean_y,
                opacity: self.opacity,
                conic_a: self.conic_a,
                conic_b: self.conic_b,
                conic_c: self.conic_c,
                rgb: self.rgb,
            },
            ProjectedBoundsGpu {
                depth: self.depth,
                radius: self.radius,
                flags: self.flags,
                tile_min: self.tile_min,
                tile_max: self.tile_max,
            },
        )
    }

    /// The record from its two stored parts.
    pub fn join(s: &ProjectedSplatGpu, b: &ProjectedBoundsGpu) -> Self {
        Self {
            mean_x: s.mean_x,
            mean_y: s.mean_y,
            depth: b.depth,
            opacity: s.opacity,
            conic_a: s.conic_a,
            conic_b: s.conic_b,
            conic_c: s.conic_c,
            radius: b.radius,
            rgb: s.rgb,
            flags: b.flags,
            tile_min: b.tile_min,
            tile_max: b.tile_max,
        }
    }

    pub fn is_visible(&self) -> bool {
        self.radius > 0.0
    }
    pub fn tiles_touched(&self) -> u64 {
        let w = self.tile_max[0].saturating_sub(self.tile_min[0]) as u64;
        let h = self.tile_max[1].saturating_sub(self.tile_min[1]) as u64;
        w * h
    }
}

/// The rasterizer's constants as pushed to the kernels; mirrors
/// [`crate::reference::RenderSettings`] (whose `Default` gives the engine's values).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct RenderConstants {
    pub near: f32,
    pub eps2d: f32,
    pub fov_clamp: f32,
    pub det_min: f32,
    pub alpha_min: f32,
    pub alpha_max: f32,
    pub t_min: f32,
    /// Bits: [`RenderConstants::SMOOTH`], [`RenderConstants::MIP_2D`].
    pub flags: u32,
}

impl RenderConstants {
    /// Smooth test mode (no alpha_min skip, no t_min stop, no alpha_max clamp).
    pub const SMOOTH: u32 = 1;
    /// Mip-Splatting's 2D Mip filter: the opacity compensation (with eps2d = 0.1).
    pub const MIP_2D: u32 = 2;
    /// Mip-Splatting's 3D filter: a per-Gaussian buffer is bound (set by the renderer and the
    /// backward when one is given).
    pub const FILTER_3D: u32 = 4;
    /// SpacetimeGaussians' full model: the DC coefficients are blended as raw features (no
    /// `+0.5`, no clamp, no view dependence; `glsl/render/preprocess.comp`), the decoder makes
    /// them colours.
    pub const RAW_COLOUR: u32 = 8;

    /// These constants with Gaussians culled at camera z ≤ `near` (world units).
    pub fn with_near(mut self, near: f32) -> Self {
        self.near = near;
        self
    }

    /// The constants of Mip-Splatting's renders (eps2d 0.1 with the 2D filter's compensation)
    /// when `mip`, else the 3DGS defaults.
    pub fn for_mip(mip: bool) -> Self {
        if mip {
            Self::from_settings(&crate::settings::raster::RenderSettings::mip_splatting())
        } else {
            Self::default()
        }
    }

    pub fn from_settings(s: &crate::settings::raster::RenderSettings) -> Self {
        assert_eq!(
            s.tile_size, TILE_SIZE,
            "the GPU rasterizer uses 16×16 tiles"
        );
        Self {
            near: s.near as f32,
            eps2d: s.eps2d as f32,
            fov_clamp: s.fov_clamp as f32,
            det_min: s.det_min as f32,
            alpha_min: s.alpha_min as f32,
            alpha_max: s.alpha_max as f32,
            t_min: s.t_min as f32,
            flags: if s.smooth { Self::SMOOTH } else { 0 }
                | if s.mip_2d { Self::MIP_2D } else { 0 },
        }
    }
}

impl Default for RenderConstants {
    fn default() -> Self {
        Self::from_settings(&crate::settings::raster::RenderSettings::default())
    }
}
