//! What a `bench trade` benchmark is asked to do: [`TradeSettings`], plain values that the
//! command line (or any other caller) fills in, and [`TradeSettings::record`], what of them
//! trade.json records for `bench merge`.

use crate::bench::budget::BenchBudget;
use crate::initial::InitSource;
use crate::lpm::config::PruneMode;
use crate::models::BaseModel;
use crate::scene::video::FrameRange;
use crate::scene::LoadOptions;
use crate::splats::budget_draw::Draw;
use crate::train::density::growth::Growth;
use crate::train::passes::world_culls::N3dvCulls;
use std::path::PathBuf;

/// One benchmark: the scene, the runs, their calendar and the settings every run shares. The
/// fields are `bench trade`'s flags of the same names (its `--help` says what each does); the
/// harness checks them itself ([`super::run`]), with messages that name those flags.
#[derive(Debug, Clone)]
pub struct TradeSettings {
    /// The scene folder.
    pub scene: PathBuf,
    /// How the scene is loaded (its resolution factor is also the table's `-r`).
    pub load_options: LoadOptions,
    /// The NeRF-synthetic test split as asked for (`None`: the scene's own choice), recorded in
    /// trade.json; `load_options` holds what it resolves to.
    pub test_split: Option<String>,
    /// The video segment as asked for (`None`: the default one), recorded in trade.json;
    /// `load_options` holds what it resolves to.
    pub frames: Option<FrameRange>,
    /// GPU memory for the training images, in MiB.
    pub image_cache_mib: f64,
    /// LPIPS weights; without them LPIPS is not reported. Loaded by the harness once the
    /// settings are checked, before the scene.
    pub lpips_weights: Option<PathBuf>,
    /// Iterations per run.
    pub iterations: u32,
    /// Base model of every run.
    pub model: BaseModel,
    /// The run length whose calendar is followed (`None`: `iterations`).
    pub calendar: Option<u32>,
    /// Iterations to evaluate at besides the last.
    pub eval_at: Vec<u32>,
    /// Initial points when the scene has no point cloud, and where they come from.
    pub init_points: usize,
    pub init: InitSource,
    /// Output folder for trade.json, trade.md, trade.png, trade.html and the models.
    pub out: PathBuf,
    /// The first seed, and how many: the runs use seeds `seed..seed + seeds`.
    pub seed: u64,
    pub seeds: u32,
    /// Frames timed for the FPS of each result.
    pub fps_frames: usize,
    /// The runs to compare, by name or alias ([`crate::bench::runs::RUNS`]; empty: the first
    /// five).
    pub runs: Vec<String>,
    /// One run after another instead of interleaved one iteration at a time.
    pub sequential: bool,
    /// LPM runs: the error blocks' side (0 follows the image size), the pruning (`None`: each
    /// rule set's own), the fraction of error pixels that keeps a block, the gradient-threshold
    /// multiplier inside zones (`None`: each rule set's own).
    pub lpm_block: u32,
    pub lpm_prune: Option<PruneMode>,
    pub lpm_block_fraction: f32,
    pub lpm_threshold_ratio: Option<f32>,
    /// Every run also densifies by the absolute-gradient test.
    pub densify_abs_grad: bool,
    /// A cap on every run's Gaussian count.
    pub max_gaussians: Option<usize>,
    /// The Gaussian budgets (several make a grid), how adc-exact* and mcmc grow to them, and
    /// how the mcmc runs that name no draw come down to one below their start.
    pub budget: Vec<BenchBudget>,
    pub budget_growth: Option<Growth>,
    pub budget_draw: Option<Draw>,
    /// LPM runs: a zone's candidate's score weight under a budget (`None`: the default).
    pub lpm_zone_weight: Option<f32>,
    /// The share of MCMC's dead Gaussians the `+lpm-surface` runs move onto surface samples
    /// (`None`: the default).
    pub lpm_surface_share: Option<f64>,
    /// Every run but adc follows adc's count at the same seed and iteration.
    pub match_adc_count: bool,
    /// spacetime-*: SpacetimeGaussians' Neural 3D Video culls.
    pub n3dv_culls: N3dvCulls,
    /// The test view trade.html shows (name, file stem or index; `None`: the first).
    pub report_view: Option<String>,
}

impl TradeSettings {
    /// How the mcmc runs that name no draw come down to a budget below their start
    /// (`--budget-draw`; by default kept whole, as `train --strategy mcmc`).
    pub fn mcmc_draw(&self) -> Draw {
        self.budget_draw.unwrap_or(Draw::Keep)
    }

    /// What changes the runs beyond the scene, model, resolution and calendar (trade.json's
    /// `settings`): `bench merge` pools only runs whose files agree here, and names the others
    /// by the difference. Settings whose name starts with `lpm_` change only the LPM runs.
    pub fn record(&self) -> serde_json::Value {
        serde_json::json!({
            "lpm_block": self.lpm_block,
            "lpm_block_fraction": self.lpm_block_fraction,
            "lpm_prune": self.lpm_prune.as_ref().map(PruneMode::name),
            "lpm_threshold_ratio": self.lpm_threshold_ratio,
            "densify_abs_grad": self.densify_abs_grad,
            "max_gaussians": self.max_gaussians,
            "match_adc_count": self.match_adc_count,
            "budget": BenchBudget::setting(&self.budget),
            "budget_growth": self.budget_growth.map(|g| g.name()),
            "budget_draw": (!self.budget.is_empty()).then(|| self.mcmc_draw().name()),
            "lpm_zone_weight": self.lpm_zone_weight,
            "lpm_surface_share": self.lpm_surface_share,
            "init": format!("{:?}", self.init).to_lowercase(),
            "init_points": self.init_points,
            "n3dv_culls": format!("{:?}", self.n3dv_culls).to_lowercase(),
            "test_split": self.test_split,
            "frames": self.frames.map(|f| serde_json::json!({"start": f.start, "count": f.count})),
        })
    }
}
