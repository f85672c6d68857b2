//! Adam on the GPU, one learning rate per parameter group, following torch.optim.Adam (the
//! multi-tensor path the reference trainer gets by default on CUDA) operation by operation:
//!
//! ```text
//! m ← m + (1 − β1)(g − m)                  torch: exp_avg.lerp_(grad, 1 − β1)
//! v ← v·β2;  v ← v + (1 − β2)(g·g)         torch: mul_(β2), addcmul_(g, g, 1 − β2)
//! d ← sqrt(v) / sqrt(1 − β2^t) + eps       torch: sqrt, div_(bias_correction2_sqrt), add_(eps)
//! p ← p + (−lr / (1 − β1^t)) · (m / d)     torch: addcdiv_(m, d, −step_size)
//! ```
//!
//! Scalars (`1 − β1`, the two bias corrections, the step size) are formed in f64 as Python does
//! and rounded once to f32; every tensor operation is one f32 rounding, with no fused
//! multiply-add (`precise` in the shader). [`adam_host_step`] does exactly the same on the host,
//! so on a device with correctly rounded `/` and `sqrt` (lavapipe) the two agree bit for bit.
//! (torch itself builds with FMA contraction on CUDA, so it is not bit-reproducible either.)
//!
//! The update is dense: every Gaussian below `count` moves, seen this iteration or not, as in
//! the reference (moments keep decaying for Gaussians with zero gradient). The one exception is
//! exact: SH rest planes wholly above the active degree are not dispatched (`active_rest`),
//! because their gradients have been zero since the start (the degree only grows), so their
//! moments are zero and the update would leave every value as it is.

