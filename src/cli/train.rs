//! `train`: fits Gaussians to a scene's training views on the GPU and writes the output folder:
//! `point_cloud.ply` (Inria layout), `renders/test/*.png`, `metrics.json`, `config.json`.

use super::lpips_scores::{self, LpipsArgs};
use super::render::parse_rgb;
use super::train_plot::{write_training_plot, EvalPoint, Sample};
use super::world_culls_arg::N3dvCulls;
use super::SceneArgs;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use lpmsplat::error::write_atomic;
use lpmsplat::gpu::{GpuContext, GpuOptions, StageTimes};
use lpmsplat::lpm::pairing::RegionKeypoints;
use lpmsplat::lpm::strategy::{LpmConfig, LpmStrategy, PruneMode};
use lpmsplat::lpm::{self, ConeRadius, NeighbourChoice, ZoneGeometry};
use lpmsplat::models::BaseModel;
use lpmsplat::scene::image_source::{TrainImages, ViewImages};
use lpmsplat::scene::{images, Image, Scene};
use lpmsplat::splats::{self, read_ply, write_ply, write_splat, GaussianParams};
use lpmsplat::train::config::ChildTime;
use lpmsplat::train::loss::LossLayout;
use lpmsplat::train::nan_check::NonFiniteCheck;
use lpmsplat::train::passes::surfels::SurfelTraining;
use lpmsplat::train::trainer::{Background, TrainConfig, Trainer, ViewMetrics};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args, Debug)]
pub struct TrainArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    #[command(flatten)]
    pub images: super::image_cache_args::ImageCacheArgs,
    /// Output folder (created; existing files in it are replaced atomically).
    #[arg(long, short = 'o')]
    pub out: PathBuf,
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u32,
    /// Base model: 3dgs, pixel-gs (Pixel-GS's pixel-weighted densification statistic),
    /// mip-splatting (3D smoothing and 2D Mip filters; the PLY has the 3D filter fused in,
    /// evaluate it with `eval --model mip-splatting`), 2dgs (surfels with the normal and
    /// distortion regularisers; see --lambda-normal, --lambda-dist, --depth-ratio),
    /// spacetime-lite (SpacetimeGaussians on a video scene: motion, rotation and opacity in
    /// time, RGB colour) or spacetime-full (the same with 9 feature channels and the per-pixel
    /// decoder, whose weights go to OUT/decoder.json). Combines with --lpm.
    #[arg(long, default_value = "3dgs", value_parser = BaseModel::parse)]
    pub model: BaseModel,
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
    /// Initial points for scenes without SfM points (the reference uses 100k random ones).
    #[arg(long, default_value_t = 100_000)]
    pub init_points: usize,
    /// Where the initial points of a scene without SfM points come from: `triangulate` (feature
    /// matches between neighbour views triangulated with the known poses, a video scene's at
    /// 10 frames over the segment with each point centred at its frame's time, topped up with
    /// random points to --init-points, as SpacetimeGaussians starts from triangulated points),
    /// `random` (a box in front of the cameras, as the NeRF-synthetic reference does) or `auto`
    /// (triangulate video scenes, random points for still ones).
    #[arg(long, value_enum, default_value_t = InitSource::Auto)]
    pub init: InitSource,
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
    #[arg(long, default_value_t = 1.6e-4)]
    pub lr_position: f64,
    #[arg(long, default_value_t = 1.6e-6)]
    pub lr_position_final: f64,
    #[arg(long, default_value_t = 30_000)]
    pub lr_position_max_steps: u32,
    #[arg(long, default_value_t = 2.5e-3)]
    pub lr_sh_dc: f64,
    #[arg(long, default_value_t = 2.5e-3 / 20.0)]
    pub lr_sh_rest: f64,
    #[arg(long, default_value_t = 0.05)]
    pub lr_opacity: f64,
    #[arg(long, default_value_t = 5e-3)]
    pub lr_scaling: f64,
    #[arg(long, default_value_t = 1e-3)]
    pub lr_rotation: f64,
    #[arg(long, default_value_t = 0.2)]
    pub ssim_weight: f32,
    #[arg(long, default_value_t = 2e-4)]
    pub densify_grad_threshold: f32,
    #[arg(long, default_value_t = 500)]
    pub densify_from: u32,
    /// Densification stops here (default the model's official value: 15000, 9000 for the
    /// spacetime models).
    #[arg(long)]
    pub densify_until: Option<u32>,
    #[arg(long, default_value_t = 100)]
    pub densify_interval: u32,
    #[arg(long, default_value_t = 3000)]
    pub opacity_reset_interval: u32,
    #[arg(long, default_value_t = 0.01)]
    pub percent_dense: f64,
    /// Prune Gaussians below this opacity. Default: 0.005, or 0.05 for 2dgs (official).
    #[arg(long)]
    pub min_opacity: Option<f64>,
    /// 2dgs: weight of the normal-consistency regulariser (official 0.05), active after
    /// --normal-from (7000).
    #[arg(long)]
    pub lambda_normal: Option<f32>,
    #[arg(long)]
    pub normal_from: Option<u32>,
    /// 2dgs: weight of the depth-distortion regulariser (official code 0; its DTU script
    /// 1000), active after --dist-from (3000).
    #[arg(long)]
    pub lambda_dist: Option<f32>,
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
    #[arg(long, value_name = "N", value_parser = parse_max_gaussians)]
    pub max_gaussians: Option<usize>,
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
}

