//! Adaptive density control on the GPU: per-iteration statistics, the densify-and-prune step
//! (Inria's clone / split / prune rules) and the opacity reset.
//!
//! # The step, kernel by kernel (`glsl/density/`)
//! 1. `decide`: one decision word per Gaussian (`DECIDE_*` bits): clone, split, remove. New
//!    Gaussians face the prune tests with their own parameters, so one that would be pruned at
//!    once is never emitted (the reference creates then prunes it: same result).
//! 2. *(hook)* a caller may run its own kernels on [`DensityControl::decisions`] here, between
//!    [`DensityControl::record_decide`] and [`DensityControl::apply`], OR-ing in
//!    `DECIDE_REMOVE` (extra pruning), `DECIDE_CLONE`, or `DECIDE_SPLIT` (the original is then
//!    removed); LPM also passes a per-Gaussian threshold multiplier to `record_decide`, and
//!    reads `DECIDE_LOWERED` to know what was densified only because of it.
//! 3. `expand` + [`PrefixScan`]: slot counts (kept 0/1, clone 0/1, children 0/2) laid out as
//!    three blocks of `count` and scanned as one array: the scan gives every destination and
//!    the new count (the only value the host reads back, with the two block starts).
//! 4. `scatter` for every per-Gaussian buffer (the parameter groups, both moment sets) and
//!    `split` for the children's positions and log-scales, in place: each group is scattered
//!    into a scratch buffer of the widest group's size and copied back (a second
//!    [`SplatState`] as destination held as much memory as the model and its moments). When
//!    the new count outgrows the capacity, [`SplatState::grow`] first moves the state into
//!    buffers of [`grown_capacity`], one buffer at a time with the rows unchanged.
//!
//! # New layout
//! `[survivors in their old order | clones in parent order | split children: two adjacent rows
//! per parent, in parent order]`. (The reference appends all first children, then all second
//! children; the order has no effect on training.)
//!
//! # What is carried
//! Survivors keep parameters and moments bit for bit. Clones copy every parameter and get zero
//! moments. Split children: position = parent mean + R·(scale ⊙ n), n ~ N(0, I) from a
//! counter-based hash of (seed, iteration, parent index, draw), so a run is deterministic for a
//! seed; log-scale = parent − ln 1.6; rotation, opacity and SH copied; zero moments. The
//! statistics are zeroed after the step, as the reference does.
//!
//! # Pruning
//! opacity < 0.005; with `prune_large` (the reference: after the first opacity reset) also
//! max world scale > 0.1·extent. Screen-size pruning: the reference resets `max_radii2D` to 0
//! right before its "> 20 px" test, so that test never fires; here it is
//! [`DensityConfig::screen_size_limit`], `None` by default (the reference's behaviour). When set,
//! it removes originals whose largest screen radius since the last step exceeds the limit.
//!
//! Thresholds are compared in the log / logit domain (`max(log_scale) ≤ ln(0.01·extent)`,
//! `logit < logit(0.005)`): monotone, so these are the reference's tests up to the rounding of
//! the threshold itself, and they need no transcendental on the GPU.

pub mod abs_quantile;
pub mod append;
pub mod budget;
pub mod growth;
mod move_in_place;
pub mod region;
pub mod rng;
mod rules;

pub use rules::{
    reset_logit, DensifyArgs, DensifyOutcome, DensifyPhase, DensityConfig, ScoreInput, Statistic,
    Thresholds,
};

use super::adam::SplatState;
use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext, Recorder};
use crate::render::layout::ProjectedBoundsGpu;
use crate::render::scan::PrefixScan;
use crate::shaders;
use crate::splats::gpu::grown_capacity;
use anyhow::{bail, ensure};
use std::sync::Arc;

/// The original is not carried over (pruned).
pub const DECIDE_REMOVE: u32 = 1;
/// Emit one identical copy.
pub const DECIDE_CLONE: u32 = 2;
/// Emit two split children; the original is removed.
pub const DECIDE_SPLIT: u32 = 4;
/// Densified (clone or split intended) only because of the per-Gaussian threshold multiplier.
pub const DECIDE_LOWERED: u32 = 8;

const WG: u32 = 128;

