//! `bench trade`'s summary: each variant at each evaluated iteration over its seeds (mean and
//! spread, paired with ADC seed by seed), the table printed and written to trade.md, and
//! trade.png (PSNR against Gaussian count and against training time).

use super::budget::{run_of, unguided};
use crate::plot::{panels_png, Panel, Series};

/// One run at one evaluated iteration: a row of trade.json's `runs` (read back by `bench merge`,
/// which is why the telemetry that older files lack defaults to zero or empty).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct TradeRow {
    pub run: String,
    pub seed: u64,
    pub iteration: u32,
    #[serde(default)]
    pub colour: [u8; 3],
    pub psnr: f64,
    pub ssim: f64,
    /// Mean LPIPS (AlexNet, v0.1) over the test views; `None` without --lpips-weights.
    pub lpips: Option<f64>,
    pub gaussians: usize,
    /// The run's Gaussian count averaged over iterations 1..=`iteration` (each counted after
    /// its density step): the model size it trained with, where `gaussians` is only where it
    /// ended. Two runs capped at one final count can differ here (the one that reaches the cap
    /// sooner trains larger); 0 in files written before this column (2026-11-29).
    #[serde(default)]
    pub mean_gaussians: f64,
    pub train_seconds: f64,
    #[serde(default)]
    pub ms_per_iteration: f64,
    #[serde(default)]
    pub lpm_ms_per_iteration: f64,
    #[serde(default)]
    pub lpm_share: f64,
    /// What LPM did up to this iteration (zeros for ADC runs): zones found, Gaussians densified
    /// only because of the lowered threshold, Gaussians added at zone centres, opacities reset.
    #[serde(default)]
    pub lpm_zones: f64,
    #[serde(default)]
    pub lpm_lowered: f64,
    #[serde(default)]
    pub lpm_added: f64,
    #[serde(default)]
    pub lpm_reset: f64,
    /// Extra (density-aware) prunes, and the zones' mean radius relative to the scene extent.
    #[serde(default)]
    pub lpm_pruned: f64,
    #[serde(default)]
    pub lpm_radius: f64,
    #[serde(default)]
    pub fps_1352x1014: f64,
    /// PSNR on the report's test view (final iteration, first seed only: the rows whose render
    /// trade.html shows).
    pub view_psnr: Option<f64>,
    /// What the base model's own rules did up to this iteration (SpacetimeGaussians' guided
    /// sampling: its choice and each sampling), as `train`'s `metrics.json` has them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub model_events: Vec<serde_json::Value>,
    /// LPM's steps up to this iteration, one object each as in `train`'s `metrics.json`
    /// (`lpm.per_step`): iteration, view, zones, radii, Gaussians inside, lowered
    /// densifications, extra prunes, resets, additions. Empty (and left out) for ADC runs.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub lpm_steps: Vec<serde_json::Value>,
    /// MCMC's totals up to this iteration (refinements, dead Gaussians relocated, of them moved
    /// onto LPM's surface samples, Gaussians added), as `train`'s `metrics.json` has them;
    /// absent for the other strategies.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mcmc: Option<serde_json::Value>,
    /// The process the row came from: 0 in `bench trade`; in `bench merge` the input file's
    /// index. Times are compared only between rows of one process (interleaved runs).
    #[serde(skip)]
    pub source: usize,
}

/// One variant at one iteration, over its seeds.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Summary {
    pub run: String,
    pub iteration: u32,
    pub colour: [u8; 3],
    pub seeds: usize,
    pub psnr: f64,
    /// Sample standard deviation over the seeds (0 with one seed).
    pub psnr_sd: f64,
    /// Mean over the seeds of (this run's PSNR − the baseline's PSNR with the same seed; the
    /// baseline is ADC, or `bench merge --baseline`); `None` when the baseline was not run.
    pub delta_psnr: Option<f64>,
    /// Standard error of that mean (sd / √pairs; `None` with fewer than two pairs).
    pub delta_psnr_se: Option<f64>,
    pub ssim: f64,
    pub ssim_sd: f64,
    /// Mean LPIPS (AlexNet, v0.1) over the test views; `None` without --lpips-weights.
    pub lpips: Option<f64>,
    pub gaussians: f64,
    /// Mean over the seeds of [`TradeRow::mean_gaussians`]; 0 when any row lacks it.
    pub mean_gaussians: f64,
    pub train_seconds: f64,
    /// Mean train seconds over the baseline's mean train seconds at the same iteration; `None`
    /// unless both ran interleaved in one process.
    pub time_vs_adc: Option<f64>,
    pub ms_per_iteration: f64,
    pub lpm_ms_per_iteration: f64,
    pub lpm_share: f64,
    pub lpm_zones: f64,
    pub lpm_lowered: f64,
    pub lpm_added: f64,
    pub lpm_reset: f64,
    /// Extra (density-aware) prunes, and the zones' mean radius relative to the scene extent.
    pub lpm_pruned: f64,
    pub lpm_radius: f64,
    pub fps_1352x1014: f64,
}

