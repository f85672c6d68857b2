//! `bench trade`'s command line: the scene, the runs, their calendar and the settings every
//! run shares, and [`TradeArgs::settings`], the harness's settings they make.

use crate::cli::lpips_scores::LpipsArgs;
use crate::cli::SceneArgs;
use clap::Args;
use lpmsplat::bench::trade::TradeSettings;
use lpmsplat::lpm::config::PruneMode;
use lpmsplat::models::BaseModel;
use lpmsplat::train::passes::world_culls::N3dvCulls;
use std::path::PathBuf;

fn parse_prune(s: &str) -> anyhow::Result<PruneMode> {
    PruneMode::parse(s)
}

#[derive(Args, Debug)]
pub struct TradeArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// `--slurm`: the seeds as a Slurm job array, one task a seed, and `bench merge` after it.
    #[command(flatten)]
    pub slurm: crate::cli::slurm_args::SlurmArgs,
    #[command(flatten)]
    pub images: crate::cli::image_cache_args::ImageCacheArgs,
    /// Iterations per run.
    #[arg(long, default_value_t = 30_000)]
    pub iterations: u32,
    /// Base model of every run (3dgs, pixel-gs, mip-splatting, 2dgs; spacetime-lite or
    /// spacetime-full on a video scene): the table compares ADC and LPM on it.
    #[arg(long, default_value = "3dgs", value_parser = BaseModel::parse)]
    pub model: BaseModel,
    /// The run length whose calendar is followed: the reference's density / LPM calendar
    /// (densify 500..15000, resets every 3000, position learning-rate decay over 30000; 2dgs's
    /// normal and distortion regularisers from 7000 and 3000) is scaled by CALENDAR / 30000. Default: --iterations (a complete, compressed schedule);
    /// `--calendar 30000 --iterations 7000` is the reference schedule stopped at 7k.
    #[arg(long)]
    pub calendar: Option<u32>,
    /// Also evaluate every run at these iterations (comma separated); the final iteration is
    /// always evaluated. trade.json / trade.md / trade.png are rewritten after each, so an
    /// interrupted benchmark keeps the rows it reached.
    #[arg(long, value_delimiter = ',')]
    pub eval_at: Vec<u32>,
    /// Initial points when the scene has no point cloud (video scenes, transforms.json without
    /// points).
    #[arg(long, default_value_t = 100_000)]
    pub init_points: usize,
    /// Where they come from: auto (triangulate video scenes), random (even where the scene has
    /// SfM points) or triangulate (as `train --init`).
    #[arg(long, value_enum, default_value_t = lpmsplat::initial::InitSource::Auto)]
    pub init: lpmsplat::initial::InitSource,
    /// Output folder for trade.json, trade.md and trade.png.
    #[arg(long, short = 'o', default_value = "bench_trade")]
    pub out: PathBuf,
    /// The first seed; with --seeds K the runs use seeds SEED to SEED+K−1.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Train every variant with K seeds (initialisation where it is random, view order,
    /// split samples, LPM's neighbour picks) and report mean ± standard deviation, and the gain
    /// over ADC as the mean ± standard error of the per-seed differences (ADC and the variant
    /// share each seed). Run-to-run spread on scenes with few test views is several tenths of a
    /// dB, so a single seed cannot separate effects that small.
    #[arg(long, default_value_t = 1)]
    pub seeds: u32,
    /// Frames timed for the FPS of each result (1352×1014).
    #[arg(long, default_value_t = 20)]
    pub fps_frames: usize,
    /// The runs to compare, comma separated (the list and what each run is: --help).
    #[arg(long, value_delimiter = ',', long_help = lpmsplat::bench::runs::runs_help())]
    pub runs: Vec<String>,
    /// Run the variants one after another instead of interleaving their iterations. Interleaving
    /// (the default) keeps every run's time measured under the same machine load, so the time
    /// ratios hold on a noisy machine; sequential needs the memory of one run only.
    #[arg(long)]
    pub sequential: bool,
    /// LPM runs: error-region block side in pixels (as `train --lpm-block`; 0 follows the
    /// image size).
    #[arg(long, default_value_t = 0)]
    pub lpm_block: u32,
    /// LPM runs: density-aware pruning (as `train --lpm-prune`; default: each rule set's own).
    #[arg(long, value_parser = parse_prune)]
    pub lpm_prune: Option<PruneMode>,
    /// LPM runs: fraction of error pixels that keeps a block (as `train --lpm-block-fraction`).
    #[arg(long, default_value_t = 0.85)]
    pub lpm_block_fraction: f32,
    /// LPM runs: gradient-threshold multiplier inside zones (as `train --lpm-threshold-ratio`;
    /// default: each rule set's own, 0.5). 1 keeps ADC's threshold in the zones, so that LPM
    /// acts only by its opacity resets, extra prunes and added points: which of its rules
    /// costs or gains what.
    #[arg(long, value_name = "R")]
    pub lpm_threshold_ratio: Option<f32>,
    /// Every run also densifies by the absolute-gradient test (as `train --densify-abs-grad`:
    /// Mip-Splatting's official densification).
    #[arg(long)]
    pub densify_abs_grad: bool,
    /// Every run trains under the same cap on the number of Gaussians (as `train
    /// --max-gaussians`): at the cap the runs compare at one count.
    #[arg(long, value_name = "N", value_parser = lpmsplat::train::density::growth::Budget::parse_count)]
    pub max_gaussians: Option<usize>,
    /// The Gaussian budget: a count (500k, 2.5M), a multiple of the initial model's (3x), or a
    /// multiple of ADC's own final count at the same seed (0.5x-adc). adc-exact* and mcmc end
    /// densification exactly there (their curves: --budget-growth); every other run trains
    /// under it as a cap (ADC at the budget). Several, comma separated, make a grid in one
    /// command: every run at every budget, its rows named RUN@BUDGET, one line per run through
    /// its budgets in trade.png. Budgets relative to ADC (the Taming protocol's 0.25x-adc,
    /// 0.5x-adc, 1x-adc) first train a free adc per seed, the reference, then the grid
    /// interleaved; adc in --runs then means ADC capped at each budget (not at 1x-adc, the
    /// reference itself).
    #[arg(long, value_name = "N", value_delimiter = ',', value_parser = lpmsplat::bench::budget::parse_bench_budget)]
    pub budget: Vec<lpmsplat::bench::budget::BenchBudget>,
    /// How adc-exact* and mcmc grow to the budget: taming (adc-exact's default), linear, mcmc
    /// (5 % a step; mcmc's default).
    #[arg(long, value_name = "CURVE", value_parser = lpmsplat::train::density::growth::Growth::parse)]
    pub budget_growth: Option<lpmsplat::train::density::growth::Growth>,
    /// How the mcmc runs not named for a draw (mcmc, mcmc+lpm*, mcmc-start, mcmc-opaque) come
    /// down to a budget below the start: keep (the default, as `train --strategy mcmc`),
    /// random or spread (`train --budget-draw`). The adc runs always draw at random;
    /// mcmc-drawn, mcmc-refit, mcmc-spread and mcmc-keep name their own. Until keep became
    /// the default every mcmc run drew at random: `--budget-draw random` repeats those figures.
    #[arg(long, value_enum, value_name = "DRAW")]
    pub budget_draw: Option<lpmsplat::splats::budget_draw::Draw>,
    /// LPM runs: a zone's candidate's score weight under a budget (as `train
    /// --lpm-zone-weight`; default 1.5).
    #[arg(long, value_name = "W")]
    pub lpm_zone_weight: Option<f32>,
    /// The share of MCMC's dead Gaussians the `+lpm-surface` runs move onto surface samples
    /// (`train --lpm-surface-share`; default 0.5).
    #[arg(long, value_name = "SHARE")]
    pub lpm_surface_share: Option<f64>,
    /// Every run but adc trains under a Gaussian budget that follows adc's count at the same
    /// seed and iteration (at most --max-gaussians too), so the runs compare at adc's count at
    /// every evaluation without knowing it beforehand. Needs adc in --runs.
    #[arg(long)]
    pub match_adc_count: bool,
    /// spacetime-*: SpacetimeGaussians' Neural 3D Video culls (as `train --n3dv-culls`; their
    /// 1000-iteration rhythm scaled to the calendar).
    #[arg(long, value_enum, default_value_t = N3dvCulls::Auto)]
    pub n3dv_culls: N3dvCulls,
    /// The test view trade.html shows (name, file stem or index into the test views; default
    /// the first): the truth beside each run's final render and error map.
    #[arg(long)]
    pub report_view: Option<String>,
    #[command(flatten)]
    pub lpips: LpipsArgs,
}

