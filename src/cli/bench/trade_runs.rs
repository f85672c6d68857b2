//! The runs `bench trade` can compare (ADC, LPM and their ablations, by name) and how each is
//! configured: the calendar every run follows and each LPM run's rules.

use super::trade_args::TradeArgs;
use anyhow::Context;
use lpmsplat::lpm::config::{LpmConfig, PruneMode};
use lpmsplat::lpm::pairing::RegionKeypoints;
use lpmsplat::lpm::region_units::RegionUnit;
use lpmsplat::lpm::{ConeRadius, NeighbourChoice, ZoneGeometry};
use lpmsplat::models::BaseModel;
use lpmsplat::scene::Scene;
use lpmsplat::splats::budget_draw::Draw;
use lpmsplat::splats::init::Look;
use lpmsplat::train::trainer::TrainConfig;

pub use lpmsplat::bench::runs::RUNS;

/// Whether run `name` fills an exact budget (the exact-budget ADC runs and MCMC).
pub fn fills_budget(name: &str) -> bool {
    name.starts_with("adc-exact") || name.starts_with("mcmc")
}

/// The configuration every run starts from: the base model's defaults with every iteration
/// its official code names on a 30k calendar (densification, opacity resets, the position
/// learning rate's decay, the models' own rules' starts) scaled to `calendar` iterations.
pub fn calendar_config(
    args: &TradeArgs,
    scene: &Scene,
    calendar: u32,
) -> anyhow::Result<TrainConfig> {
    let scale = |t: u32| ((t as u64 * calendar as u64) / 30_000) as u32;
    let mut base = TrainConfig {
        iterations: args.iterations,
        seed: args.seed,
        background: lpmsplat::train::config::Background::choose(None, scene.background)?,
        ..TrainConfig::default()
    };
    base.schedule.densify_from = scale(500);
    base.schedule.densify_until = scale(args.model.default_densify_until());
    base.schedule.opacity_reset_interval = (scale(3000) / 100).max(1) * 100;
    base.lr.position_max_steps = calendar;
    base.density.min_opacity = args.model.default_min_opacity();
    args.model.configure(&mut base);
    if args.densify_abs_grad {
        abs_grad_applies(args.model)?;
        base.density.abs_grad = true;
    }
    base.density.max_gaussians = args.max_gaussians;
    if let Some(g) = base.spacetime.as_mut().and_then(|s| s.guided.as_mut()) {
        // SpacetimeGaussians' guided sampling on the same calendar (official 1600 and 100).
        g.from = scale(g.from);
        g.gap = scale(g.gap);
    }
    if let Some(f) = base
        .spacetime
        .as_mut()
        .and_then(|s| s.omega_freeze.as_mut())
    {
        // The angular-velocity split on the same calendar (official 8001 of 30k).
        f.from = scale(f.from);
    }
    // The Neural 3D Video culls on the same calendar (official: every 1000 of 30k).
    lpmsplat::train::passes::world_culls::apply_choice(
        args.n3dv_culls,
        &scene.root,
        args.model.name(),
        &mut base,
        scale(1000),
    )?;
    if let Some(t) = base.surfels.as_mut() {
        // 2DGS's regularisers start on the same calendar (official 7000 and 3000 of 30k).
        t.normal_from = scale(t.normal_from);
        t.distortion_from = scale(t.distortion_from);
    }
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
pub fn run_lpm_config(name: &str, cfg: &TrainConfig, args: &TradeArgs) -> Option<LpmConfig> {
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
        c.surface_share = args.lpm_surface_share.unwrap_or(SURFACE_SHARE);
    }
    if let Some(p) = args.lpm_prune {
        c.prune = p;
    }
    if let Some(r) = args.lpm_threshold_ratio {
        c.threshold_ratio = r;
    }
    if let Some(w) = args.lpm_zone_weight {
        c.zone_weight = w;
    }
    c.regions.block = args.lpm_block;
    c.regions.keep_fraction = if name == "lpm-loose-blocks" {
        LOOSE_BLOCK_FRACTION
    } else {
        args.lpm_block_fraction
    };
    Some(c)
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
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_calendar_scales_the_official_schedule() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            trade: TradeArgs,
        }
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/lund_door_small");
        let scene = Scene::load(std::path::Path::new(root), &Default::default()).unwrap();
        // The shortened calendar the LPM tables use: 3,000 iterations on a 3,000 calendar is
        // train's --densify-from 50 --densify-until 1500 --opacity-reset-interval 300
        // --lr-position-max-steps 3000.
        let args = Cli::parse_from([
            "bench",
            "scene",
            "--iterations",
            "3000",
            "--max-gaussians",
            "9",
        ]);
        let c = calendar_config(&args.trade, &scene, 3000).unwrap();
        let s = &c.schedule;
        assert_eq!(
            (s.densify_from, s.densify_until, s.opacity_reset_interval),
            (50, 1500, 300)
        );
        assert_eq!((c.iterations, c.lr.position_max_steps), (3000, 3000));
        assert_eq!(c.density.max_gaussians, Some(9));
        // The full calendar is the official schedule itself; the reset interval stays a
        // multiple of 100 and at least 100 on a short one.
        let c = calendar_config(&args.trade, &scene, 30_000).unwrap();
        let s = &c.schedule;
        assert_eq!(
            (s.densify_from, s.densify_until, s.opacity_reset_interval),
            (500, 15_000, 3000)
        );
        let c = calendar_config(&args.trade, &scene, 1000).unwrap();
        assert_eq!(c.schedule.opacity_reset_interval, 100);
    }

    #[test]
    fn each_lpm_run_gets_its_rules_and_the_benchmark_overrides() {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            trade: TradeArgs,
        }
        let args = Cli::parse_from(["bench", "scene", "--lpm-block", "6", "--lpm-prune", "off"]);
        let cfg = TrainConfig {
            seed: 7,
            ..TrainConfig::default()
        };
        assert!(run_lpm_config("adc", &cfg, &args.trade).is_none());
        let ours = run_lpm_config("adc+lpm", &cfg, &args.trade).unwrap();
        let authors = run_lpm_config("lpm-authors", &cfg, &args.trade).unwrap();
        let authors_adc = run_lpm_config("lpm-authors-adc", &cfg, &args.trade).unwrap();
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
        let no_add = run_lpm_config("lpm-no-add", &cfg, &args.trade).unwrap();
        assert!(!no_add.add_points && no_add.reset);
        let no_reset = run_lpm_config("lpm-no-reset", &cfg, &args.trade).unwrap();
        assert!(no_reset.add_points && !no_reset.reset);
        let sphere = run_lpm_config("lpm-sphere", &cfg, &args.trade).unwrap();
        assert_eq!(sphere.zones.geometry, ZoneGeometry::Sphere);
        let plain = Cli::parse_from(["bench", "scene"]);
        let additive = run_lpm_config("lpm-additive", &cfg, &plain.trade).unwrap();
        let default = run_lpm_config("adc+lpm", &cfg, &plain.trade).unwrap();
        assert_eq!(additive.prune, PruneMode::Additive);
        assert_ne!(default.prune, PruneMode::Additive);
        let mut same = additive.clone();
        same.prune = default.prune;
        assert_eq!(same, default, "only the pruning differs");
        assert_eq!(ours.zones.geometry, ZoneGeometry::Triangulated);
        // lpm-slab: our rules but for the zone's shape.
        let slab = run_lpm_config("lpm-slab", &cfg, &plain.trade).unwrap();
        assert_eq!(slab.zones.geometry, ZoneGeometry::Slab);
        let mut same = slab.clone();
        same.zones.geometry = ZoneGeometry::Triangulated;
        assert_eq!(same, default, "only the zone geometry differs");
        // The local zones, and the control that differs from them only in where the blocks are.
        let local = run_lpm_config("adc-exact+lpm-local", &cfg, &plain.trade).unwrap();
        let random = run_lpm_config("adc-exact+lpm-random", &cfg, &plain.trade).unwrap();
        let mcmc_local = run_lpm_config("mcmc+lpm-local", &cfg, &plain.trade).unwrap();
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
        let loose = run_lpm_config("lpm-loose-blocks", &cfg, &plain.trade).unwrap();
        assert_eq!(loose.regions.keep_fraction, 0.7);
        let mut same = loose.clone();
        same.regions.keep_fraction = default.regions.keep_fraction;
        assert_eq!(same, default, "only the block fraction differs");
        let flagged = Cli::parse_from(["bench", "scene", "--lpm-block-fraction", "0.6"]);
        let loose = run_lpm_config("lpm-loose-blocks", &cfg, &flagged.trade).unwrap();
        let ours = run_lpm_config("adc+lpm", &cfg, &flagged.trade).unwrap();
        assert_eq!(
            (loose.regions.keep_fraction, ours.regions.keep_fraction),
            (0.7, 0.6)
        );
        // lpm-local-resets: our rules but for the reset's largest zone.
        let local = run_lpm_config("lpm-local-resets", &cfg, &plain.trade).unwrap();
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