/// Per-Gaussian statistics accumulated between steps (capacity-sized, Gaussian `i` at `i`).
pub struct DensityStats {
    /// Sum of the NDC mean-gradient norms over the views that saw the Gaussian.
    pub grad_accum: GpuBuffer<f32>,
    /// Number of such views (f32, as in the reference).
    pub denom: GpuBuffer<f32>,
    /// Largest screen radius (px) since the last step.
    pub max_radii: GpuBuffer<f32>,
    /// Sum of the absolute-gradient statistic over the same views (with
    /// [`DensityConfig::abs_grad`]; zeros otherwise).
    pub abs_accum: GpuBuffer<f32>,
}

impl DensityStats {
    fn zeroed(ctx: &Arc<GpuContext>, capacity: usize) -> anyhow::Result<Self> {
        let z = vec![0.0f32; capacity.max(1)];
        Ok(Self {
            grad_accum: GpuBuffer::from_slice(ctx, "density grad_accum", &z)?,
            denom: GpuBuffer::from_slice(ctx, "density denom", &z)?,
            max_radii: GpuBuffer::from_slice(ctx, "density max_radii", &z)?,
            abs_accum: GpuBuffer::from_slice(ctx, "density abs_accum", &z)?,
        })
    }

    pub fn capacity(&self) -> usize {
        self.denom.len()
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CountPush {
    count: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct AccumulatePush {
    count: u32,
    mode: u32,
    depth_scale: f32,
    abs_grad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct DecidePush {
    count: u32,
    flags: u32,
    grad_threshold: f32,
    log_clone_max: f32,
    min_opacity_logit: f32,
    log_world_max: f32,
    log_split_shrink: f32,
    screen_max: f32,
    /// The absolute-gradient quantile (with flag 4).
    abs_threshold: f32,
    /// The growth region's bands (with flag 128): axis, lo, hi per band.
    region: [f32; 10],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BudgetPush {
    count: u32,
    cut_score: f32,
    cut_index: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SplitPush {
    count: u32,
    seed: u32,
    step: u32,
    log_split_shrink: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BoxPush {
    count: u32,
    lo: [f32; 3],
    hi: [f32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ResetPush {
    count: u32,
    max_logit: f32,
    filtered: u32,
}

/// Density control: owns the statistics and the step's scratch buffers.
pub struct DensityControl {
    ctx: Arc<GpuContext>,
    pub config: DensityConfig,
    accumulate: ComputePipeline,
    decide: ComputePipeline,
    budget: ComputePipeline,
    prune_box: ComputePipeline,
    expand: ComputePipeline,
    scatter: ComputePipeline,
    split: ComputePipeline,
    reset: ComputePipeline,
    stats: DensityStats,
    decisions: GpuBuffer<u32>,
    /// Each Gaussian's score of the last decision (`decide.comp`; the budget's ranking).
    scores: GpuBuffer<f32>,
    /// Slot counts, scanned in place into destinations (3 × scratch capacity).
    slots: GpuBuffer<u32>,
    scan: PrefixScan,
    /// `[3·count (scan length), new count, kept, kept + clones]`.
    counts: GpuBuffer<u32>,
    /// Bound in place of a missing threshold-scale buffer.
    dummy: GpuBuffer<f32>,
    /// Bound in place of the pixel counts under the gradient statistic.
    no_counts: GpuBuffer<u32>,
    scratch_capacity: usize,
    /// Count `record_decide` ran on, so `apply` can check it is applied to the same state.
    decided: Option<usize>,
    /// The absolute-gradient quantile of the last decision (with `config.abs_grad`).
    pub last_abs_threshold: Option<f32>,
    /// What the Gaussian budget dropped at the last decision (`None`: the step fitted, or no
    /// cap).
    pub last_budget: Option<budget::BudgetCut>,
    /// Where each group is scattered before it is copied back (`record_move_in_place`).
    move_scratch: [GpuBuffer<f32>; 2],
}

impl DensityControl {
    /// Sized for states of up to `capacity` Gaussians (grows with them).
    pub fn new(
        ctx: &Arc<GpuContext>,
        capacity: usize,
        config: DensityConfig,
    ) -> anyhow::Result<Self> {
        reset_logit(&config)?;
        let pipe = |name: &str, spirv: &[u8], buffers: u32, push: usize| {
            ComputePipeline::new(ctx, name, spirv, buffers, push as u32, WG, &[])
        };
        use std::mem::size_of;
        let capacity = capacity.max(1);
        Ok(Self {
            ctx: ctx.clone(),
            config,
            accumulate: pipe(
                "density/accumulate",
                shaders::DENSITY_ACCUMULATE,
                8,
                size_of::<AccumulatePush>(),
            )?,
            decide: pipe(
                "density/decide",
                shaders::DENSITY_DECIDE,
                11,
                size_of::<DecidePush>(),
            )?,
            budget: pipe(
                "density/budget",
                shaders::DENSITY_BUDGET,
                2,
                size_of::<BudgetPush>(),
            )?,
            prune_box: pipe(
                "density/prune_outside_box",
                shaders::DENSITY_PRUNE_OUTSIDE_BOX,
                2,
                size_of::<BoxPush>(),
            )?,
            expand: pipe(
                "density/expand",
                shaders::DENSITY_EXPAND,
                3,
                size_of::<CountPush>(),
            )?,
            scatter: pipe(
                "density/scatter",
                shaders::DENSITY_SCATTER,
                4,
                size_of::<move_in_place::ScatterPush>(),
            )?,
            split: pipe(
                "density/split",
                shaders::DENSITY_SPLIT,
                7,
                size_of::<SplitPush>(),
            )?,
            reset: pipe(
                "density/reset_opacity",
                shaders::DENSITY_RESET_OPACITY,
                5,
                size_of::<ResetPush>(),
            )?,
            stats: DensityStats::zeroed(ctx, capacity)?,
            decisions: GpuBuffer::new(ctx, "density decisions", capacity, BufferKind::DeviceLocal)?,
            scores: GpuBuffer::new(ctx, "density scores", capacity, BufferKind::DeviceLocal)?,
            slots: GpuBuffer::new(ctx, "density slots", 3 * capacity, BufferKind::DeviceLocal)?,
            scan: PrefixScan::new(ctx, 3 * capacity as u64)?,
            counts: GpuBuffer::from_slice(ctx, "density counts", &[0u32; 4])?,
            dummy: GpuBuffer::from_slice(ctx, "density no threshold scale", &[1.0f32])?,
            no_counts: GpuBuffer::from_slice(ctx, "density no pixel counts", &[0u32])?,
            scratch_capacity: capacity,
            decided: None,
            last_abs_threshold: None,
            last_budget: None,
            move_scratch: [
                GpuBuffer::new(ctx, "density move scratch", 1, BufferKind::DeviceLocal)?,
                GpuBuffer::new(ctx, "density move scratch", 1, BufferKind::DeviceLocal)?,
            ],
        })
    }

    pub fn stats(&self) -> &DensityStats {
        &self.stats
    }

    /// The decision words of the last `record_decide` (first `count` entries; `DECIDE_*` bits).
    /// Kernels recorded between `record_decide` and `apply` may modify them (the LPM hook).
    pub fn decisions(&self) -> &GpuBuffer<u32> {
        &self.decisions
    }

    /// Each Gaussian's score of the last `record_decide` (first `count` entries; the budget's
    /// ranking, [`budget`]).
    pub fn scores(&self) -> &GpuBuffer<f32> {
        &self.scores
    }

    /// Grows the statistics to `capacity` Gaussians, keeping their values (for callers that
    /// add Gaussians themselves). Submits and waits: no recorded work may still use the stats.
    pub fn ensure_capacity(&mut self, capacity: usize) -> anyhow::Result<()> {
        if capacity <= self.stats.capacity() {
            return Ok(());
        }
        let grown = DensityStats::zeroed(&self.ctx, capacity)?;
        let n = self.stats.capacity();
        let mut rec = Recorder::new(&self.ctx)?;
        rec.copy(&self.stats.grad_accum, &grown.grad_accum, n);
        rec.copy(&self.stats.denom, &grown.denom, n);
        rec.copy(&self.stats.max_radii, &grown.max_radii, n);
        rec.copy(&self.stats.abs_accum, &grown.abs_accum, n);
        rec.submit_and_wait()?;
        self.stats = grown;
        Ok(())
    }

    fn ensure_scratch(&mut self, capacity: usize) -> anyhow::Result<()> {
        if capacity <= self.scratch_capacity {
            return Ok(());
        }
        let ctx = &self.ctx;
        self.decisions =
            GpuBuffer::new(ctx, "density decisions", capacity, BufferKind::DeviceLocal)?;
        self.scores = GpuBuffer::new(ctx, "density scores", capacity, BufferKind::DeviceLocal)?;
        self.slots = GpuBuffer::new(ctx, "density slots", 3 * capacity, BufferKind::DeviceLocal)?;
        self.scan = PrefixScan::new(ctx, 3 * capacity as u64)?;
        self.scratch_capacity = capacity;
        Ok(())
    }

    /// Records zeroing of the statistics.
    pub fn record_reset_stats(&self, rec: &mut Recorder) {
        rec.barrier();
        rec.fill(&self.stats.grad_accum, 0);
        rec.fill(&self.stats.denom, 0);
        rec.fill(&self.stats.max_radii, 0);
        rec.fill(&self.stats.abs_accum, 0);
        rec.barrier();
    }

    /// Records this view's contribution to the statistics: `view_grad_norm[i]` is |dL/d mean2d|
    /// in NDC for Gaussian `i` (written by the backward pass), `bounds[i].radius > 0` marks
    /// the visible ones; `pixel_count` (the backward's, required by the pixel-weighted
    /// statistic) the pixels each contributed to; `abs_grad` (the backward's, required with
    /// [`DensityConfig::abs_grad`]) the absolute-gradient statistic; `extent` the scene extent.
    #[allow(clippy::too_many_arguments)]
    pub fn record_accumulate(
        &self,
        rec: &mut Recorder,
        view_grad_norm: &GpuBuffer<f32>,
        bounds: &GpuBuffer<ProjectedBoundsGpu>,
        pixel_count: Option<&GpuBuffer<u32>>,
        abs_grad: Option<&GpuBuffer<f32>>,
        extent: f64,
        count: usize,
    ) -> anyhow::Result<()> {
        let abs = match (self.config.abs_grad, abs_grad) {
            (false, _) => None,
            (true, Some(a)) => {
                ensure!(
                    a.len() >= count,
                    "density statistics: {count} Gaussians but {} absolute gradients",
                    a.len()
                );
                Some(a)
            }
            (true, None) => bail!(
                "density statistics: the absolute-gradient test needs the backward's absolute \
                 gradients; pass them (BackwardArgs::abs_grad)"
            ),
        };
        let (mode, depth_scale) = self.config.statistic.kernel_mode(extent)?;
        let counts = match (self.config.statistic.needs_pixel_counts(), pixel_count) {
            (false, _) => &self.no_counts,
            (true, Some(c)) => {
                ensure!(
                    c.len() >= count,
                    "density statistics: {count} Gaussians but {} pixel counts",
                    c.len()
                );
                c
            }
            (true, None) => bail!(
                "density statistics: the {} statistic needs the backward's pixel counts; pass \
                 them (BackwardArgs::pixel_count)",
                self.config.statistic.name()
            ),
        };
        ensure!(
            count <= self.stats.capacity()
                && count <= view_grad_norm.len()
                && count <= bounds.len(),
            "density statistics: {count} Gaussians, but stats hold {}, gradient norms {}, projected {}",
            self.stats.capacity(),
            view_grad_norm.len(),
            bounds.len()
        );
        if count == 0 {
            return Ok(());
        }
        rec.barrier();
        rec.dispatch_named(
            &self.accumulate,
            &[
                ("view_grad_norm", view_grad_norm),
                ("bounds", bounds),
                ("grad_accum", &self.stats.grad_accum),
                ("denom", &self.stats.denom),
                ("max_radii", &self.stats.max_radii),
                ("pixel_count", counts),
                ("abs_grad", abs.unwrap_or(&self.dummy)),
                ("abs_accum", &self.stats.abs_accum),
            ],
            &AccumulatePush {
                count: count as u32,
                mode,
                depth_scale,
                abs_grad: abs.is_some() as u32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
        Ok(())
    }

    /// Records the decision kernel for `state` (see the module docs). `threshold_scale`, when
    /// given, multiplies the gradient threshold per Gaussian (e.g. 0.5 inside LPM zones);
    /// `score` multiplies each candidate's score, the ranking a budget keeps the best of (a
    /// guide's preference, e.g. LPM's zones), or replaces it (a strategy's own ranking). May reallocate the scratch buffers (decisions,
    /// slots) when the state outgrew them, so record it once per step and follow it with
    /// [`DensityControl::apply`].
    pub fn record_decide(
        &mut self,
        rec: &mut Recorder,
        state: &SplatState,
        args: &DensifyArgs,
        threshold_scale: Option<&GpuBuffer<f32>>,
        score: Option<ScoreInput<&GpuBuffer<f32>>>,
    ) -> anyhow::Result<()> {
        let score_weight = score.map(|s| *s.values());
        let t = Thresholds::new(&self.config, args)?;
        let count = state.count();
        ensure!(
            count <= self.stats.capacity(),
            "density control: {count} Gaussians but statistics for {} (call ensure_capacity after adding Gaussians)",
            self.stats.capacity()
        );
        ensure!(
            count < (u32::MAX / 3) as usize,
            "density control: {count} Gaussians exceed the 32-bit slot scan"
        );
        for (what, b) in [
            ("threshold scale", threshold_scale),
            ("score weight", score_weight),
        ] {
            if let Some(s) = b {
                ensure!(
                    s.len() >= count,
                    "density control: {what} buffer has {} entries for {count} Gaussians",
                    s.len()
                );
            }
        }
        self.ensure_scratch(state.capacity().max(count))?;
        self.decided = Some(count);
        self.last_budget = None;
        if count == 0 {
            return Ok(());
        }
        // The quantile needs every Gaussian's statistics: read back once per densify step
        // (the statistics are complete: the iteration's command buffer has been waited for).
        let abs_threshold = if self.config.abs_grad {
            let read = |b: &GpuBuffer<f32>| b.read_range(0, count);
            Some(abs_quantile::abs_grad_threshold(
                &read(&self.stats.grad_accum)?,
                &read(&self.stats.denom)?,
                &read(&self.stats.abs_accum)?,
                t.grad_threshold,
            ))
        } else {
            None
        };
        self.last_abs_threshold = abs_threshold;
        let push = DecidePush {
            count: count as u32,
            abs_threshold: abs_threshold.unwrap_or(f32::INFINITY),
            flags: t.prune_large as u32
                | ((threshold_scale.is_some() as u32) << 1)
                | ((abs_threshold.is_some() as u32) << 2)
                | ((t.rank_all as u32) << 3)
                | ((score_weight.is_some() as u32) << 4)
                | ((t.rank_lowered as u32) << 5)
                | ((matches!(score, Some(ScoreInput::Replace(_))) as u32) << 6)
                | ((t.region.is_some() as u32) << 7),
            grad_threshold: t.grad_threshold,
            log_clone_max: t.log_clone_max,
            min_opacity_logit: t.min_opacity_logit,
            log_world_max: t.log_world_max,
            log_split_shrink: t.log_split_shrink,
            screen_max: t.screen_max,
            region: t.region.unwrap_or([0.0; 10]),
        };
        rec.barrier();
        rec.dispatch_named(
            &self.decide,
            &[
                ("grad_accum", &self.stats.grad_accum),
                ("denom", &self.stats.denom),
                ("max_radii", &self.stats.max_radii),
                ("log_scales", &state.params.log_scales),
                ("opacity_logits", &state.params.opacity_logits),
                ("threshold_scale", threshold_scale.unwrap_or(&self.dummy)),
                ("decisions", &self.decisions),
                ("abs_accum", &self.stats.abs_accum),
                ("scores", &self.scores),
                ("score_weight", score_weight.unwrap_or(&self.dummy)),
                ("positions", &state.params.positions),
            ],
            &push,
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
        if let Some(cap) = self.step_cap(args.iteration, count) {
            self.record_budget(rec, count, cap)?;
        }
        Ok(())
    }

    /// The most Gaussians the density step at `iteration` may end with, for a model of
    /// `count`: the cap and the exact budget's target there, whichever is lower.
    pub fn step_cap(&self, iteration: u32, count: usize) -> Option<usize> {
        let exact = self
            .config
            .exact_budget
            .map(|b| b.target_at(iteration, count));
        match (self.config.max_gaussians, exact) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The Gaussian budget after `decide` (see [`budget`]): submits what `rec` holds, reads
    /// the decisions back (and the scores, when the step would end above `cap`) and records
    /// the pass that drops the additions below the cut. Leaves `rec` begun.
    fn record_budget(
        &mut self,
        rec: &mut Recorder,
        count: usize,
        cap: usize,
    ) -> anyhow::Result<()> {
        rec.submit_and_wait()?;
        rec.begin()?;
        let decisions = self.decisions.read_range(0, count)?;
        if budget::after_count(&decisions) <= cap {
            return Ok(());
        }
        let scores = self.scores.read_range(0, count)?;
        let Some(cut) = budget::budget_cut(&decisions, &scores, cap) else {
            return Ok(());
        };
        rec.dispatch_named(
            &self.budget,
            &[("decisions", &self.decisions), ("scores", &self.scores)],
            &BudgetPush {
                count: count as u32,
                cut_score: cut.score,
                cut_index: cut.index,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
        self.last_budget = Some(cut);
        Ok(())
    }

    /// Records decisions that remove exactly the Gaussians of `state` whose centre lies
    /// outside the box `[lo, hi]` (infinite bounds leave an axis open), in place of
    /// [`DensityControl::record_decide`]; follow it with [`DensityControl::apply`], which
    /// also zeroes the statistics (a model's world culls run outside the densification
    /// window, where they are unused).
    pub fn record_prune_outside(
        &mut self,
        rec: &mut Recorder,
        state: &SplatState,
        lo: [f32; 3],
        hi: [f32; 3],
    ) -> anyhow::Result<()> {
        // No budget on a cull (it only removes).
        let count = self.begin_removal(state)?;
        if count == 0 {
            return Ok(());
        }
        let push = BoxPush {
            count: count as u32,
            lo,
            hi,
        };
        rec.barrier();
        rec.dispatch_named(
            &self.prune_box,
            &[
                ("positions", &state.params.positions),
                ("decisions", &self.decisions),
            ],
            &push,
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
        Ok(())
    }

    /// Records decisions that remove exactly `remove` (rows of `state`, each below its count)
    /// and keep every other row, in place of [`DensityControl::record_decide`]; follow it with
    /// [`DensityControl::apply`]. The decisions are uploaded at once (a one-off submission):
    /// for steps that wait for the device anyway (MCMC's refinement, whose plan is the host's).
    pub fn record_remove_rows(&mut self, state: &SplatState, remove: &[u32]) -> anyhow::Result<()> {
        let count = self.begin_removal(state)?;
        let mut words = vec![0u32; count];
        for &r in remove {
            ensure!(
                (r as usize) < count,
                "density control: row {r} to remove, of {count} Gaussians"
            );
            words[r as usize] = DECIDE_REMOVE;
        }
        self.decisions.upload(&words)?;
        Ok(())
    }

    /// What a step that only removes sets up before writing its decisions: scratch for the
    /// state, the count `apply` will check, and no budget cut. Returns the count.
    fn begin_removal(&mut self, state: &SplatState) -> anyhow::Result<usize> {
        let count = state.count();
        ensure!(
            count <= self.stats.capacity(),
            "density control: {count} Gaussians but statistics for {}",
            self.stats.capacity()
        );
        self.ensure_scratch(state.capacity().max(count))?;
        self.decided = Some(count);
        self.last_budget = None;
        Ok(count)
    }

    /// Applies the recorded decisions: submits everything recorded in `rec` so far, reads the
    /// new count, moves every per-Gaussian buffer into the new layout in place (after growing
    /// the state's buffers when the count outgrows its capacity), zeroes the statistics, and
    /// leaves `rec` begun and empty. Waits for the GPU twice, and once more per buffer on a
    /// step that grows the state.
    pub fn apply(
        &mut self,
        rec: &mut Recorder,
        state: &mut SplatState,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        let t = Thresholds::new(&self.config, args)?;
        let count = state.count();
        match self.decided.take() {
            Some(c) if c == count => {}
            Some(c) => bail!("density control: decisions were recorded for {c} Gaussians, the state holds {count}"),
            None => bail!("density control: apply without record_decide"),
        }
        if count == 0 {
            self.record_reset_stats(rec);
            rec.submit_and_wait()?;
            rec.begin()?;
            return Ok(DensifyOutcome {
                before: 0,
                after: 0,
                kept: 0,
                clones: 0,
                split_children: 0,
                grew: false,
                capacity: state.capacity(),
                skipped: false,
                budget_dropped: 0,
            });
        }

        // Phase 1: slots, scan, and the three numbers the host needs.
        rec.barrier();
        rec.dispatch_named(
            &self.expand,
            &[
                ("decisions", &self.decisions),
                ("slots", &self.slots),
                ("counts", &self.counts),
            ],
            &CountPush {
                count: count as u32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        self.scan.record(rec, &self.slots, &self.counts, 0, Some(1));
        rec.copy_region(&self.slots, count, &self.counts, 2, 1);
        rec.copy_region(&self.slots, 2 * count, &self.counts, 3, 1);
        rec.submit_and_wait()?;
        let c = self.counts.read_range(1, 3)?;
        let (after, kept, kept_and_clones) = (c[0] as usize, c[1] as usize, c[2] as usize);
        ensure!(
            kept <= kept_and_clones && kept_and_clones <= after && after <= 3 * count,
            "density control: inconsistent counts from the GPU ({kept}, {kept_and_clones}, {after})"
        );

        // The state's own buffers are the destination (grown geometrically first when the
        // new count does not fit), each group moved through a scratch buffer and copied back
        // (`record_move_in_place`): two groups' width of scratch rather than a second state,
        // which held about 40 % of a large model's training memory.
        let grew = after > state.capacity();
        let capacity = if grew {
            grown_capacity(after)
        } else {
            state.capacity()
        };
        let split = SplitPush {
            count: count as u32,
            seed: rng::fold_seed(self.config.seed),
            step: args.iteration,
            log_split_shrink: t.log_split_shrink,
        };
        if grew {
            // Nothing pending uses the old statistics (phase 1 has completed).
            self.stats = DensityStats::zeroed(&self.ctx, capacity)?;
            // Bigger buffers first, rows in their old order, one buffer at a time: running out
            // of memory there leaves the Gaussians as they were for the checkpoint (moving
            // each set straight into its bigger buffer would lower the peak as much but could
            // fail with some sets in the new layout and some in the old).
            state.grow(&self.ctx, rec, capacity)?;
        }
        self.ensure_move_scratch(move_in_place::move_scratch_floats(state))?;
        rec.begin()?;
        self.record_move_in_place(rec, state, count, after, &split);
        self.record_reset_stats(rec);
        rec.submit_and_wait()?;
        rec.begin()?;
        state.set_count(after);
        self.release_move_scratch()?;
        Ok(DensifyOutcome {
            before: count,
            after,
            kept,
            clones: kept_and_clones - kept,
            split_children: after - kept_and_clones,
            grew,
            capacity,
            skipped: false,
            budget_dropped: self.last_budget.map_or(0, |c| c.dropped),
        })
    }

    /// `record_decide` then `apply`: one densify-and-prune step.
    pub fn step(
        &mut self,
        rec: &mut Recorder,
        state: &mut SplatState,
        args: &DensifyArgs,
        threshold_scale: Option<&GpuBuffer<f32>>,
    ) -> anyhow::Result<DensifyOutcome> {
        self.record_decide(rec, state, args, threshold_scale, None)?;
        self.apply(rec, state, args)
    }

    /// Records the opacity reset of `state`: opacity = min(opacity, `opacity_reset_value`) and
    /// the opacity group's moments zeroed (first `count` Gaussians).
    pub fn record_opacity_reset(
        &self,
        rec: &mut Recorder,
        state: &SplatState,
    ) -> anyhow::Result<()> {
        self.record_opacity_reset_filtered(rec, state, None)
    }

    /// [`DensityControl::record_opacity_reset`] on the opacity the renderer uses when
    /// Mip-Splatting's 3D filter `filter3d` is given (σ(x)·ρ, see `reset_opacity.comp`).
    pub fn record_opacity_reset_filtered(
        &self,
        rec: &mut Recorder,
        state: &SplatState,
        filter3d: Option<&GpuBuffer<f32>>,
    ) -> anyhow::Result<()> {
        if let Some(f) = filter3d {
            ensure!(
                f.len() >= state.count(),
                "opacity reset: {} 3D filter values for {} Gaussians",
                f.len(),
                state.count()
            );
        }
        let max_logit = reset_logit(&self.config)?;
        let count = state.count();
        if count == 0 {
            return Ok(());
        }
        rec.barrier();
        rec.dispatch_named(
            &self.reset,
            &[
                ("opacity_logits", &state.params.opacity_logits),
                ("m", &state.m.opacity_logits),
                ("v", &state.v.opacity_logits),
                ("log_scales", &state.params.log_scales),
                ("filter3d", filter3d.unwrap_or(&self.dummy)),
            ],
            &ResetPush {
                count: count as u32,
                max_logit,
                filtered: filter3d.is_some() as u32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        rec.barrier();
        Ok(())
    }
}
