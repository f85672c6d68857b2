//! What a benchmark writes: the tables (trade.md, also printed), trade.json, trade.png and
//! trade.html, rewritten after every evaluation so that an interrupted benchmark keeps the rows
//! it reached.

use super::TradeSettings;
use crate::bench::budget::BenchBudget;
use crate::bench::report;
use crate::bench::summary::{
    column_header, guide_table, paired_table, plot, summarize, table_rows, Summary, TradeRow,
};
use crate::error::write_atomic;
use crate::lpm::regions::RegionSettings;
use crate::scene::Scene;
use std::io::Write;

/// What the tables say about the setting besides the arguments: the device and the LPM error
/// blocks' side in pixels over the training views (the automatic size follows each image's).
pub struct RunFacts {
    pub device: String,
    pub lpm_blocks: (u32, u32),
}

impl RunFacts {
    pub fn new(device: &str, scene: &Scene, lpm_block: u32) -> RunFacts {
        let settings = RegionSettings {
            block: lpm_block,
            ..RegionSettings::default()
        };
        let sides = scene.train.iter().map(|&v| {
            let c = &scene.views[v].camera;
            settings.resolved(c.width, c.height).block
        });
        let lpm_blocks = match sides.fold((u32::MAX, 0), |(lo, hi), b| (lo.min(b), hi.max(b))) {
            (lo, hi) if lo > hi => (lpm_block, lpm_block), // no training view
            range => range,
        };
        RunFacts {
            device: device.to_string(),
            lpm_blocks,
        }
    }

    /// "12 px", or "10–12 px" where the training images differ in size.
    pub fn blocks_px(&self) -> String {
        match self.lpm_blocks {
            (lo, hi) if lo == hi => format!("{lo} px"),
            (lo, hi) => format!("{lo}–{hi} px"),
        }
    }
}

/// The table: what was run, how to read it, and the rows ([`table_rows`]).
pub fn table(rows: &[Summary], facts: &RunFacts, settings: &TradeSettings) -> String {
    let device = &facts.device;
    let resolution = settings
        .load_options
        .resolution_factor
        .map_or("full resolution".to_string(), |r| format!("-r {r}"));
    let several = rows.iter().any(|r| r.seeds > 1);
    let s = format!(
        "bench trade: {} {resolution}, base model {}, {} iterations on the calendar of {}, {device}; LPM \
         error blocks of {} kept above {} error pixels{}\n\n{} \
         trade.png plots test PSNR against Gaussians and training seconds (top), and PSNR and \
         Gaussians against iterations (bottom), one named line per run through its evaluated \
         iterations; trade.html shows the plot, this table and the runs' renders. LPIPS is \
         AlexNet v0.1 (n/a without --lpips-weights).{}{}\n\n",
        settings.scene.display(),
        settings.model.name(),
        settings.iterations,
        settings.calendar.unwrap_or(settings.iterations),
        if settings.lpm_block == 0 {
            format!(
                "the image's size ({} here: 16 px at 1 MP, scaled with the diagonal, at least 4)",
                facts.blocks_px()
            )
        } else {
            format!("{} px", settings.lpm_block)
        },
        settings.lpm_block_fraction,
        settings.lpm_threshold_ratio
            .map_or(String::new(), |r| format!(", gradient threshold × {r} inside zones")),
        if settings.sequential {
            "Runs were sequential: compare their times only on an otherwise idle machine."
        } else {
            "Runs were interleaved one iteration at a time, so their times saw the same machine load."
        },
        budget_sentence(settings),
        if several {
            format!(
                " Each row is the mean over {} seeds ({}..{}): PSNR and SSIM ± their standard \
                 deviation, ΔPSNR ± the standard error of the per-seed differences from ADC, \
                 the rest means; the plot shows the means.",
                settings.seeds,
                settings.seed,
                settings.seed + settings.seeds as u64 - 1
            )
        } else {
            String::new()
        }
    );
    s + &column_header("adc") + &table_rows(rows)
}

/// What the table header says of the Gaussian budget, if the runs had one.
fn budget_sentence(settings: &TradeSettings) -> String {
    let follow = "Every run but adc trained under a budget of adc's count at the same seed and \
                  iteration";
    let grid = if settings.budget.len() > 1
        || settings
            .budget
            .iter()
            .any(|b| matches!(b, BenchBudget::TimesAdc(_)))
    {
        format!(
            " Every run trained at each budget ({}; RUN@BUDGET), x-adc of the final count of a \
             free adc of the same seed, trained first (the rows named adc): adc-exact* and mcmc \
             fill the budget exactly, the others are capped at it.",
            settings
                .budget
                .iter()
                .map(BenchBudget::label)
                .collect::<Vec<_>>()
                .join(", ")
        )
    } else {
        String::new()
    };
    let cap = match (settings.match_adc_count, settings.max_gaussians) {
        (true, None) => format!(" {follow} (--match-adc-count)."),
        (true, Some(n)) => format!(" {follow}, at most {n} Gaussians (--match-adc-count)."),
        (false, Some(n)) => format!(" Every run trained under a budget of at most {n} Gaussians."),
        (false, None) => String::new(),
    };
    cap + &grid
}

/// [`table`] of the rows' summary, and with several seeds each run's per-seed differences from
/// ADC ([`paired_table`]).
pub fn tables(rows: &[TradeRow], facts: &RunFacts, settings: &TradeSettings) -> String {
    let mut s = table(&summarize(rows), facts, settings);
    if settings.seeds > 1 && rows.iter().any(|r| r.run == "adc") {
        s += "\n";
        s += &paired_table(rows, "adc");
    }
    if let Some(g) = guide_table(rows) {
        s += "\n";
        s += &g;
    }
    s
}

/// Writes trade.md, trade.json and trade.png for the rows so far (atomically).
pub fn write_outputs(
    rows: &[TradeRow],
    facts: &RunFacts,
    view_name: &str,
    settings: &TradeSettings,
) -> anyhow::Result<()> {
    let summary = summarize(rows);
    let table = tables(rows, facts, settings);
    write_atomic(&settings.out.join("trade.md"), |f| {
        Ok(f.write_all(table.as_bytes())?)
    })?;
    let json = serde_json::json!({
        "scene": settings.scene.display().to_string(),
        "model": settings.model.name(),
        "resolution": settings.load_options.resolution_factor,
        "iterations": settings.iterations,
        "calendar": settings.calendar.unwrap_or(settings.iterations),
        "interleaved": !settings.sequential,
        "device": facts.device,
        "seeds": settings.seeds,
        "lpm_block": settings.lpm_block,
        // The block sides the LPM runs used over the training views: [smallest, largest].
        "lpm_block_px": [facts.lpm_blocks.0, facts.lpm_blocks.1],
        "lpm_block_fraction": settings.lpm_block_fraction,
        "settings": settings.record(),
        "summary": summary,
        "runs": rows,
    });
    let text = serde_json::to_string_pretty(&json)?;
    write_atomic(&settings.out.join("trade.json"), |f| {
        Ok(f.write_all(text.as_bytes())?)
    })?;
    let png = plot(&summary.iter().map(Summary::as_row).collect::<Vec<_>>())?;
    write_atomic(&settings.out.join("trade.png"), |f| Ok(f.write_all(&png)?))?;
    let title = format!(
        "bench trade: {}, {}, {} iterations",
        settings.scene.display(),
        settings.model.name(),
        settings.iterations
    );
    let page = report::Page {
        title: &title,
        baseline: "adc",
        view: Some(view_name),
        sources: &[],
    };
    report::write_html(&settings.out, &page, rows, &summary, &table)?;
    Ok(())
}
