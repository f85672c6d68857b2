//! Localized Point Management as a density strategy (docs/algorithms/lpm.md steps 1–9): a wrapper around an
//! ADC-family strategy (plain ADC, or ADC with Pixel-GS's statistic: whatever the trainer's
//! density config names), fused into the density-control step of the iterations it runs at.
//! On other densify iterations the wrapped strategy runs alone.
//!
//! One LPM step, for the view V rendered this iteration (its image is still in the renderer):
//! 1. error map → per-block error counts on the GPU ([`LpmGpu::record_error_blocks`]; only the
//!    counts come back) → regions on the host;
//! 2. a neighbour V' of V at random, the cached correspondences of (V, V') → paired regions →
//!    zones ([`zones_for_step`]) → zone records uploaded;
//! 3. membership of the current Gaussians, a threshold scale (× `threshold_ratio` inside zones,
//!    `glsl/lpm/threshold_scale.comp`) and a score weight (× `zone_weight` inside zones: where a
//!    budget's room goes) given to ADC's own `record_decide`, so densification
//!    inside zones goes through the same clone / split code; then density-aware pruning: as many
//!    of the lowest-opacity plain survivors as the lowered threshold added
//!    (`glsl/lpm/lowered_count.comp`, an exact rank selection, `glsl/lpm/prune_lowest.comp`)
//!    get `DECIDE_REMOVE` before `apply`;
//! 4. after ADC's `apply` and its global opacity reset: membership of the new Gaussians, the LPM
//!    opacity reset of the in-front Gaussians ([`LpmGpu::record_opacity_reset`]), and one new
//!    Gaussian at the centre of every zone with fewer than `add_below` Gaussians inside (appended
//!    rows, zero Adam moments).
//!
//! A step that finds no zone is a plain ADC step. Global ADC runs in every case.
//!
//! Time: [`LpmTotals::seconds`] is the wall time of the step (host work and the GPU work it
//! waits for) minus the time of ADC's own `apply`, i.e. what LPM adds to the iteration.

use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use rand::SeedableRng;

use crate::gpu::{BufferKind, ComputePipeline, GpuBuffer, GpuContext};
use crate::lpm::config::{LpmConfig, PruneMode};
use crate::lpm::gpu::{block_grid, ErrorImages, FilteredOpacity, LpmGpu};
use crate::lpm::pairing::RegionKeypoints;
use crate::lpm::record::local_zones_for_step;
use crate::lpm::record::ZONE_NO_RESET;
use crate::lpm::region_units::step_regions;
use crate::lpm::report::{LpmStepReport, LpmTotals};
use crate::lpm::surface::zone_samples;
use crate::lpm::view_points::ViewPoints;
use crate::lpm::{regions, zones_for_step, Correspondences, ZoneGeometry, ZoneRecord};
use crate::scene::image_source::{ImageSource, TrainImages};
use crate::scene::{Image, Scene, View};
use crate::shaders;
use crate::splats::gpu::grown_capacity;
use crate::train::density::{DensifyArgs, DensifyOutcome, ScoreInput};
use crate::train::strategy::{
    Adc, DensityContext, DensityStrategy, Guide, IterationView, StrategyEvent,
};