/// Localized Point Management (LPM.md), fused into the density steps.
#[derive(Args, Debug, Clone)]
pub struct LpmArgs {
    /// Turn LPM on (ADC always runs).
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
    /// LPM window: from < iteration < until.
    #[arg(long, default_value_t = 500)]
    pub lpm_from: u32,
    #[arg(long, default_value_t = 15_000)]
    pub lpm_until: u32,
    /// Gradient-threshold multiplier inside zones.
    #[arg(long, default_value_t = 0.5)]
    pub lpm_threshold_ratio: f32,
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
    /// span: only what is drawn over the region), sphere (the paper: the cone intersection's
    /// enclosing sphere), ray-pairs, authors-box.
    #[arg(long, value_parser = ["triangulated", "slab", "sphere", "ray-pairs", "authors-box"])]
    pub lpm_zone: Option<String>,
    /// The cone whose Gaussians count as in front of a zone (the opacity reset's candidates):
    /// region (default under ours: the view's cone through its error region, capped at the
    /// bounding sphere), bounding (the cone to the zone's bounding sphere, LPM.md step 7), or
    /// smallest-half-extent (the authors': a ball of the box's smallest half-extent).
    #[arg(long, value_parser = ["bounding", "smallest-half-extent", "region"])]
    pub lpm_cone: Option<String>,
    /// Drop zones whose radius exceeds this many scene extents (default: keep every zone). A
    /// region spanning near and far surfaces can triangulate to a zone wider than the scene,
    /// which then lowers the threshold and resets opacities over most of the model.
    #[arg(long, value_name = "EXTENTS")]
    pub lpm_max_zone_radius: Option<f64>,
    /// Dump PNGs of every LPM step (error map, kept blocks, paired regions, zones) here.
    #[arg(long)]
    pub lpm_debug: Option<PathBuf>,
}

impl LpmArgs {
    /// The LPM configuration, or `None` without `--lpm`.
    pub fn config(&self, densify_interval: u32, seed: u64) -> anyhow::Result<Option<LpmConfig>> {
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
        c.from = self.lpm_from;
        c.until = self.lpm_until;
        c.threshold_ratio = self.lpm_threshold_ratio;
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
        }
        if let Some(k) = &self.lpm_cone {
            c.cone = ConeRadius::parse(k)?;
        }
        c.max_zone_radius = self.lpm_max_zone_radius;
        c.validate()?;
        Ok(Some(c))
    }
}

/// A zone geometry by its command-line name.
pub fn parse_zone(name: &str) -> anyhow::Result<ZoneGeometry> {
    Ok(match name {
        "triangulated" => ZoneGeometry::Triangulated,
        "slab" => ZoneGeometry::Slab,
        "sphere" => ZoneGeometry::Sphere,
        "ray-pairs" => ZoneGeometry::SphereRayPairs,
        "authors-box" => ZoneGeometry::AuthorsBox,
        other => anyhow::bail!(
            "LPM zone geometry {other:?} is unknown. Fix: choose triangulated, slab, sphere, \
             ray-pairs or authors-box"
        ),
    })
}

/// Builds the LPM state for a trainer: correspondences from the cache in `cache_dir` (built and
/// written there when missing or stale).
pub fn build_lpm(
    ctx: &std::sync::Arc<GpuContext>,
    scene: &Scene,
    train_images: &TrainImages,
    config: LpmConfig,
    cache_dir: &Path,
) -> anyhow::Result<LpmStrategy> {
    let loader = |i: usize| -> anyhow::Result<Image> {
        match scene.train.iter().position(|&v| v == i) {
            Some(k) => train_images.source.load(k),
            None => Ok(images::load_images(scene, &[i])?.remove(0)),
        }
    };
    let cache = cache_dir.join(lpm::CACHE_FILE_NAME);
    let (corr, summary) = lpm::load_or_build(scene, &config.matching, &cache, &loader, None)?;
    eprintln!("LPM correspondences: {summary}");
    LpmStrategy::new(ctx, scene, train_images.clone(), corr, config)
}

pub fn background_from(arg: Option<&str>, scene: &Scene) -> anyhow::Result<Background> {
    Ok(match arg {
        None => Background::Fixed(scene.background.unwrap_or([0.0; 3])),
        Some("black") => Background::Fixed([0.0; 3]),
        Some("white") => Background::Fixed([1.0; 3]),
        Some("random") => Background::Random,
        Some(s) => Background::Fixed(
            parse_rgb(s)
                .map_err(|e| anyhow::anyhow!("--background {e}; or use black, white or random"))?,
        ),
    })
}

