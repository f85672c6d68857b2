//! NaN check mode: a GPU scan of the parameters for the first non-finite value (NaN or ±inf)
//! per parameter group (`glsl/train/find_non_finite.comp`), so a diverging run stops at the
//! iteration it broke, naming the group and the Gaussian, instead of training on garbage.

use std::sync::Arc;

use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::GpuSplats;

const WG: u32 = 256;
const NONE: u32 = u32::MAX;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push {
    n: u32,
    stride: u32,
    slot: u32,
}

/// A non-finite parameter: the group and the lowest Gaussian index holding one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NonFinite {
    pub group: String,
    pub gaussian: usize,
}

pub struct NonFiniteCheck {
    ctx: Arc<GpuContext>,
    pipe: ComputePipeline,
    first: GpuBuffer<u32>,
    first_host: GpuBuffer<u32>,
    rec: Recorder,
}

impl NonFiniteCheck {
    pub fn new(ctx: &Arc<GpuContext>) -> anyhow::Result<Self> {
        Ok(Self {
            ctx: ctx.clone(),
            pipe: ComputePipeline::new(
                ctx,
                "train/find_non_finite",
                shaders::TRAIN_FIND_NON_FINITE,
                2,
                std::mem::size_of::<Push>() as u32,
                WG,
                &[],
            )?,
            first: GpuBuffer::new(ctx, "non-finite first", 6, BufferKind::DeviceLocal)?,
            first_host: GpuBuffer::new(ctx, "non-finite first (host)", 6, BufferKind::Readback)?,
            rec: Recorder::new(ctx)?,
        })
    }

    /// The first non-finite value of every group in `GpuSplats::groups()` order (None where
    /// the group is finite), for the first `splats.count` Gaussians. Submits and waits.
    pub fn scan(&mut self, splats: &GpuSplats) -> anyhow::Result<Vec<Option<usize>>> {
        let n = splats.count;
        let names = splats.shape().storage_strides();
        if self.first.len() < names.len() {
            self.first = GpuBuffer::new(
                &self.ctx,
                "non-finite first",
                names.len(),
                BufferKind::DeviceLocal,
            )?;
            self.first_host = GpuBuffer::new(
                &self.ctx,
                "non-finite first (host)",
                names.len(),
                BufferKind::Readback,
            )?;
        }
        self.rec.begin()?;
        self.rec.fill(&self.first, NONE);
        self.rec.barrier();
        for (slot, (buf, stride)) in splats.groups().iter().enumerate() {
            let floats = n * stride;
            if floats == 0 {
                continue;
            }
            anyhow::ensure!(
                floats <= u32::MAX as usize,
                "NaN check: {} holds {floats} floats, more than the kernel indexes",
                names[slot].0
            );
            let push = Push {
                n: floats as u32,
                stride: *stride as u32,
                slot: slot as u32,
            };
            let groups = self.ctx.groups_1d(floats as u64, WG);
            self.rec.dispatch_named(
                &self.pipe,
                &[("values", *buf), ("first", &self.first)],
                &push,
                groups,
            );
        }
        self.rec.barrier();
        self.rec.copy(&self.first, &self.first_host, names.len());
        self.rec.submit_and_wait()?;
        let v = self.first_host.read_range(0, names.len())?;
        Ok(v.iter()
            .map(|&x| (x != NONE).then_some(x as usize))
            .collect())
    }

    /// The first non-finite parameter (lowest group in `GpuSplats::groups()` order, then lowest
    /// Gaussian), if any.
    pub fn first(&mut self, splats: &GpuSplats) -> anyhow::Result<Option<NonFinite>> {
        let names = splats.shape().storage_strides();
        Ok(self.scan(splats)?.iter().enumerate().find_map(|(g, i)| {
            i.map(|gaussian| NonFinite {
                group: names[g].0.clone(),
                gaussian,
            })
        }))
    }

    /// An error naming `iteration`, the group and the Gaussian when any parameter is not
    /// finite.
    pub fn check(&mut self, splats: &GpuSplats, iteration: u32) -> anyhow::Result<()> {
        if let Some(nf) = self.first(splats)? {
            anyhow::bail!(
                "NaN check: after iteration {iteration}, parameter group '{}' of Gaussian {} is \
                 not finite (NaN or inf). Fix: lower the learning rates (e.g. --lr-position, \
                 --lr-scaling), or resume from an earlier checkpoint",
                nf.group,
                nf.gaussian
            );
        }
        Ok(())
    }
}