const WG: u32 = 256;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ScalePush {
    count: u32,
    ratio: f32,
    weight: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ModePush {
    count: u32,
    mode: u32,
}

/// The step in progress between [`LpmStrategy::densify`] and [`LpmStrategy::finish`].
struct Pending {
    report: LpmStepReport,
    records: Vec<ZoneRecord>,
    start: Instant,
    /// Time spent in ADC's own apply (not LPM's).
    adc_seconds: f64,
}

/// LPM around a wrapped strategy.
pub struct LpmStrategy {
    pub config: LpmConfig,
    /// Runs the density iterations LPM does not run at.
    inner: Box<dyn DensityStrategy>,
    ctx: Arc<GpuContext>,
    gpu: LpmGpu,
    corr: Correspondences,
    /// The SfM points each view observes (the local zones' depths).
    view_points: ViewPoints,
    views: Vec<View>,
    /// The training images (read at LPM steps, for zone colours and debug images) and the
    /// image number of each scene view (training views only).
    images: Arc<dyn ImageSource>,
    image_of_view: Vec<Option<usize>>,
    threshold_scale: ComputePipeline,
    lowered_count: ComputePipeline,
    prune_lowest: ComputePipeline,
    block_counts: GpuBuffer<u32>,
    zones: GpuBuffer<ZoneRecord>,
    zone_inside: GpuBuffer<u32>,
    flags: GpuBuffer<u32>,
    scale: GpuBuffer<f32>,
    /// Each Gaussian's score weight for a budget's ranking (`zone_weight` inside zones).
    weight: GpuBuffer<f32>,
    candidates: GpuBuffer<u32>,
    /// The centres at the frame's time, for a model whose Gaussians move (LPM in time).
    frame_positions: GpuBuffer<f32>,
    counters: GpuBuffer<u32>,
    pending: Option<Pending>,
    pub totals: LpmTotals,
    /// Every step's report, in order (the per-step telemetry of `metrics.json`).
    pub steps: Vec<LpmStepReport>,
}

impl LpmStrategy {
    /// Image `k` of `train_images` is that of `scene.train[k]` (as given to the trainer);
    /// `corr` comes from [`crate::lpm::load_or_build`] with `config.matching`.
    pub fn new(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        corr: Correspondences,
        config: LpmConfig,
    ) -> anyhow::Result<Self> {
        config.validate()?;
        let images = train_images.into().source;
        anyhow::ensure!(
            images.count() == scene.train.len(),
            "LPM: {} images for {} training views",
            images.count(),
            scene.train.len()
        );
        let mut image_of_view = vec![None; scene.views.len()];
        let (mut max_px, mut max_blocks) = (1u32, 1u32);
        for (k, &v) in scene.train.iter().enumerate() {
            let (w, h) = images.size(k);
            max_px = max_px.max(w * h);
            let (bx, by) = block_grid(w, h, config.regions.resolved(w, h).block);
            max_blocks = max_blocks.max(bx * by);
            image_of_view[v] = Some(k);
        }
        let pipe = |name: &str, spv: &[u8], buffers: u32, push: usize| {
            ComputePipeline::new(ctx, name, spv, buffers, push as u32, WG, &[])
        };
        use std::mem::size_of;
        let per = |name: &str| GpuBuffer::<u32>::new(ctx, name, 1024, BufferKind::DeviceLocal);
        Ok(Self {
            ctx: ctx.clone(),
            inner: Box::new(Adc),
            gpu: LpmGpu::new(ctx, max_px)?,
            corr,
            view_points: ViewPoints::new(scene),
            views: scene.views.clone(),
            images,
            image_of_view,
            threshold_scale: pipe(
                "lpm/threshold_scale",
                shaders::LPM_THRESHOLD_SCALE,
                3,
                size_of::<ScalePush>(),
            )?,
            lowered_count: pipe(
                "lpm/lowered_count",
                shaders::LPM_LOWERED_COUNT,
                3,
                size_of::<ModePush>(),
            )?,
            prune_lowest: pipe(
                "lpm/prune_lowest",
                shaders::LPM_PRUNE_LOWEST,
                5,
                size_of::<ModePush>(),
            )?,
            block_counts: GpuBuffer::new(
                ctx,
                "lpm block counts",
                max_blocks as usize,
                BufferKind::DeviceLocal,
            )?,
            zones: GpuBuffer::new(ctx, "lpm zones", 16, BufferKind::DeviceLocal)?,
            zone_inside: per("lpm zone inside")?,
            flags: per("lpm flags")?,
            scale: GpuBuffer::new(ctx, "lpm threshold scale", 1024, BufferKind::DeviceLocal)?,
            weight: GpuBuffer::new(ctx, "lpm score weight", 1024, BufferKind::DeviceLocal)?,
            candidates: per("lpm prune candidates")?,
            frame_positions: GpuBuffer::new(
                ctx,
                "lpm frame positions",
                3 * 1024,
                BufferKind::DeviceLocal,
            )?,
            counters: GpuBuffer::new(ctx, "lpm counters", 4, BufferKind::DeviceLocal)?,
            pending: None,
            totals: LpmTotals::default(),
            steps: Vec::new(),
            config,
        })
    }

    /// Per-Gaussian scratch for `n` Gaussians (nothing recorded may use the old buffers).
    fn ensure_gaussians(&mut self, n: usize) -> anyhow::Result<()> {
        if self.flags.len() >= n {
            return Ok(());
        }
        let cap = grown_capacity(n);
        let ctx = &self.ctx;
        self.flags = GpuBuffer::new(ctx, "lpm flags", cap, BufferKind::DeviceLocal)?;
        self.scale = GpuBuffer::new(ctx, "lpm threshold scale", cap, BufferKind::DeviceLocal)?;
        self.weight = GpuBuffer::new(ctx, "lpm score weight", cap, BufferKind::DeviceLocal)?;
        self.candidates =
            GpuBuffer::new(ctx, "lpm prune candidates", cap, BufferKind::DeviceLocal)?;
        self.frame_positions =
            GpuBuffer::new(ctx, "lpm frame positions", 3 * cap, BufferKind::DeviceLocal)?;
        Ok(())
    }

    fn ensure_zones(&mut self, n: usize) -> anyhow::Result<()> {
        if self.zones.len() < n {
            let cap = n.next_power_of_two();
            self.zones = GpuBuffer::new(&self.ctx, "lpm zones", cap, BufferKind::DeviceLocal)?;
        }
        if self.zone_inside.len() < n {
            self.zone_inside = GpuBuffer::new(
                &self.ctx,
                "lpm zone inside",
                n.next_power_of_two(),
                BufferKind::DeviceLocal,
            )?;
        }
        Ok(())
    }

    /// Steps 1–2 for the view rendered this iteration: error blocks → regions → a neighbour →
    /// zones, and the debug dump. `t.rec` must be begun; it is left begun and empty. The report
    /// holds the counts and radii; the records are the finite zones.
    fn find_zones(
        &mut self,
        t: &mut DensityContext,
        view: usize,
        bg: [f32; 3],
        iteration: u32,
        extent: f64,
    ) -> anyhow::Result<(LpmStepReport, Vec<ZoneRecord>, Vec<Vec<NewGaussian>>)> {
        let mut report = LpmStepReport {
            iteration,
            view,
            ..Default::default()
        };
        // 1. Error blocks of this iteration's render.
        let (w, h) = (t.width, t.height);
        let settings = self.config.regions.resolved(w, h);
        report.block = settings.block;
        let (bx, by) = self.gpu.record_error_blocks(
            t.rec,
            &ErrorImages {
                render: t.render,
                gt: t.truth,
                gt_offset: t.truth_offset_px,
                width: w,
                height: h,
                background: bg,
            },
            &settings,
            &self.block_counts,
        )?;
        t.rec.submit_and_wait()?;
        t.rec.begin()?;
        let counts = self.block_counts.read_range(0, (bx * by) as usize)?;
        let mask = regions::BlockMask::from_error_counts(
            w,
            h,
            settings.block,
            &counts,
            settings.keep_fraction,
        )?;
        // 2. Neighbour, regions, pairing, zones.
        // Drawn from (seed, iteration) rather than a running stream, so a run resumed from a
        // checkpoint makes the same picks without saving generator state.
        let step_seed = self.config.seed
            ^ 0x4c50_4d5f_7374_6570
            ^ (iteration as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(step_seed);
        let reference = self.corr.neighbours.pick(view, &mut rng);
        report.reference = reference;
        // Local zones take their depths from the SfM points the view observes, when it has
        // tracks; otherwise (and for every other geometry) from the matches with V'.
        let sfm = self.view_points.of(view);
        let from_sfm = self.config.zones.geometry == ZoneGeometry::Local && !sfm.0.is_empty();
        let matched_in_view = match from_sfm {
            true => sfm.0,
            false => reference
                .and_then(|r| self.corr.oriented(view, r))
                .map_or(&[][..], |(xy_v, _)| xy_v),
        };
        let (regions, owners) =
            step_regions(self.config.region_unit, &mask, matched_in_view, step_seed);
        let owners =
            (self.config.region_keypoints == RegionKeypoints::ErrorBlocks).then_some(&owners);
        report.regions = regions.len();
        let mut samples: Vec<Vec<NewGaussian>> = Vec::new();
        let step = match reference {
            _ if from_sfm && !regions.is_empty() => {
                let gt = self
                    .ground_truth(view)?
                    .context("LPM: the current view has no ground truth")?;
                let step = local_zones_for_step(
                    &self.views[view],
                    &regions,
                    owners,
                    sfm.0,
                    sfm.1,
                    &gt,
                    bg,
                    &self.config.zones,
                );
                if self.config.surface_share > 0.0 {
                    samples = step
                        .zones
                        .iter()
                        .zip(&step.pairs)
                        .map(|(z, p)| {
                            zone_samples(
                                &self.views[view],
                                z,
                                &p.in_view,
                                &p.matched,
                                sfm.0,
                                sfm.1,
                                &gt,
                                bg,
                                self.config.add_opacity,
                            )
                        })
                        .collect();
                }
                step
            }
            Some(r) if !regions.is_empty() => {
                let (xy_v, xy_r) = self.corr.oriented(view, r).unwrap_or((&[], &[]));
                let gt = self
                    .ground_truth(view)?
                    .context("LPM: the current view has no ground truth")?;
                zones_for_step(
                    &self.views[view],
                    &self.views[r],
                    &regions,
                    owners,
                    xy_v,
                    xy_r,
                    &gt,
                    bg,
                    &self.config.zones,
                    self.config.cone,
                )
            }
            _ => Default::default(),
        };
        report.paired = step.pairing.paired;
        // Each record with its samples (none unless asked for), filtered together.
        samples.resize_with(step.records.len(), Vec::new);
        let finite: Vec<(ZoneRecord, Vec<NewGaussian>)> = step
            .records
            .into_iter()
            .zip(samples)
            .filter(|(z, _)| z.radius.is_finite() && z.center.iter().all(|c| c.is_finite()))
            .collect();
        let found = finite.len();
        let widest = self.config.max_zone_radius.map(|r| r * extent);
        let (mut records, samples): (Vec<ZoneRecord>, Vec<Vec<NewGaussian>>) = finite
            .into_iter()
            .filter(|(z, _)| widest.is_none_or(|w| z.radius as f64 <= w))
            .unzip();
        report.wide = found - records.len();
        if let Some(w) = self.config.reset_max_zone_radius.map(|r| r * extent) {
            // Kept for the lowered threshold and point addition; the reset ignores them.
            for z in records.iter_mut().filter(|z| z.radius as f64 > w) {
                z.shape |= ZONE_NO_RESET;
                report.no_reset += 1;
            }
        }
        report.set_zone_sizes(records.iter().map(|z| z.radius), extent);
        if let Some(dir) = self.config.debug_dir.clone() {
            let gt_view = self.ground_truth(view)?;
            let gt_reference = match reference {
                Some(r) => self.ground_truth(r)?,
                None => None,
            };
            super::debug_dump::dump_step(
                &dir,
                iteration,
                &self.gpu,
                &mask,
                &self.views,
                (gt_view.as_ref(), gt_reference.as_ref()),
                view,
                reference,
                &step.zones,
                &regions,
                owners,
                self.corr.oriented(view, reference.unwrap_or(view)),
            )?;
        }
        Ok((report, records, samples))
    }

    /// The training image of scene view `view` (`None` for a view not trained on).
    fn ground_truth(&self, view: usize) -> anyhow::Result<Option<Image>> {
        match self.image_of_view.get(view).copied().flatten() {
            Some(k) => Ok(Some(self.images.load(k)?)),
            None => Ok(None),
        }
    }

    /// For a model whose Gaussians move: records the current Gaussians' centres at the frame's
    /// time (NaN for those absent from it) and returns them for the membership; `None`: the
    /// stored positions are where they are. The per-Gaussian scratch must be sized.
    fn record_positions(&self, t: &mut DensityContext) -> anyhow::Result<Option<&GpuBuffer<f32>>> {
        let Some(moving) = t.moving else {
            return Ok(None);
        };
        moving.record_frame_positions(
            t.rec,
            &t.state.params,
            t.state.count(),
            &self.frame_positions,
        )?;
        t.rec.barrier();
        Ok(Some(&self.frame_positions))
    }

    /// Records the LPM opacity reset of the current Gaussians from the flags of the last
    /// membership pass.
    /// Under Mip-Splatting's 3D filter the reset ranks and caps the drawn opacities (the filter
    /// is recomputed first: the density step may have moved every Gaussian).
    fn record_reset(&self, t: &mut DensityContext) -> anyhow::Result<()> {
        let count = t.state.count();
        let filter3d = match &t.opacity_filter {
            Some(f) => Some(f.record_fresh(t.rec, &t.state.params.positions, count)?),
            None => None,
        };
        let filtered = filter3d.map(|filter3d| FilteredOpacity {
            filter3d,
            log_scales: &t.state.params.log_scales,
            effective: &self.scale,
        });
        self.gpu.record_opacity_reset(
            t.rec,
            &self.flags,
            &t.state.params.opacity_logits,
            count as u32,
            &self.config.reset_settings,
            filtered.as_ref(),
        )
    }

    /// Gaussian centres inside the first `zones` zones of a completed membership of `count`
    /// Gaussians: their sum and the largest share of the model one zone holds, into `report`.
    fn note_inside(
        &self,
        report: &mut LpmStepReport,
        zones: usize,
        count: usize,
    ) -> anyhow::Result<()> {
        let inside = self.zone_inside.read_range(0, zones)?;
        report.inside = inside.iter().map(|&n| n as u64).sum();
        let most = inside.iter().copied().max().unwrap_or(0);
        report.inside_max_share = most as f64 / count.max(1) as f64;
        Ok(())
    }

    /// Uploads `records` and records their membership. With `max_zone_share`, the zones that
    /// hold more than that share of the model are dropped first (one readback of the per-zone
    /// counts, once a step) and the membership of the rest recorded again. Returns the zones
    /// kept; `report` gets their count and sizes.
    /// `samples` (one list a record) are kept with their records.
    fn record_kept_membership(
        &mut self,
        t: &mut DensityContext,
        records: Vec<ZoneRecord>,
        samples: &mut Vec<Vec<NewGaussian>>,
        report: &mut LpmStepReport,
        extent: f64,
    ) -> anyhow::Result<Vec<ZoneRecord>> {
        self.record_zone_membership(t, &records)?;
        let Some(share) = self.config.max_zone_share else {
            return Ok(records);
        };
        t.rec.submit_and_wait()?;
        t.rec.begin()?;
        let count = t.state.count();
        let inside = self.zone_inside.read_range(0, records.len())?;
        let most = share * count as f64;
        let keep: Vec<bool> = inside.iter().map(|&n| n as f64 <= most).collect();
        let kept: Vec<ZoneRecord> = records
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(z, _)| *z)
            .collect();
        if samples.len() == records.len() {
            let mut k = keep.iter();
            samples.retain(|_| *k.next().unwrap_or(&false));
        }
        report.too_full = records.len() - kept.len();
        report.set_zone_sizes(kept.iter().map(|z| z.radius), extent);
        if report.too_full > 0 && !kept.is_empty() {
            self.record_zone_membership(t, &kept)?;
        }
        Ok(kept)
    }

    /// Uploads `records` and records the membership of the first `count` Gaussians.
    fn record_zone_membership(
        &mut self,
        t: &mut DensityContext,
        records: &[ZoneRecord],
    ) -> anyhow::Result<()> {
        let count = t.state.count();
        self.ensure_gaussians(t.state.capacity().max(count))?;
        self.ensure_zones(records.len())?;
        self.zones.upload(records)?;
        let positions = self.record_positions(t)?;
        self.gpu.record_membership(
            t.rec,
            positions.unwrap_or(&t.state.params.positions),
            count as u32,
            &self.zones,
            records.len() as u32,
            &self.flags,
            &self.zone_inside,
        )
    }

    /// Steps 1–3 and ADC's densify-and-prune (with the lowered threshold inside zones and the
    /// density-aware pruning). `t.rec` must be begun; on return it is begun and empty, as after
    /// [`crate::train::density::DensityControl::step`]. `bg` is the background this iteration's render
    /// of `view` used. With `skip_adc_without_zone` and no zone, nothing changes and the
    /// outcome says `skipped`.
    fn densify_with_zones(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        let start = Instant::now();
        let (mut report, records, mut samples) =
            self.find_zones(t, at.view, at.background, args.iteration, args.extent)?;
        // Membership of the current Gaussians (the zones too full for a local zone dropped).
        let records = match records.is_empty() {
            true => records,
            false => {
                self.record_kept_membership(t, records, &mut samples, &mut report, args.extent)?
            }
        };
        if records.is_empty() {
            let a0 = Instant::now();
            let outcome = if self.config.skip_adc_without_zone {
                report.skipped_adc = true;
                DensifyOutcome::unchanged(t.state.count(), t.state.capacity())
            } else {
                self.inner.densify(t, at, args)?
            };
            self.pending = Some(Pending {
                report,
                records,
                start,
                adc_seconds: a0.elapsed().as_secs_f64(),
            });
            return Ok(outcome);
        }

        // 3. Membership, lowered threshold inside zones, density-aware pruning; or, for a
        // strategy that takes a guide (MCMC), the zone weights alone, and its own step.
        let count = t.state.count();
        if self.inner.takes_guide() {
            t.rec.dispatch_named(
                &self.threshold_scale,
                &[
                    ("flags", &self.flags),
                    ("scale", &self.scale),
                    ("weight_out", &self.weight),
                ],
                &ScalePush {
                    count: count as u32,
                    ratio: 1.0,
                    weight: self.config.zone_weight,
                },
                self.ctx.groups_1d(count as u64, WG),
            );
            t.rec.barrier();
            let a0 = Instant::now();
            let samples: Vec<NewGaussian> = samples.into_iter().flatten().collect();
            report.surface_samples = samples.len();
            let guide = Guide {
                weight: &self.weight,
                samples: &samples,
                sample_share: self.config.surface_share,
            };
            let outcome = self.inner.densify_guided(t, at, args, &guide)?;
            self.note_inside(&mut report, records.len(), count)?;
            self.pending = Some(Pending {
                report,
                records,
                start,
                adc_seconds: a0.elapsed().as_secs_f64(),
            });
            return Ok(outcome);
        }
        t.rec.dispatch_named(
            &self.threshold_scale,
            &[
                ("flags", &self.flags),
                ("scale", &self.scale),
                ("weight_out", &self.weight),
            ],
            &ScalePush {
                count: count as u32,
                ratio: self.config.threshold_ratio,
                weight: self.config.zone_weight,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        t.density.record_decide(
            t.rec,
            t.state,
            args,
            Some(&self.scale),
            Some(ScoreInput::Weight(&self.weight)),
        )?;
        t.rec.fill(&self.counters, 0);
        t.rec.barrier();
        let authors = self.config.prune == PruneMode::Authors;
        t.rec.dispatch_named(
            &self.lowered_count,
            &[
                ("decisions", t.density.decisions()),
                ("candidates", &self.candidates),
                ("counters", &self.counters),
            ],
            &ModePush {
                count: count as u32,
                mode: authors as u32,
            },
            self.ctx.groups_1d(count as u64, WG),
        );
        t.rec.submit_and_wait()?;
        t.rec.begin()?;
        let c = self.counters.read_range(0, 2)?;
        self.note_inside(&mut report, records.len(), count)?;
        report.lowered = c[0];
        let k = c[0].min(c[1]);
        let prunes = self.config.prune != PruneMode::Off && k > 0;
        if prunes {
            // Additive: rank k − 1 among the untouched survivors, exactly k of them removed.
            // Authors: rank k − 1 of the model after densification (weights 1 or 2), every
            // Gaussian at or below it removed.
            self.gpu.record_rank_selection(
                t.rec,
                &t.state.params.opacity_logits,
                &self.candidates,
                3,
                authors,
                count as u32,
                c[1],
                k - 1,
            )?;
            t.rec.dispatch_named(
                &self.prune_lowest,
                &[
                    ("candidates", &self.candidates),
                    ("logits", &t.state.params.opacity_logits),
                    ("state", self.gpu.rank_selection_state()),
                    ("decisions", t.density.decisions()),
                    ("counters", &self.counters),
                ],
                &ModePush {
                    count: count as u32,
                    mode: authors as u32,
                },
                self.ctx.groups_1d(count as u64, WG),
            );
            t.rec.barrier();
        }
        let a0 = Instant::now();
        let outcome = t.density.apply(t.rec, t.state, args)?;
        let adc_seconds = a0.elapsed().as_secs_f64();
        if prunes {
            // prune_lowest counts the Gaussians it took from ADC's survivors in counters[3].
            report.pruned = self.counters.read_range(3, 1)?[0];
        }
        self.pending = Some(Pending {
            report,
            records,
            start,
            adc_seconds,
        });
        Ok(outcome)
    }

    /// Step 4, after ADC's apply and its global opacity reset (recorded in `t.rec`, which this
    /// submits): membership of the new Gaussians, the LPM opacity reset (when `reset_interval`
    /// falls on this iteration), added points. Leaves `t.rec` begun and empty.
    fn finish(&mut self, t: &mut DensityContext) -> anyhow::Result<LpmStepReport> {
        let mut p = self.pending.take().context("LPM: finish without densify")?;
        let nz = p.records.len() as u32;
        let count = t.state.count();
        let resets = nz > 0 && self.config.resets_at(p.report.iteration);
        if nz > 0 && (resets || self.config.add_points) {
            self.ensure_gaussians(t.state.capacity().max(count))?;
            let positions = self.record_positions(t)?;
            self.gpu.record_membership(
                t.rec,
                positions.unwrap_or(&t.state.params.positions),
                count as u32,
                &self.zones,
                nz,
                &self.flags,
                &self.zone_inside,
            )?;
            if resets {
                self.record_reset(t)?;
            }
        }
        t.rec.submit_and_wait()?;
        t.rec.begin()?;
        if resets {
            p.report.reset = self.gpu.read_opacity_reset_stats()?.reset;
        }
        if nz > 0 && self.config.add_points {
            let inside = self.zone_inside.read_range(0, nz as usize)?;
            let rows: Vec<NewGaussian> = p
                .records
                .iter()
                .zip(&inside)
                .filter(|(z, &n)| n < self.config.add_below && z.radius > 0.0)
                .map(|(z, _)| NewGaussian {
                    position: z.center,
                    scale: z.radius / 3.0,
                    color: z.color,
                    opacity: self.config.add_opacity,
                    camera_center: z.camera_center,
                })
                .collect();
            // Under a Gaussian budget only the rows that fit are added.
            p.report.added = append_gaussians(t, &rows)? as u32;
        }
        p.report.seconds = (p.start.elapsed().as_secs_f64() - p.adc_seconds).max(0.0);
        self.totals.add(&p.report);
        self.steps.push(p.report.clone());
        Ok(p.report)
    }

    /// The opacity reset alone, on a reset iteration where LPM's density part does not run
    /// (`reset_interval` not a multiple of the density interval, or past the densification
    /// window): zones of this iteration's render, membership, reset. Runs after the
    /// iteration's optimizer step, so the reset logits are not moved by it until the next
    /// iteration (the authors reset just before their optimizer step; one Adam step on a logit
    /// is at most the opacity learning rate). `t.rec` must not be begun; it is left idle.
    fn reset_only(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
    ) -> anyhow::Result<LpmStepReport> {
        let start = Instant::now();
        t.rec.begin()?;
        let extent = t.extent;
        let (mut report, records, mut samples) =
            self.find_zones(t, at.view, at.background, at.iteration, extent)?;
        report.reset_only = true;
        let records = match records.is_empty() {
            true => records,
            false => self.record_kept_membership(t, records, &mut samples, &mut report, extent)?,
        };
        if !records.is_empty() {
            self.record_reset(t)?;
            t.rec.submit_and_wait()?;
            self.note_inside(&mut report, records.len(), t.state.count())?;
            report.reset = self.gpu.read_opacity_reset_stats()?.reset;
        } else {
            t.rec.submit_and_wait()?;
        }
        report.seconds = start.elapsed().as_secs_f64();
        self.totals.add(&report);
        self.steps.push(report.clone());
        Ok(report)
    }
}

impl LpmStrategy {
    /// Wraps `inner` instead of plain ADC (it runs the density iterations LPM does not run at,
    /// and the zone-less ones unless `skip_adc_without_zone`).
    pub fn wrapping(mut self, inner: Box<dyn DensityStrategy>) -> Self {
        self.inner = inner;
        self
    }

    /// The strategy LPM guides.
    pub fn inner(&self) -> &dyn DensityStrategy {
        self.inner.as_ref()
    }
}

impl DensityStrategy for LpmStrategy {
    fn name(&self) -> &'static str {
        "lpm"
    }

    fn densify(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        args: &DensifyArgs,
    ) -> anyhow::Result<DensifyOutcome> {
        if self.config.runs_at(at.iteration) {
            self.densify_with_zones(t, at, args)
        } else {
            self.inner.densify(t, at, args)
        }
    }

    fn after_density(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        if self.pending.is_none() {
            return self.inner.after_density(t, at);
        }
        Ok(Some(Arc::new(self.finish(t)?)))
    }

    fn after_iteration(
        &mut self,
        t: &mut DensityContext,
        at: &IterationView,
        reported: bool,
    ) -> anyhow::Result<Option<Arc<dyn StrategyEvent>>> {
        // LPM's reset on its own interval, where its density part did not run.
        if !reported && self.config.resets_at(at.iteration) {
            return Ok(Some(Arc::new(self.reset_only(t, at)?)));
        }
        self.inner.after_iteration(t, at, reported)
    }

    /// LPM's own work outside densify steps is its reset on its own interval.
    fn quiet_after(&self, iteration: u32) -> bool {
        !self.config.resets_at(iteration) && self.inner.quiet_after(iteration)
    }

    fn record_gradient_terms(
        &self,
        rec: &mut crate::gpu::Recorder,
        state: &crate::train::adam::SplatState,
        grads: &crate::splats::gpu::GpuSplats,
        iteration: u32,
    ) -> anyhow::Result<()> {
        self.inner
            .record_gradient_terms(rec, state, grads, iteration)
    }

    fn record_after_optimizer(
        &self,
        rec: &mut crate::gpu::Recorder,
        state: &crate::train::adam::SplatState,
        iteration: u32,
        position_lr: f64,
        extent: f64,
    ) -> anyhow::Result<()> {
        self.inner
            .record_after_optimizer(rec, state, iteration, position_lr, extent)
    }

    fn settings_json(&self) -> serde_json::Value {
        let mut s = serde_json::json!({ "lpm": self.config.checkpoint_json() });
        // A wrapped strategy with settings of its own is part of the run's settings too.
        let inner = self.inner.settings_json();
        if !inner.is_null() {
            s["lpm"]["wraps"] = inner;
        }
        s
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any {
        self
    }
}

pub use crate::train::density::append::{append_gaussians, new_point_shape, NewGaussian};
