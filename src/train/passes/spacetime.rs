//! SpacetimeGaussians (lite) as a base model: the Gaussians carry four extra groups (cubic
//! motion, angular velocity, temporal centre and log-scale, BASE_MODELS.md §4.2); each frame
//! the temporal step (`render::spacetime`) writes the model at the view's time as still 3D
//! Gaussians, which the 3DGS passes draw and differentiate unchanged, and the still Gaussians'
//! gradients go back through the temporal step to the model's.
//!
//! New Gaussians: clones and split children get a temporal centre uniform over the segment
//! (the official rule; `glsl/spacetime/random_centres.comp`, [`ChildTime`]), LPM's added points
//! the time of the frame whose error asked for them; the rest of the official density schedule
//! (six clone/split rounds, then pruning only) is not followed: ADC's schedule runs.
//!
//! Colour: the official lite model uses its three features as RGB directly; here they are the
//! SH DC coefficients at degree 0 (colour `0.5 + C₀·f`, clamped at 0 like every 3DGS colour), the
//! same model up to an affine change of variable except that a colour cannot go negative.

use std::sync::Arc;

use anyhow::{ensure, Result};

use super::gaussians::GaussianPasses;
use super::{FrameArgs, GradArgs, ModelPasses};
use crate::gpu::{ComputePipeline, GpuBuffer, GpuContext, Recorder, TimestampPool};
use crate::reference::spacetime::PRESENT_MIN_WEIGHT;
use crate::render::forward::Capacity;
use crate::render::layout::{CameraGpu, ProjectedGpu};
use crate::render::spacetime::{At, InstantBuffers, TemporalBuffers, TemporalStep};
use crate::splats::gpu::{grown_capacity, GpuSplats};
use crate::splats::GaussianParams;
use crate::train::adam::SplatState;
use crate::train::config::{ChildTime, TrainConfig};
use crate::train::density::rng::{fold_seed, rng_uniform};
use crate::train::density::DensityControl;
use crate::train::strategy::{FramePositions, Primitive};

pub use crate::render::spacetime::{extra_groups, GROUPS};
pub use crate::train::config::SpacetimeTraining;

pub struct SpacetimePasses {
    ctx: Arc<GpuContext>,
    inner: GaussianPasses,
    step: TemporalStep,
    rates: SpacetimeTraining,
    /// The time of every view (indices into the camera buffer).
    view_times: Vec<f32>,
    /// The model at the current frame's time, and its gradients.
    instant: GpuSplats,
    instant_grads: GpuSplats,
    /// The time of the last recorded frame (new Gaussians are centred there).
    time: f32,
    /// Draws clones' and split children's temporal centres ([`ChildTime::Random`]).
    random_centres: Option<ComputePipeline>,
    seed: u32,
    rec: Recorder,
}

const WG: u32 = 256;

/// Keeps the child-time draws apart from the split's position draws of the same step.
const CHILD_TIME_SALT: u32 = 0x5354_4354;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct CentresPush {
    first: u32,
    end: u32,
    seed: u32,
    step: u32,
}

/// The temporal centre `glsl/spacetime/random_centres.comp` gives new row `row` at density step
/// `step` of a run with `seed` (the kernel's numbers, for tests).
pub fn random_child_centre(seed: u64, step: u32, row: u32) -> f32 {
    rng_uniform(fold_seed(seed) ^ CHILD_TIME_SALT, step, row, 0) as f32
}

fn temporal(s: &GpuSplats) -> Result<TemporalBuffers<'_>> {
    TemporalBuffers::of(s)
}

fn instant(s: &GpuSplats) -> InstantBuffers<'_> {
    InstantBuffers::of(s)
}

