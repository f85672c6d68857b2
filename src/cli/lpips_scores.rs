//! LPIPS for the commands that score renders (`eval`, `train`'s evaluations, `bench trade`):
//! the weights flag they share, and filling each view's score in ([`lpmsplat::lpips::scores`],
//! re-exported here).

use clap::Args;
use lpmsplat::lpips::Lpips;
use std::path::PathBuf;

pub use lpmsplat::lpips::scores::{mean, score_view};

/// The flag, flattened into each command that scores renders.
#[derive(Args, Debug, Clone)]
pub struct LpipsArgs {
    /// LPIPS weights (AlexNet + the v0.1 linear heads, the LPM paper's metric) as a
    /// safetensors file; see docs/lpips.md for how to make it from the
    /// official ones. Without it LPIPS is not reported. Also read from LPMSPLAT_LPIPS_WEIGHTS.
    #[arg(long, env = "LPMSPLAT_LPIPS_WEIGHTS", value_name = "FILE")]
    pub lpips_weights: Option<PathBuf>,
}

impl LpipsArgs {
    /// Loads the network when a file was given, before any long work starts, so a wrong path
    /// or a malformed file stops the command at once with the loader's message.
    pub fn load(&self) -> anyhow::Result<Option<Lpips>> {
        self.lpips_weights.as_deref().map(Lpips::load).transpose()
    }
}

/// What the JSON and tables say when LPIPS was not computed.
pub const NOT_COMPUTED: &str = "LPIPS not computed: pass --lpips-weights FILE (see docs/lpips.md)";
