//! `generate-city`: a procedural district surveyed from the air, written as a COLMAP scene with
//! its truth (`lpmsplat::synthetic`).

use clap::Args;
use lpmsplat::gpu::{GpuContext, GpuOptions};
use lpmsplat::synthetic::{generate, write_city, CitySpec};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct GenerateCityArgs {
    /// Output folder (created; an existing folder must be empty): images/, sparse/0/,
    /// truth.ply (the Gaussians the images were rendered from) and city.json.
    pub out: PathBuf,
    /// Lots along the two ground axes, e.g. 6x4 (a lot is 1 × 1, streets 0.4 wide).
    #[arg(long, default_value = "6x6", value_parser = parse_pair)]
    pub lots: (usize, usize),
    /// Gaussians of the truth (e.g. 2M, 500k): the surfaces' sampling is chosen to hold them.
    #[arg(long, default_value = "1M", value_parser = super::partition::parse_count)]
    pub gaussians: u64,
    /// Survey views, four headings a station; every 8th by name is a test view.
    #[arg(long, default_value_t = 160)]
    pub views: usize,
    /// Image size WxH (default 1152x864, one megapixel).
    #[arg(long, default_value = "1152x864", value_parser = parse_pair)]
    pub size: (usize, usize),
    /// SfM points sampled from the truth's centres (kept where two views or more see them).
    #[arg(long, default_value = "100k", value_parser = super::partition::parse_count)]
    pub points: u64,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// `AxB`: two positive whole numbers.
fn parse_pair(s: &str) -> Result<(usize, usize), String> {
    let bad = || format!("'{s}': give two positive whole numbers as AxB, e.g. 6x4");
    let (a, b) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    match (a.trim().parse::<usize>(), b.trim().parse::<usize>()) {
        (Ok(a), Ok(b)) if a > 0 && b > 0 => Ok((a, b)),
        _ => Err(bad()),
    }
}

pub fn run(gpu: &GpuOptions, args: &GenerateCityArgs) -> anyhow::Result<()> {
    let spec = CitySpec {
        lots: args.lots,
        gaussians: args.gaussians as usize,
        views: args.views,
        width: u32::try_from(args.size.0)?,
        height: u32::try_from(args.size.1)?,
        seed: args.seed,
    };
    let city = generate(&spec)?;
    eprintln!(
        "district of {}x{} lots: {} buildings, {} Gaussians, {} views of {}x{}",
        spec.lots.0,
        spec.lots.1,
        city.buildings.len(),
        city.params.len(),
        city.views.len(),
        spec.width,
        spec.height
    );
    let ctx = GpuContext::new(gpu)?;
    let report = write_city(&ctx, &city, &spec, &args.out, args.points as usize)?;
    println!(
        "wrote {}: {} views ({} test), {} SfM points (mean track {:.1}), truth.ply with {} \
         Gaussians; rendering took {:.0} s",
        args.out.display(),
        report.views,
        report.test_views,
        report.sfm_points,
        report.mean_track,
        report.gaussians,
        report.render_seconds
    );
    Ok(())
}