impl Summary {
    /// The means as a row (for the plot).
    pub fn as_row(&self) -> TradeRow {
        TradeRow {
            run: self.run.clone(),
            seed: 0,
            iteration: self.iteration,
            colour: self.colour,
            psnr: self.psnr,
            ssim: self.ssim,
            lpips: self.lpips,
            gaussians: self.gaussians.round() as usize,
            mean_gaussians: self.mean_gaussians,
            train_seconds: self.train_seconds,
            ms_per_iteration: self.ms_per_iteration,
            lpm_ms_per_iteration: self.lpm_ms_per_iteration,
            lpm_share: self.lpm_share,
            lpm_zones: self.lpm_zones,
            lpm_lowered: self.lpm_lowered,
            lpm_added: self.lpm_added,
            lpm_reset: self.lpm_reset,
            lpm_pruned: self.lpm_pruned,
            lpm_radius: self.lpm_radius,
            fps_1352x1014: self.fps_1352x1014,
            view_psnr: None,
            model_events: Vec::new(),
            lpm_steps: Vec::new(),
            mcmc: None,
            source: 0,
        }
    }
}

/// Mean and sample standard deviation (0 for fewer than two values).
fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    if v.len() < 2 {
        return (mean, 0.0);
    }
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// Groups `rows` by (run, iteration), in the rows' order of first appearance, each paired with
/// ADC seed by seed ([`summarize_against`] with `"adc"`).
pub fn summarize(rows: &[TradeRow]) -> Vec<Summary> {
    summarize_against(rows, "adc")
}