impl TradeArgs {
    /// The harness's settings: the flags as they are, the scene's resolved into its load
    /// options (which refuses `-r 0`).
    pub fn settings(&self) -> anyhow::Result<TradeSettings> {
        Ok(TradeSettings {
            scene: self.scene.scene.clone(),
            load_options: self.scene.load_options()?,
            test_split: self.scene.test_split.clone(),
            frames: self.scene.frames,
            image_cache_mib: self.images.image_cache,
            lpips_weights: self.lpips.lpips_weights.clone(),
            iterations: self.iterations,
            model: self.model,
            calendar: self.calendar,
            eval_at: self.eval_at.clone(),
            init_points: self.init_points,
            init: self.init,
            out: self.out.clone(),
            seed: self.seed,
            seeds: self.seeds,
            fps_frames: self.fps_frames,
            runs: self.runs.clone(),
            sequential: self.sequential,
            lpm_block: self.lpm_block,
            lpm_prune: self.lpm_prune,
            lpm_block_fraction: self.lpm_block_fraction,
            lpm_threshold_ratio: self.lpm_threshold_ratio,
            densify_abs_grad: self.densify_abs_grad,
            max_gaussians: self.max_gaussians,
            budget: self.budget.clone(),
            budget_growth: self.budget_growth,
            budget_draw: self.budget_draw,
            lpm_zone_weight: self.lpm_zone_weight,
            lpm_surface_share: self.lpm_surface_share,
            match_adc_count: self.match_adc_count,
            n3dv_culls: self.n3dv_culls,
            report_view: self.report_view.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        trade: TradeArgs,
    }

    #[test]
    fn the_trade_flags_become_the_harness_settings_as_given() {
        let args = Cli::parse_from([
            "bench",
            "scene",
            "-r",
            "4",
            "--iterations",
            "3000",
            "--max-gaussians",
            "9",
            "--lpm-block",
            "6",
            "--lpm-prune",
            "off",
            "--runs",
            "adc,lpm",
            "--budget",
            "1x,0.5x-adc",
            "--image-cache",
            "512",
            "-o",
            "elsewhere",
        ]);
        let s = args.trade.settings().unwrap();
        assert_eq!(s.scene, PathBuf::from("scene"));
        assert_eq!(s.load_options.resolution_factor, Some(4));
        assert_eq!((s.test_split.as_deref(), s.frames), (None, None));
        assert_eq!((s.iterations, s.max_gaussians), (3000, Some(9)));
        assert_eq!((s.lpm_block, s.lpm_prune), (6, Some(PruneMode::Off)));
        assert_eq!(s.runs, ["adc", "lpm"]);
        assert_eq!(s.budget, args.trade.budget);
        assert_eq!(s.image_cache_mib, 512.0);
        assert_eq!(s.out, PathBuf::from("elsewhere"));
        // With a budget trade.json records how the mcmc runs come down to it: kept whole unless
        // --budget-draw says otherwise.
        assert_eq!(s.record()["budget_draw"], "keep");
        // -r 0 is refused as every command that loads a scene refuses it.
        let zero = Cli::parse_from(["bench", "scene", "-r", "0"]);
        assert!(zero.trade.settings().is_err());
    }
}
