//! Mip-Splatting's 3D smoothing filter on the GPU (the f64 oracle is
//! `crate::reference::mip::filter3d`): one standard deviation per Gaussian from the finest
//! sampling interval of the training cameras that see its centre. Two passes
//! (`glsl/render/filter3d_depth.comp`, `filter3d_fill.comp`), one invocation per Gaussian looping
//! over the training cameras; nothing comes back to the host.

use std::sync::Arc;

use super::layout::CameraGpu;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::grown_capacity;

const WG: u32 = 128;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DepthPush {
    count: u32,
    n_cameras: u32,
    scale: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CountPush {
    count: u32,
}

pub struct SmoothingFilter {
    ctx: Arc<GpuContext>,
    depth: ComputePipeline,
    fill: ComputePipeline,
    train_ids: GpuBuffer<u32>,
    n_cameras: u32,
    /// √0.2 / (largest training focal length).
    scale: f32,
    seen_max: GpuBuffer<u32>,
    values: GpuBuffer<f32>,
}

impl SmoothingFilter {
    /// For the training cameras `train` (indices into `cameras`, the host copy of the camera
    /// buffer the updates will read), with room for `capacity` Gaussians.
    pub fn new(
        ctx: &Arc<GpuContext>,
        cameras: &[CameraGpu],
        train: &[usize],
        capacity: usize,
    ) -> anyhow::Result<Self> {
        anyhow::ensure!(
            !train.is_empty() && train.iter().all(|&v| v < cameras.len()),
            "Mip-Splatting 3D filter: {} training cameras (indices into {} cameras); it needs at \
             least one",
            train.len(),
            cameras.len()
        );
        let f_max = train
            .iter()
            .map(|&v| cameras[v].intrinsics[0] as f64)
            .fold(0.0, f64::max);
        anyhow::ensure!(
            f_max.is_finite() && f_max > 0.0,
            "Mip-Splatting 3D filter: the largest focal length is {f_max}; cameras need finite \
             positive focal lengths"
        );
        let ids: Vec<u32> = train.iter().map(|&v| v as u32).collect();
        use std::mem::size_of;
        Ok(Self {
            ctx: ctx.clone(),
            depth: ComputePipeline::new(
                ctx,
                "render/filter3d_depth",
                shaders::RENDER_FILTER3D_DEPTH,
                5,
                size_of::<DepthPush>() as u32,
                WG,
                &[],
            )?,
            fill: ComputePipeline::new(
                ctx,
                "render/filter3d_fill",
                shaders::RENDER_FILTER3D_FILL,
                2,
                size_of::<CountPush>() as u32,
                WG,
                &[],
            )?,
            train_ids: GpuBuffer::from_slice(ctx, "filter3d train cameras", &ids)?,
            n_cameras: ids.len() as u32,
            scale: (crate::reference::mip::FILTER_SCALE.sqrt() / f_max) as f32,
            seen_max: GpuBuffer::new(ctx, "filter3d seen max", 1, BufferKind::DeviceLocal)?,
            values: GpuBuffer::new(ctx, "filter3d", capacity.max(1), BufferKind::DeviceLocal)?,
        })
    }

    /// The filter of the Gaussians of the last update.
    pub fn values(&self) -> &GpuBuffer<f32> {
        &self.values
    }

    /// Makes room for `count` Gaussians (reallocates: only with no recorded work using the
    /// old buffer pending; the values must then be updated).
    pub fn reserve(&mut self, count: usize) -> anyhow::Result<()> {
        if self.values.len() < count {
            self.values = GpuBuffer::new(
                &self.ctx,
                "filter3d",
                grown_capacity(count),
                BufferKind::DeviceLocal,
            )?;
        }
        Ok(())
    }

    /// Records the filter of the first `count` Gaussians at `positions` (barriers included).
    pub fn record_update(
        &self,
        rec: &mut Recorder,
        positions: &GpuBuffer<f32>,
        cameras: &GpuBuffer<CameraGpu>,
        count: usize,
    ) -> anyhow::Result<()> {
        anyhow::ensure!(
            count <= self.values.len() && positions.len() >= 3 * count,
            "Mip-Splatting 3D filter: {count} Gaussians, room for {} (call reserve), {} position \
             floats",
            self.values.len(),
            positions.len()
        );
        if count == 0 {
            return Ok(());
        }
        rec.barrier();
        rec.fill(&self.seen_max, 0);
        rec.barrier();
        let groups = self.ctx.groups_1d(count as u64, WG);
        rec.dispatch(
            &self.depth,
            &[
                positions,
                cameras,
                &self.train_ids,
                &self.values,
                &self.seen_max,
            ],
            &DepthPush {
                count: count as u32,
                n_cameras: self.n_cameras,
                scale: self.scale,
            },
            groups,
        );
        rec.barrier();
        rec.dispatch(
            &self.fill,
            &[&self.values, &self.seen_max],
            &CountPush {
                count: count as u32,
            },
            groups,
        );
        rec.barrier();
        Ok(())
    }
}