/// Groups `rows` by (run, iteration), in the rows' order of first appearance: means and spread
/// over the seeds, ΔPSNR paired with the `baseline` run of the same seed and iteration, and the
/// time ratio to the baseline only where the group and the baseline's rows all come from one
/// process ([`TradeRow::source`]), whose runs were interleaved.
pub fn summarize_against(rows: &[TradeRow], baseline: &str) -> Vec<Summary> {
    let mut keys: Vec<(&str, u32)> = Vec::new();
    for r in rows {
        if !keys.contains(&(r.run.as_str(), r.iteration)) {
            keys.push((r.run.as_str(), r.iteration));
        }
    }
    let group = |run: &str, it: u32| -> Vec<&TradeRow> {
        rows.iter()
            .filter(|r| r.run == run && r.iteration == it)
            .collect()
    };
    keys.iter()
        .map(|&(run, it)| {
            let g = group(run, it);
            let base = group(baseline, it);
            let col = |f: &dyn Fn(&TradeRow) -> f64| g.iter().map(|r| f(r)).collect::<Vec<_>>();
            let (psnr, psnr_sd) = mean_sd(&col(&|r| r.psnr));
            let (ssim, ssim_sd) = mean_sd(&col(&|r| r.ssim));
            // Paired differences: the baseline run with the same seed.
            let diffs: Vec<f64> = g
                .iter()
                .filter_map(|r| {
                    base.iter()
                        .find(|a| a.seed == r.seed)
                        .map(|a| r.psnr - a.psnr)
                })
                .collect();
            let (delta_psnr, delta_psnr_se) = if diffs.is_empty() {
                (None, None)
            } else {
                let (m, sd) = mean_sd(&diffs);
                (
                    Some(m),
                    (diffs.len() > 1).then(|| sd / (diffs.len() as f64).sqrt()),
                )
            };
            let train_seconds = mean_sd(&col(&|r| r.train_seconds)).0;
            let one_process = g.iter().chain(&base).all(|r| r.source == g[0].source);
            let time_vs_adc = (!base.is_empty() && one_process).then(|| {
                let a: Vec<f64> = base.iter().map(|r| r.train_seconds).collect();
                train_seconds / mean_sd(&a).0.max(1e-12)
            });
            Summary {
                run: run.to_string(),
                iteration: it,
                colour: g[0].colour,
                seeds: g.len(),
                psnr,
                psnr_sd,
                delta_psnr,
                delta_psnr_se,
                ssim,
                ssim_sd,
                lpips: g
                    .iter()
                    .map(|r| r.lpips)
                    .collect::<Option<Vec<f64>>>()
                    .map(|v| mean_sd(&v).0),
                gaussians: mean_sd(&col(&|r| r.gaussians as f64)).0,
                mean_gaussians: if g.iter().all(|r| r.mean_gaussians > 0.0) {
                    mean_sd(&col(&|r| r.mean_gaussians)).0
                } else {
                    0.0
                },
                train_seconds,
                time_vs_adc,
                ms_per_iteration: mean_sd(&col(&|r| r.ms_per_iteration)).0,
                lpm_ms_per_iteration: mean_sd(&col(&|r| r.lpm_ms_per_iteration)).0,
                lpm_share: mean_sd(&col(&|r| r.lpm_share)).0,
                lpm_zones: mean_sd(&col(&|r| r.lpm_zones)).0,
                lpm_lowered: mean_sd(&col(&|r| r.lpm_lowered)).0,
                lpm_added: mean_sd(&col(&|r| r.lpm_added)).0,
                lpm_reset: mean_sd(&col(&|r| r.lpm_reset)).0,
                lpm_pruned: mean_sd(&col(&|r| r.lpm_pruned)).0,
                lpm_radius: mean_sd(&col(&|r| r.lpm_radius)).0,
                fps_1352x1014: mean_sd(&col(&|r| r.fps_1352x1014)).0,
            }
        })
        .collect()
}

