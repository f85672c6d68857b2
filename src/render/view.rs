//! Rendering trained models for tools (`render`, `eval`, the orbit GIF): one trait over the
//! 3D-Gaussian renderer and the surfel renderer, so a tool renders whatever model it was given
//! without naming one; the surfel renderer also hands out its depth and normal maps.

use std::sync::Arc;

use anyhow::Result;

use super::forward::{Capacity, FrameSettings, Renderer};
use super::layout::{CameraGpu, RenderConstants};
use super::surfel::forward::{SurfelFrameSettings, SurfelRenderer};
use super::surfel::layout::{SurfelConstants, SurfelMapsGpu, MAPS_STRIDE};
use crate::gpu::{GpuBuffer, GpuContext};
use crate::splats::gpu::GpuSplats;

/// Per-pixel geometry of a surfel frame (row-major).
pub struct GeometryMaps {
    pub maps: Vec<SurfelMapsGpu>,
    /// Accumulated alpha `1 − T`.
    pub alpha: Vec<f32>,
}

impl GeometryMaps {
    /// `(1 − depth_ratio)·D/alpha + depth_ratio·median` (0 where `D/alpha` is not finite):
    /// camera z of the surface, as the regulariser and a TSDF fusion see it.
    pub fn surface_depth(&self, depth_ratio: f32) -> Vec<f32> {
        self.maps
            .iter()
            .zip(&self.alpha)
            .map(|(m, &a)| {
                let e = m.depth / a;
                let e = if e.is_finite() { e } else { 0.0 };
                (1.0 - depth_ratio) * e + depth_ratio * m.median_depth
            })
            .collect()
    }

    /// The accumulated normals in world space, `Wᵀ N` (unnormalised: their length is the
    /// alpha-weighted agreement of the surfels at the pixel).
    pub fn world_normals(&self, pose: &crate::scene::Pose) -> Vec<[f32; 3]> {
        let w = pose.rotation;
        self.maps
            .iter()
            .map(|m| {
                let n = m.normal.map(f64::from);
                [0, 1, 2].map(|c| (w[0][c] * n[0] + w[1][c] * n[1] + w[2][c] * n[2]) as f32)
            })
            .collect()
    }
}

pub trait ViewRenderer {
    /// Renders `cameras[index]` (host copy `camera`) and waits; RGB interleaved.
    fn render(
        &mut self,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        index: u32,
        camera: &CameraGpu,
        background: [f32; 3],
    ) -> Result<Vec<f32>>;
    /// The last frame's depth and normal maps, for models that render them.
    fn geometry(&self, camera: &CameraGpu) -> Result<Option<GeometryMaps>>;
}

/// 3D Gaussians with the given rasterizer constants (3DGS, Mip-Splatting's 2D filter).
pub struct GaussianView {
    renderer: Renderer,
    constants: RenderConstants,
}

impl GaussianView {
    pub fn new(
        ctx: &Arc<GpuContext>,
        gaussians: usize,
        camera: &CameraGpu,
        constants: RenderConstants,
    ) -> Result<Self> {
        Ok(Self {
            renderer: Renderer::for_camera(ctx, gaussians, camera)?,
            constants,
        })
    }
}

impl ViewRenderer for GaussianView {
    fn render(
        &mut self,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        index: u32,
        camera: &CameraGpu,
        background: [f32; 3],
    ) -> Result<Vec<f32>> {
        self.renderer.fit_camera(camera)?;
        let settings = FrameSettings {
            sh_degree: splats.sh_degree,
            background,
            constants: self.constants,
            filter3d: None,
            features: None,
        };
        self.renderer
            .render_blocking(splats, cameras, index, camera, &settings)?;
        self.renderer.read_image()
    }

    fn geometry(&self, _: &CameraGpu) -> Result<Option<GeometryMaps>> {
        Ok(None)
    }
}

/// 2DGS surfels stored with three log-scales (the third unused, as training writes them).
pub struct SurfelView {
    renderer: SurfelRenderer,
}

impl SurfelView {
    pub fn new(ctx: &Arc<GpuContext>, surfels: usize, camera: &CameraGpu) -> Result<Self> {
        Ok(Self {
            renderer: SurfelRenderer::new(ctx, Capacity::for_frame(surfels, camera))?,
        })
    }
}

impl ViewRenderer for SurfelView {
    fn render(
        &mut self,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        index: u32,
        camera: &CameraGpu,
        background: [f32; 3],
    ) -> Result<Vec<f32>> {
        let settings = SurfelFrameSettings {
            sh_degree: splats.sh_degree,
            background,
            constants: SurfelConstants::default(),
        };
        self.renderer
            .render_blocking(splats, 3, cameras, index, camera, &settings)?;
        self.renderer.base.read_image()
    }

    fn geometry(&self, camera: &CameraGpu) -> Result<Option<GeometryMaps>> {
        let px = (camera.width() * camera.height()) as usize;
        let flat = self.renderer.surfel.maps.read_range(0, px * MAPS_STRIDE)?;
        let t = self.renderer.base.frame.final_t.read_range(0, px)?;
        Ok(Some(GeometryMaps {
            maps: bytemuck::cast_slice(&flat).to_vec(),
            alpha: t.iter().map(|t| 1.0 - t).collect(),
        }))
    }
}

/// SpacetimeGaussians: the model at each camera's time (the temporal step, then the 3D-Gaussian
/// renderer on the still model).
pub struct SpacetimeView {
    ctx: Arc<GpuContext>,
    renderer: Renderer,
    /// The time of every camera in the buffer the renders index.
    times: Vec<f32>,
    /// The full model's decoder weights (`None`: lite).
    decoder: Option<Vec<f32>>,
    /// The temporal step for the model last rendered (its Gaussian count).
    timed: Option<(usize, super::spacetime::TimedModel)>,
}

impl SpacetimeView {
    /// `decoder`: the full model's weights (`None`: the lite model).
    pub fn new(
        ctx: &Arc<GpuContext>,
        gaussians: usize,
        camera: &CameraGpu,
        times: Vec<f32>,
        decoder: Option<Vec<f32>>,
    ) -> Result<Self> {
        Ok(Self {
            ctx: ctx.clone(),
            renderer: Renderer::for_camera(ctx, gaussians, camera)?,
            times,
            decoder,
            timed: None,
        })
    }
}

impl ViewRenderer for SpacetimeView {
    fn render(
        &mut self,
        splats: &GpuSplats,
        cameras: &GpuBuffer<CameraGpu>,
        index: u32,
        camera: &CameraGpu,
        background: [f32; 3],
    ) -> Result<Vec<f32>> {
        let t = *self.times.get(index as usize).ok_or_else(|| {
            anyhow::anyhow!("camera {index} has no time ({} cameras)", self.times.len())
        })?;
        let n = splats.count;
        if self.timed.as_ref().map(|t| t.0) != Some(n) {
            self.timed = None;
            let timed =
                super::spacetime::TimedModel::new(&self.ctx, splats, self.decoder.as_deref())?;
            self.timed = Some((n, timed));
        }
        let (_, timed) = self.timed.as_mut().expect("made above");
        self.renderer.fit_camera(camera)?;
        let mut rec = crate::gpu::Recorder::new(&self.ctx)?;
        rec.begin()?;
        timed.record(&mut rec, splats, t)?;
        rec.submit_and_wait()?;
        self.renderer.render_blocking(
            &timed.instant,
            cameras,
            index,
            camera,
            &timed.settings(background),
        )?;
        self.renderer.read_image()
    }

    fn geometry(&self, _: &CameraGpu) -> Result<Option<GeometryMaps>> {
        Ok(None)
    }
}
