//! The MCMC kernels (`glsl/mcmc/`): a plan's row copies and corrections, the position noise and
//! the regularisers' gradients.

use std::sync::Arc;

use super::plan::Plan;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::GpuSplats;
use crate::train::adam::SplatState;

const WG: u32 = 128;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RowsPush {
    count: u32,
    width: u32,
    mode: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CorrectPush {
    count: u32,
    axes: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct NoisePush {
    count: u32,
    seed: u32,
    step: u32,
    amount: f32,
    gate_k: f32,
    gate_t: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RegularisePush {
    count: u32,
    axes: u32,
    opacity_coeff: f32,
    scale_coeff: f32,
}

/// A plan uploaded for the GPU: keep it alive until the work recorded with it has run.
pub struct UploadedPlan {
    pairs: Option<GpuBuffer<u32>>,
    rows: Option<GpuBuffer<u32>>,
    values: Option<GpuBuffer<f32>>,
    copies: usize,
    updates: usize,
}

pub struct McmcKernels {
    ctx: Arc<GpuContext>,
    copy_rows: ComputePipeline,
    correct: ComputePipeline,
    noise: ComputePipeline,
    regularise: ComputePipeline,
}

impl McmcKernels {
    pub fn new(ctx: &Arc<GpuContext>) -> anyhow::Result<Self> {
        let pipe = |name: &str, spirv: &[u8], buffers: u32, push: usize| {
            ComputePipeline::new(ctx, name, spirv, buffers, push as u32, WG, &[])
        };
        use std::mem::size_of;
        Ok(Self {
            ctx: ctx.clone(),
            copy_rows: pipe(
                "mcmc/copy_rows",
                shaders::MCMC_COPY_ROWS,
                2,
                size_of::<RowsPush>(),
            )?,
            correct: pipe(
                "mcmc/correct",
                shaders::MCMC_CORRECT,
                4,
                size_of::<CorrectPush>(),
            )?,
            noise: pipe("mcmc/noise", shaders::MCMC_NOISE, 4, size_of::<NoisePush>())?,
            regularise: pipe(
                "mcmc/regularise",
                shaders::MCMC_REGULARISE,
                4,
                size_of::<RegularisePush>(),
            )?,
        })
    }

    /// Uploads `plan` (staging buffers, written now).
    pub fn upload(&self, plan: &Plan) -> anyhow::Result<UploadedPlan> {
        let up =
            |name: &str, n: usize| GpuBuffer::<u32>::new(&self.ctx, name, n, BufferKind::Upload);
        let pairs = if plan.copies.is_empty() {
            None
        } else {
            let b = up("mcmc pairs", 2 * plan.copies.len())?;
            let flat: Vec<u32> = plan.copies.iter().flat_map(|&(d, s)| [d, s]).collect();
            b.upload(&flat)?;
            Some(b)
        };
        let (rows, values) = if plan.updates.is_empty() {
            (None, None)
        } else {
            let r = up("mcmc rows", plan.updates.len())?;
            r.upload(&plan.updates.iter().map(|u| u.0).collect::<Vec<_>>())?;
            let v = GpuBuffer::<f32>::new(
                &self.ctx,
                "mcmc values",
                2 * plan.updates.len(),
                BufferKind::Upload,
            )?;
            v.upload(
                &plan
                    .updates
                    .iter()
                    .flat_map(|u| [u.1, u.2])
                    .collect::<Vec<_>>(),
            )?;
            (Some(r), Some(v))
        };
        Ok(UploadedPlan {
            pairs,
            rows,
            values,
            copies: plan.copies.len(),
            updates: plan.updates.len(),
        })
    }

    /// Records `plan` on `state` (rows below its count): every group's rows copied, both moment
    /// sets' rows of each pair zeroed, then the corrections of the first `axes` log-scales.
    pub fn record_plan(
        &self,
        rec: &mut Recorder,
        state: &SplatState,
        plan: &UploadedPlan,
        axes: u32,
    ) -> anyhow::Result<()> {
        if let Some(pairs) = &plan.pairs {
            rec.barrier();
            for (set, mode) in [(&state.params, 0u32), (&state.m, 1), (&state.v, 1)] {
                for (buf, width) in set.groups() {
                    if width == 0 {
                        continue;
                    }
                    let n = (plan.copies * width) as u64;
                    rec.dispatch_named(
                        &self.copy_rows,
                        &[("pairs", pairs), ("rows", buf)],
                        &RowsPush {
                            count: plan.copies as u32,
                            width: width as u32,
                            mode,
                        },
                        self.ctx.groups_1d(n, WG),
                    );
                }
            }
        }
        if let (Some(rows), Some(values)) = (&plan.rows, &plan.values) {
            rec.barrier();
            rec.dispatch_named(
                &self.correct,
                &[
                    ("rows", rows),
                    ("values", values),
                    ("opacity_logits", &state.params.opacity_logits),
                    ("log_scales", &state.params.log_scales),
                ],
                &CorrectPush {
                    count: plan.updates as u32,
                    axes,
                },
                self.ctx.groups_1d(plan.updates as u64, WG),
            );
        }
        rec.barrier();
        Ok(())
    }

    /// Records the noise step of the first `count` Gaussians of `params`.
    #[allow(clippy::too_many_arguments)]
    pub fn record_noise(
        &self,
        rec: &mut Recorder,
        params: &GpuSplats,
        count: usize,
        seed: u32,
        step: u32,
        amount: f32,
        gate: (f32, f32),
    ) {
        if count == 0 || amount == 0.0 {
            return;
        }
        rec.barrier();
        rec.dispatch_named(
            &self.noise,
            &[
                ("positions", &params.positions),
                ("log_scales", &params.log_scales),
                ("rotations", &params.rotations),
                ("opacity_logits", &params.opacity_logits),
            ],
            &NoisePush {
                count: count as u32,
                seed,
                step,
                amount,
                gate_k: gate.0,
                gate_t: gate.1,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
    }

    /// Records the regularisers' gradients of the first `count` Gaussians into `grads`
    /// (weights `λ_o`, `λ_s`; the mean's `1 / N` is applied here).
    pub fn record_regularise(
        &self,
        rec: &mut Recorder,
        params: &GpuSplats,
        grads: &GpuSplats,
        count: usize,
        weights: (f64, f64),
        axes: u32,
    ) {
        if count == 0 || (weights.0 == 0.0 && weights.1 == 0.0) {
            return;
        }
        let n = count as f64;
        rec.barrier();
        rec.dispatch_named(
            &self.regularise,
            &[
                ("opacity_logits", &params.opacity_logits),
                ("log_scales", &params.log_scales),
                ("grad_opacity", &grads.opacity_logits),
                ("grad_log_scales", &grads.log_scales),
            ],
            &RegularisePush {
                count: count as u32,
                axes,
                opacity_coeff: (weights.0 / n) as f32,
                scale_coeff: (weights.1 / (n * axes as f64)) as f32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
    }
}
