//! `export`: converts a trained PLY to the compact `.splat` format of web viewers.

use anyhow::Context;
use clap::Args;
use lpmsplat::models::BaseModel;
use lpmsplat::splats::{require_nonempty, splat_file::SPLAT_ROW_BYTES, write_splat};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Trained Gaussians (Inria-layout PLY; a Mip-Splatting export already holds its 3D filter;
    /// a 2DGS one, also in the official two-scale layout, becomes flat discs).
    #[arg(long)]
    pub ply: PathBuf,
    /// The `.splat` file to write (32 bytes per Gaussian, SH degree 0, sorted by size ×
    /// opacity). Default: the PLY's path with the extension `.splat`.
    #[arg(long)]
    pub splat: Option<PathBuf>,
}

pub fn run(args: &ExportArgs) -> anyhow::Result<()> {
    let params = BaseModel::read_still_ply(&args.ply)?;
    require_nonempty(&args.ply, &params)?;
    let out = args
        .splat
        .clone()
        .unwrap_or_else(|| args.ply.with_extension("splat"));
    anyhow::ensure!(
        out != args.ply,
        "{}: --splat names the input PLY. Fix: give another file name",
        out.display()
    );
    write_splat(&out, &params).with_context(|| format!("exporting {}", args.ply.display()))?;
    println!(
        "{} ({} Gaussians, {} bytes)",
        out.display(),
        params.len(),
        params.len() * SPLAT_ROW_BYTES
    );
    Ok(())
}
