//! How each run `bench trade` can compare ([`RUNS`]: ADC, LPM and their ablations, by name) is
//! configured: which runs `--runs` selects, the calendar every run follows, each LPM run's
//! rules, how a run's start comes down to a budget and the budget it trains under.

use super::TradeSettings;
use crate::bench::runs::RUNS;
use crate::lpm::config::{LpmConfig, PruneMode};
use crate::lpm::pairing::RegionKeypoints;
use crate::lpm::region_units::RegionUnit;
use crate::lpm::{ConeRadius, NeighbourChoice, ZoneGeometry};
use crate::mcmc::McmcConfig;
use crate::models::BaseModel;
use crate::scene::Scene;
use crate::splats::budget_draw::Draw;
use crate::splats::init::Look;
use crate::train::density::growth::{BudgetCurve, Growth};
use crate::train::trainer::TrainConfig;
use anyhow::Context;

/// Whether run `name` fills an exact budget (the exact-budget ADC runs and MCMC).
pub fn fills_budget(name: &str) -> bool {
    name.starts_with("adc-exact") || name.starts_with("mcmc")
}

/// The configuration every run starts from: the base model's defaults with every iteration
/// its official code names on a 30k calendar (densification, opacity resets, the position
/// learning rate's decay, the models' own rules' starts) scaled to `calendar` iterations.
pub fn calendar_config(
    settings: &TradeSettings,
    scene: &Scene,
    calendar: u32,
) -> anyhow::Result<TrainConfig> {
    let scale = |t: u32| ((t as u64 * calendar as u64) / 30_000) as u32;
    let mut base = TrainConfig {
        iterations: settings.iterations,
        seed: settings.seed,
        background: crate::train::config::Background::choose(None, scene.background)?,
        ..TrainConfig::default()
    };
    base.schedule.densify_from = scale(500);
    base.schedule.densify_until = scale(settings.model.default_densify_until());
    base.schedule.opacity_reset_interval = (scale(3000) / 100).max(1) * 100;
    base.lr.position_max_steps = calendar;
    base.density.min_opacity = settings.model.default_min_opacity();
    settings.model.configure(&mut base);
    if settings.densify_abs_grad {
        abs_grad_applies(settings.model)?;
        base.density.abs_grad = true;
    }
    base.density.max_gaussians = settings.max_gaussians;
    // The model's own iterations (2DGS's regularisers, SpacetimeGaussians' rules) on the same
    // calendar.
    settings.model.model().rescale_calendar(&mut base, &scale);
    // The Neural 3D Video culls on the same calendar (official: every 1000 of 30k).
    crate::train::passes::world_culls::apply_choice(
        settings.n3dv_culls,
        &scene.root,
        settings.model.name(),
        &mut base,
        scale(1000),
    )?;
    Ok(base)
}

/// The absolute-gradient test needs the mean-gradient statistic of a Gaussian model.
pub fn abs_grad_applies(model: BaseModel) -> anyhow::Result<()> {
    anyhow::ensure!(
        model.takes_abs_grad(),
        "bench trade: the absolute-gradient test (--densify-abs-grad, run adc-abs-grad) with \
         --model {}: it applies to 3dgs, mip-splatting and the spacetime models. Fix: drop it",
        model.name()
    );
    Ok(())
}

/// How run `name`'s start comes down to a budget below it: the draw and whether the kept
/// Gaussians' scales are refitted to their new spacing (`train --budget-draw`,
/// `--budget-refit-scales`). `mcmc`: the draw of the mcmc runs that name none.
pub fn run_draw(name: &str, mcmc: Draw) -> (Draw, bool) {
    match name {
        "mcmc-drawn" => (Draw::Random, false),
        "mcmc-refit" => (Draw::Random, true),
        "mcmc-spread" => (Draw::Spread, true),
        "mcmc-keep" => (Draw::Keep, false),
        _ if name.starts_with("mcmc") => (mcmc, false),
        _ => (Draw::Random, false),
    }
}

/// How run `name`'s start from points looks (`train --init-opacity`, `--init-scale`).
pub fn run_look(name: &str) -> Look {
    match name {
        "mcmc-start" => Look::MCMC,
        "mcmc-opaque" => Look {
            opacity: Look::MCMC.opacity,
            scale: 1.0,
        },
        _ => Look::STANDARD,
    }
}

/// The share of MCMC's dead Gaussians the `+lpm-surface` runs move onto the local zones'
/// surface samples (`--lpm-surface-share` overrides it).
const SURFACE_SHARE: f64 = 0.5;

/// The block rule of `lpm-loose-blocks`: ahead of the paper's 0.85 at one Gaussian count on
/// Truck `-r 4` over eleven seeds (docs/results/lpm.md), not yet measured at full size.
const LOOSE_BLOCK_FRACTION: f32 = 0.7;

