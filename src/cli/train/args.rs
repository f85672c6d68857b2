//! `train`'s command line: the flags, their checks, and the training configuration they make.

use super::strategy_args::{StrategyArgs, StrategyName};
use crate::cli::image_cache_args::ImageCacheArgs;
use crate::cli::lpips_scores::LpipsArgs;
use crate::cli::SceneArgs;
use clap::Args;
use lpmsplat::lpm::config::{LpmConfig, PruneMode};
use lpmsplat::lpm::pairing::RegionKeypoints;
use lpmsplat::lpm::region_units::RegionUnit;
use lpmsplat::lpm::{ConeRadius, NeighbourChoice, ZoneGeometry};
use lpmsplat::models::{BaseModel, ModelOptions};
use lpmsplat::scene::Scene;
use lpmsplat::train::density::growth::Budget;
use lpmsplat::train::loss::LossLayout;
use lpmsplat::train::passes::spacetime_settings::ChildTime;
use lpmsplat::train::passes::world_culls::N3dvCulls;
use lpmsplat::train::schedule::DensitySchedule;
use lpmsplat::train::trainer::{Background, TrainConfig};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct TrainArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub images: ImageCacheArgs,
    /// Output folder (created; existing files in it are replaced atomically).
    #[arg(long, short = 'o')]
    pub out: PathBuf,
    /// Optimizer steps (the schedule's defaults are the reference's 30k calendar; shorter runs
    /// keep it, so pass --densify-until and the like to compress it).
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u32,
    /// Base model: 3dgs, pixel-gs (Pixel-GS's pixel-weighted densification statistic),
    /// mip-splatting (3D smoothing and 2D Mip filters; the PLY has the 3D filter fused in,
    /// evaluate it with `eval --model mip-splatting`), 2dgs (surfels with the normal and
    /// distortion regularisers; see --lambda-normal, --lambda-dist, --depth-ratio),
    /// spacetime-lite (SpacetimeGaussians on a video scene: motion, rotation and opacity in
    /// time, RGB colour) or spacetime-full (the same with 9 feature channels and the per-pixel
    /// decoder, whose weights go to OUT/point_cloud.decoder.json). Combines with --lpm.
    #[arg(long, default_value = "3dgs", value_parser = BaseModel::parse)]
    pub model: BaseModel,
    /// Seed of everything random: random initial points, the view order, split samples, LPM's
    /// neighbour picks.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Highest SH degree (0–3).
    #[arg(long, default_value_t = 3)]
    pub sh_degree: u32,
    /// Background: black, white, random, or r,g,b. Default: white for NeRF-synthetic, else black.
    #[arg(long)]
    pub background: Option<String>,
    /// Start from this PLY instead of the SfM points / random points.
    #[arg(long)]
    pub init_ply: Option<PathBuf>,
    /// Initial points for scenes without SfM points, or with --init random (the reference uses
    /// 100k random ones).
    #[arg(long, default_value_t = 100_000)]
    pub init_points: usize,
    /// Where the initial points of a scene without SfM points come from: `triangulate` (feature
    /// matches between neighbour views triangulated with the known poses, a video scene's at
    /// 10 frames over the segment with each point centred at its frame's time, topped up with
    /// random points to --init-points, as SpacetimeGaussians starts from triangulated points),
    /// `random` (--init-points in a box in front of the cameras, as the NeRF-synthetic
    /// reference does; named, it replaces a scene's SfM points too, as MCMC's random start) or
    /// `auto` (triangulate video scenes, random points for still ones).
    #[arg(long, value_enum, default_value_t = InitSource::Auto)]
    pub init: InitSource,
    /// Opacity every Gaussian of a start from points begins with (3DGS: 0.1; MCMC as gsplat
    /// ships it: 0.5, with --init-scale 0.1).
    #[arg(long, value_name = "O")]
    pub init_opacity: Option<f32>,
    /// Factor on the initial scales, which are set from each point's 3 nearest neighbours
    /// (3DGS: 1; MCMC as gsplat ships it: 0.1).
    #[arg(long, value_name = "F")]
    pub init_scale: Option<f32>,
    /// Evaluate on the test views every N iterations (0 = only at the end).
    #[arg(long, default_value_t = 0)]
    pub eval_every: u32,
    /// LPIPS in the evaluations (see `eval --lpips-weights`).
    #[command(flatten)]
    pub lpips: LpipsArgs,
    /// Collect per-stage GPU timestamps and report their shares.
    #[arg(long)]
    pub timestamps: bool,
    /// Pixels per invocation of the tile rasterizers, forward and backward (default: 1 on GPUs;
    /// on CPU drivers 8, and 16 for the 2DGS backward). A tuning knob for comparing layouts with
    /// --timestamps: 1, 2, 4 or 8 (2DGS also 16) where the device's subgroups allow it (the
    /// refusal names this device's choices).
    #[arg(long, value_name = "N")]
    pub raster_pixels: Option<u32>,
    /// The loss kernels' layout: segments (the default: row and column segments in registers,
    /// which suits CPU drivers) or tiles (16×16 blocks in shared memory, one pixel an
    /// invocation, built for GPUs and not yet timed on one). A tuning knob for --timestamps.
    #[arg(long, value_name = "LAYOUT", value_parser = LossLayout::parse)]
    pub loss_layout: Option<LossLayout>,
    /// Record each iteration's command buffer while the previous iteration runs on the GPU
    /// (on, the default), wherever the previous one leaves the host nothing to do; off records
    /// every iteration between two (the GPU waits for the host's recording). The results are
    /// the same; a knob for timing the two side by side.
    #[arg(long, value_enum, default_value_t = RecordAhead::On)]
    pub record_ahead: RecordAhead,
    /// Write OUT/checkpoint.bin every N iterations (0 = only at the end and on Ctrl-C).
    #[arg(long, default_value_t = 0)]
    pub checkpoint_every: u32,
    /// Continue the run saved in this checkpoint (same scene and flags; --iterations may grow).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Stop at the first NaN or inf in the parameters, naming the iteration, the parameter
    /// group and the Gaussian; checks every N iterations (N = 1 when given without a value).
    #[arg(long, num_args = 0..=1, default_missing_value = "1")]
    pub nan_check: Option<u32>,
    // Learning rates and density control (reference defaults).
    /// Position learning rate at the start, times the scene extent (reference).
    #[arg(long, default_value_t = 1.6e-4)]
    pub lr_position: f64,
    /// Position learning rate at --lr-position-max-steps (log-linear decay), times the extent.
    #[arg(long, default_value_t = 1.6e-6)]
    pub lr_position_final: f64,
    /// The iteration the position learning rate's decay reaches its final value.
    #[arg(long, default_value_t = 30_000)]
    pub lr_position_max_steps: u32,
    /// Learning rate of the colours' DC coefficients.
    #[arg(long, default_value_t = 2.5e-3)]
    pub lr_sh_dc: f64,
    /// Learning rate of the higher SH coefficients (the reference: DC's / 20).
    #[arg(long, default_value_t = 2.5e-3 / 20.0)]
    pub lr_sh_rest: f64,
    /// Learning rate of the opacity logits.
    #[arg(long, default_value_t = 0.05)]
    pub lr_opacity: f64,
    /// Learning rate of the log-scales.
    #[arg(long, default_value_t = 5e-3)]
    pub lr_scaling: f64,
    /// Learning rate of the rotation quaternions.
    #[arg(long, default_value_t = 1e-3)]
    pub lr_rotation: f64,
    /// Weight of D-SSIM in the loss, (1 − w)·L1 + w·(1 − SSIM).
    #[arg(long, default_value_t = 0.2)]
    pub ssim_weight: f32,
    /// ADC clones or splits a Gaussian whose mean view-space gradient norm (NDC units) reaches
    /// this (LPM lowers it inside its zones by --lpm-threshold-ratio).
    #[arg(long, default_value_t = 2e-4)]
    pub densify_grad_threshold: f32,
    /// Densification starts after this iteration.
    #[arg(long, default_value_t = 500)]
    pub densify_from: u32,
    /// Densification stops here (default the model's official value: 15000, 9000 for the
    /// spacetime models).
    #[arg(long)]
    pub densify_until: Option<u32>,
    /// Density control runs every N iterations inside the densification window.
    #[arg(long, default_value_t = 100)]
    pub densify_interval: u32,
    /// ADC's global opacity reset every N iterations while densifying.
    #[arg(long, default_value_t = 3000)]
    pub opacity_reset_interval: u32,
    /// Clone (below) or split (above) at this fraction of the scene extent, the largest scale.
    #[arg(long, default_value_t = 0.01)]
    pub percent_dense: f64,
    /// Prune Gaussians below this opacity. Default: 0.005, or 0.05 for 2dgs (official).
    #[arg(long)]
    pub min_opacity: Option<f64>,
    /// 2dgs: weight of the normal-consistency regulariser (official 0.05), active after
    /// --normal-from (7000).
    #[arg(long)]
    pub lambda_normal: Option<f32>,
    /// 2dgs: the iteration the normal-consistency regulariser starts (official 7000).
    #[arg(long)]
    pub normal_from: Option<u32>,
    /// 2dgs: weight of the depth-distortion regulariser (official code 0; its DTU script
    /// 1000), active after --dist-from (3000).
    #[arg(long)]
    pub lambda_dist: Option<f32>,
    /// 2dgs: the iteration the depth-distortion regulariser starts (official 3000).
    #[arg(long)]
    pub dist_from: Option<u32>,
    /// 2dgs: the surface depth the normal regulariser differentiates: 0 the expected depth
    /// (official default), 1 the median depth (official DTU and TnT scripts).
    #[arg(long)]
    pub depth_ratio: Option<f32>,
    /// Prune Gaussians whose screen radius exceeds this many pixels (off by default, as the
    /// reference's test never fires).
    #[arg(long)]
    pub screen_size_limit: Option<f32>,
    /// Also densify by Gaussian Opacity Fields' absolute-gradient test, as Mip-Splatting's
    /// official code does: a Gaussian whose averaged Σ|per-pixel mean gradient| reaches the
    /// quantile that selects as many Gaussians as the usual test is densified too (off: the
    /// papers' rule). 3dgs, mip-splatting and the spacetime models.
    #[arg(long)]
    pub densify_abs_grad: bool,
    /// At most N Gaussians: a density step that would end with more keeps the clones and splits
    /// whose statistic is furthest over their own threshold (LPM's lowered one inside its
    /// zones), as many as fit; LPM's and the models' point additions stop at the cap too.
    /// Default: no cap
    #[arg(long, value_name = "N", value_parser = Budget::parse_count)]
    pub max_gaussians: Option<usize>,
    /// Clone and split only Gaussians whose centre lies in the region FILE describes (JSON:
    /// two bands `{"axis": [x, y, z], "lo": a, "hi": b}` in the scene's own frame; `partition
    /// --grow-within-region` writes one per block): the others still train and are pruned,
    /// but never multiply. Held: ADC's clones and splits, with or without a budget; not held:
    /// LPM's point additions. Refused with --strategy mcmc (it grows by relocation).
    #[arg(long, value_name = "FILE")]
    pub grow_within: Option<std::path::PathBuf>,
    /// spacetime-lite, spacetime-full: the temporal centre of clones and split children: random (uniform over
    /// the segment, the official rule) or parent.
    #[arg(long, value_parser = ChildTime::parse)]
    pub child_time: Option<ChildTime>,
    /// Only the first N densify steps clone and split (without pruning); the later ones only
    /// prune (SpacetimeGaussians' official rule: 6).
    #[arg(long)]
    pub growth_rounds: Option<u32>,
    /// spacetime-lite, spacetime-full: the official guided error sampling (on) or off.
    #[arg(long, value_parser = ["on", "off"])]
    pub guided_sampling: Option<String>,
    /// spacetime-lite, spacetime-full: the iteration guided sampling starts recording the cameras' SSIM
    /// (official 1600).
    #[arg(long)]
    pub guided_from: Option<u32>,
    /// spacetime-*: the iteration of the official angular-velocity / rotation split (8001:
    /// Gaussians that move, are mid-sized and opaque keep an angular velocity and stop learning
    /// rotation; the others lose it and keep learning rotation), or `off`.
    #[arg(long)]
    pub omega_freeze: Option<String>,
    /// spacetime-*: SpacetimeGaussians' Neural 3D Video culls by world position (remove
    /// Gaussians with world z < 4.5 before training; `official` also after densification, at
    /// …500 of every 1000 iterations, and outside the initial points' bounding box 1000
    /// iterations after it ends). `auto`: as the official config of the scene (the six N3DV
    /// scenes by folder name), off elsewhere.
    #[arg(long, value_enum, default_value_t = N3dvCulls::Auto)]
    pub n3dv_culls: N3dvCulls,
    /// Views per optimizer step, their gradients averaged: the scheduled view and others of its
    /// time (another camera of the same frame in a video). Default 2 for the spacetime models (the
    /// official batch), 1 otherwise.
    #[arg(long)]
    pub batch_views: Option<u32>,
    #[command(flatten)]
    pub lpm: Box<LpmArgs>,
    #[command(flatten)]
    pub density_strategy: StrategyArgs,
}

