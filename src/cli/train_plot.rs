//! `training.png`: what a training run did, as curves: test PSNR, Gaussian count and training
//! loss, each against iterations (left) and training time (right).

use lpmsplat::plot::{write_panels_png, Panel, Series, PALETTE};
use std::path::Path;

/// One sample of the run, taken every few iterations.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Sample {
    pub iteration: u32,
    /// Seconds of training so far, evaluations and checkpoints excluded.
    pub seconds: f64,
    /// The loss, smoothed (exponential moving average, weight 0.1 per iteration).
    pub loss: f64,
    pub gaussians: usize,
}

/// One evaluation on the test views.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct EvalPoint {
    pub iteration: u32,
    pub seconds: f64,
    pub psnr: f64,
    pub gaussians: usize,
}

/// Writes the six panels (3 rows × 2 columns) to `path`.
pub fn write_training_plot(
    path: &Path,
    run_name: &str,
    samples: &[Sample],
    evals: &[EvalPoint],
) -> anyhow::Result<()> {
    let axes = [
        ("iteration", false),
        ("training time (s, evaluations excluded)", true),
    ];
    let one = |title: &str, y: &str, name: &str, colour, markers, pts: Vec<(f64, f64)>| Panel {
        title: title.to_string(),
        x_label: String::new(),
        y_label: y.to_string(),
        series: vec![Series {
            name: name.to_string(),
            colour,
            points: pts,
            markers,
        }],
    };
    let mut panels = Vec::new();
    for (what, quantity) in [
        ("test PSNR", "PSNR (dB)"),
        ("Gaussians", "Gaussians"),
        ("loss", "loss (EMA)"),
    ] {
        for (x_label, by_time) in axes {
            let x = |it: u32, s: f64| if by_time { s } else { it as f64 };
            let mut p = match what {
                "test PSNR" => one(
                    &format!("{run_name}: test PSNR"),
                    quantity,
                    "test views",
                    PALETTE[0],
                    true,
                    evals
                        .iter()
                        .map(|e| (x(e.iteration, e.seconds), e.psnr))
                        .collect(),
                ),
                "Gaussians" => one(
                    &format!("{run_name}: Gaussians"),
                    quantity,
                    "",
                    PALETTE[2],
                    false,
                    samples
                        .iter()
                        .map(|s| (x(s.iteration, s.seconds), s.gaussians as f64))
                        .collect(),
                ),
                _ => one(
                    &format!("{run_name}: training loss"),
                    quantity,
                    "",
                    PALETTE[3],
                    false,
                    samples
                        .iter()
                        .map(|s| (x(s.iteration, s.seconds), s.loss))
                        .collect(),
                ),
            };
            p.x_label = x_label.to_string();
            panels.push(p);
        }
    }
    write_panels_png(path, &panels, 2, 520, 300)
}