impl SpacetimePasses {
    pub fn new(
        ctx: &Arc<GpuContext>,
        config: &TrainConfig,
        cameras: &[CameraGpu],
        train_views: &[usize],
        view_times: &[f64],
        capacity: usize,
        frame: Capacity,
    ) -> Result<Self> {
        ensure!(
            view_times.len() == cameras.len() && view_times.iter().all(|t| t.is_finite()),
            "SpacetimeGaussians: {} view times for {} views (a video scene gives every view a \
             finite time)",
            view_times.len(),
            cameras.len()
        );
        let Some(rates) = config.spacetime else {
            anyhow::bail!("SpacetimeGaussians' passes need the config's temporal rates");
        };
        ensure!(
            config.sh_degree == 0,
            "SpacetimeGaussians (lite) has no view-dependent colour: SH degree 0, not {}",
            config.sh_degree
        );
        Ok(Self {
            ctx: ctx.clone(),
            inner: GaussianPasses::new(ctx, config, cameras, train_views, capacity, frame)?,
            step: TemporalStep::new(ctx)?,
            rates,
            view_times: view_times.iter().map(|&t| t as f32).collect(),
            instant: GpuSplats::zeroed(ctx, "instant ", 0, 0, capacity.max(1))?,
            instant_grads: GpuSplats::zeroed(ctx, "instant grad ", 0, 0, capacity.max(1))?,
            time: 0.0,
            random_centres: match rates.child_time {
                ChildTime::Random => Some(ComputePipeline::new(
                    ctx,
                    "spacetime/random_centres",
                    crate::shaders::SPACETIME_RANDOM_CENTRES,
                    1,
                    std::mem::size_of::<CentresPush>() as u32,
                    WG,
                    &[],
                )?),
                ChildTime::Parent => None,
            },
            seed: fold_seed(config.seed) ^ CHILD_TIME_SALT,
            rec: Recorder::new(ctx)?,
        })
    }

    fn time_of(&self, view: u32) -> Result<f32> {
        self.view_times.get(view as usize).copied().ok_or_else(|| {
            anyhow::anyhow!(
                "SpacetimeGaussians: view {view} has no time ({} views)",
                self.view_times.len()
            )
        })
    }

    /// Records the still Gaussians of `f.params` at the view's time into `instant`.
    fn record_instant(&mut self, rec: &mut Recorder, f: &FrameArgs) -> Result<()> {
        let count = f.params.count;
        ensure!(
            self.instant.capacity >= count,
            "SpacetimeGaussians: {count} Gaussians, room for {} (reserve first)",
            self.instant.capacity
        );
        self.time = self.time_of(f.view)?;
        self.instant.count = count;
        rec.barrier();
        self.step.record_forward(
            rec,
            &temporal(f.params)?,
            &instant(&self.instant),
            At {
                count,
                t: self.time,
            },
        )?;
        // Scales and colour do not change with time.
        rec.copy(&f.params.log_scales, &self.instant.log_scales, 3 * count);
        rec.copy(&f.params.sh_dc, &self.instant.sh_dc, 3 * count);
        rec.barrier();
        Ok(())
    }
}

/// `f` with the still Gaussians `instant` as its model.
fn at_instant<'a>(instant: &'a GpuSplats, f: &FrameArgs<'a>) -> FrameArgs<'a> {
    FrameArgs {
        params: instant,
        cameras: f.cameras,
        view: f.view,
        camera: f.camera,
        sh_degree: 0,
        background: f.background,
        iteration: f.iteration,
    }
}

impl ModelPasses for SpacetimePasses {
    fn primitive(&self) -> Primitive {
        Primitive::Gaussian
    }

    fn reserve(&mut self, capacity: usize) -> Result<()> {
        if self.instant.capacity < capacity {
            let cap = grown_capacity(capacity);
            self.instant = GpuSplats::zeroed(&self.ctx, "instant ", 0, 0, cap)?;
            self.instant_grads = GpuSplats::zeroed(&self.ctx, "instant grad ", 0, 0, cap)?;
        }
        self.inner.reserve(capacity)
    }

    fn record_prepare(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        config: &TrainConfig,
    ) -> Result<()> {
        self.inner.record_prepare(rec, f, config)
    }

    fn record_forward(
        &mut self,
        rec: &mut Recorder,
        f: &FrameArgs,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        self.record_instant(rec, f)?;
        let g = at_instant(&self.instant, f);
        self.inner.record_forward(rec, &g, timestamps)
    }

    fn image(&self) -> &GpuBuffer<f32> {
        self.inner.image()
    }

    fn projected(&self) -> &GpuBuffer<ProjectedGpu> {
        self.inner.projected()
    }

    fn pixel_count(&self) -> Option<&GpuBuffer<u32>> {
        self.inner.pixel_count()
    }

