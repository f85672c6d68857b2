//! `merge`: the blocks' trained models, each cropped to its core, as one model with a report.

use std::path::PathBuf;

use clap::Args;
use lpmsplat::partition::{merge, Plan};
use lpmsplat::splats::{ply::write_ply_with_comments, write_splat};

#[derive(Args, Debug)]
pub struct MergeArgs {
    /// The plan.json `partition` wrote.
    pub plan: PathBuf,
    /// The folder of the blocks' runs (a run per block, named as the block). Default: runs/
    /// beside the plan.
    #[arg(long)]
    pub runs: Option<PathBuf>,
    /// Output folder: point_cloud.ply (and .splat for a still model), merge_report.json.
    #[arg(long, short = 'o')]
    pub out: PathBuf,
}

pub fn run(args: &MergeArgs) -> anyhow::Result<()> {
    let plan = Plan::read(&args.plan)?;
    let runs = args.runs.clone().unwrap_or_else(|| {
        args.plan
            .parent()
            .unwrap_or(std::path::Path::new("."))
            .join("runs")
    });
    let merged = merge::merge(&plan, &runs)?;
    std::fs::create_dir_all(&args.out)?;
    let ply = args.out.join("point_cloud.ply");
    write_ply_with_comments(&ply, &merged.params, &merged.comments)?;
    if merged.params.extra.is_empty() {
        write_splat(&args.out.join("point_cloud.splat"), &merged.params)?;
    }
    let report = args.out.join("merge_report.json");
    let text = serde_json::to_string_pretty(&merged.report)?;
    lpmsplat::error::write_atomic(&report, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())?;
        Ok(())
    })?;
    println!(
        "{:<8} {:>10} {:>10} {:>7} {:>8} {:>9} {:>9}",
        "block", "Gaussians", "kept", "PSNR", "SSIM", "train s", "peak MiB"
    );
    let opt = |v: Option<f64>, p: usize| v.map_or("-".to_string(), |x| format!("{x:.p$}"));
    for b in &merged.report.blocks {
        println!(
            "{:<8} {:>10} {:>10} {:>7} {:>8} {:>9} {:>9}",
            b.name,
            b.gaussians,
            b.kept,
            opt(b.test_psnr, 2),
            opt(b.test_ssim, 4),
            opt(b.train_seconds, 0),
            opt(b.device_buffers_peak_mib, 0)
        );
    }
    println!(
        "merged: {} {} Gaussians -> {}",
        merged.report.gaussians,
        merged.base.name(),
        ply.display()
    );
    println!(
        "score it on the whole scene: lpmsplat eval {} --ply {}",
        plan.scene.display(),
        ply.display()
    );
    Ok(())
}