/// Localized Point Management (docs/algorithms/lpm.md), fused into the density steps.
#[derive(Args, Debug, Clone)]
pub struct LpmArgs {
    /// Turn LPM on, on top of ADC (which runs on every density step unless --lpm-skip-adc or
    /// --lpm-rules authors skips it on steps without a zone).
    #[arg(long)]
    pub lpm: bool,
    /// Ablation: no point addition in sparse zones.
    #[arg(long)]
    pub lpm_no_add: bool,
    /// Ablation: no opacity reset of the Gaussians in front of zones.
    #[arg(long)]
    pub lpm_no_reset: bool,
    /// LPM runs every N iterations (a multiple of --densify-interval: it is fused with it).
    #[arg(long, default_value_t = 100)]
    pub lpm_interval: u32,
    /// LPM's window starts after this iteration (LPM runs at from < iteration < until).
    /// Default: the densification window's start, --densify-from.
    #[arg(long)]
    pub lpm_from: Option<u32>,
    /// LPM's window ends before this iteration. Default: the densification window's end,
    /// --densify-until (the model's: 15000, 9000 for the spacetime models): LPM only steers
    /// densification, so neither its lowered threshold nor its opacity reset runs after it.
    #[arg(long)]
    pub lpm_until: Option<u32>,
    /// Gradient-threshold multiplier inside zones.
    #[arg(long, default_value_t = 0.5)]
    pub lpm_threshold_ratio: f32,
    /// Under a budget (--budget, --max-gaussians): a zone's candidate's score, on the one
    /// scale every candidate is ranked on, is multiplied by this (1: zones do not rank).
    #[arg(long, value_name = "W", default_value_t = 1.5)]
    pub lpm_zone_weight: f32,
    /// Under a budget: rank candidates on one scale times --lpm-zone-weight (weighted), or
    /// each over its own lowered threshold (lowered: the paper's rule, where a zone's
    /// candidate at 0.6 τ outranks one outside at 1.1 τ).
    #[arg(long, default_value = "weighted", value_parser = ["weighted", "lowered"])]
    pub lpm_rank: String,
    /// Error pixels: above this quantile of the error map.
    #[arg(long, default_value_t = 0.4)]
    pub lpm_error_quantile: f32,
    /// Error regions are built from square blocks of this many pixels a side. 0 (default):
    /// follow the image size, 16 px at one megapixel (the paper's block at its resolution)
    /// scaled with the image diagonal, at least 4 px. At low resolution a 16-pixel block is a
    /// large part of the image and error rarely fills one.
    #[arg(long, default_value_t = 0)]
    pub lpm_block: u32,
    /// A block is kept when more than this fraction of its pixels are error pixels.
    #[arg(long, default_value_t = 0.85)]
    pub lpm_block_fraction: f32,
    /// Which rules LPM follows: `ours` (local triangulated zones, the paper's point addition,
    /// the authors' pruning, ADC on every density step) or `authors` (the authors' code
    /// exactly: box zones, the in-front cone and the reset set on a ball of the box's smallest
    /// half-extent, the top 70 % reset, pruning OR-ed into ADC's mask, no point addition, no
    /// ADC on steps without a zone). The flags below override single rules.
    #[arg(long, default_value = "ours", value_parser = ["ours", "authors"])]
    pub lpm_rules: String,
    /// Opacity reset: in-front Gaussians at or above this quantile of the opacities inside zones
    /// (0.3 = the top 70 %, the authors' k = int(0.7 n); default 0.3 under both rules).
    #[arg(long)]
    pub lpm_reset_quantile: Option<f64>,
    /// LPM's opacity reset runs every N iterations inside its window, also where the density
    /// step does not (the authors' reset_interval: 100; 200 suggested indoors).
    #[arg(long, default_value_t = 100)]
    pub lpm_reset_interval: u32,
    /// Density-aware pruning: authors (the k-th smallest opacity after densification OR-ed
    /// into ADC's mask), additive (exactly k more of the faintest untouched Gaussians), off.
    #[arg(long, value_parser = ["authors", "additive", "off"])]
    pub lpm_prune: Option<String>,
    /// Skip ADC on density steps where LPM finds no zone (true under `--lpm-rules authors`).
    #[arg(long)]
    pub lpm_skip_adc: Option<bool>,
    /// Largest optical-axis angle between neighbour views, degrees (90 suggested indoors).
    #[arg(long, default_value_t = 45.0)]
    pub lpm_neighbour_angle: f64,
    /// Which views within the angle become a view's neighbours: random (default; the paper and
    /// the authors' code: three at random) or overlap (those sharing the most SfM tracks with
    /// it, else the nearest camera centres).
    #[arg(long, value_parser = ["overlap", "random"])]
    pub lpm_neighbours: Option<String>,
    /// Which matched keypoints speak for an error region: box (default; the paper and the
    /// authors' code: all inside its bounding box, which also covers what lies between its
    /// blocks) or error-blocks (only those on the region's own error blocks).
    #[arg(long, value_parser = ["error-blocks", "box"])]
    pub lpm_region_keypoints: Option<String>,
    /// Zone geometry: triangulated (ours: the enclosing sphere of the triangulated matches),
    /// slab (the view's cone through the region, cut to the distances the triangulated matches
    /// span: only what is drawn over the region), local (zones local by construction: one per
    /// error block, the slab cut to the 20–80 % quantiles ± 5 % of the depths of matches seen
    /// at ≥ 2° of parallax, none holding more than 1 % of the model; --lpm-regions and
    /// --lpm-max-zone-share override the last two), sphere (the paper: the cone intersection's
    /// enclosing sphere), ray-pairs, authors-box.
    #[arg(long, value_parser = ["triangulated", "slab", "local", "sphere", "ray-pairs", "authors-box"])]
    pub lpm_zone: Option<String>,
    /// What a zone is built from: components (the paper: a connected component of error
    /// blocks, as its box), blocks (each error block alone), random-blocks (the control: as many
    /// blocks drawn at random among those holding a match, each alone). Default: blocks under
    /// --lpm-zone local, components otherwise.
    #[arg(long, value_parser = ["components", "blocks", "random-blocks"])]
    pub lpm_regions: Option<String>,
    /// Drop the zones that hold more than this share of the model's Gaussians (0.01 under
    /// --lpm-zone local; default otherwise: no limit). Counted on the GPU at each step.
    #[arg(long, value_name = "SHARE")]
    pub lpm_max_zone_share: Option<f64>,
    /// With --strategy mcmc and --lpm-zone local: the largest share of each refinement's dead
    /// Gaussians moved onto surface samples inside the zones (the SfM points the view observes
    /// there, coloured from the ground truth) instead of onto live Gaussians. Default 0: none.
    #[arg(long, value_name = "SHARE", default_value_t = 0.0)]
    pub lpm_surface_share: f64,
    /// The cone whose Gaussians count as in front of a zone (the opacity reset's candidates):
    /// region (default under ours: the view's cone through its error region, capped at the
    /// bounding sphere), bounding (the cone to the zone's bounding sphere, docs/algorithms/lpm.md step 7), or
    /// smallest-half-extent (the authors': a ball of the box's smallest half-extent).
    #[arg(long, value_parser = ["bounding", "smallest-half-extent", "region"])]
    pub lpm_cone: Option<String>,
    /// Drop zones whose radius exceeds this many scene extents (default: keep every zone). A
    /// region spanning near and far surfaces can triangulate to a zone wider than the scene,
    /// which then lowers the threshold and resets opacities over most of the model.
    #[arg(long, value_name = "EXTENTS")]
    pub lpm_max_zone_radius: Option<f64>,
    /// Zones wider than this many scene extents keep their lowered threshold and point
    /// addition, but the opacity reset ignores them (default: every zone resets). One such zone
    /// can reset a quarter of the model's opacities in one step.
    #[arg(long, value_name = "EXTENTS")]
    pub lpm_reset_max_zone_radius: Option<f64>,
    /// Dump PNGs of every LPM step (error map, kept blocks, paired regions, zones) here.
    #[arg(long)]
    pub lpm_debug: Option<PathBuf>,
}

