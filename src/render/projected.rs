//! The projected Gaussians of a frame on the GPU: [`ProjectedGpu`] records stored as two
//! buffers, the rasterizers' part ([`ProjectedSplatGpu`], 36 bytes a Gaussian) and the binning
//! part ([`ProjectedBoundsGpu`], 28 bytes). One 64-byte buffer passed lavapipe's 128 MiB storage
//! binding at 2.1 M Gaussians; split, the widest per-Gaussian buffer of every model is 36 bytes
//! (3.7 M Gaussians a binding on lavapipe, 119 M at 4 GiB). Kernels bind the part they read.

use std::sync::Arc;

use super::layout::{ProjectedBoundsGpu, ProjectedGpu, ProjectedSplatGpu};
use crate::gpu::{BufferKind, GpuBuffer, GpuContext};

pub struct ProjectedBuffers {
    /// Means, opacities, conics and colours: what the rasterizers read.
    pub splats: GpuBuffer<ProjectedSplatGpu>,
    /// Depths, radii, clamp flags and tile rectangles: what binning and the backward's culling read.
    pub bounds: GpuBuffer<ProjectedBoundsGpu>,
}

impl ProjectedBuffers {
    /// Buffers for `len` Gaussians, named `name` (splats) and `name` bounds.
    pub fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        len: usize,
        kind: BufferKind,
    ) -> anyhow::Result<Self> {
        Ok(Self {
            splats: GpuBuffer::new(ctx, &format!("{name} splats"), len, kind)?,
            bounds: GpuBuffer::new(ctx, &format!("{name} bounds"), len, kind)?,
        })
    }

    /// Device-local buffers holding `records`.
    pub fn from_records(
        ctx: &Arc<GpuContext>,
        name: &str,
        records: &[ProjectedGpu],
    ) -> anyhow::Result<Self> {
        let out = Self::new(ctx, name, records.len(), BufferKind::DeviceLocal)?;
        out.upload(records)?;
        Ok(out)
    }

    /// Writes `records` at the start of both buffers.
    pub fn upload(&self, records: &[ProjectedGpu]) -> anyhow::Result<()> {
        let (splats, bounds): (Vec<_>, Vec<_>) = records.iter().map(ProjectedGpu::split).unzip();
        self.splats.upload(&splats)?;
        self.bounds.upload(&bounds)
    }

    /// Reads `count` records starting at `first` (after the work that wrote them completed).
    pub fn read_range(&self, first: usize, count: usize) -> anyhow::Result<Vec<ProjectedGpu>> {
        let splats = self.splats.read_range(first, count)?;
        let bounds = self.bounds.read_range(first, count)?;
        Ok(splats
            .iter()
            .zip(&bounds)
            .map(|(s, b)| ProjectedGpu::join(s, b))
            .collect())
    }

    /// Gaussians they hold.
    pub fn len(&self) -> usize {
        self.splats.len()
    }

    pub fn is_empty(&self) -> bool {
        self.splats.is_empty()
    }

    /// Bytes of both buffers.
    pub fn byte_len(&self) -> u64 {
        self.splats.byte_len() + self.bounds.byte_len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_are_the_kernels_std430_sizes_and_round_trip() {
        // std430 packs a struct of scalars with 4-byte alignment: 9 and 7 words.
        assert_eq!(std::mem::size_of::<ProjectedSplatGpu>(), 36);
        assert_eq!(std::mem::size_of::<ProjectedBoundsGpu>(), 28);
        let p = ProjectedGpu {
            mean_x: 1.0,
            mean_y: 2.0,
            depth: 3.0,
            opacity: 0.5,
            conic_a: 4.0,
            conic_b: 5.0,
            conic_c: 6.0,
            radius: 7.0,
            rgb: [0.1, 0.2, 0.3],
            flags: 5,
            tile_min: [8, 9],
            tile_max: [10, 11],
        };
        let (s, b) = p.split();
        assert_eq!(ProjectedGpu::join(&s, &b), p);
    }
}
