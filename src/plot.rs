//! Line charts as PNG files, drawn with `plotters`: the training curves of `train`
//! (`training.png`) and the trade-off plots of `bench trade` (`trade.png`).
//!
//! Text uses a subset of DejaVu Sans embedded in the binary (`assets/fonts`, Bitstream Vera
//! licence), so plots need no system fonts, fontconfig or freetype.

use anyhow::{anyhow, Context};
use plotters::prelude::*;
use std::path::Path;

use crate::error::write_atomic;

static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans-subset.ttf");
const FAMILY: &str = "sans-serif";

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and parsed at first use; a failure is a build defect.
        plotters::style::register_font(FAMILY, FontStyle::Normal, FONT)
            .unwrap_or_else(|_| panic!("the embedded plot font does not parse"));
    });
}

/// One named line (with optional point markers) in one colour.
#[derive(Debug, Clone)]
pub struct Series {
    pub name: String,
    pub colour: [u8; 3],
    pub points: Vec<(f64, f64)>,
    /// Draw a dot at every point (for sparse evaluations).
    pub markers: bool,
}

/// One chart: a title, axis titles, and its series (the legend lists every named series).
#[derive(Debug, Clone)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
}

/// Colours that stay apart for up to ten series (Tableau 10).
pub const PALETTE: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// The range of the finite values, widened by 5 % each side (or by ±1 / ±5 % of the value when
/// all are equal), so a single point or a flat line is still drawn inside the frame.
fn padded_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return None;
    }
    let span = hi - lo;
    let pad = if span > 0.0 {
        0.05 * span
    } else if lo != 0.0 {
        0.05 * lo.abs()
    } else {
        1.0
    };
    Some((lo - pad, hi + pad))
}

/// Axis tick labels for an axis spanning `lo..hi` with about six ticks: thousands as "k" and
/// millions as "M", and as many decimals as the tick step needs (no more).
fn tick_label(v: f64, lo: f64, hi: f64) -> String {
    let top = lo.abs().max(hi.abs());
    let (scale, unit) = if top >= 1e6 {
        (1e6, "M")
    } else if top >= 1e4 {
        (1e3, "k")
    } else {
        (1.0, "")
    };
    let step = ((hi - lo) / 6.0 / scale).abs();
    let decimals = if step > 0.0 && step.is_finite() {
        (-step.log10().floor()).clamp(0.0, 6.0) as usize
    } else {
        0
    };
    format!("{:.*}{unit}", decimals, v / scale)
}

/// Draws `panels` on a grid of `cols` columns, each panel `panel_w` × `panel_h` pixels, and
/// returns the PNG bytes. Non-finite points are left out; a panel with no finite point says so.
pub fn panels_png(
    panels: &[Panel],
    cols: usize,
    panel_w: u32,
    panel_h: u32,
) -> anyhow::Result<Vec<u8>> {
    anyhow::ensure!(!panels.is_empty() && cols > 0, "a plot needs a panel");
    register_font();
    let rows = panels.len().div_ceil(cols);
    let (w, h) = (panel_w * cols as u32, panel_h * rows as u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| anyhow!("drawing a plot: {e}");
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let areas = root.split_evenly((rows, cols));
        for (area, panel) in areas.iter().zip(panels) {
            draw_panel(area, panel).map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("plot buffer size")?;
    let mut out = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

fn draw_panel(
    area: &Area<'_>,
    panel: &Panel,
) -> Result<(), DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>> {
    let finite = |s: &Series| -> Vec<(f64, f64)> {
        s.points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect()
    };
    let all: Vec<(f64, f64)> = panel.series.iter().flat_map(finite).collect();
    let (Some(xr), Some(yr)) = (
        padded_range(all.iter().map(|p| p.0)),
        padded_range(all.iter().map(|p| p.1)),
    ) else {
        area.titled(&panel.title, (FAMILY, 17))?.draw_text(
            "no data",
            &(FAMILY, 14).into_text_style(area),
            (20, 20),
        )?;
        return Ok(());
    };
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FAMILY, 17))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    chart
        .configure_mesh()
        .x_desc(&panel.x_label)
        .y_desc(&panel.y_label)
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&|v| tick_label(*v, xr.0, xr.1))
        .y_label_formatter(&|v| tick_label(*v, yr.0, yr.1))
        .label_style((FAMILY, 13))
        .axis_desc_style((FAMILY, 14))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(215, 215, 215))
        .draw()?;
    let mut named = false;
    for s in &panel.series {
        let pts = finite(s);
        if pts.is_empty() {
            continue;
        }
        let [r, g, b] = s.colour;
        let colour = RGBColor(r, g, b);
        let line = chart.draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))?;
        if !s.name.is_empty() {
            named = true;
            line.label(s.name.clone()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 22, y)], colour.stroke_width(3))
            });
        }
        if s.markers {
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, colour.filled())))?;
        }
    }
    if named {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .label_font((FAMILY, 13))
            .draw()?;
    }
    Ok(())
}

