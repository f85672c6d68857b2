//! `trade.html`: the page a `bench trade` run leaves for people to look at: the plot, the
//! table, and for one test view the ground truth beside every run's final render and its error
//! map (so ADC and LPM are compared by eye, not only by numbers).

use super::summary::{Summary, TradeRow};
use crate::error::write_atomic;
use crate::plot::{captioned_grid, error_map, Tile};
use crate::scene::{images, Image, Scene};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// Error maps span 0 (dark) .. this mean absolute RGB error (bright); larger errors saturate.
pub const ERROR_MAP_MAX: f32 = 0.25;

/// The folder (inside the output folder) that holds the report's images.
pub const REPORT_DIR: &str = "report";

/// The test view the report shows: a view name, file stem or index into the test views;
/// default the first test view.
pub fn report_view(scene: &Scene, choice: Option<&str>) -> anyhow::Result<usize> {
    let Some(c) = choice else { return Ok(0) };
    if let Ok(k) = c.parse::<usize>() {
        anyhow::ensure!(
            k < scene.test.len(),
            "bench trade --report-view {k}: the scene has {} test views. Fix: pass 0..{}",
            scene.test.len(),
            scene.test.len().saturating_sub(1)
        );
        return Ok(k);
    }
    scene
        .test
        .iter()
        .position(|&v| scene.views[v].name == c || scene.views[v].stem == c)
        .ok_or_else(|| {
            let names: Vec<&str> = scene
                .test
                .iter()
                .map(|&v| scene.views[v].stem.as_str())
                .collect();
            anyhow::anyhow!(
                "bench trade --report-view {c:?}: no such test view. Fix: pass one of {} or an index",
                names.join(", ")
            )
        })
}

