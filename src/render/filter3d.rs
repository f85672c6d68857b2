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
            scale: (crate::settings::mip::FILTER_SCALE.sqrt() / f_max) as f32,
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
        rec.dispatch_named(
            &self.depth,
            &[
                ("positions", positions),
                ("cameras", cameras),
                ("train_ids", &self.train_ids),
                ("filter3d", &self.values),
                ("seen_max", &self.seen_max),
            ],
            &DepthPush {
                count: count as u32,
                n_cameras: self.n_cameras,
                scale: self.scale,
            },
            groups,
        );
        rec.barrier();
        rec.dispatch_named(
            &self.fill,
            &[("filter3d", &self.values), ("seen_max", &self.seen_max)],
            &CountPush {
                count: count as u32,
            },
            groups,
        );
        rec.barrier();
        Ok(())
    }
}

/// `model` with the 3D filter `filter` (one standard deviation per Gaussian, as the GPU pass
/// wrote it) folded into its scales and opacities, as the official `create_fused_ply.py` does
/// for export: scale² + f² per axis, and the opacity times √(Π s² / Π (s² + f²)), so viewers
/// without the filter render the filtered model. In f64 per Gaussian, rounded once to f32;
/// `crate::reference::mip::fuse` is its oracle.
pub fn fold_into(
    model: &crate::splats::GaussianParams,
    filter: &[f32],
) -> anyhow::Result<crate::splats::GaussianParams> {
    anyhow::ensure!(
        filter.len() == model.len(),
        "Mip-Splatting 3D filter: {} filter values for {} Gaussians",
        filter.len(),
        model.len()
    );
    let sigmoid = |x: f64| 1.0 / (1.0 + (-x).exp());
    let logit = |p: f64| (p / (1.0 - p)).ln();
    let mut out = model.clone();
    for (i, &f) in filter.iter().enumerate() {
        let phi = f as f64 * f as f64;
        let mut log_ratio = 0.0;
        for k in 0..3 {
            let s2 = (2.0 * model.log_scales[i][k] as f64).exp();
            out.log_scales[i][k] = (0.5 * (s2 + phi).ln()) as f32;
            log_ratio += (s2 / (s2 + phi)).ln();
        }
        let o = sigmoid(model.opacity_logits[i] as f64) * (0.5 * log_ratio).exp();
        out.opacity_logits[i] = logit(o) as f32;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reference::{mip, RefGaussians};
    use rand::{Rng, SeedableRng};

    /// The export's fold equals the f64 oracle's, rounded to f32, bit for bit.
    #[test]
    fn the_fold_matches_the_oracle() {
        let mut rng = rand_pcg::Pcg32::seed_from_u64(7);
        let mut p = crate::splats::init::random_init(64, [0.0; 3], [1.0; 3], 1, 3).unwrap();
        for i in 0..p.len() {
            p.log_scales[i] = [0; 3].map(|_| rng.gen_range(-7.0..1.0f32));
            p.opacity_logits[i] = rng.gen_range(-6.0..6.0);
        }
        let filter: Vec<f32> = (0..p.len()).map(|_| rng.gen_range(0.0..0.05f32)).collect();
        let got = fold_into(&p, &filter).unwrap();
        let want = mip::fuse(
            &RefGaussians::from_params(&p),
            &filter.iter().map(|&v| v as f64).collect::<Vec<_>>(),
        )
        .unwrap()
        .to_params(p.sh_degree);
        assert_eq!(got.log_scales, want.log_scales);
        assert_eq!(got.opacity_logits, want.opacity_logits);
        assert_eq!(got.positions, want.positions);
        assert_eq!(got.sh_rest, want.sh_rest);
        assert!(fold_into(&p, &filter[1..]).is_err());
    }
}