impl LpmArgs {
    /// The LPM configuration, or `None` without `--lpm`. Its window defaults to the schedule's
    /// densification window.
    pub fn config(
        &self,
        schedule: &DensitySchedule,
        seed: u64,
    ) -> anyhow::Result<Option<LpmConfig>> {
        let densify_interval = schedule.interval;
        if !self.lpm {
            return Ok(None);
        }
        anyhow::ensure!(
            self.lpm_interval > 0
                && densify_interval > 0
                && self.lpm_interval.is_multiple_of(densify_interval),
            "--lpm-interval {} must be a positive multiple of --densify-interval {} (LPM runs \
             inside the density step)",
            self.lpm_interval,
            densify_interval
        );
        anyhow::ensure!(
            self.lpm_neighbour_angle > 0.0 && self.lpm_neighbour_angle <= 180.0,
            "--lpm-neighbour-angle {}: must be in (0, 180] degrees",
            self.lpm_neighbour_angle
        );
        let mut c = match self.lpm_rules.as_str() {
            "authors" => LpmConfig::authors(),
            _ => LpmConfig::default(),
        };
        c.interval = self.lpm_interval;
        c.from = self.lpm_from.unwrap_or(schedule.densify_from);
        c.until = self.lpm_until.unwrap_or(schedule.densify_until);
        c.threshold_ratio = self.lpm_threshold_ratio;
        c.zone_weight = self.lpm_zone_weight;
        c.add_points &= !self.lpm_no_add;
        c.reset = !self.lpm_no_reset;
        c.seed = seed;
        c.debug_dir = self.lpm_debug.clone();
        c.reset_interval = self.lpm_reset_interval;
        c.regions.quantile = self.lpm_error_quantile;
        c.regions.block = self.lpm_block;
        c.regions.keep_fraction = self.lpm_block_fraction;
        if let Some(q) = self.lpm_reset_quantile {
            c.reset_settings.quantile = q;
        }
        if let Some(p) = &self.lpm_prune {
            c.prune = PruneMode::parse(p)?;
        }
        if let Some(skip) = self.lpm_skip_adc {
            c.skip_adc_without_zone = skip;
        }
        c.matching.neighbours.max_angle_deg = self.lpm_neighbour_angle;
        c.matching.neighbours.seed = seed;
        if let Some(k) = &self.lpm_region_keypoints {
            c.region_keypoints = RegionKeypoints::parse(k)?;
        }
        if let Some(n) = &self.lpm_neighbours {
            c.matching.neighbours.choice = NeighbourChoice::parse(n)?;
        }
        if let Some(z) = &self.lpm_zone {
            c.zones.geometry = parse_zone(z)?;
            if c.zones.geometry == ZoneGeometry::Local {
                c = c.with_local_zones();
            }
        }
        if let Some(u) = &self.lpm_regions {
            c.region_unit = RegionUnit::parse(u)?;
        }
        if let Some(share) = self.lpm_max_zone_share {
            c.max_zone_share = Some(share);
        }
        c.surface_share = self.lpm_surface_share;
        if let Some(k) = &self.lpm_cone {
            c.cone = ConeRadius::parse(k)?;
        }
        c.max_zone_radius = self.lpm_max_zone_radius;
        c.reset_max_zone_radius = self.lpm_reset_max_zone_radius;
        c.validate()?;
        Ok(Some(c))
    }
}

