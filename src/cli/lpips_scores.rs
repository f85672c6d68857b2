//! LPIPS for the commands that score renders (`eval`, `train`'s evaluations, `bench trade`):
//! the weights flag they share, and filling each view's score in.

use clap::Args;
use lpmsplat::lpips::Lpips;
use lpmsplat::scene::{images, Image};
use lpmsplat::train::trainer::ViewMetrics;
use std::path::PathBuf;

/// The flag, flattened into each command that scores renders.
#[derive(Args, Debug, Clone)]
pub struct LpipsArgs {
    /// LPIPS weights (AlexNet + the v0.1 linear heads, the LPM paper's metric) as a
    /// safetensors file; see the README's "LPIPS weights" for how to make it from the
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
pub const NOT_COMPUTED: &str =
    "LPIPS not computed: pass --lpips-weights FILE (see the README's \"LPIPS weights\")";

/// Scores each view's render against its ground truth (composited on `background`, as PSNR and
/// SSIM are) and stores it in the view's metrics. Returns the mean, or `None` without weights.
pub fn score(
    lpips: Option<&Lpips>,
    metrics: &mut [ViewMetrics],
    renders: &[Vec<f32>],
    truths: &[Image],
    background: [f32; 3],
) -> anyhow::Result<Option<f64>> {
    let Some(net) = lpips else { return Ok(None) };
    let mut sum = 0.0;
    for ((m, render), truth) in metrics.iter_mut().zip(renders).zip(truths) {
        let gt = images::composite_on_background(truth, background);
        let d = net.distance(render, &gt.rgb, gt.width as usize, gt.height as usize)?;
        m.lpips = Some(d);
        sum += d;
    }
    Ok(Some(sum / metrics.len().max(1) as f64))
}