/// File stem of a run's images in the report folder (`adc+lpm` → `adc+lpm.png`,
/// `adc+lpm-error.png`).
fn run_stem(run: &str) -> String {
    run.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "+-_.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Saves the truth (once per call; it is the same for every run), the run's render and its
/// error map as PNGs in OUT/report/.
pub fn save_view_images(
    out: &Path,
    run: &str,
    render: &[f32],
    truth: &Image,
) -> anyhow::Result<()> {
    let dir = out.join(REPORT_DIR);
    std::fs::create_dir_all(&dir)?;
    images::save_png(&dir.join("truth.png"), truth)?;
    let (width, height) = (truth.width, truth.height);
    images::save_png(
        &dir.join(format!("{}.png", run_stem(run))),
        &Image {
            width,
            height,
            rgb: render.to_vec(),
            alpha: None,
        },
    )?;
    let err = error_map(render, &truth.rgb, ERROR_MAP_MAX);
    images::save_png(
        &dir.join(format!("{}-error.png", run_stem(run))),
        &Image {
            width,
            height,
            rgb: err.iter().map(|&b| b as f32 / 255.0).collect(),
            alpha: None,
        },
    )
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// What a trade.html shows beside its rows.
pub struct Page<'a> {
    pub title: &'a str,
    /// The run ΔPSNR and the time ratio are measured against.
    pub baseline: &'a str,
    /// The test view whose renders the rows carry (`bench trade`, which saved them in
    /// OUT/report/); None shows no renders (`bench merge`: they stay in its inputs' folders).
    pub view: Option<&'a str>,
    /// The pages the rows came from (`bench merge`'s inputs): (what to call it, link or None
    /// where the input has no trade.html).
    pub sources: &'a [(String, Option<String>)],
}

/// Writes OUT/trade.html from the rows so far.
pub fn write_html(
    out: &Path,
    page: &Page<'_>,
    rows: &[TradeRow],
    summary: &[Summary],
    table_md: &str,
) -> anyhow::Result<()> {
    let (title, baseline) = (page.title, page.baseline);
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>\
         body{{font-family:sans-serif;margin:24px;max-width:1400px}}\
         table{{border-collapse:collapse;font-size:14px}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}\
         th{{background:#f3f3f3}}td:first-child{{text-align:left}}\
         figure{{display:inline-block;margin:6px;vertical-align:top}}figcaption{{font-size:13px;text-align:center}}\
         figure img{{image-rendering:pixelated;border:1px solid #ddd}}\
         .bar{{display:inline-block;width:220px;height:12px;vertical-align:middle;\
         background:linear-gradient(to right,#440154,#3b528b,#21918c,#5ec962,#fde725)}}\
         </style></head><body>\n<h1>{t}</h1>\n",
        t = esc(title)
    );
    h.push_str("<h2>Trade-off</h2>\n<img src=\"trade.png\" alt=\"PSNR against Gaussians, training time and iterations, one line per run\">\n");
    if !page.sources.is_empty() {
        h.push_str("<h2>Merged from</h2>\n<ul>\n");
        for (name, link) in page.sources {
            let _ = match link {
                Some(l) => writeln!(h, "<li><a href=\"{}\">{}</a></li>", esc(l), esc(name)),
                None => writeln!(h, "<li>{} (no trade.html beside it)</li>", esc(name)),
            };
        }
        h.push_str("</ul>\n");
    }
    let _ = writeln!(
        h,
        "<h2>Runs (mean over seeds)</h2>\n<table><tr><th>run</th><th>iteration</th><th>seeds</th><th>PSNR (dB)</th><th>ΔPSNR vs {b}</th><th>SSIM</th><th>LPIPS</th><th>Gaussians</th><th>train s</th><th>time vs {b}</th><th>FPS 1352×1014</th></tr>",
        b = esc(baseline)
    );
    for s in summary {
        let [r, g, b] = s.colour;
        let _ = writeln!(
            h,
            "<tr><td><span style=\"color:rgb({r},{g},{b})\">■</span> {}</td><td>{}</td><td>{}</td><td>{:.3}{}</td><td>{}</td><td>{:.4}</td><td>{}</td><td>{:.0}</td><td>{:.1}</td><td>{}</td><td>{:.1}</td></tr>",
            esc(&s.run),
            s.iteration,
            s.seeds,
            s.psnr,
            if s.seeds > 1 { format!(" ± {:.3}", s.psnr_sd) } else { String::new() },
            s.delta_psnr.map_or("–".into(), |d| format!("{d:+.3}")),
            s.ssim,
            s.lpips.map_or("n/a".to_string(), |d| format!("{d:.4}")),
            s.gaussians,
            s.train_seconds,
            s.time_vs_adc.map_or("–".into(), |t| format!("{t:.3}×")),
            s.fps_1352x1014
        );
    }
    h.push_str("</table>\n");

    let shown: Vec<&TradeRow> = rows.iter().filter(|r| r.view_psnr.is_some()).collect();
    if let (Some(view_name), false) = (page.view, shown.is_empty()) {
        let _ = write!(
            h,
            "<h2>Test view {v}: final renders and errors</h2>\n<p>Top: the ground truth and each \
             run's render at its last iteration (first seed). Bottom: |render − truth| averaged \
             over RGB, 0 <span class=\"bar\"></span> ≥ {ERROR_MAP_MAX} (viridis).</p>\n<div>\n\
             <figure><img src=\"{REPORT_DIR}/truth.png\" alt=\"truth\"><figcaption>ground truth</figcaption></figure>\n",
            v = esc(view_name)
        );
        for r in &shown {
            let _ = writeln!(
                h,
                "<figure><img src=\"{REPORT_DIR}/{s}.png\" alt=\"{n}\"><figcaption>{n} @ {it}: {p:.2} dB</figcaption></figure>",
                s = esc(&run_stem(&r.run)),
                n = esc(&r.run),
                it = r.iteration,
                p = r.view_psnr.unwrap_or(f64::NAN)
            );
        }
        h.push_str("</div>\n<div>\n<figure style=\"visibility:hidden\"><img src=\"report/truth.png\" alt=\"\"></figure>\n");
        for r in &shown {
            let _ = writeln!(
                h,
                "<figure><img src=\"{REPORT_DIR}/{s}-error.png\" alt=\"{n} error\"><figcaption>{n}: error</figcaption></figure>",
                s = esc(&run_stem(&r.run)),
                n = esc(&r.run)
            );
        }
        h.push_str("</div>\n");
        write_side_by_side(out, &shown)?;
        let _ = writeln!(
            h,
            "<p>The same as one picture: <a href=\"{REPORT_DIR}/side_by_side.png\">{REPORT_DIR}/side_by_side.png</a>.</p>"
        );
    }
    let _ = write!(
        h,
        "<h2>Full table</h2>\n<pre>{}</pre>\n</body></html>\n",
        esc(table_md)
    );
    write_atomic(&out.join("trade.html"), |f| Ok(f.write_all(h.as_bytes())?))
}

/// OUT/report/side_by_side.png: the truth and each shown run's render (top row) above their
/// error maps (bottom row), captioned.
fn write_side_by_side(out: &Path, shown: &[&TradeRow]) -> anyhow::Result<()> {
    let dir = out.join(REPORT_DIR);
    let tile = |file: String, caption: String| -> anyhow::Result<Tile> {
        let img = images::decode_image(&dir.join(file))?;
        Ok(Tile {
            caption,
            width: img.width,
            height: img.height,
            rgb: img
                .rgb
                .iter()
                .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
                .collect(),
        })
    };
    let mut top = vec![tile("truth.png".into(), "ground truth".into())?];
    // The error maps' colour scale, left to right 0 .. ERROR_MAP_MAX, under the truth.
    let (bar_w, bar_h) = (top[0].width, 16u32);
    let ramp: Vec<f32> = (0..bar_h)
        .flat_map(|_| {
            (0..bar_w).flat_map(move |x| [ERROR_MAP_MAX * x as f32 / (bar_w.max(2) - 1) as f32; 3])
        })
        .collect();
    let mut bottom = vec![Tile {
        caption: format!("error 0 to {ERROR_MAP_MAX}"),
        width: bar_w,
        height: bar_h,
        rgb: error_map(&ramp, &vec![0.0; ramp.len()], ERROR_MAP_MAX),
    }];
    for r in shown {
        let stem = run_stem(&r.run);
        top.push(tile(
            format!("{stem}.png"),
            format!("{}: {:.2} dB", r.run, r.view_psnr.unwrap_or(f64::NAN)),
        )?);
        bottom.push(tile(
            format!("{stem}-error.png"),
            format!("{} error", r.run),
        )?);
    }
    let cols = top.len();
    top.extend(bottom);
    let png = captioned_grid(&top, cols)?;
    write_atomic(&dir.join("side_by_side.png"), |f| Ok(f.write_all(&png)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_names_make_safe_file_stems() {
        assert_eq!(run_stem("adc+lpm"), "adc+lpm");
        assert_eq!(run_stem("adc-threshold-1e-4"), "adc-threshold-1e-4");
        assert_eq!(run_stem("a b/c"), "a_b_c");
    }

    #[test]
    fn html_is_escaped() {
        assert_eq!(esc("<a & \"b\">"), "&lt;a &amp; &quot;b&quot;&gt;");
    }
}