/// A zone geometry by its command-line name.
pub fn parse_zone(name: &str) -> anyhow::Result<ZoneGeometry> {
    Ok(match name {
        "triangulated" => ZoneGeometry::Triangulated,
        "slab" => ZoneGeometry::Slab,
        "local" => ZoneGeometry::Local,
        "sphere" => ZoneGeometry::Sphere,
        "ray-pairs" => ZoneGeometry::SphereRayPairs,
        "authors-box" => ZoneGeometry::AuthorsBox,
        other => anyhow::bail!(
            "LPM zone geometry {other:?} is unknown. Fix: choose triangulated, slab, local, \
             sphere, ray-pairs or authors-box"
        ),
    })
}

impl TrainArgs {
    /// The model settings as given, for the model to take or refuse.
    pub fn model_options(&self) -> anyhow::Result<ModelOptions> {
        Ok(ModelOptions {
            lambda_normal: self.lambda_normal,
            normal_from: self.normal_from,
            lambda_dist: self.lambda_dist,
            dist_from: self.dist_from,
            depth_ratio: self.depth_ratio,
            child_time: self.child_time,
            guided_sampling: self.guided_sampling.as_deref().map(|v| v == "on"),
            guided_from: self.guided_from,
            omega_freeze: self
                .omega_freeze
                .as_deref()
                .map(ModelOptions::parse_omega_freeze)
                .transpose()?,
            densify_abs_grad: self.densify_abs_grad,
        })
    }