    fn record_backward(
        &mut self,
        ctx: &GpuContext,
        rec: &mut Recorder,
        g: &GradArgs,
        config: &TrainConfig,
        timestamps: Option<&mut TimestampPool>,
    ) -> Result<()> {
        let count = g.count;
        self.instant_grads.count = count;
        {
            let args = GradArgs {
                frame: at_instant(&self.instant, &g.frame),
                dl_dimage: g.dl_dimage,
                grads: &self.instant_grads,
                view_grad_norm: g.view_grad_norm,
                count,
            };
            self.inner
                .record_backward(ctx, rec, &args, config, timestamps)?;
        }
        rec.barrier();
        self.step.record_backward(
            rec,
            &temporal(g.frame.params)?,
            &instant(&self.instant_grads),
            &temporal(g.grads)?,
            At {
                count,
                t: self.time,
            },
            false,
        )?;
        rec.copy(
            &self.instant_grads.log_scales,
            &g.grads.log_scales,
            3 * count,
        );
        rec.copy(&self.instant_grads.sh_dc, &g.grads.sh_dc, 3 * count);
        rec.barrier();
        Ok(())
    }

    fn after_frame(&mut self) -> Result<bool> {
        self.inner.after_frame()
    }

    fn intersection_capacity(&self) -> usize {
        self.inner.intersection_capacity()
    }

    fn reserve_intersections(&mut self, n: usize) -> Result<()> {
        self.inner.reserve_intersections(n)
    }

    fn model_changed(&mut self) {
        self.inner.model_changed()
    }

    /// ADC's reset lowers the base opacity σ(o), which caps the opacity at every time.
    fn record_opacity_reset(
        &mut self,
        rec: &mut Recorder,
        density: &DensityControl,
        state: &SplatState,
        cameras: &GpuBuffer<CameraGpu>,
    ) -> Result<()> {
        self.inner
            .record_opacity_reset(rec, density, state, cameras)
    }

    fn render_view(&mut self, f: &FrameArgs) -> Result<Vec<f32>> {
        self.reserve(f.params.count)?;
        let mut rec = std::mem::replace(&mut self.rec, Recorder::new(&self.ctx)?);
        rec.begin()?;
        let recorded = self.record_instant(&mut rec, f);
        if recorded.is_ok() {
            rec.submit_and_wait()?;
        }
        self.rec = rec;
        recorded?;
        let g = at_instant(&self.instant, f);
        self.inner.render_view(&g)
    }

    fn extra_lrs(&self, _iteration: u32, extent: f64) -> Vec<f64> {
        let r = &self.rates;
        vec![r.motion * extent, r.omega, r.t_center, r.t_log_scale]
    }

    fn new_gaussian_extras(&self) -> Vec<Vec<f32>> {
        vec![vec![0.0; 9], vec![0.0; 4], vec![self.time], vec![0.0]]
    }

    fn frame_positions(&self) -> Option<&dyn FramePositions> {
        Some(self)
    }

    fn record_new_gaussians(
        &mut self,
        rec: &mut Recorder,
        state: &SplatState,
        new: std::ops::Range<usize>,
        iteration: u32,
    ) -> Result<()> {
        let Some(pipe) = &self.random_centres else {
            return Ok(());
        };
        let centres = temporal(&state.params)?.t_center;
        ensure!(
            new.end <= centres.len() && new.start <= new.end,
            "SpacetimeGaussians: new rows {new:?} outside the {} temporal centres",
            centres.len()
        );
        if new.is_empty() {
            return Ok(());
        }
        rec.barrier();
        rec.dispatch(
            pipe,
            &[centres],
            &CentresPush {
                first: new.start as u32,
                end: new.end as u32,
                seed: self.seed,
                step: iteration,
            },
            self.ctx.groups_1d(new.len() as u64, WG),
        );
        rec.barrier();
        Ok(())
    }

    fn export(
        &mut self,
        _params: &GpuSplats,
        _cameras: &GpuBuffer<CameraGpu>,
        _iteration: u32,
        model: GaussianParams,
    ) -> Result<GaussianParams> {
        Ok(model)
    }
}

/// LPM in time: zones are tested against the centres at the trained frame's time, and a
/// Gaussian whose temporal weight there is below [`PRESENT_MIN_WEIGHT`] is absent (neither
/// inside nor in front of a zone, not counted), so a zone acts on what the frame shows.
impl FramePositions for SpacetimePasses {
    fn record_frame_positions(
        &self,
        rec: &mut Recorder,
        params: &GpuSplats,
        count: usize,
        out: &GpuBuffer<f32>,
    ) -> Result<()> {
        self.step.record_positions(
            rec,
            &temporal(params)?,
            out,
            At {
                count,
                t: self.time,
            },
            PRESENT_MIN_WEIGHT,
        )
    }
}
