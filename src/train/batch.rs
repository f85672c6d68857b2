//! Several views in one optimizer step (SpacetimeGaussians trains every step on two cameras
//! at one time, docs/algorithms/base-models.md §4.4): which views join the scheduled one, and the mean of their
//! gradients (`glsl/train/grads_blend.comp`). The trainer renders and differentiates each view
//! in turn, adds each later view's gradients into the first's and scales the sum to the mean
//! before the one Adam step; the density statistics come from the last view only, as in the
//! official code.

use std::sync::Arc;

use anyhow::ensure;
use rand::seq::SliceRandom;
use rand::SeedableRng;

use crate::gpu::{ComputePipeline, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::GpuSplats;

const WG: u32 = 256;

/// The views a step trains with `view` besides it: up to `batch − 1` other training views of
/// the same time (other cameras of the same frame in a video; `times` `None`: a still scene,
/// any other training view), drawn without repeats from (seed, iteration), so a resumed run
/// draws the same. Fewer when fewer exist.
pub fn batch_partners(
    view: usize,
    train: &[usize],
    times: Option<&[f64]>,
    batch: u32,
    seed: u64,
    iteration: u32,
) -> Vec<usize> {
    if batch <= 1 {
        return Vec::new();
    }
    let mut candidates: Vec<usize> = train
        .iter()
        .copied()
        .filter(|&o| o != view && times.is_none_or(|t| t[o] == t[view]))
        .collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(
        seed ^ 0x6261_7463_6876_6965 ^ (iteration as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15),
    );
    candidates.shuffle(&mut rng);
    candidates.truncate(batch as usize - 1);
    candidates
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BlendPush {
    n: u32,
    scale: f32,
}

/// `dst = (dst + src) · scale` over every parameter group of two gradient sets.
pub struct GradBlend {
    ctx: Arc<GpuContext>,
    pipe: ComputePipeline,
}

impl GradBlend {
    pub fn new(ctx: &Arc<GpuContext>) -> anyhow::Result<Self> {
        Ok(Self {
            ctx: ctx.clone(),
            pipe: ComputePipeline::new(
                ctx,
                "train/grads_blend",
                shaders::TRAIN_GRADS_BLEND,
                2,
                std::mem::size_of::<BlendPush>() as u32,
                WG,
                &[],
            )?,
        })
    }

    /// Records the blend of the first `count` Gaussians' gradients, with barriers before (the
    /// backward must be complete) and after.
    pub fn record(
        &self,
        rec: &mut Recorder,
        dst: &GpuSplats,
        src: &GpuSplats,
        count: usize,
        scale: f32,
    ) -> anyhow::Result<()> {
        let (d, s) = (dst.groups(), src.groups());
        ensure!(
            d.len() == s.len() && d.iter().zip(&s).all(|(a, b)| a.1 == b.1),
            "gradient blend: the two gradient sets have different groups"
        );
        rec.barrier();
        for ((dg, stride), (sg, _)) in d.into_iter().zip(s) {
            let n = count * stride;
            if n == 0 {
                continue;
            }
            ensure!(
                dg.len() >= n && sg.len() >= n,
                "gradient blend: {} holds {} floats, {} holds {}, {count} Gaussians need {n}",
                dg.name(),
                dg.len(),
                sg.name(),
                sg.len()
            );
            rec.dispatch_named(
                &self.pipe,
                &[("dst", dg), ("src", sg)],
                &BlendPush { n: n as u32, scale },
                self.ctx.groups_1d(n as u64, WG),
            );
        }
        rec.barrier();
        Ok(())
    }
}
