//! `render --depth --normals`: a surfel frame's surface depth and world normals as pictures
//! people can look at (PNG) and as raw float32 maps (PFM).

use std::path::{Path, PathBuf};

use lpmsplat::render::view::GeometryMaps;
use lpmsplat::scene::{images, Image, PinholeCamera, Pose};

/// Pixels with less accumulated alpha show no depth or normal (black in the PNGs; the PFMs
/// keep every value).
const MIN_ALPHA: f32 = 0.5;

/// Writes OUT/<stem>_depth.{png,pfm} and/or OUT/<stem>_normal.{png,pfm}; returns the paths.
#[allow(clippy::too_many_arguments)]
pub fn write(
    out: &Path,
    stem: &str,
    maps: &GeometryMaps,
    camera: &PinholeCamera,
    pose: &Pose,
    depth_ratio: f32,
    depth: bool,
    normals: bool,
) -> anyhow::Result<Vec<PathBuf>> {
    let (w, h) = (camera.width, camera.height);
    let mut written = Vec::new();
    if depth {
        let d = maps.surface_depth(depth_ratio);
        let pfm = out.join(format!("{stem}_depth.pfm"));
        images::save_pfm(&pfm, w, h, 1, &d)?;
        let png = out.join(format!("{stem}_depth.png"));
        images::save_png(&png, &depth_picture(&d, &maps.alpha, w, h))?;
        written.extend([png, pfm]);
    }
    if normals {
        let n = maps.world_normals(pose);
        let flat: Vec<f32> = n.iter().flatten().copied().collect();
        let pfm = out.join(format!("{stem}_normal.pfm"));
        images::save_pfm(&pfm, w, h, 3, &flat)?;
        let rgb = n
            .iter()
            .zip(&maps.alpha)
            .flat_map(|(v, &a)| {
                let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if a < MIN_ALPHA || len <= 0.0 {
                    [0.0; 3]
                } else {
                    v.map(|c| 0.5 * (c / len + 1.0))
                }
            })
            .collect();
        let png = out.join(format!("{stem}_normal.png"));
        images::save_png(
            &png,
            &Image {
                width: w,
                height: h,
                rgb,
                alpha: None,
            },
        )?;
        written.extend([png, pfm]);
    }
    Ok(written)
}

/// Depth colour-mapped (turbo-like viridis, near = bright) between the 2nd and 98th
/// percentiles of the covered pixels' depths; uncovered pixels black.
pub fn depth_picture(depth: &[f32], alpha: &[f32], width: u32, height: u32) -> Image {
    use plotters::style::colors::colormaps::{ColorMap, ViridisRGB};
    use plotters::style::RGBColor;
    let mut valid: Vec<f32> = depth
        .iter()
        .zip(alpha)
        .filter(|(d, &a)| a >= MIN_ALPHA && d.is_finite() && **d > 0.0)
        .map(|(d, _)| *d)
        .collect();
    valid.sort_by(f32::total_cmp);
    let pick = |q: f32| valid[((valid.len() - 1) as f32 * q).round() as usize];
    let (near, far) = if valid.is_empty() {
        (0.0, 1.0)
    } else {
        (pick(0.02), pick(0.98))
    };
    let span = (far - near).max(1e-12);
    let rgb = depth
        .iter()
        .zip(alpha)
        .flat_map(|(&d, &a)| {
            if a < MIN_ALPHA || !d.is_finite() || d <= 0.0 {
                return [0.0; 3];
            }
            let t = (1.0 - (d - near) / span).clamp(0.0, 1.0);
            let c: RGBColor = ViridisRGB.get_color(t);
            [c.0, c.1, c.2].map(|v| v as f32 / 255.0)
        })
        .collect();
    Image {
        width,
        height,
        rgb,
        alpha: None,
    }
}
