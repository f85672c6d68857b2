//! The surfel forward pass: `glsl/surfel/preprocess.comp` → 3DGS's depth sort, binning, tile
//! sort and tile ranges ([`Renderer`]) → `glsl/surfel/rasterize.comp`, recorded into the
//! caller's command buffer. Sizes grow like [`Renderer`]'s: the surfel geometry with the
//! Gaussian capacity, the maps with the pixel capacity.

use std::sync::Arc;

use super::layout::{SurfelConstants, GEOM_STRIDE, MAPS_STRIDE, NORMAL_STRIDE};
use crate::gpu::{
    Bindable, BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder, TimestampPool,
};
use crate::render::backward::default_pixels_per_invocation;
use crate::render::bands::{FrameWork, TileBand};
use crate::render::blocking::BandedRenderer;
use crate::render::forward::{Capacity, Pairing, Renderer};
use crate::render::layout::CameraGpu;
use crate::shaders;
use crate::splats::gpu::{GpuSplats, PARAM_BINDINGS};

const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PreprocessPush {
    count: u32,
    camera_index: u32,
    sh_degree: u32,
    rest_coeffs: u32,
    scale_stride: u32,
    _pad: [u32; 3],
    sc: SurfelConstants,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RasterPush {
    sc: SurfelConstants,
    camera_index: u32,
    background: [f32; 3],
    /// The band's first tile (`glsl/surfel/rasterize.glsl`).
    tile_offset: u32,
}

/// What a surfel frame needs besides the splats and the camera buffer.
#[derive(Debug, Clone, Copy)]
pub struct SurfelFrameSettings {
    pub sh_degree: u32,
    pub background: [f32; 3],
    pub constants: SurfelConstants,
}

/// The surfel buffers of the last frame (the backward reads them with [`Renderer::frame`]).
pub struct SurfelFrame {
    /// [`super::layout::SurfelGeomGpu`] per surfel, as flat floats.
    pub geom: GpuBuffer<f32>,
    /// The camera-facing camera-space normal per surfel, [`NORMAL_STRIDE`] floats.
    pub normals: GpuBuffer<f32>,
    /// [`super::layout::SurfelMapsGpu`] per pixel, as flat floats.
    pub maps: GpuBuffer<f32>,
    /// Per pixel: list position plus one of the median contributor (0 = none).
    pub median_index: GpuBuffer<u32>,
}

impl SurfelFrame {
    fn new(ctx: &Arc<GpuContext>, cap: &Capacity) -> anyhow::Result<Self> {
        let dl = BufferKind::DeviceLocal;
        let (n, px) = (cap.gaussians.max(1), cap.pixels.max(1));
        Ok(Self {
            geom: GpuBuffer::new(ctx, "surfel geometry", n * GEOM_STRIDE, dl)?,
            normals: GpuBuffer::new(ctx, "surfel normals", n * NORMAL_STRIDE, dl)?,
            maps: GpuBuffer::new(ctx, "surfel maps", px * MAPS_STRIDE, dl)?,
            median_index: GpuBuffer::new(ctx, "surfel median index", px, dl)?,
        })
    }
}

/// The 2DGS renderer: 3DGS's binning with the surfel preprocess and rasterizer.
pub struct SurfelRenderer {
    ctx: Arc<GpuContext>,
    /// The shared stages and buffers (projected, tile lists, image, final T, last index).
    pub base: Renderer,
    pub surfel: SurfelFrame,
    preprocess: ComputePipeline,
    raster: ComputePipeline,
}

impl SurfelRenderer {
    pub fn new(ctx: &Arc<GpuContext>, capacity: Capacity) -> anyhow::Result<Self> {
        let pixels = default_pixels_per_invocation(&ctx.info);
        Ok(Self {
            ctx: ctx.clone(),
            base: Renderer::new(ctx, capacity)?,
            surfel: SurfelFrame::new(ctx, &capacity)?,
            preprocess: ComputePipeline::new(
                ctx,
                "surfel/preprocess",
                shaders::SURFEL_PREPROCESS,
                18,
                std::mem::size_of::<PreprocessPush>() as u32,
                WG,
                &[],
            )?,
            raster: Self::raster_pipeline(ctx, pixels)?,
        })
    }

    /// The same renderer with `pixels` pixels per rasterizer invocation (1, 2, 4, 8 or 16, with
    /// whole subgroups; the default follows the device): tests cover every layout on any device.
    pub fn with_raster_pixels(mut self, pixels: u32) -> anyhow::Result<Self> {
        crate::render::backward::raster_workgroup(&self.ctx.info, pixels, 16, "surfel renderer")?;
        anyhow::ensure!(
            pixels == 1 || self.ctx.info.subgroup_shuffle,
            "surfel renderer: {pixels} pixels per invocation needs subgroup shuffles, which this \
             device lacks; use 1"
        );
        self.raster = Self::raster_pipeline(&self.ctx, pixels)?;
        Ok(self)
    }

    fn raster_pipeline(ctx: &Arc<GpuContext>, pixels: u32) -> anyhow::Result<ComputePipeline> {
        // A device without subgroup shuffles gets SPIR-V that does not declare them.
        let (name, spirv) = if ctx.info.subgroup_shuffle {
            ("surfel/rasterize", shaders::SURFEL_RASTERIZE)
        } else {
            ("surfel/rasterize_plain", shaders::SURFEL_RASTERIZE_PLAIN)
        };
        // Specialisation constants: workgroup size, subgroup size (added by the pipeline),
        // pixels per invocation.
        ComputePipeline::new(
            ctx,
            name,
            spirv,
            11,
            std::mem::size_of::<RasterPush>() as u32,
            WG / pixels,
            &[pixels],
        )
    }

    /// Grows the buffers when `need` exceeds the capacity (see [`Renderer::ensure_capacity`]).
    pub fn ensure_capacity(&mut self, need: Capacity) -> anyhow::Result<bool> {
        let before = self.base.capacity();
        let grew = self.base.ensure_capacity(need)?;
        let after = self.base.capacity();
        if after.gaussians != before.gaussians || after.pixels != before.pixels {
            // Free the old buffers first so peak memory does not double.
            self.surfel = SurfelFrame::new(&self.ctx, &Capacity::single())?;
            self.surfel = SurfelFrame::new(&self.ctx, &after)?;
        }
        Ok(grew)
    }

    /// Records one whole frame of the surfels `splats` (log-scales `scale_stride` floats
    /// apart: 2, or 3 in a 3DGS-shaped buffer whose third entry is unused) seen from
    /// `cameras[camera_index]` (host copy `camera`), as training does.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        splats: &GpuSplats,
        scale_stride: u32,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        settings: &SurfelFrameSettings,
        timestamps: Option<&mut TimestampPool>,
    ) -> anyhow::Result<()> {
        let work = FrameWork::Bands(vec![TileBand::whole(camera)]);
        self.record_work(
            rec,
            splats,
            scale_stride,
            cameras,
            camera_index,
            camera,
            settings,
            &work,
            timestamps,
        )
    }

    /// Records the preprocess and depth sort of a frame, then `work`
    /// ([`crate::render::bands`]).
    #[allow(clippy::too_many_arguments)]
    fn record_work(
        &mut self,
        rec: &mut Recorder,
        splats: &GpuSplats,
        scale_stride: u32,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        settings: &SurfelFrameSettings,
        work: &FrameWork,
        mut timestamps: Option<&mut TimestampPool>,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            scale_stride >= 2,
            "surfel renderer: a log-scale stride of {scale_stride}; surfels have two scales"
        );
        self.base.check_frame(splats.count, camera)?;
        if let FrameWork::Bands(bands) = work {
            self.base.prepare_bands(rec, bands.len())?;
        }
        let ctx = self.ctx.clone();
        let n = splats.count as u64;
        let f = &self.base.frame;
        rec.fill(&f.tile_ranges, 0);
        let own: [(&str, &dyn Bindable); 8] = [
            ("cameras", cameras),
            ("projected_splats", &f.projected.splats),
            ("depth_keys", &f.depth_keys),
            ("depth_vals", &f.depth_vals),
            ("counts", &f.counts),
            ("geom", &self.surfel.geom),
            ("projected_bounds_out", &f.projected.bounds),
            ("normals", &self.surfel.normals),
        ];
        let buffers: Vec<(&str, &dyn Bindable)> = own
            .into_iter()
            .chain(splats.bindings(&PARAM_BINDINGS))
            .collect();
        rec.dispatch_named(
            &self.preprocess,
            &buffers,
            &PreprocessPush {
                count: splats.count as u32,
                camera_index,
                sh_degree: settings.sh_degree.min(splats.sh_degree),
                rest_coeffs: (splats.sh_degree + 1) * (splats.sh_degree + 1) - 1,
                scale_stride,
                _pad: [0; 3],
                sc: settings.constants,
            },
            // At least one invocation so counts[0] is written for an empty scene.
            ctx.groups_1d(n.max(1), WG),
        );
        rec.barrier();
        if let Some(p) = timestamps.as_deref_mut() {
            rec.timestamp(p, "preprocess");
        }

        self.base.record_depth_sort(rec, timestamps.as_deref_mut());
        let bands = match work {
            FrameWork::RowTotals => {
                self.base
                    .record_row_totals(rec, camera, Pairing::Rectangle)?;
                self.base.finish_frame(rec, camera, 0);
                return Ok(());
            }
            FrameWork::Bands(bands) => bands,
        };
        for (slot, band) in bands.iter().enumerate() {
            self.base.record_band_binning(
                rec,
                camera,
                Pairing::Rectangle,
                band,
                slot as u32,
                timestamps.as_deref_mut(),
            );
            let f = &self.base.frame;
            rec.dispatch_named(
                &self.raster,
                &[
                    ("splats", &f.projected.splats),
                    ("geom", &self.surfel.geom),
                    ("sorted_ids", self.base.sorted_ids()),
                    ("ranges", &f.tile_ranges),
                    ("cameras", cameras),
                    ("image", &f.image),
                    ("final_t", &f.final_t),
                    ("last_index", &f.last_index),
                    ("maps", &self.surfel.maps),
                    ("median_index", &self.surfel.median_index),
                    ("normals", &self.surfel.normals),
                ],
                &RasterPush {
                    sc: settings.constants,
                    camera_index,
                    background: settings.background,
                    tile_offset: band.first_row * camera.tiles_x(),
                },
                ctx.groups_1d(band.tiles(camera), 1),
            );
            rec.barrier();
            if let Some(p) = timestamps.as_deref_mut() {
                rec.timestamp(p, "rasterize");
            }
        }
        self.base.finish_frame(rec, camera, bands.len());
        Ok(())
    }

    /// Renders one frame and waits, regrowing and re-rendering when the intersections did not
    /// fit, in bands of tile rows when they pass one binding ([`crate::render::blocking`]). For
    /// tools and tests; the trainer records frames into its own command buffers.
    pub fn render_blocking(
        &mut self,
        splats: &GpuSplats,
        scale_stride: u32,
        cameras: &GpuBuffer<CameraGpu>,
        camera_index: u32,
        camera: &CameraGpu,
        settings: &SurfelFrameSettings,
    ) -> anyhow::Result<()> {
        let need = Capacity::for_frame(splats.count, camera);
        self.ensure_capacity(need)?;
        crate::render::blocking::render_blocking(self, camera, |r, rec, work| {
            r.record_work(
                rec,
                splats,
                scale_stride,
                cameras,
                camera_index,
                camera,
                settings,
                work,
                None,
            )
        })
    }
}

impl BandedRenderer for SurfelRenderer {
    fn base(&mut self) -> &mut Renderer {
        &mut self.base
    }
    fn grow(&mut self, need: Capacity) -> anyhow::Result<bool> {
        self.ensure_capacity(need)
    }
}
