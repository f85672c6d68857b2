//! The Gaussian parameters as GPU buffers, one buffer per parameter group (the groups Adam gives
//! separate learning rates), sized for growth: `capacity` ≥ `count`, so density control can add
//! Gaussians without reallocating every step.
//!
//! Layout (flat f32 arrays, Gaussian `i` at `i * stride`): positions stride 3, log-scales 3,
//! rotations 4 (w, x, y, z), opacity logits 1, SH DC 3, SH rest `3 * ((d+1)² − 1)` stored
//! coefficient-major (`[coef][channel]`, as in [`GaussianParams`]).

use super::GaussianParams;
use crate::gpu::{BufferKind, GpuBuffer, GpuContext};
use anyhow::bail;
use std::sync::Arc;

pub struct GpuSplats {
    pub count: usize,
    pub capacity: usize,
    pub sh_degree: u32,
    pub positions: GpuBuffer<f32>,
    pub log_scales: GpuBuffer<f32>,
    pub rotations: GpuBuffer<f32>,
    pub opacity_logits: GpuBuffer<f32>,
    pub sh_dc: GpuBuffer<f32>,
    pub sh_rest: GpuBuffer<f32>,
}

/// Capacity for `count` Gaussians with room to grow: 1.5× (at least 1024 more), the geometric
/// growth density control relies on.
pub fn grown_capacity(count: usize) -> usize {
    (count + count / 2).max(count + 1024)
}

impl GpuSplats {
    /// Uploads `params` (validated first: NaN or inf never reaches the GPU) into buffers of
    /// `capacity` Gaussians (at least `params.len()`).
    pub fn upload(
        ctx: &Arc<GpuContext>,
        params: &GaussianParams,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        params.validate()?;
        let n = params.len();
        if capacity < n {
            bail!("GPU capacity {capacity} is smaller than the {n} Gaussians to upload");
        }
        let rest = params.rest_stride();
        let make = |name: &str, stride: usize, data: &[f32]| -> anyhow::Result<GpuBuffer<f32>> {
            let b = GpuBuffer::new(ctx, name, capacity * stride, BufferKind::DeviceLocal)?;
            b.upload(data)?;
            Ok(b)
        };
        Ok(Self {
            count: n,
            capacity,
            sh_degree: params.sh_degree,
            positions: make("positions", 3, bytemuck::cast_slice(&params.positions))?,
            log_scales: make("log_scales", 3, bytemuck::cast_slice(&params.log_scales))?,
            rotations: make("rotations", 4, bytemuck::cast_slice(&params.rotations))?,
            opacity_logits: make("opacity_logits", 1, &params.opacity_logits)?,
            sh_dc: make("sh_dc", 3, bytemuck::cast_slice(&params.sh_dc))?,
            sh_rest: make("sh_rest", rest, &params.sh_rest)?,
        })
    }

    /// Buffers of the same layout filled with zeros on the host side (for gradients and Adam
    /// moments: they mirror the parameters group by group). Names get `prefix`.
    pub fn zeroed(
        ctx: &Arc<GpuContext>,
        prefix: &str,
        sh_degree: u32,
        count: usize,
        capacity: usize,
    ) -> anyhow::Result<Self> {
        let rest = GaussianParams::empty(sh_degree).rest_stride();
        let make = |name: &str, stride: usize| -> anyhow::Result<GpuBuffer<f32>> {
            let len = (capacity * stride).max(1);
            let b = GpuBuffer::new(
                ctx,
                &format!("{prefix}{name}"),
                len,
                BufferKind::DeviceLocal,
            )?;
            b.upload(&vec![0.0; len])?;
            Ok(b)
        };
        Ok(Self {
            count,
            capacity,
            sh_degree,
            positions: make("positions", 3)?,
            log_scales: make("log_scales", 3)?,
            rotations: make("rotations", 4)?,
            opacity_logits: make("opacity_logits", 1)?,
            sh_dc: make("sh_dc", 3)?,
            sh_rest: make("sh_rest", rest)?,
        })
    }

    /// The parameter groups in Adam's order with their per-Gaussian stride (floats):
    /// positions, log-scales, rotations, opacity logits, SH DC, SH rest.
    pub fn groups(&self) -> [(&GpuBuffer<f32>, usize); 6] {
        let rest = GaussianParams::empty(self.sh_degree).rest_stride();
        [
            (&self.positions, 3),
            (&self.log_scales, 3),
            (&self.rotations, 4),
            (&self.opacity_logits, 1),
            (&self.sh_dc, 3),
            (&self.sh_rest, rest),
        ]
    }

    /// Reads the first `count` Gaussians back.
    pub fn download(&self) -> anyhow::Result<GaussianParams> {
        let n = self.count;
        let mut p = GaussianParams::empty(self.sh_degree);
        let rest = p.rest_stride();
        p.positions = bytemuck::cast_slice(&self.positions.read_range(0, n * 3)?).to_vec();
        p.log_scales = bytemuck::cast_slice(&self.log_scales.read_range(0, n * 3)?).to_vec();
        p.rotations = bytemuck::cast_slice(&self.rotations.read_range(0, n * 4)?).to_vec();
        p.opacity_logits = self.opacity_logits.read_range(0, n)?;
        p.sh_dc = bytemuck::cast_slice(&self.sh_dc.read_range(0, n * 3)?).to_vec();
        p.sh_rest = self.sh_rest.read_range(0, n * rest)?;
        Ok(p)
    }
}