/// The table's head: its columns, the differences and the time ratio against `baseline`.
pub fn column_header(baseline: &str) -> String {
    format!(
        "| run | iteration | colour | PSNR | ΔPSNR vs {baseline} | SSIM | LPIPS | Gaussians (mean \
         over the run) | train s | time vs {baseline} | ms/it | LPM ms/it (share) | LPM zones · \
         densified · pruned · added · reset · zone radius / extent | FPS 1352×1014 |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
}

/// The table's rows, one per run and evaluated iteration (under [`column_header`]).
pub fn table_rows(rows: &[Summary]) -> String {
    let several = rows.iter().any(|r| r.seeds > 1);
    let mut s = String::new();
    for r in rows {
        let pm = |sd: f64, digits: usize| {
            if several {
                format!(" ± {sd:.digits$}")
            } else {
                String::new()
            }
        };
        let dpsnr = match (r.delta_psnr, r.delta_psnr_se) {
            (Some(d), Some(se)) => format!("{d:+.3} ± {se:.3}"),
            (Some(d), None) => format!("{d:+.3}"),
            _ => "n/a".into(),
        };
        let mean_count = if r.mean_gaussians > 0.0 {
            format!("{:.0}", r.mean_gaussians)
        } else {
            "n/a".to_string()
        };
        let dtime = r
            .time_vs_adc
            .map_or("n/a".to_string(), |t| format!("{t:.3}×"));
        let lpm_activity = if r.run.contains("lpm") {
            format!(
                "{:.0} · {:.0} · {:.0} · {:.0} · {:.0} · {:.3}",
                r.lpm_zones, r.lpm_lowered, r.lpm_pruned, r.lpm_added, r.lpm_reset, r.lpm_radius
            )
        } else {
            "—".to_string()
        };
        s += &format!(
            "| {} | {} | #{:02x}{:02x}{:02x} | {:.3}{} | {dpsnr} | {:.4}{} | {} | {:.0} ({mean_count}) | {:.1} | {dtime} | {:.2} | {:.3} ({:.2} %) | {} | {:.1} |\n",
            r.run,
            r.iteration,
            r.colour[0],
            r.colour[1],
            r.colour[2],
            r.psnr,
            pm(r.psnr_sd, 3),
            r.ssim,
            pm(r.ssim_sd, 4),
            r.lpips.map_or("n/a".to_string(), |d| format!("{d:.4}")),
            r.gaussians,
            r.train_seconds,
            r.ms_per_iteration,
            r.lpm_ms_per_iteration,
            100.0 * r.lpm_share,
            lpm_activity,
            r.fps_1352x1014
        );
    }
    s
}

/// Each run's per-seed ΔPSNR against the baseline, one line per run and iteration.
pub fn paired_table(rows: &[TradeRow], baseline: &str) -> String {
    let mut s = format!("| run | iteration | ΔPSNR vs {baseline}, seed by seed |\n|---|---|---|\n");
    let mut keys: Vec<(&str, u32)> = Vec::new();
    for r in rows {
        if r.run != baseline && !keys.contains(&(r.run.as_str(), r.iteration)) {
            keys.push((r.run.as_str(), r.iteration));
        }
    }
    for (run, it) in keys {
        let mut pairs: Vec<(u64, f64)> = rows
            .iter()
            .filter(|r| r.run == run && r.iteration == it)
            .filter_map(|r| {
                rows.iter()
                    .find(|b| b.run == baseline && b.iteration == it && b.seed == r.seed)
                    .map(|b| (r.seed, r.psnr - b.psnr))
            })
            .collect();
        pairs.sort_by_key(|p| p.0);
        let cells = if pairs.is_empty() {
            "no seed of the baseline".to_string()
        } else {
            pairs
                .iter()
                .map(|(seed, d)| format!("{seed}: {d:+.3}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        s += &format!("| {run} | {it} | {cells} |\n");
    }
    s
}

/// LPM as a guide at one count: every run with LPM against the same strategy without it at the
/// same budget (`mcmc+lpm-local@0.5x-adc` − `mcmc@0.5x-adc`), paired by seed, at each evaluated
/// iteration: the mean ± standard error of the PSNR and SSIM differences, and each seed's.
/// `None` when no run with LPM has its twin among the rows.
pub fn guide_table(rows: &[TradeRow]) -> Option<String> {
    let mut keys: Vec<(&str, u32, String)> = Vec::new();
    for r in rows {
        if let Some(twin) = unguided(&r.run) {
            let known = keys.iter().any(|k| k.0 == r.run && k.1 == r.iteration);
            if !known && rows.iter().any(|b| b.run == twin) {
                keys.push((r.run.as_str(), r.iteration, twin));
            }
        }
    }
    if keys.is_empty() {
        return None;
    }
    let mut s = String::from(
        "LPM as a guide at one count: each run with LPM against the same strategy without it \
         at the same budget, paired by seed (mean ± standard error over the pairs).\n\n\
         | run | against | iteration | ΔPSNR | ΔSSIM | pairs | ΔPSNR seed by seed |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for (run, it, twin) in keys {
        let mut pairs: Vec<(u64, f64, f64)> = rows
            .iter()
            .filter(|r| r.run == run && r.iteration == it)
            .filter_map(|r| {
                rows.iter()
                    .find(|b| b.run == twin && b.iteration == it && b.seed == r.seed)
                    .map(|b| (r.seed, r.psnr - b.psnr, r.ssim - b.ssim))
            })
            .collect();
        pairs.sort_by_key(|p| p.0);
        if pairs.is_empty() {
            continue;
        }
        let pm = |v: Vec<f64>, digits: usize| {
            let (m, sd) = mean_sd(&v);
            if v.len() > 1 {
                format!("{m:+.digits$} ± {:.digits$}", sd / (v.len() as f64).sqrt())
            } else {
                format!("{m:+.digits$}")
            }
        };
        let dpsnr = pm(pairs.iter().map(|p| p.1).collect(), 3);
        let dssim = pm(pairs.iter().map(|p| p.2).collect(), 4);
        let cells = pairs
            .iter()
            .map(|(seed, d, _)| format!("{seed}: {d:+.3}"))
            .collect::<Vec<_>>()
            .join(", ");
        s += &format!(
            "| {run} | {twin} | {it} | {dpsnr} | {dssim} | {} | {cells} |\n",
            pairs.len()
        );
    }
    Some(s)
}

/// A grid's quality against model size at the final evaluation: one line per run through its
/// budgets (`RUN@BUDGET` rows), in the run's colour, sorted by count; a row without a budget
/// (the free adc reference) is a point of its own.
fn budget_lines(rows: &[TradeRow]) -> Vec<Series> {
    let Some(last) = rows.iter().map(|r| r.iteration).max() else {
        return Vec::new();
    };
    let finals: Vec<&TradeRow> = rows.iter().filter(|r| r.iteration == last).collect();
    let mut names: Vec<&str> = Vec::new();
    for r in &finals {
        let n = if r.run.contains('@') {
            run_of(&r.run)
        } else {
            r.run.as_str()
        };
        if !names.contains(&n) {
            names.push(n);
        }
    }
    names
        .iter()
        .map(|&n| {
            let mut own: Vec<&&TradeRow> = finals
                .iter()
                .filter(|r| r.run == n || (r.run.contains('@') && run_of(&r.run) == n))
                .collect();
            own.sort_by_key(|r| r.gaussians);
            // The darkest of its cells' colours: the run's own (the grid lightens the others).
            let colour = own
                .iter()
                .map(|r| r.colour)
                .min_by_key(|c| c.iter().map(|&v| v as u32).sum::<u32>())
                .unwrap_or([0; 3]);
            Series {
                name: n.to_string(),
                colour,
                points: own.iter().map(|r| (r.gaussians as f64, r.psnr)).collect(),
                markers: true,
            }
        })
        .collect()
}

/// Four panels (2 × 2): PSNR against Gaussians and against training seconds (the trade-off),
/// then PSNR and Gaussians against iterations (the curves). One line per run through its
/// evaluated iterations, in the run's colour, named in the legend; a dot per evaluation. A grid
/// of budgets draws the first panel as one line per run through its budgets ([`budget_lines`]).
pub fn plot(rows: &[TradeRow]) -> anyhow::Result<Vec<u8>> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.run.as_str()) {
            names.push(&r.run);
        }
    }
    let series = |x: &dyn Fn(&TradeRow) -> f64, y: &dyn Fn(&TradeRow) -> f64| -> Vec<Series> {
        names
            .iter()
            .map(|&n| {
                let mut own: Vec<&TradeRow> = rows.iter().filter(|r| r.run == n).collect();
                own.sort_by_key(|r| r.iteration);
                Series {
                    name: n.to_string(),
                    colour: own[0].colour,
                    points: own.iter().map(|r| (x(r), y(r))).collect(),
                    markers: true,
                }
            })
            .collect()
    };
    let panel = |title: &str, x_label: &str, y_label: &str, series: Vec<Series>| Panel {
        title: title.into(),
        x_label: x_label.into(),
        y_label: y_label.into(),
        series,
    };
    let psnr = |r: &TradeRow| r.psnr;
    let gaussians = |r: &TradeRow| r.gaussians as f64;
    let seconds = |r: &TradeRow| r.train_seconds;
    let iteration = |r: &TradeRow| r.iteration as f64;
    let grid = rows.iter().any(|r| r.run.contains('@'));
    let panels = [
        if grid {
            panel(
                "PSNR against model size: one line per run through its budgets",
                "Gaussians (final iteration)",
                "test PSNR (dB)",
                budget_lines(rows),
            )
        } else {
            panel(
                "PSNR against model size",
                "Gaussians",
                "test PSNR (dB)",
                series(&gaussians, &psnr),
            )
        },
        panel(
            "PSNR against training time",
            "training seconds",
            "test PSNR (dB)",
            series(&seconds, &psnr),
        ),
        panel(
            "PSNR over training",
            "iteration",
            "test PSNR (dB)",
            series(&iteration, &psnr),
        ),
        panel(
            "Gaussians over training",
            "iteration",
            "Gaussians",
            series(&iteration, &gaussians),
        ),
    ];
    panels_png(&panels, 2, 520, 340)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each test run's colour in the plot.
    const COLOURS: [(&str, [u8; 3]); 3] = [
        ("adc", [31, 119, 180]),
        ("adc+lpm", [214, 39, 40]),
        ("lpm-no-add", [44, 160, 44]),
    ];

    fn row(run: &str, iteration: u32, psnr: f64, gaussians: usize, secs: f64) -> TradeRow {
        let colour = COLOURS.iter().find(|r| r.0 == run).unwrap().1;
        TradeRow {
            run: run.into(),
            seed: 0,
            iteration,
            colour,
            psnr,
            ssim: 0.9,
            lpips: None,
            gaussians,
            mean_gaussians: 0.8 * gaussians as f64,
            train_seconds: secs,
            ms_per_iteration: 1.0,
            lpm_ms_per_iteration: 0.0,
            lpm_share: 0.0,
            lpm_zones: 0.0,
            lpm_lowered: 0.0,
            lpm_added: 0.0,
            lpm_reset: 0.0,
            lpm_pruned: 0.0,
            lpm_radius: 0.0,
            fps_1352x1014: 1.0,
            view_psnr: None,
            model_events: Vec::new(),
            lpm_steps: Vec::new(),
            mcmc: None,
            source: 0,
        }
    }

    #[test]
    fn plot_draws_each_run_in_its_colour() {
        let rows = [
            row("adc", 1000, 33.937, 44_467, 487.7),
            row("adc+lpm", 1000, 34.398, 45_529, 482.7),
            row("adc", 2000, 35.597, 119_237, 1804.3),
            row("adc+lpm", 2000, 35.632, 119_566, 1779.6),
        ];
        let png = plot(&rows).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!((img.width(), img.height()), (1040, 680));
        let count = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
        // Two dots (~50 px each) per panel, four panels, plus the lines and the legend swatch.
        for (name, colour) in [COLOURS[0], COLOURS[1]] {
            assert!(count(colour) >= 4 * 2 * 40, "{name}: {}", count(colour));
        }
        // A run without a finite PSNR draws nothing in the PSNR panels, only in the Gaussians
        // one (bottom right).
        let mut bad = rows.to_vec();
        bad.push(row("lpm-no-add", 2000, f64::NAN, 10, 1.0));
        let img = image::load_from_memory(&plot(&bad).unwrap())
            .unwrap()
            .to_rgb8();
        let in_psnr_panels = img
            .enumerate_pixels()
            .filter(|(x, y, p)| (*y < 340 || *x < 520) && p.0 == COLOURS[2].1)
            .count();
        assert_eq!(in_psnr_panels, 0);
        if let Ok(dir) = std::env::var("LPMSPLAT_KEEP_PLOT") {
            std::fs::write(std::path::Path::new(&dir).join("trade_plot.png"), &png).unwrap();
        }
    }

    #[test]
    fn summary_pairs_each_seed_with_adc() {
        let mut rows = vec![];
        for (seed, adc, lpm) in [(0, 30.0, 30.5), (1, 31.0, 31.3), (2, 29.0, 29.7)] {
            let mut a = row("adc", 100, adc, 1000 + seed as usize, 10.0);
            a.seed = seed;
            let mut l = row("adc+lpm", 100, lpm, 1100, 11.0);
            l.seed = seed;
            rows.push(a);
            rows.push(l);
        }
        let mut lone = row("lpm-no-add", 100, 28.0, 900, 12.0);
        lone.seed = 7;
        rows.push(lone);
        let s = summarize(&rows);
        assert_eq!(s.len(), 3);
        let (adc, lpm, lone) = (&s[0], &s[1], &s[2]);
        assert_eq!((adc.run.as_str(), adc.seeds), ("adc", 3));
        assert!((adc.psnr - 30.0).abs() < 1e-12);
        assert!((adc.psnr_sd - 1.0).abs() < 1e-12);
        assert!((adc.gaussians - 1001.0).abs() < 1e-12);
        assert_eq!(adc.delta_psnr, Some(0.0));
        // Differences 0.5, 0.3, 0.7: mean 0.5, sd 0.2, se 0.2/√3.
        assert!((lpm.delta_psnr.unwrap() - 0.5).abs() < 1e-9);
        assert!((lpm.delta_psnr_se.unwrap() - 0.2 / 3f64.sqrt()).abs() < 1e-9);
        assert!((lpm.time_vs_adc.unwrap() - 1.1).abs() < 1e-12);
        // No ADC run with its seed: no difference to report.
        assert_eq!((lone.delta_psnr, lone.delta_psnr_se), (None, None));
        assert_eq!(lone.psnr_sd, 0.0);
    }
}
