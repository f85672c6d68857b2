//! The reference forward pass converted into the GPU data contract of
//! `lpmsplat::render::layout`, so GPU kernels can be tested stage by stage against the oracle
//! without the other GPU stages: the backward kernels get the reference's projected Gaussians,
//! tile lists and per-pixel outputs; the forward kernels get something to compare with.
//!
//! Also converts [`RefGaussians`] to the f32 [`GaussianParams`] the GPU buffers are filled from,
//! and rounds scenes to f32 so the f64 oracle sees exactly the values the GPU sees.

#![allow(dead_code)] // each module of the gpu crate uses part of it

use bytemuck::Zeroable;

use lpmsplat::reference::{RefGaussians, RenderOutput};
use lpmsplat::render::layout::{
    CameraGpu, ProjectedGpu, FLAG_CLAMPED_B, FLAG_CLAMPED_G, FLAG_CLAMPED_R,
};
use lpmsplat::scene::{PinholeCamera, Pose};
use lpmsplat::splats::GaussianParams;

/// A reference forward pass in the GPU contract layout (host vectors, ready to upload).
#[derive(Debug, Clone, PartialEq)]
pub struct GpuForwardFixture {
    pub camera: CameraGpu,
    /// One per Gaussian; culled ones have `radius == 0` and an empty tile rectangle.
    pub projected: Vec<ProjectedGpu>,
    /// Per tile (row-major), the `[start, end)` range of its entries in `sorted_ids`.
    pub tile_ranges: Vec<[u32; 2]>,
    /// The tiles' sorted lists concatenated in row-major tile order.
    pub sorted_ids: Vec<u32>,
    /// `[(y·W + x)·3 + c]`, background included.
    pub image: Vec<f32>,
    pub final_t: Vec<f32>,
    /// The reference's `last_contributor`.
    pub last_index: Vec<u32>,
}

/// Converts the reference forward pass `forward` (made for `camera`, `pose`) to the GPU layout.
pub fn gpu_forward_fixture(
    forward: &RenderOutput,
    camera: &PinholeCamera,
    pose: &Pose,
) -> GpuForwardFixture {
    let projected = forward
        .projected
        .iter()
        .map(|p| {
            if p.culled {
                return ProjectedGpu {
                    depth: p.depth as f32,
                    ..Zeroable::zeroed()
                };
            }
            let mut flags = 0;
            for (bit, clamped) in [FLAG_CLAMPED_R, FLAG_CLAMPED_G, FLAG_CLAMPED_B]
                .into_iter()
                .zip(p.rgb_clamped)
            {
                if clamped {
                    flags |= bit;
                }
            }
            ProjectedGpu {
                mean_x: p.mean2d[0] as f32,
                mean_y: p.mean2d[1] as f32,
                depth: p.depth as f32,
                opacity: p.opacity as f32,
                conic_a: p.conic[0] as f32,
                conic_b: p.conic[1] as f32,
                conic_c: p.conic[2] as f32,
                radius: p.radius as f32,
                rgb: p.rgb.map(|v| v as f32),
                flags,
                tile_min: p.tile_min,
                tile_max: p.tile_max,
            }
        })
        .collect();
    let mut tile_ranges = Vec::with_capacity(forward.bins.lists.len());
    let mut sorted_ids = Vec::new();
    for list in &forward.bins.lists {
        let start = sorted_ids.len() as u32;
        sorted_ids.extend_from_slice(list);
        tile_ranges.push([start, sorted_ids.len() as u32]);
    }
    let raster = &forward.raster;
    GpuForwardFixture {
        camera: CameraGpu::new(camera, pose),
        projected,
        tile_ranges,
        sorted_ids,
        image: raster.image.iter().flatten().map(|&v| v as f32).collect(),
        final_t: raster
            .final_transmittance
            .iter()
            .map(|&v| v as f32)
            .collect(),
        last_index: raster.last_contributor.clone(),
    }
}

/// The Gaussians as f32 [`GaussianParams`] of SH degree `sh_degree` (coefficients above it are
/// dropped; `sh_rest` coefficient-major).
pub fn gaussian_params(g: &RefGaussians, sh_degree: u32) -> GaussianParams {
    let f = |v: f64| v as f32;
    let rest = (sh_degree as usize + 1).pow(2);
    GaussianParams {
        sh_degree,
        positions: g.positions.iter().map(|p| p.map(f)).collect(),
        log_scales: g.log_scales.iter().map(|p| p.map(f)).collect(),
        rotations: g.rotations.iter().map(|p| p.map(f)).collect(),
        opacity_logits: g.opacity_logits.iter().map(|&v| f(v)).collect(),
        sh_dc: g.sh.iter().map(|s| s[0].map(f)).collect(),
        sh_rest: g
            .sh
            .iter()
            .flat_map(|s| s[1..rest].iter().flatten().map(|&v| f(v)))
            .collect(),
        extra: Vec::new(),
    }
}

/// The same Gaussians with every value rounded to f32 (what the GPU holds).
pub fn round_gaussians_to_f32(g: &RefGaussians) -> RefGaussians {
    let r = |v: f64| v as f32 as f64;
    RefGaussians {
        positions: g.positions.iter().map(|p| p.map(r)).collect(),
        log_scales: g.log_scales.iter().map(|p| p.map(r)).collect(),
        rotations: g.rotations.iter().map(|p| p.map(r)).collect(),
        opacity_logits: g.opacity_logits.iter().map(|&v| r(v)).collect(),
        sh: g.sh.iter().map(|s| s.map(|c| c.map(r))).collect(),
    }
}

/// The camera and pose with every value rounded to f32 (what [`CameraGpu`] holds).
pub fn round_view_to_f32(camera: &PinholeCamera, pose: &Pose) -> (PinholeCamera, Pose) {
    let r = |v: f64| v as f32 as f64;
    (
        PinholeCamera {
            fx: r(camera.fx),
            fy: r(camera.fy),
            cx: r(camera.cx),
            cy: r(camera.cy),
            ..*camera
        },
        Pose {
            rotation: pose.rotation.map(|row| row.map(r)),
            translation: pose.translation.map(r),
        },
    )
}