/// LPM's configuration for run `name` (None for the runs without LPM), on `cfg`'s calendar
/// and seed, with the benchmark's LPM overrides.
pub fn run_lpm_config(
    name: &str,
    cfg: &TrainConfig,
    settings: &TradeSettings,
) -> Option<LpmConfig> {
    if !name.contains("lpm") {
        return None;
    }
    let mut c = if name.starts_with("lpm-authors") {
        LpmConfig::authors()
    } else {
        LpmConfig::default()
    };
    if name == "lpm-authors-adc" {
        c.skip_adc_without_zone = false;
    }
    c.from = cfg.schedule.densify_from;
    c.until = cfg.schedule.densify_until;
    c.add_points &= name != "lpm-no-add";
    c.reset = name != "lpm-no-reset";
    c.seed = cfg.seed;
    if name == "lpm-sphere" {
        c.zones.geometry = ZoneGeometry::Sphere;
    }
    if name == "lpm-additive" {
        c.prune = PruneMode::Additive;
    }
    if name == "lpm-overlap-neighbours" {
        c.matching.neighbours.choice = NeighbourChoice::Overlap;
    }
    if name == "lpm-error-blocks" {
        c.region_keypoints = RegionKeypoints::ErrorBlocks;
    }
    if name == "lpm-bounding-cone" {
        c.cone = ConeRadius::Bounding;
    }
    if name == "lpm-local-zones" {
        c.max_zone_radius = Some(1.0);
    }
    if name == "lpm-slab" {
        c.zones.geometry = ZoneGeometry::Slab;
    }
    if name == "lpm-local-resets" {
        c.reset_max_zone_radius = Some(1.0);
    }
    let surface = name.ends_with("+lpm-surface") || name.ends_with("+lpm-surface-random");
    if name.ends_with("+lpm-local") || name.ends_with("+lpm-random") || surface {
        c = c.with_local_zones();
    }
    if name.ends_with("+lpm-random") || name.ends_with("+lpm-surface-random") {
        c.region_unit = RegionUnit::RandomBlocks;
    }
    if surface {
        c.surface_share = settings.lpm_surface_share.unwrap_or(SURFACE_SHARE);
    }
    if let Some(p) = settings.lpm_prune {
        c.prune = p;
    }
    if let Some(r) = settings.lpm_threshold_ratio {
        c.threshold_ratio = r;
    }
    if let Some(w) = settings.lpm_zone_weight {
        c.zone_weight = w;
    }
    c.regions.block = settings.lpm_block;
    c.regions.keep_fraction = if name == "lpm-loose-blocks" {
        LOOSE_BLOCK_FRACTION
    } else {
        settings.lpm_block_fraction
    };
    Some(c)
}

/// The runs `runs` selects ([`selected_runs`]), once the benchmark is known to train
/// something: what every `bench trade` checks first, the harness itself and the command line
/// before it writes a Slurm sweep of it.
pub fn runs_to_train(iterations: u32, seeds: u32, runs: &[String]) -> anyhow::Result<Vec<usize>> {
    anyhow::ensure!(
        iterations > 0,
        "bench trade: --iterations 0. Fix: pass at least 1"
    );
    anyhow::ensure!(seeds > 0, "bench trade: --seeds 0. Fix: pass at least 1");
    selected_runs(runs)
}

/// Indices into [`RUNS`] for the `--runs` list (all when empty), in table order.
pub fn selected_runs(names: &[String]) -> anyhow::Result<Vec<usize>> {
    if names.is_empty() {
        return Ok((0..5).collect());
    }
    let mut out = Vec::new();
    for n in names {
        let canonical = match n.trim() {
            "adc-1e-4" => "adc-threshold-1e-4",
            "lpm" => "adc+lpm",
            other => other,
        };
        let k = RUNS
            .iter()
            .position(|r| r.name == canonical)
            .with_context(|| {
                format!(
                    "bench trade --runs: unknown run {n:?}. Fix: choose from {}",
                    RUNS.iter().map(|r| r.name).collect::<Vec<_>>().join(", ")
                )
            })?;
        anyhow::ensure!(
            !out.contains(&k),
            "bench trade --runs: {n:?} is listed twice. Fix: name each run once"
        );
        out.push(k);
    }
    out.sort_unstable();
    Ok(out)
}

