//! LPIPS in the evaluations' per-view metrics: every command that scores renders (`eval`,
//! `train`'s evaluations, the `bench trade` harness) fills a view's score in and averages them
//! the same way, with or without weights.

use super::Lpips;
use crate::scene::Image;
use crate::train::trainer::ViewMetrics;

/// Scores one view's render against its ground truth (already composited on the background
/// PSNR and SSIM used) into its metrics; nothing without weights.
pub fn score_view(
    lpips: Option<&Lpips>,
    metrics: &mut ViewMetrics,
    render: &[f32],
    truth: &Image,
) -> anyhow::Result<()> {
    if let Some(net) = lpips {
        metrics.lpips = Some(net.distance(
            render,
            &truth.rgb,
            truth.width as usize,
            truth.height as usize,
        )?);
    }
    Ok(())
}

/// The mean LPIPS of views scored by [`score_view`] (`None` when none was).
pub fn mean(metrics: &[ViewMetrics]) -> Option<f64> {
    let scored: Vec<f64> = metrics.iter().filter_map(|m| m.lpips).collect();
    (!scored.is_empty()).then(|| scored.iter().sum::<f64>() / scored.len() as f64)
}