use crate::gpu::{ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::shaders;
use crate::splats::gpu::{logical_group, sh_rest_plane, GpuSplats, SplatShape};
use crate::splats::sh_planes::COEFS_PER_PLANE;
use anyhow::{bail, ensure};
use std::sync::Arc;

const WG: u32 = 256;

/// Learning rates of the logical groups ([`SplatShape::strides`] order): positions,
/// log-scales, rotations, opacity logits, SH DC, SH rest (all three of its planes), then the
/// model's extra groups.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupLrs(pub Vec<f64>);

/// Adam's constants (torch defaults except eps, which 3DGS sets to 1e-15).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamHyper {
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl Default for AdamHyper {
    fn default() -> Self {
        Self {
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

/// The per-step scalars the kernel gets, already rounded to f32.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepScalars {
    pub one_minus_beta1: f32,
    pub beta2: f32,
    pub one_minus_beta2: f32,
    /// −lr / (1 − β1^t)
    pub neg_step_size: f32,
    /// sqrt(1 − β2^t)
    pub bias2_sqrt: f32,
    pub eps: f32,
}

impl AdamHyper {
    /// Checks the constants: β1 must be in (0.5, 1) because the moment update is written as
    /// torch's lerp for weights below 0.5, β2 in [0, 1), eps ≥ 0.
    pub fn validate(&self) -> anyhow::Result<()> {
        if !(self.beta1 > 0.5 && self.beta1 < 1.0) {
            bail!(
                "Adam beta1 is {}; this optimiser needs 0.5 < beta1 < 1 (default 0.9)",
                self.beta1
            );
        }
        if !(0.0..1.0).contains(&self.beta2) {
            bail!(
                "Adam beta2 is {}; it must be in [0, 1) (default 0.999)",
                self.beta2
            );
        }
        if !(self.eps >= 0.0 && self.eps.is_finite()) {
            bail!("Adam eps is {}; it must be finite and ≥ 0", self.eps);
        }
        Ok(())
    }

    /// Scalars of step `step` (1-based: the first update is step 1) at learning rate `lr`.
    pub fn scalars(&self, lr: f64, step: u32) -> StepScalars {
        let bias1 = 1.0 - self.beta1.powf(step as f64);
        let bias2 = 1.0 - self.beta2.powf(step as f64);
        StepScalars {
            one_minus_beta1: (1.0 - self.beta1) as f32,
            beta2: self.beta2 as f32,
            one_minus_beta2: (1.0 - self.beta2) as f32,
            neg_step_size: (-(lr / bias1)) as f32,
            bias2_sqrt: bias2.sqrt() as f32,
            eps: self.eps as f32,
        }
    }
}

/// One Adam step on flat f32 arrays, the arithmetic of `glsl/train/adam.comp` in the same order:
/// the host reference for tests.
pub fn adam_host_step(
    hyper: &AdamHyper,
    params: &mut [f32],
    grads: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    lr: f64,
    step: u32,
) {
    let s = hyper.scalars(lr, step);
    for i in 0..params.len() {
        let g = grads[i];
        let m1 = m[i] + s.one_minus_beta1 * (g - m[i]);
        let v1 = v[i] * s.beta2;
        let v2 = v1 + s.one_minus_beta2 * (g * g);
        let d = v2.sqrt() / s.bias2_sqrt + s.eps;
        params[i] += s.neg_step_size * (m1 / d);
        m[i] = m1;
        v[i] = v2;
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AdamPush {
    n: u32,
    one_minus_beta1: f32,
    beta2: f32,
    one_minus_beta2: f32,
    neg_step_size: f32,
    bias2_sqrt: f32,
    eps: f32,
    pad: u32,
}

/// The parameters with their two Adam moment sets, all of one capacity and count. Density
/// control replaces the whole set at once (every per-Gaussian buffer moves together).
pub struct SplatState {
    pub params: GpuSplats,
    /// First moments (torch's `exp_avg`).
    pub m: GpuSplats,
    /// Second moments (torch's `exp_avg_sq`).
    pub v: GpuSplats,
}

impl SplatState {
    /// Wraps uploaded parameters with zero moments of the same capacity.
    pub fn new(ctx: &Arc<GpuContext>, params: GpuSplats) -> anyhow::Result<Self> {
        let shape = params.shape();
        let m = GpuSplats::zeroed_shape(ctx, "adam m ", &shape, params.count, params.capacity)?;
        let v = GpuSplats::zeroed_shape(ctx, "adam v ", &shape, params.count, params.capacity)?;
        Ok(Self { params, m, v })
    }

    pub fn count(&self) -> usize {
        self.params.count
    }
    pub fn capacity(&self) -> usize {
        self.params.capacity
    }
    pub fn sh_degree(&self) -> u32 {
        self.params.sh_degree
    }
    pub fn shape(&self) -> SplatShape {
        self.params.shape()
    }

    /// Grows every buffer to `capacity` Gaussians, keeping the rows below the count. One buffer
    /// at a time: a bigger buffer, a copy, a wait, the old one freed; so the state grows by at
    /// most one buffer beyond itself, where a second whole state (parameters and both moments,
    /// 708 bytes a Gaussian at SH degree 3) used to sit beside the first. Running out of memory
    /// part-way returns the error with the same Gaussians in the same rows, some buffers already
    /// bigger and the capacity still the old one: a state as good as before for the checkpoint.
    /// Waits for the GPU once per buffer (growth is geometric: a few times a run); expects `rec`
    /// not recording and leaves it so.
    pub fn grow(
        &mut self,
        ctx: &Arc<GpuContext>,
        rec: &mut Recorder,
        capacity: usize,
    ) -> anyhow::Result<()> {
        ensure!(
            capacity >= self.capacity(),
            "growing a state of capacity {} to {capacity}",
            self.capacity()
        );
        let count = self.count();
        for set in [&mut self.params, &mut self.m, &mut self.v] {
            for (buf, width) in set.groups_mut() {
                let bigger =
                    GpuBuffer::new(ctx, buf.name(), (capacity * width).max(1), buf.kind())?;
                if count * width > 0 {
                    rec.begin()?;
                    rec.copy_region(buf, 0, &bigger, 0, count * width);
                    rec.submit_and_wait()?;
                }
                *buf = bigger;
            }
        }
        for set in [&mut self.params, &mut self.m, &mut self.v] {
            set.capacity = capacity;
        }
        Ok(())
    }

    /// Sets the count of all three sets.
    pub fn set_count(&mut self, count: usize) {
        self.params.count = count;
        self.m.count = count;
        self.v.count = count;
    }
}

/// The Adam kernel; stateless apart from the pipeline (the moments live in [`SplatState`] or
/// wherever the caller keeps them).
pub struct Adam {
    pipe: ComputePipeline,
    pub hyper: AdamHyper,
}

impl Adam {
    pub fn new(ctx: &Arc<GpuContext>) -> anyhow::Result<Self> {
        Self::with_hyper(ctx, AdamHyper::default())
    }

    pub fn with_hyper(ctx: &Arc<GpuContext>, hyper: AdamHyper) -> anyhow::Result<Self> {
        hyper.validate()?;
        let pipe = ComputePipeline::new(
            ctx,
            "train/adam",
            shaders::TRAIN_ADAM,
            4,
            std::mem::size_of::<AdamPush>() as u32,
            WG,
            &[],
        )?;
        Ok(Self { pipe, hyper })
    }

    /// Records step `step` (1-based) on the first `count` Gaussians of every group: one
    /// dispatch a stored group, with a barrier before (the gradients must be complete) and after
    /// (the parameters are read next). `params`, `m` and `v` are updated in place.
    /// `active_rest`: the SH rest coefficients the step's render used; planes wholly above
    /// them are skipped, which is exact only when their gradients have always been zero (the
    /// trainer's degree only grows). `None`: every plane.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        params: &GpuSplats,
        grads: &GpuSplats,
        m: &GpuSplats,
        v: &GpuSplats,
        count: usize,
        step: u32,
        lrs: &GroupLrs,
        active_rest: Option<usize>,
    ) -> anyhow::Result<()> {
        ensure!(step >= 1, "Adam step numbers start at 1 (got 0)");
        for (name, s) in [("gradients", grads), ("m", m), ("v", v)] {
            ensure!(
                s.sh_degree == params.sh_degree,
                "Adam: {name} have SH degree {}, the parameters {}",
                s.sh_degree,
                params.sh_degree
            );
            ensure!(
                s.extra_groups == params.extra_groups,
                "Adam: {name} have extra groups {:?}, the parameters {:?}",
                s.extra_groups,
                params.extra_groups
            );
        }
        for (name, s) in [
            ("parameters", params),
            ("gradients", grads),
            ("m", m),
            ("v", v),
        ] {
            ensure!(
                count <= s.capacity,
                "Adam: {count} Gaussians exceed the {name}' capacity {}",
                s.capacity
            );
        }
        if let Some((g, lr)) = lrs.0.iter().enumerate().find(|(_, lr)| !lr.is_finite()) {
            bail!("Adam: learning rate of group {g} is {lr}");
        }
        let (p, g, mm, vv) = (params.groups(), grads.groups(), m.groups(), v.groups());
        let logical = params.shape().strides().len();
        ensure!(
            lrs.0.len() == logical,
            "Adam: {} learning rates for {logical} parameter groups",
            lrs.0.len(),
        );
        rec.barrier();
        for k in 0..p.len() {
            let n = (count * p[k].1) as u64;
            let unused = match (sh_rest_plane(k), active_rest) {
                (Some(plane), Some(rest)) => plane * COEFS_PER_PLANE >= rest,
                _ => false,
            };
            if n == 0 || unused {
                continue;
            }
            ensure!(
                n <= u32::MAX as u64,
                "Adam: group {k} has {n} floats, over 2^32"
            );
            let push = self.push(n as u32, lrs.0[logical_group(k)], step);
            rec.dispatch_named(
                &self.pipe,
                &[
                    ("params", p[k].0),
                    ("grads", g[k].0),
                    ("m", mm[k].0),
                    ("v", vv[k].0),
                ],
                &push,
                ctx.groups_1d(n / 4 + n % 4, WG),
            );
        }
        rec.barrier();
        Ok(())
    }

    /// The kernel's constants for `n` floats at learning rate `lr`, step `step`.
    fn push(&self, n: u32, lr: f64, step: u32) -> AdamPush {
        let s = self.hyper.scalars(lr, step);
        AdamPush {
            n,
            one_minus_beta1: s.one_minus_beta1,
            beta2: s.beta2,
            one_minus_beta2: s.one_minus_beta2,
            neg_step_size: s.neg_step_size,
            bias2_sqrt: s.bias2_sqrt,
            eps: s.eps,
            pad: 0,
        }
    }

    /// Records step `step` on one flat parameter buffer (`n` floats: a model's own
    /// parameters, not per Gaussian), with a barrier before and after.
    #[allow(clippy::too_many_arguments)]
    pub fn record_flat(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        params: &GpuBuffer<f32>,
        grads: &GpuBuffer<f32>,
        m: &GpuBuffer<f32>,
        v: &GpuBuffer<f32>,
        n: usize,
        step: u32,
        lr: f64,
    ) -> anyhow::Result<()> {
        ensure!(step >= 1, "Adam step numbers start at 1 (got 0)");
        ensure!(lr.is_finite(), "Adam: learning rate {lr}");
        for (name, b) in [
            ("parameters", params),
            ("gradients", grads),
            ("m", m),
            ("v", v),
        ] {
            ensure!(
                b.len() >= n,
                "Adam: the {name} hold {} floats, not {n}",
                b.len()
            );
        }
        if n == 0 {
            return Ok(());
        }
        let push = self.push(n as u32, lr, step);
        let n = n as u64;
        rec.barrier();
        rec.dispatch_named(
            &self.pipe,
            &[("params", params), ("grads", grads), ("m", m), ("v", v)],
            &push,
            ctx.groups_1d(n / 4 + n % 4, WG),
        );
        rec.barrier();
        Ok(())
    }

    /// [`Adam::record`] on a [`SplatState`] (its own count).
    #[allow(clippy::too_many_arguments)]
    pub fn record_state(
        &self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        state: &SplatState,
        grads: &GpuSplats,
        step: u32,
        lrs: &GroupLrs,
        active_rest: Option<usize>,
    ) -> anyhow::Result<()> {
        self.record(
            ctx,
            rec,
            &state.params,
            grads,
            &state.m,
            &state.v,
            state.count(),
            step,
            lrs,
            active_rest,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_each_parameter_by_about_lr_against_the_gradient_sign() {
        // With bias correction, step 1 gives m̂ = g, v̂ = g², so Δp ≈ −lr·sign(g).
        let h = AdamHyper::default();
        let mut p = vec![1.0f32, -2.0, 0.5, 3.0];
        let g = vec![0.3f32, -1e-3, 7.0, 0.0];
        let (mut m, mut v) = (vec![0.0; 4], vec![0.0; 4]);
        let before = p.clone();
        adam_host_step(&h, &mut p, &g, &mut m, &mut v, 0.01, 1);
        for i in 0..3 {
            let d = (p[i] - before[i]) as f64;
            assert!(
                (d + 0.01 * (g[i] as f64).signum()).abs() < 1e-5,
                "i={i} d={d}"
            );
        }
        assert_eq!(p[3], before[3], "zero gradient, zero moments: no move");
    }

    #[test]
    fn host_step_matches_an_f64_adam_closely() {
        // The f32 op-by-op version stays within f32 rounding of the textbook formula.
        let h = AdamHyper::default();
        let mut p = vec![0.7f32, -0.2];
        let (mut m, mut v) = (vec![0.0f32; 2], vec![0.0f32; 2]);
        let (mut p64, mut m64, mut v64) = ([0.7f64, -0.2], [0.0f64; 2], [0.0f64; 2]);
        for t in 1..=50u32 {
            let g = [((t as f32) * 0.37).sin(), ((t as f32) * 1.3).cos() * 0.01];
            adam_host_step(&h, &mut p, &g, &mut m, &mut v, 1e-3, t);
            for i in 0..2 {
                let g = g[i] as f64;
                m64[i] = 0.9 * m64[i] + 0.1 * g;
                v64[i] = 0.999 * v64[i] + 0.001 * g * g;
                let mh = m64[i] / (1.0 - 0.9f64.powi(t as i32));
                let vh = v64[i] / (1.0 - 0.999f64.powi(t as i32));
                p64[i] -= 1e-3 * mh / (vh.sqrt() + 1e-15);
            }
        }
        for i in 0..2 {
            assert!(
                (p[i] as f64 - p64[i]).abs() < 1e-5,
                "{} vs {}",
                p[i],
                p64[i]
            );
        }
    }

    #[test]
    fn bad_hyperparameters_are_refused() {
        for h in [
            AdamHyper {
                beta1: 0.3,
                ..Default::default()
            },
            AdamHyper {
                beta2: 1.0,
                ..Default::default()
            },
            AdamHyper {
                eps: f64::NAN,
                ..Default::default()
            },
        ] {
            assert!(h.validate().is_err(), "{h:?}");
        }
        AdamHyper::default().validate().unwrap();
    }
}