impl TrainArgs {
    pub fn config(&self, scene: &Scene) -> anyhow::Result<TrainConfig> {
        let densify_until = self
            .densify_until
            .unwrap_or(self.model.default_densify_until());
        anyhow::ensure!(
            self.sh_degree <= 3,
            "--sh-degree {}: the engine supports 0..=3. Fix: pass 0, 1, 2 or 3",
            self.sh_degree
        );
        anyhow::ensure!(
            self.iterations > 0,
            "--iterations 0: nothing to train. Fix: pass at least 1"
        );
        anyhow::ensure!(
            self.densify_from <= densify_until,
            "--densify-from {} is after --densify-until {}. Fix: make from ≤ until",
            self.densify_from,
            densify_until
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.ssim_weight),
            "--ssim-weight {} must lie in [0, 1]",
            self.ssim_weight
        );
        let mut c = TrainConfig {
            iterations: self.iterations,
            seed: self.seed,
            sh_degree: self.sh_degree,
            background: background_from(self.background.as_deref(), scene)?,
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
        if self.model == BaseModel::Surfels2d {
            let mut t = SurfelTraining::default();
            t.normal_weight = self.lambda_normal.unwrap_or(t.normal_weight);
            t.normal_from = self.normal_from.unwrap_or(t.normal_from);
            t.distortion_weight = self.lambda_dist.unwrap_or(t.distortion_weight);
            t.distortion_from = self.dist_from.unwrap_or(t.distortion_from);
            t.depth_ratio = self.depth_ratio.unwrap_or(t.depth_ratio);
            anyhow::ensure!(
                t.normal_weight >= 0.0 && t.distortion_weight >= 0.0,
                "--lambda-normal {} and --lambda-dist {} must be ≥ 0",
                t.normal_weight,
                t.distortion_weight
            );
            anyhow::ensure!(
                (0.0..=1.0).contains(&t.depth_ratio),
                "--depth-ratio {} must lie in [0, 1] (0: expected depth, 1: median depth)",
                t.depth_ratio
            );
            c.surfels = Some(t);
        } else {
            for (flag, given) in [
                ("--lambda-normal", self.lambda_normal.is_some()),
                ("--normal-from", self.normal_from.is_some()),
                ("--lambda-dist", self.lambda_dist.is_some()),
                ("--dist-from", self.dist_from.is_some()),
                ("--depth-ratio", self.depth_ratio.is_some()),
            ] {
                anyhow::ensure!(
                    !given,
                    "{flag} applies to --model 2dgs only (this run trains {}). Fix: drop the \
                     flag or pass --model 2dgs",
                    self.model.name()
                );
            }
        }
        self.model.configure(&mut c);
        match (c.spacetime.as_mut(), self.child_time) {
            (Some(st), Some(ct)) => st.child_time = ct,
            (None, Some(_)) => anyhow::bail!(
                "--child-time applies to --model spacetime-lite or spacetime-full only (this run trains {}). Fix: \
                 drop the flag",
                self.model.name()
            ),
            _ => {}
        }
        if self.guided_sampling.is_some() || self.guided_from.is_some() {
            let Some(st) = c.spacetime.as_mut() else {
                anyhow::bail!(
                    "--guided-sampling and --guided-from apply to --model spacetime-full or spacetime-lite only \
                     (this run trains {}). Fix: drop the flag",
                    self.model.name()
                );
            };
            if self.guided_sampling.as_deref() == Some("off") {
                anyhow::ensure!(
                    self.guided_from.is_none(),
                    "--guided-from with --guided-sampling off: nothing would sample. Fix: drop \
                     one of them"
                );
                st.guided = None;
            } else if let (Some(g), Some(from)) = (st.guided.as_mut(), self.guided_from) {
                g.from = from;
            }
        }
        c.density.max_gaussians = self.max_gaussians;
        if self.densify_abs_grad {
            anyhow::ensure!(
                matches!(
                    c.density.statistic,
                    lpmsplat::train::density::Statistic::Gradient
                ) && c.surfels.is_none(),
                "--densify-abs-grad applies to the models densified by the mean gradient: 3dgs, \
                 mip-splatting, spacetime-lite, spacetime-full (this run trains {}, whose \
                 statistic it would not combine with). Fix: drop the flag",
                self.model.name()
            );
            c.density.abs_grad = true;
        }
        if let Some(v) = &self.omega_freeze {
            let Some(st) = c.spacetime.as_mut() else {
                anyhow::bail!(
                    "--omega-freeze applies to the spacetime models only (this run trains {}). \
                     Fix: drop the flag",
                    self.model.name()
                );
            };
            st.omega_freeze = match v.as_str() {
                "off" => None,
                n => {
                    let from: u32 = n.parse().map_err(|_| {
                        anyhow::anyhow!(
                            "--omega-freeze {n:?} is not an iteration. Fix: give one (official 8001) or off"
                        )
                    })?;
                    Some(lpmsplat::train::config::OmegaFreeze {
                        from,
                        ..st.omega_freeze.unwrap_or_default()
                    })
                }
            };
        }
        super::world_culls_arg::apply(self.n3dv_culls, &scene.root, self.model, &mut c, 1000)?;
        if let Some(b) = self.batch_views {
            anyhow::ensure!(
                (1..=16).contains(&b),
                "--batch-views {b}: choose 1 to 16 views per step"
            );
            c.batch_views = b;
        }
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

/// Where a scene without SfM points gets its initial points (`--init`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum InitSource {
    /// Triangulate video scenes, random points for still ones.
    Auto,
    Random,
    Triangulate,
}

impl InitSource {
    /// Whether `scene`'s initial points are triangulated (when it has no SfM points).
    pub fn triangulates(self, scene: &Scene) -> bool {
        match self {
            InitSource::Triangulate => true,
            InitSource::Random => false,
            InitSource::Auto => scene.view_times.is_some(),
        }
    }
}

/// Fewer triangulated points than this fall back to random points (with a message).
const MIN_TRIANGULATED: usize = 100;

/// Initial Gaussians of `model`: a PLY, the SfM points, points triangulated from the views
/// (`--init`), or random points in the cameras' bounds; then the model's own groups. A video
/// model's triangulated points are centred in time at their frame's time.
pub fn initial_model(
    model: BaseModel,
    scene: &Scene,
    init_ply: Option<&Path>,
    source: InitSource,
    init_points: usize,
    seed: u64,
    sh_degree: u32,
) -> anyhow::Result<GaussianParams> {
    let ignored = |by: &str| {
        // Only when asked for by name: `auto` falls back silently.
        if source == InitSource::Triangulate {
            eprintln!("--init triangulate: not used, the initial points come from {by}");
        }
    };
    if let Some(p) = init_ply {
        ignored(&format!("--init-ply {}", p.display()));
        return Ok(model.initialise(read_ply(p)?, seed));
    }
    if let Some(points) = scene.points.as_ref().filter(|p| !p.is_empty()) {
        ignored("the scene's SfM points");
        return Ok(model.initialise(splats::init::from_sfm(points, sh_degree)?, seed));
    }
    if source.triangulates(scene) {
        let t0 = std::time::Instant::now();
        let tri = lpmsplat::triangulated_init::triangulate_scene(scene, init_points, seed)?;
        eprintln!(
            "initial points: {} triangulated from {} matches in {} view pairs ({:.1} s)",
            tri.positions.len(),
            tri.matches,
            tri.pairs,
            t0.elapsed().as_secs_f64()
        );
        if tri.positions.len() >= MIN_TRIANGULATED {
            let params = lpmsplat::triangulated_init::topped_up_model(
                &tri,
                scene,
                init_points,
                seed,
                sh_degree,
            )?;
            let params = model.initialise_at_times(params, seed, &tri.times);
            return Ok(params);
        }
        eprintln!(
            "initial points: fewer than {MIN_TRIANGULATED} triangulated; {init_points} random \
             points instead"
        );
    }
    let (center, half) = scene.random_init_box();
    let params = splats::init::random_init(init_points, center, [half; 3], seed, sh_degree)?;
    Ok(model.initialise(params, seed))
}

/// Creates `out` and proves it writable before any work is done.
pub fn prepare_output(out: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| {
        format!(
            "{}: cannot create the output folder. Fix: choose a writable --out",
            out.display()
        )
    })?;
    let probe = out.join(".lpmsplat-write-test");
    std::fs::write(&probe, b"ok").with_context(|| {
        format!(
            "{}: the output folder is not writable. Fix: choose a writable --out",
            out.display()
        )
    })?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

fn stage_shares(t: &StageTimes) -> serde_json::Value {
    let total = t.total_ms().max(1e-12);
    serde_json::Value::Array(
        t.stages
            .iter()
            .map(|(n, ms)| serde_json::json!({"stage": n, "ms_total": ms, "share": ms / total}))
            .collect(),
    )
}

/// Flag combinations that cannot work, caught before anything is loaded.
fn check_flags(args: &TrainArgs) -> anyhow::Result<()> {
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

/// How to continue this run: its own command line with `--resume CHECKPOINT` (for messages).
fn resume_hint(checkpoint: &Path) -> String {
    resume_hint_without(checkpoint, "--resume")
}

/// [`resume_hint`] without the valued flag `flag` as well.
fn resume_hint_without(checkpoint: &Path, flag: &str) -> String {
    let mut words = Vec::new();
    let mut args = std::env::args();
    while let Some(a) = args.next() {
        if a == "--resume" || a == flag {
            args.next();
        } else if !a.starts_with("--resume=") && !a.starts_with(&format!("{flag}=")) {
            words.push(a);
        }
    }
    words.push("--resume".into());
    words.push(checkpoint.display().to_string());
    words.join(" ")
}

/// The error of a run that ran out of device memory, after saving what can be resumed: the
/// checkpoint (the trainer's state, untouched by the allocation that failed) and, when it can
/// still be exported, the PLY.
fn save_after_oom(
    trainer: &mut Trainer,
    scene: &Scene,
    args: &TrainArgs,
    oom: &lpmsplat::gpu::OutOfDeviceMemory,
) -> anyhow::Error {
    let checkpoint = args.out.join("checkpoint.bin");
    let (it, n) = (trainer.iteration, trainer.state.count());
    if let Err(e) = trainer.save_checkpoint(scene, &checkpoint) {
        return anyhow::anyhow!(
            "after iteration {it} ({n} Gaussians): {oom}; saving a checkpoint failed as well: \
             {e:#}. Fix: train with fewer Gaussians (a higher --densify-grad-threshold or an \
             earlier --densify-until) or on a device with more memory"
        );
    }
    let ply = args.out.join("point_cloud.ply");
    let ply_note = match trainer.export_model().and_then(|m| write_ply(&ply, &m)) {
        Ok(()) => format!(" and {}", ply.display()),
        Err(e) => format!(" (the PLY could not be exported: {e:#})"),
    };
    anyhow::anyhow!(
        "after iteration {it} ({n} Gaussians): {oom}. Wrote {}{ply_note}: the model at \
         iteration {it}. Fix: continue on a device with more memory (or with a higher \
         --memory-limit MIB): {}; or train again with fewer Gaussians (a higher \
         --densify-grad-threshold or an earlier --densify-until)",
        checkpoint.display(),
        resume_hint_without(&checkpoint, "--memory-limit")
    )
}

pub fn run(gpu: &GpuOptions, args: &TrainArgs) -> anyhow::Result<()> {
    check_flags(args)?;
    let scene = Scene::load(&args.scene.scene, &args.scene.load_options()?)?;
    let config = args.config(&scene)?;
    let lpm_config = args.lpm.config(args.densify_interval, args.seed)?;
    let lpips = args.lpips.load()?;
    prepare_output(&args.out)?;
    let checkpoint_path = args.out.join("checkpoint.bin");
    let t_load = Instant::now();
    let train_images = args.images.train_images(&scene)?;
    let test_images = ViewImages::new(&scene, &scene.test)?;
    let resumed = match &args.resume {
        Some(p) => Some(lpmsplat::train::checkpoint::Checkpoint::read(p)?),
        None => None,
    };
    if let (Some(ck), Some(p)) = (&resumed, &args.resume) {
        anyhow::ensure!(
            ck.iteration < config.iterations,
            "{}: iteration: the checkpoint is already at iteration {}, and --iterations is {}. \
             Fix: pass --iterations above {} to train further",
            p.display(),
            ck.iteration,
            config.iterations,
            ck.iteration
        );
    }
    let init = match &resumed {
        Some(ck) => ck.params(),
        None => initial_model(
            args.model,
            &scene,
            args.init_ply.as_deref(),
            args.init,
            args.init_points,
            args.seed,
            config.sh_degree,
        )?,
    };
    let ctx = GpuContext::new(gpu)?;
    // From here on Ctrl-C is polled after each iteration (and saves a checkpoint).
    super::interrupt::install();
    eprintln!(
        "{}: {} training / {} test views at {}×{}, {} initial Gaussians, {} on {}",
        args.scene.scene.display(),
        scene.train.len(),
        scene.test.len(),
        scene.views[scene.train[0]].camera.width,
        scene.views[scene.train[0]].camera.height,
        init.len(),
        config.background.describe(),
        ctx.info.name
    );
    let trainer = match (&resumed, &args.resume) {
        (Some(ck), Some(p)) => {
            Trainer::restore(&ctx, &scene, train_images.clone(), config.clone(), ck, p)
                .inspect(|t| eprintln!("resuming {} at iteration {}", p.display(), t.iteration))
        }
        _ => Trainer::new(&ctx, &scene, train_images.clone(), &init, config.clone()),
    };
    let mut trainer = trainer.map_err(|e| match lpmsplat::gpu::out_of_memory(&e) {
        Some(oom) => anyhow::anyhow!(
            "setting up the training: {oom}. Fix: a device with more memory or a higher \
             --memory-limit, or less to hold: a coarser -r, fewer initial Gaussians \
             (--init-points), --image-cache MIB to stream the training images"
        ),
        None => e,
    })?;
    let resumed_at = resumed.as_ref().map(|ck| (ck.iteration, init.len()));
    drop(resumed);
    let mut nan_check = match args.nan_check {
        Some(_) => Some(NonFiniteCheck::new(&ctx)?),
        None => None,
    };
    if let Some(c) = lpm_config.clone() {
        trainer.set_strategy(Box::new(build_lpm(
            &ctx,
            &scene,
            &train_images,
            c,
            &args.out,
        )?));
    }
    if let Some(p) = &args.resume {
        trainer.check_resumed_strategy(p)?;
    }
    let load_s = t_load.elapsed().as_secs_f64();
    let cache = trainer.image_cache_stats();
    eprintln!("training images: {}", cache.describe());
    // Recording a step while the one before runs needs slots for both steps' images.
    let per_step = config.batch_views.max(1) as usize;
    if args.record_ahead == RecordAhead::On && !cache.resident && cache.slots < 2 * per_step {
        let slot = cache.bytes as f64 / cache.slots.max(1) as f64;
        let need = (2 * per_step) as f64 * slot / (1u64 << 20) as f64;
        eprintln!(
            "note: the image cache's {} slots hold fewer than two steps' {} images, so each \
             iteration is recorded after the one before ends (slower on a GPU). Fix: \
             --image-cache {:.2} or more",
            cache.slots,
            2 * per_step,
            (need * 100.0).ceil() / 100.0
        );
    }
    let start_iteration = trainer.iteration;
    let bar = ProgressBar::new(config.iterations as u64);
    bar.set_position(start_iteration as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} {msg} [{elapsed_precise} < {eta_precise}, {per_sec}]",
        )
        .unwrap(),
    );
    // Without a terminal (CI, logs) the bar is hidden: print a plain line every ~10 s instead.
    let plain = !std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut last_line = Instant::now();
    let t0 = Instant::now();
    let mut stages = StageTimes::default();
    let mut evals = Vec::new();
    let mut ema_loss = None::<f64>;
    // For training.png: samples every 10 iterations, and the evaluations, on a clock that
    // leaves out evaluations and checkpoints.
    let mut samples: Vec<Sample> = Vec::new();
    let mut eval_points: Vec<EvalPoint> = Vec::new();
    let mut paused_s = 0.0;
    let mut model_events = Vec::new();
    // Under --max-gaussians: additions the budget dropped, and on how many density steps.
    let mut budget = (0usize, 0usize);
    for _ in start_iteration..config.iterations {
        let next = trainer.iteration + 1;
        if next == config.iterations || (args.eval_every > 0 && next % args.eval_every == 0) {
            // Evaluate and export the model as it stands before this iteration's density
            // control, as the reference does.
            trainer.snapshot_next_step();
        }
        // Record the iteration after `next` while `next` runs, unless the host has work
        // between them (an evaluation or checkpoint after `next`, a snapshot before the one
        // after, the end).
        let snapshot_after = |k: u32| {
            k == config.iterations || (args.eval_every > 0 && k.is_multiple_of(args.eval_every))
        };
        let prepare = args.record_ahead == RecordAhead::On
            && next < config.iterations
            && !snapshot_after(next)
            && !snapshot_after(next + 1)
            && (args.checkpoint_every == 0 || !next.is_multiple_of(args.checkpoint_every));
        let r = match trainer.step_ahead(prepare) {
            Ok(r) => r,
            Err(e) => {
                bar.abandon();
                return Err(match lpmsplat::gpu::out_of_memory(&e) {
                    Some(oom) => save_after_oom(&mut trainer, &scene, args, oom),
                    None => e,
                });
            }
        };
        for e in &r.model_events {
            if plain {
                eprintln!("{}", e.describe());
            } else {
                bar.println(e.describe());
            }
            model_events.push(e.to_json());
        }
        if let (Some(check), Some(every)) = (nan_check.as_mut(), args.nan_check) {
            if r.iteration % every == 0 || r.iteration == config.iterations {
                check.check(&trainer.state.params, r.iteration)?;
            }
        }
        if super::interrupt::requested() {
            bar.abandon();
            // The next iteration may be recorded already: run it, and save after it.
            let r = match trainer.has_prepared() {
                true => trainer.step()?,
                false => r,
            };
            trainer.save_checkpoint(&scene, &checkpoint_path)?;
            write_ply(&args.out.join("point_cloud.ply"), &trainer.export_model()?)?;
            anyhow::bail!(
                "interrupted (Ctrl-C) after iteration {}: wrote {} and {}. To continue: {}",
                r.iteration,
                checkpoint_path.display(),
                args.out.join("point_cloud.ply").display(),
                resume_hint(&checkpoint_path)
            );
        }
        if args.checkpoint_every > 0
            && r.iteration % args.checkpoint_every == 0
            && r.iteration < config.iterations
        {
            let t_pause = Instant::now();
            trainer.save_checkpoint(&scene, &checkpoint_path)?;
            paused_s += t_pause.elapsed().as_secs_f64();
        }
        if let Some(s) = &r.stages {
            stages.accumulate(s);
        }
        if let Some(d) = r.densified.filter(|d| d.budget_dropped > 0) {
            budget.0 += d.budget_dropped;
            budget.1 += 1;
        }
        let l = r.loss as f64;
        let ema = ema_loss.map_or(l, |e| 0.9 * e + 0.1 * l);
        ema_loss = Some(ema);
        if r.iteration % 10 == 0 || r.iteration == config.iterations {
            samples.push(Sample {
                iteration: r.iteration,
                seconds: t0.elapsed().as_secs_f64() - paused_s,
                loss: ema,
                gaussians: r.gaussians,
            });
            let psnr_l1 = -10.0 * (r.l1 as f64).max(1e-12).log10();
            bar.set_message(format!(
                "loss {ema:.4} (L1 {:.4}, ~{psnr_l1:.1} dB) | {} Gaussians",
                r.l1, r.gaussians
            ));
            bar.set_position(r.iteration as u64);
            if plain
                && (last_line.elapsed().as_secs_f64() > 10.0 || r.iteration == config.iterations)
            {
                last_line = Instant::now();
                let el = t0.elapsed().as_secs_f64();
                let rate = (r.iteration - start_iteration) as f64 / el;
                eprintln!(
                    "[{}/{}] loss {ema:.4} (L1 {:.4}) | {} Gaussians | {rate:.2} it/s | ETA {:.0} s",
                    r.iteration,
                    config.iterations,
                    r.l1,
                    r.gaussians,
                    (config.iterations - r.iteration) as f64 / rate
                );
            }
        }
        if args.eval_every > 0
            && r.iteration % args.eval_every == 0
            && r.iteration < config.iterations
            && !scene.test.is_empty()
        {
            let t_pause = Instant::now();
            let m = trainer.evaluate(&scene, &scene.test, &test_images, |_, m, r, gt| {
                lpips_scores::score_view(lpips.as_ref(), m, r, gt)
            })?;
            let lp = lpips_scores::mean(&m);
            let (p, s) = mean_metrics(&m);
            eval_points.push(EvalPoint {
                iteration: r.iteration,
                seconds: t_pause.duration_since(t0).as_secs_f64() - paused_s,
                psnr: p,
                gaussians: trainer.gaussians(),
            });
            let line = format!(
                "[{}] test PSNR {p:.3} dB, SSIM {s:.4},{} {} Gaussians",
                r.iteration,
                lp.map_or(String::new(), |d| format!(" LPIPS {d:.4},")),
                trainer.gaussians()
            );
            if plain {
                eprintln!("{line}");
            } else {
                bar.println(line);
            }
            evals.push(serde_json::json!({
                "iteration": r.iteration,
                "psnr": p,
                "ssim": s,
                "lpips": lp,
                "gaussians": trainer.gaussians(),
                "per_view": m,
            }));
            paused_s += t_pause.elapsed().as_secs_f64();
        }
    }
    bar.finish();
    let train_s = t0.elapsed().as_secs_f64();
    let plot_train_s = train_s - paused_s;
    let trained = (config.iterations - start_iteration).max(1);
    let model = trainer.export_model()?;
    write_ply(&args.out.join("point_cloud.ply"), &model)?;
    for (ext, contents) in trainer.export_files()? {
        let path = args.out.join("point_cloud.ply").with_extension(&ext);
        std::fs::write(&path, contents).with_context(|| format!("writing {}", path.display()))?;
    }
    // A .splat holds still Gaussians: a video model's would show it at no time at all.
    if model.extra.is_empty() {
        write_splat(&args.out.join("point_cloud.splat"), &model)?;
    }
    trainer.save_checkpoint(&scene, &checkpoint_path)?;