/// Writes the panels as a PNG at `path`, atomically.
pub fn write_panels_png(
    path: &Path,
    panels: &[Panel],
    cols: usize,
    panel_w: u32,
    panel_h: u32,
) -> anyhow::Result<()> {
    let png = panels_png(panels, cols, panel_w, panel_h)?;
    write_atomic(path, |f| {
        use std::io::Write;
        Ok(f.write_all(&png)?)
    })
    .with_context(|| format!("{}: writing the plot failed", path.display()))
}

/// A colour-mapped error image: per pixel the mean over RGB of |a − b|, from 0 (dark) to
/// `max_error` and above (bright), with the viridis colour map. Inputs are interleaved RGB.
pub fn error_map(a: &[f32], b: &[f32], max_error: f32) -> Vec<u8> {
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    a.chunks_exact(3)
        .zip(b.chunks_exact(3))
        .flat_map(|(p, q)| {
            let e = (0..3).map(|c| (p[c] - q[c]).abs()).sum::<f32>() / 3.0;
            let t = if e.is_finite() {
                (e / max_error).clamp(0.0, 1.0)
            } else {
                1.0
            };
            let c: RGBColor = ViridisRGB.get_color(t);
            [c.0, c.1, c.2]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(1_250_000.0, 0.0, 3e6), "1.2M");
        assert_eq!(tick_label(2_000_000.0, 0.0, 3e6), "2.0M");
        assert_eq!(tick_label(45_000.0, 0.0, 60_000.0), "45k");
        assert_eq!(tick_label(11_384.0, 11_000.0, 11_600.0), "11.4k");
        assert_eq!(tick_label(1200.0, 0.0, 2000.0), "1200");
        assert_eq!(tick_label(25.5, 25.0, 26.0), "25.5");
        assert_eq!(tick_label(0.0125, 0.0, 0.4), "0.01");
    }

    #[test]
    fn ranges_are_padded_and_skip_non_finite_values() {
        assert_eq!(padded_range([f64::NAN].into_iter()), None);
        let (lo, hi) = padded_range([1.0, 3.0, f64::INFINITY].into_iter()).unwrap();
        assert!((lo - 0.9).abs() < 1e-12 && (hi - 3.1).abs() < 1e-12);
        let (lo, hi) = padded_range([0.0].into_iter()).unwrap();
        assert_eq!((lo, hi), (-1.0, 1.0));
    }
}

/// One picture of a [`captioned_grid`]: 8-bit RGB, `width` × `height`, and its caption.
#[derive(Debug, Clone)]
pub struct Tile {
    pub caption: String,
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Lays `tiles` out row by row, `cols` to a row, each with its caption above it, on white, and
/// returns the PNG bytes. An empty caption and an empty `rgb` leave a blank cell.
pub fn captioned_grid(tiles: &[Tile], cols: usize) -> anyhow::Result<Vec<u8>> {
    anyhow::ensure!(!tiles.is_empty() && cols > 0, "a grid needs a tile");
    register_font();
    const CAPTION: u32 = 22;
    const GAP: u32 = 6;
    // Wide enough for the widest picture and the longest caption (DejaVu Sans at 15 px
    // averages under 9 px a character).
    let caption_w = tiles
        .iter()
        .map(|t| 9 * t.caption.chars().count() as u32 + 4)
        .max()
        .unwrap_or(0);
    let cell_w = tiles
        .iter()
        .map(|t| t.width)
        .max()
        .unwrap_or(1)
        .max(caption_w);
    let cell_h = tiles.iter().map(|t| t.height).max().unwrap_or(1) + CAPTION;
    let rows = tiles.len().div_ceil(cols) as u32;
    let (w, h) = (
        cols as u32 * (cell_w + GAP) + GAP,
        rows * (cell_h + GAP) + GAP,
    );
    let mut buf = vec![255u8; (w * h * 3) as usize];
    for (k, t) in tiles.iter().enumerate() {
        if t.rgb.len() != (t.width * t.height * 3) as usize {
            anyhow::ensure!(
                t.rgb.is_empty(),
                "tile {k}: {} bytes for {}×{}",
                t.rgb.len(),
                t.width,
                t.height
            );
            continue;
        }
        let x0 = GAP + (k % cols) as u32 * (cell_w + GAP);
        let y0 = GAP + (k / cols) as u32 * (cell_h + GAP) + CAPTION;
        for y in 0..t.height {
            let src = &t.rgb[(y * t.width * 3) as usize..((y + 1) * t.width * 3) as usize];
            let at = (((y0 + y) * w + x0) * 3) as usize;
            buf[at..at + src.len()].copy_from_slice(src);
        }
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let style = (FAMILY, 15).into_text_style(&root).color(&BLACK);
        for (k, t) in tiles.iter().enumerate() {
            let x0 = GAP + (k % cols) as u32 * (cell_w + GAP);
            let y0 = GAP + (k / cols) as u32 * (cell_h + GAP);
            root.draw_text(&t.caption, &style, (x0 as i32 + 2, y0 as i32 + 3))
                .map_err(|e| anyhow!("drawing a caption: {e}"))?;
        }
        root.present()
            .map_err(|e| anyhow!("drawing a caption: {e}"))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("grid buffer size")?;
    let mut out = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)?;
    Ok(out)
}