    pub fn config(&self, scene: &Scene) -> anyhow::Result<TrainConfig> {
        let densify_until = self
            .densify_until
            .unwrap_or(self.model.default_densify_until());
        let mut c = TrainConfig {
            iterations: self.iterations,
            seed: self.seed,
            sh_degree: self.sh_degree,
            background: Background::choose(self.background.as_deref(), scene.background)?,
            ssim_weight: self.ssim_weight,
            timestamps: self.timestamps,
            raster_pixels: self.raster_pixels,
            loss_layout: self.loss_layout,
            ..TrainConfig::default()
        };
        c.lr.position_init = self.lr_position;
        c.lr.position_final = self.lr_position_final;
        c.lr.position_max_steps = self.lr_position_max_steps;
        c.lr.sh_dc = self.lr_sh_dc;
        c.lr.sh_rest = self.lr_sh_rest;
        c.lr.opacity = self.lr_opacity;
        c.lr.scaling = self.lr_scaling;
        c.lr.rotation = self.lr_rotation;
        c.density.grad_threshold = self.densify_grad_threshold;
        c.density.percent_dense = self.percent_dense;
        c.density.min_opacity = self.min_opacity.unwrap_or(self.model.default_min_opacity());
        c.density.screen_size_limit = self.screen_size_limit;
        c.schedule.densify_from = self.densify_from;
        c.schedule.densify_until = densify_until;
        c.schedule.interval = self.densify_interval;
        c.schedule.opacity_reset_interval = self.opacity_reset_interval;
        c.schedule.growth_rounds = self.growth_rounds;
        c.schedule.white_background = c.background == Background::Fixed([1.0; 3]);
        self.model.apply_options(&self.model_options()?, &mut c)?;
        c.density.max_gaussians = self.max_gaussians;
        if let Some(path) = &self.grow_within {
            anyhow::ensure!(
                self.density_strategy.strategy != StrategyName::Mcmc,
                "--grow-within with --strategy mcmc: MCMC grows by relocating and sampling \
                 Gaussians, not by ADC's clones and splits, so the region would not hold it. \
                 Fix: drop --grow-within, or train with --strategy adc"
            );
            c.density.grow_within =
                Some(lpmsplat::train::density::region::GrowthRegion::read(path)?);
        }
        c.density.rank_lowered = self.lpm.lpm && self.lpm.lpm_rank == "lowered";
        if self.density_strategy.strategy == StrategyName::Mcmc {
            // `train`'s schedule is the official 30 000-iteration one whatever --iterations.
            lpmsplat::mcmc::config::apply_schedule(&mut c.schedule, 30_000, self.densify_until);
        }
        lpmsplat::train::passes::world_culls::apply_choice(
            self.n3dv_culls,
            &scene.root,
            self.model.name(),
            &mut c,
            1000,
        )?;
        if let Some(b) = self.batch_views {
            c.batch_views = b;
        }
        c.validate()?;
        Ok(c)
    }
}