    // Final evaluation and renders (written as each view is scored).
    let render_dir = args.out.join("renders").join("test");
    std::fs::create_dir_all(&render_dir)
        .with_context(|| format!("creating {}", render_dir.display()))?;
    let per_view = trainer.evaluate(&scene, &scene.test, &test_images, |k, m, r, gt| {
        lpips_scores::score_view(lpips.as_ref(), m, r, gt)?;
        let img = Image {
            width: gt.width,
            height: gt.height,
            rgb: r.to_vec(),
            alpha: None,
        };
        let stem = &scene.views[scene.test[k]].stem;
        images::save_png(&render_dir.join(format!("{stem}.png")), &img)
    })?;
    let lpips_mean = lpips_scores::mean(&per_view);
    let (psnr, ssim) = mean_metrics(&per_view);
    if !per_view.is_empty() {
        eval_points.push(EvalPoint {
            iteration: config.iterations,
            seconds: plot_train_s,
            psnr,
            gaussians: model.len(),
        });
    }
    let run_name = format!(
        "{}{}",
        args.model.name(),
        if lpm_config.is_some() { " + LPM" } else { "" }
    );
    write_training_plot(
        &args.out.join("training.png"),
        &run_name,
        &samples,
        &eval_points,
    )?;
    let metrics = serde_json::json!({
        "scene": args.scene.scene.display().to_string(),
        "iterations": config.iterations,
        "gaussians": model.len(),
        "test_views": scene.test.len(),
        "psnr": psnr,
        "ssim": ssim,
        "lpips": lpips_mean,
        "per_view": per_view,
        "evaluations": evals,
        "history": samples,
        "train_seconds": train_s,
        "iterations_per_second": trained as f64 / train_s,
        // Of train_seconds, the intermediate evaluations (--eval-every) and checkpoints
        // (--checkpoint-every): the training's own rate is without them.
        "paused_seconds": paused_s,
        "iterations_per_second_unpaused": trained as f64 / plot_train_s.max(1e-9),
        "resumed_from": start_iteration,
        "setup_seconds": load_s,
        "dropped_frames": trainer.dropped_frames,
        // Iterations submitted, how many were recorded while the previous one ran
        // (--record-ahead), and the host's recording time.
        "recording": trainer.recording,
        "image_cache": trainer.image_cache_stats(),
        "model_events": model_events,
        "device": ctx.info.name,
        "gpu_memory_mib": ctx.memory_in_use().1 as f64 / (1u64 << 20) as f64,
        "device_buffers_peak_mib": ctx.memory.peak() as f64 / (1u64 << 20) as f64,
        // The rasterizers' pixels per invocation when --raster-pixels set them (null: the
        // device's default).
        "raster_pixels": config.raster_pixels,
        // The loss kernels' layout when --loss-layout set it (null: the default, segments).
        "loss_layout": config.loss_layout.map(|l| l.name()),
        // The radix sorts' digit width when --sort-digits set it (null: the default, 4).
        "sort_digits": ctx.sort_digit_bits,
        "max_gaussians": config.density.max_gaussians.map(|cap| serde_json::json!({
            "cap": cap, "dropped_additions": budget.0, "steps_at_cap": budget.1,
        })),
        "stages": if config.timestamps { stage_shares(&stages) } else { serde_json::Value::Null },
        "lpm": trainer.strategy_as::<LpmStrategy>().map(|l| {
            let mut j = lpm_summary(&l.totals, train_s, config.iterations);
            j["per_step"] = l.steps.iter().map(|r| r.to_json()).collect();
            j
        }),
    });
    let text = serde_json::to_string_pretty(&metrics)?;
    write_atomic(&args.out.join("metrics.json"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    let mut cfg = config.to_json();
    cfg["scene"] = serde_json::json!(args.scene.scene.display().to_string());
    cfg["resolution"] = serde_json::json!(args.scene.resolution);
    cfg["model"] = serde_json::json!(args.model.name());
    match (resumed_at, &args.resume) {
        // The checkpoint's model is not the run's initialisation: say where the run resumed.
        (Some((iteration, gaussians)), Some(p)) => {
            cfg["resumed_from"] = serde_json::json!({
                "checkpoint": p.display().to_string(),
                "iteration": iteration,
                "gaussians": gaussians,
            });
        }
        _ => {
            cfg["init_points"] = serde_json::json!(init.len());
            cfg["init"] = serde_json::json!(format!("{:?}", args.init).to_lowercase());
        }
    }
    cfg["lpm"] = lpm_config
        .as_ref()
        .map_or(serde_json::Value::Null, |c| c.to_json());
    let text = serde_json::to_string_pretty(&cfg)?;
    write_atomic(&args.out.join("config.json"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    // Intermediate evaluations and checkpoints are in the wall time; say what they took.
    let unpaused = if paused_s > 0.0 {
        format!(
            "; {:.1} s and {:.2} it/s without {:.1} s of intermediate evaluations and checkpoints",
            plot_train_s,
            trained as f64 / plot_train_s.max(1e-9),
            paused_s
        )
    } else {
        String::new()
    };
    println!(
        "trained {} iterations in {:.1} s ({:.2} it/s{unpaused}): {} Gaussians, test PSNR {:.3} dB, SSIM {:.4}{}",
        config.iterations,
        train_s,
        trained as f64 / train_s,
        model.len(),
        psnr,
        ssim,
        lpips_mean.map_or(String::new(), |d| format!(", LPIPS {d:.4}"))
    );
    if config.timestamps {
        let total = stages.total_ms().max(1e-12);
        for (n, ms) in &stages.stages {
            println!(
                "  {n:<20} {:>6.1}%  ({:.2} ms/it)",
                100.0 * ms / total,
                ms / trained as f64
            );
        }
        println!(
            "  the stages sum to {:.2} ms/it of {:.2} ms/it wall (the rest: host work, \
             submission, waits, evaluation and checkpoints)",
            total / trained as f64,
            1e3 * train_s / trained as f64
        );
        let r = trainer.recording;
        println!(
            "  host recording {:.3} ms/it; {} of {} iterations recorded while the one before ran \
             (--record-ahead {}); {} prepared ones dropped and recorded again",
            1e3 * r.seconds / r.iterations.max(1) as f64,
            r.ahead,
            r.iterations,
            args.record_ahead.name(),
            r.dropped
        );
    }
    if let Some(cap) = config.density.max_gaussians {
        println!(
            "  Gaussian budget {cap}: {} clones and splits dropped on {} density steps",
            budget.0, budget.1
        );
    }
    if let Some(l) = trainer.strategy_as::<LpmStrategy>() {
        let t = &l.totals;
        println!(
            "  LPM: {} steps ({} with zones), {} error regions, {} paired, {} zones{}, {} \
             densified by the lowered threshold, {} extra prunes, {} opacity resets, {} added; \
             {:.2} s = {:.2} % of training ({:.3} ms/it); zone radius mean {:.3} / largest {:.3} \
             scene extents",
            t.steps,
            t.steps_with_zones,
            t.regions,
            t.paired,
            t.zones,
            if t.wide > 0 {
                format!(" (and {} wider than the largest radius, dropped)", t.wide)
            } else {
                String::new()
            },
            t.lowered,
            t.pruned,
            t.reset,
            t.added,
            t.seconds,
            100.0 * t.seconds / train_s.max(1e-12),
            1e3 * t.seconds / config.iterations as f64,
            t.radius_mean,
            t.radius_max
        );
    }
    println!("wrote {}", args.out.display());
    ctx.check_validation()?;
    Ok(())
}

pub fn mean_metrics(m: &[ViewMetrics]) -> (f64, f64) {
    if m.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = m.len() as f64;
    (
        m.iter().map(|v| v.psnr).sum::<f64>() / n,
        m.iter().map(|v| v.ssim).sum::<f64>() / n,
    )
}

/// LPM totals for `metrics.json`.
pub fn lpm_summary(
    t: &lpmsplat::lpm::strategy::LpmTotals,
    train_seconds: f64,
    iterations: u32,
) -> serde_json::Value {
    serde_json::json!({
        "steps": t.steps, "steps_with_zones": t.steps_with_zones, "regions": t.regions,
        "paired": t.paired, "zones": t.zones,
        "lowered": t.lowered, "pruned_extra": t.pruned, "opacity_reset": t.reset,
        "added": t.added, "inside": t.inside, "radius_mean_rel": t.radius_mean,
        "radius_max_rel": t.radius_max, "wide_dropped": t.wide, "skipped_adc": t.skipped_adc,
        "seconds": t.seconds,
        "share_of_training": t.seconds / train_seconds.max(1e-12),
        "ms_per_iteration": 1e3 * t.seconds / iterations.max(1) as f64,
    })
}

/// `--max-gaussians N`: a positive count.
pub fn parse_max_gaussians(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if n > 0 => Ok(n),
        _ => Err(format!(
            "'{s}' is not a Gaussian count. Fix: give a positive whole number, e.g. 500000"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_zone_geometry_has_its_command_line_name() {
        for (name, g) in [
            ("triangulated", ZoneGeometry::Triangulated),
            ("slab", ZoneGeometry::Slab),
            ("sphere", ZoneGeometry::Sphere),
            ("ray-pairs", ZoneGeometry::SphereRayPairs),
            ("authors-box", ZoneGeometry::AuthorsBox),
        ] {
            assert_eq!(parse_zone(name).unwrap(), g);
        }
        let e = parse_zone("cone").unwrap_err().to_string();
        assert!(e.contains("\"cone\"") && e.contains("slab"), "{e}");
    }
}