/// The budget of run `name` on `cfg` (its initial model of `initial` Gaussians, the budget
/// `target` resolved before the start was drawn down to it, its calendar):
/// a cap for ADC and its LPM runs, the exact budget for adc-exact* (adc's count under
/// --match-adc-count when no --budget is given), and MCMC's settings for mcmc (returned).
pub fn apply_budget(
    name: &str,
    cfg: &mut TrainConfig,
    settings: &TradeSettings,
    (initial, target): (usize, Option<usize>),
    calendar: u32,
) -> anyhow::Result<Option<McmcConfig>> {
    anyhow::ensure!(
        !fills_budget(name)
            || !settings.budget.is_empty()
            || (settings.match_adc_count && !name.starts_with("mcmc")),
        "bench trade: run {name} fills a Gaussian budget. Fix: pass --budget N (e.g. adc's final \
         count), or --match-adc-count for the adc-exact runs"
    );
    let mcmc = name.starts_with("mcmc");
    if mcmc {
        crate::mcmc::config::apply_schedule(&mut cfg.schedule, calendar, None);
    }
    if name.ends_with("lpm-lowered") {
        cfg.density.rank_lowered = true;
    }
    let window = (
        cfg.schedule.densify_from,
        cfg.schedule
            .densify_until
            .min(settings.iterations.saturating_add(1)),
        cfg.schedule.interval,
    );
    let curve = |default: Growth| {
        target.map(|target| BudgetCurve {
            target,
            growth: settings.budget_growth.unwrap_or(default),
            initial,
            window,
        })
    };
    if mcmc {
        let c = curve(Growth::Mcmc).expect("checked above");
        // The cap stops a guide's added points at the budget too.
        cfg.density.max_gaussians = Some(c.target);
        return Ok(Some(McmcConfig {
            seed: cfg.seed,
            ..McmcConfig::with_budget(c)
        }));
    }
    if name.starts_with("adc-exact") {
        // Without a budget the cap (adc's count, moved every iteration) decides each step.
        cfg.density.exact_budget = Some(curve(Growth::Taming).unwrap_or(BudgetCurve {
            target: usize::MAX / 4,
            growth: Growth::Linear,
            initial,
            window,
        }));
    } else if let Some(c) = curve(Growth::Taming) {
        cfg.density.max_gaussians = Some(
            cfg.density
                .max_gaussians
                .map_or(c.target, |m| m.min(c.target)),
        );
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `bench trade scene`'s settings with the command line's defaults, changed by `f`.
    fn settings(f: impl FnOnce(&mut TradeSettings)) -> TradeSettings {
        let mut s = TradeSettings {
            scene: "scene".into(),
            load_options: Default::default(),
            test_split: None,
            frames: None,
            image_cache_mib: 2048.0,
            lpips_weights: None,
            iterations: 30_000,
            model: BaseModel::default(),
            calendar: None,
            eval_at: Vec::new(),
            init_points: 100_000,
            init: crate::initial::InitSource::Auto,
            out: "bench_trade".into(),
            seed: 0,
            seeds: 1,
            fps_frames: 20,
            runs: Vec::new(),
            sequential: false,
            lpm_block: 0,
            lpm_prune: None,
            lpm_block_fraction: 0.85,
            lpm_threshold_ratio: None,
            densify_abs_grad: false,
            max_gaussians: None,
            budget: Vec::new(),
            budget_growth: None,
            budget_draw: None,
            lpm_zone_weight: None,
            lpm_surface_share: None,
            match_adc_count: false,
            n3dv_culls: crate::train::passes::world_culls::N3dvCulls::Auto,
            report_view: None,
        };
        f(&mut s);
        s
    }

    #[test]
    fn the_calendar_scales_the_official_schedule() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");
        let scene = Scene::load(std::path::Path::new(root), &Default::default()).unwrap();
        // The shortened calendar the LPM tables use: 3,000 iterations on a 3,000 calendar is
        // train's --densify-from 50 --densify-until 1500 --opacity-reset-interval 300
        // --lr-position-max-steps 3000.
        let settings = settings(|s| {
            s.iterations = 3000;
            s.max_gaussians = Some(9);
        });
        let c = calendar_config(&settings, &scene, 3000).unwrap();
        let s = &c.schedule;
        assert_eq!(
            (s.densify_from, s.densify_until, s.opacity_reset_interval),
            (50, 1500, 300)
        );
        assert_eq!((c.iterations, c.lr.position_max_steps), (3000, 3000));
        assert_eq!(c.density.max_gaussians, Some(9));
        // The full calendar is the official schedule itself; the reset interval stays a
        // multiple of 100 and at least 100 on a short one.
        let c = calendar_config(&settings, &scene, 30_000).unwrap();
        let s = &c.schedule;
        assert_eq!(
            (s.densify_from, s.densify_until, s.opacity_reset_interval),
            (500, 15_000, 3000)
        );
        let c = calendar_config(&settings, &scene, 1000).unwrap();
        assert_eq!(c.schedule.opacity_reset_interval, 100);
    }

    #[test]
    fn each_lpm_run_gets_its_rules_and_the_benchmark_overrides() {
        let args = settings(|s| {
            s.lpm_block = 6;
            s.lpm_prune = Some(PruneMode::Off);
        });
        let cfg = TrainConfig {
            seed: 7,
            ..TrainConfig::default()
        };
        assert!(run_lpm_config("adc", &cfg, &args).is_none());
        let ours = run_lpm_config("adc+lpm", &cfg, &args).unwrap();
        let authors = run_lpm_config("lpm-authors", &cfg, &args).unwrap();
        let authors_adc = run_lpm_config("lpm-authors-adc", &cfg, &args).unwrap();
        assert!(!ours.skip_adc_without_zone && ours.add_points);
        assert!(authors.skip_adc_without_zone && !authors.add_points);
        // The same rules as lpm-authors but for ADC on steps without a zone.
        assert!(!authors_adc.skip_adc_without_zone);
        let mut same = authors_adc.clone();
        same.skip_adc_without_zone = true;
        assert_eq!(same, authors);
        for c in [&ours, &authors, &authors_adc] {
            assert_eq!((c.seed, c.regions.block, c.prune), (7, 6, PruneMode::Off));
            assert_eq!(
                (c.from, c.until),
                (cfg.schedule.densify_from, cfg.schedule.densify_until)
            );
        }
        let no_add = run_lpm_config("lpm-no-add", &cfg, &args).unwrap();
        assert!(!no_add.add_points && no_add.reset);
        let no_reset = run_lpm_config("lpm-no-reset", &cfg, &args).unwrap();
        assert!(no_reset.add_points && !no_reset.reset);
        let sphere = run_lpm_config("lpm-sphere", &cfg, &args).unwrap();
        assert_eq!(sphere.zones.geometry, ZoneGeometry::Sphere);
        let plain = settings(|_| {});
        let additive = run_lpm_config("lpm-additive", &cfg, &plain).unwrap();
        let default = run_lpm_config("adc+lpm", &cfg, &plain).unwrap();
        assert_eq!(additive.prune, PruneMode::Additive);
        assert_ne!(default.prune, PruneMode::Additive);
        let mut same = additive.clone();
        same.prune = default.prune;
        assert_eq!(same, default, "only the pruning differs");
        assert_eq!(ours.zones.geometry, ZoneGeometry::Triangulated);
        // lpm-slab: our rules but for the zone's shape.
        let slab = run_lpm_config("lpm-slab", &cfg, &plain).unwrap();
        assert_eq!(slab.zones.geometry, ZoneGeometry::Slab);
        let mut same = slab.clone();
        same.zones.geometry = ZoneGeometry::Triangulated;
        assert_eq!(same, default, "only the zone geometry differs");
        // The local zones, and the control that differs from them only in where the blocks are.
        let local = run_lpm_config("adc-exact+lpm-local", &cfg, &plain).unwrap();
        let random = run_lpm_config("adc-exact+lpm-random", &cfg, &plain).unwrap();
        let mcmc_local = run_lpm_config("mcmc+lpm-local", &cfg, &plain).unwrap();
        assert_eq!(local, default.clone().with_local_zones());
        assert_eq!(mcmc_local, local);
        assert_eq!(
            (local.region_unit, random.region_unit),
            (RegionUnit::Blocks, RegionUnit::RandomBlocks)
        );
        let mut same = random.clone();
        same.region_unit = RegionUnit::Blocks;
        assert_eq!(same, local, "only the blocks' choice differs");
        // lpm-loose-blocks: our rules but for the block fraction, whatever the flag says.
        let loose = run_lpm_config("lpm-loose-blocks", &cfg, &plain).unwrap();
        assert_eq!(loose.regions.keep_fraction, 0.7);
        let mut same = loose.clone();
        same.regions.keep_fraction = default.regions.keep_fraction;
        assert_eq!(same, default, "only the block fraction differs");
        let flagged = settings(|s| s.lpm_block_fraction = 0.6);
        let loose = run_lpm_config("lpm-loose-blocks", &cfg, &flagged).unwrap();
        let ours = run_lpm_config("adc+lpm", &cfg, &flagged).unwrap();
        assert_eq!(
            (loose.regions.keep_fraction, ours.regions.keep_fraction),
            (0.7, 0.6)
        );
        // lpm-local-resets: our rules but for the reset's largest zone.
        let local = run_lpm_config("lpm-local-resets", &cfg, &plain).unwrap();
        assert_eq!(local.reset_max_zone_radius, Some(1.0));
        let mut same = local.clone();
        same.reset_max_zone_radius = None;
        assert_eq!(same, default, "only the reset's largest zone differs");
    }

    #[test]
    fn runs_are_selected_by_name_or_alias_in_table_order() {
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(selected_runs(&[]).unwrap(), vec![0, 1, 2, 3, 4]);
        assert_eq!(
            selected_runs(&names(&["lpm", "adc-1e-4", "adc"])).unwrap(),
            vec![0, 1, 2]
        );
        assert!(selected_runs(&names(&["adc", "lpm", "adc+lpm"])).is_err());
    }
}