/// Whether an iteration is recorded while the one before runs (`--record-ahead`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RecordAhead {
    On,
    Off,
}

impl RecordAhead {
    pub fn name(self) -> &'static str {
        match self {
            RecordAhead::On => "on",
            RecordAhead::Off => "off",
        }
    }
}

use lpmsplat::initial::InitSource;
use lpmsplat::splats::init::Look;

impl TrainArgs {
    /// How a start from points looks: --init-opacity and --init-scale over 3DGS's start.
    pub fn look(&self) -> Look {
        Look {
            opacity: self.init_opacity.unwrap_or(Look::STANDARD.opacity),
            scale: self.init_scale.unwrap_or(Look::STANDARD.scale),
        }
    }
}

/// Flag combinations that cannot work, caught before anything is loaded.
pub(super) fn check_flags(args: &TrainArgs) -> anyhow::Result<()> {
    if args.init_opacity.is_some() || args.init_scale.is_some() {
        anyhow::ensure!(
            args.init_ply.is_none() && args.resume.is_none(),
            "--init-opacity / --init-scale shape a start from points; {} brings its own \
             Gaussians. Fix: drop them",
            if args.resume.is_some() {
                "--resume"
            } else {
                "--init-ply"
            }
        );
        args.look().validate()?;
    }
    if let Some(r) = &args.resume {
        anyhow::ensure!(
            args.init_ply.is_none(),
            "--resume {} with --init-ply: a resumed run continues from the checkpoint's \
             Gaussians. Fix: drop --init-ply (or drop --resume to start fresh from the PLY)",
            r.display()
        );
        anyhow::ensure!(
            r.is_file(),
            "{}: --resume: no such checkpoint file. Fix: pass the checkpoint.bin a previous run \
             wrote into its output folder",
            r.display()
        );
    }
    anyhow::ensure!(
        args.nan_check != Some(0),
        "--nan-check 0: the check interval must be at least 1. Fix: pass --nan-check or \
         --nan-check N with N ≥ 1"
    );
    Ok(())
}

/// `--max-gaussians N`: a positive count.
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_zone_geometry_has_its_command_line_name() {
        for (name, g) in [
            ("triangulated", ZoneGeometry::Triangulated),
            ("slab", ZoneGeometry::Slab),
            ("local", ZoneGeometry::Local),
            ("sphere", ZoneGeometry::Sphere),
            ("ray-pairs", ZoneGeometry::SphereRayPairs),
            ("authors-box", ZoneGeometry::AuthorsBox),
        ] {
            assert_eq!(parse_zone(name).unwrap(), g);
        }
        let e = parse_zone("cone").unwrap_err().to_string();
        assert!(e.contains("\"cone\"") && e.contains("slab"), "{e}");
    }

    /// LPM steers densification, so its window is the densify window unless given: a
    /// spacetime model densifies until 9000, and an LPM window to 3DGS's 15000 would run its
    /// opacity resets for 6000 iterations after the last densification.
    #[test]
    fn the_lpm_window_follows_the_densify_window_unless_given() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            train: TrainArgs,
        }
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");
        let scene = Scene::load(std::path::Path::new(root), &Default::default()).unwrap();
        let window = |flags: &[&str]| {
            let args = Cli::parse_from(
                ["train", "scene", "--out", "o", "--lpm"]
                    .iter()
                    .chain(flags),
            );
            let c = args.train.config(&scene).unwrap();
            let lpm = args.train.lpm.config(&c.schedule, 0).unwrap().unwrap();
            (lpm.from, lpm.until)
        };
        assert_eq!(window(&[]), (500, 15_000));
        assert_eq!(
            window(&["--densify-from", "50", "--densify-until", "1500"]),
            (50, 1500)
        );
        assert_eq!(window(&["--model", "spacetime-lite"]).1, 9000);
        assert_eq!(
            window(&[
                "--densify-until",
                "1500",
                "--lpm-from",
                "700",
                "--lpm-until",
                "1200"
            ]),
            (700, 1200)
        );
        let off = Cli::parse_from(["train", "scene", "--out", "o"]);
        let c = off.train.config(&scene).unwrap();
        assert!(off.train.lpm.config(&c.schedule, 0).unwrap().is_none());
    }
}
