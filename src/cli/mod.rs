//! Subcommands. Each lives in its own file; this one parses and dispatches.

mod bench;
mod eval;
mod export;
mod generate;
mod geometry_outputs;
mod image_cache_args;
mod info;
mod interrupt;
mod lpips_scores;
mod matching;
mod merge;
mod mesh;
mod model_segment;
mod output_folder;
mod partition;
// docs/cli.md is written from the definitions; only its test needs the writer.
#[cfg(test)]
mod reference_doc;
mod render;
mod slurm_args;

mod train;
mod train_plot;

use clap::{Args, Parser, Subcommand};
use lpmsplat::gpu::GpuOptions;
use lpmsplat::scene::{LoadOptions, NerfTestSplit};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "lpmsplat",
    version,
    about = "3D Gaussian Splatting with Localized Point Management, on Vulkan"
)]
pub struct Cli {
    /// Vulkan device: an index or a name substring (see `info`). Default: prefer a discrete GPU.
    #[arg(long, global = true)]
    pub device: Option<String>,
    /// Enable the Khronos validation layer (also LPMSPLAT_VALIDATION=1).
    #[arg(long, global = true)]
    pub validation: bool,
    /// Use at most this much device memory (MiB of device-local buffers), as if the device had
    /// no more: to share a GPU between runs, or to rehearse a smaller one. A training run that
    /// needs more stops with a checkpoint to resume from. Default: the device's own.
    #[arg(long, global = true, value_name = "MIB")]
    pub memory_limit: Option<u64>,
    /// The radix sorts' digit width: 4 (4-bit passes, 5-bit where that saves one: 7 passes for
    /// depths, 3 for tile ids) or 8 (passes ranked by subgroup ballots: 4 and 2). Default: 4;
    /// 8 is for timing on GPUs (`scripts/device/run.sh sortdigits`), slower on lavapipe, and
    /// refused where shared memory is too small.
    #[arg(long, global = true, value_name = "BITS", value_parser = ["4", "8"])]
    pub sort_digits: Option<String>,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Print the Vulkan devices, the chosen device's limits and, given a scene, its summary.
    Info(info::InfoArgs),
    /// Extract and cache LPM correspondences for all neighbour view pairs.
    Match(matching::MatchArgs),
    /// Render chosen cameras of a scene from a trained PLY into PNGs, or an orbit into a GIF.
    Render(render::RenderArgs),
    /// Train a scene (ADC, or ADC + LPM with --lpm) and write the PLY, test renders and metrics.
    // A repeated flag takes its last value, so `scripts/demo.sh --iterations 500` overrides
    // the script's own `--iterations 2000`.
    #[command(args_override_self = true)]
    Train(Box<train::TrainArgs>),
    /// PSNR and SSIM of a trained PLY on a scene's test views (table, JSON, side-by-side PNGs).
    Eval(eval::EvalArgs),
    /// Benchmarks: `bench fps` (rendering speed and per-stage GPU time), `bench trade` (ADC
    /// against ADC + LPM and ablations, side by side) and `bench merge` (several `bench trade`
    /// results as one table).
    Bench(bench::BenchArgs),
    /// Convert a trained PLY to the compact `.splat` format of web viewers.
    Export(export::ExportArgs),
    /// A triangle mesh (PLY) of a trained 2DGS model: its rendered depth fused into a TSDF.
    Mesh(mesh::MeshArgs),
    /// Cut a COLMAP or transforms scene into overlapping blocks on its ground plane: a plan,
    /// each block a scene folder `train` reads, and (--slurm) a job array that trains them and
    /// a merge job.
    Partition(Box<partition::PartitionArgs>),
    /// The blocks' trained models of a plan, each cropped to its core, as one model.
    Merge(merge::MergeArgs),
    /// A procedural district of box buildings surveyed from the air, rendered from its known
    /// Gaussians into a COLMAP scene (images, SfM points, truth.ply): a scene as large as asked.
    GenerateCity(generate::GenerateCityArgs),
}

/// Scene-loading flags shared by the subcommands that read a scene.
#[derive(Args, Debug, Clone)]
pub struct SceneArgs {
    /// Scene folder: a COLMAP model (sparse/0 or sparse, with images/), transforms*.json, or a
    /// multi-view video (Neural 3D Video's poses_bounds.npy + camNN/ frames, or Panoptic's
    /// train_meta.json).
    pub scene: PathBuf,
    /// Downscale images by this factor (e.g. 2, 4, 8). Default: keep, capped at 1600 px wide.
    #[arg(short = 'r', long = "resolution")]
    pub resolution: Option<u32>,
    /// NeRF-synthetic: use `val` or `test` as the test split (default: test if present, else val).
    #[arg(long, value_parser = ["val", "test"])]
    pub test_split: Option<String>,
    /// Video scenes: the segment of frames, START..END (END excluded) or START.. (50 frames,
    /// SpacetimeGaussians' segment length, fewer when the video is shorter). Frame k of the
    /// segment trained on has time k / its length; the model's PLY records that segment, so
    /// `render` and `eval` load it by default and take any part of it (e.g. 10..20 of a model
    /// trained on 0..50: frames 10 to 19 at times 0.2 to 0.38). Default: 0.. for `train`, the
    /// model's segment for `render` and `eval`.
    #[arg(long, value_name = "START..END")]
    pub frames: Option<lpmsplat::scene::video::FrameRange>,
}

impl SceneArgs {
    pub fn load_options(&self) -> anyhow::Result<LoadOptions> {
        if self.resolution == Some(0) {
            anyhow::bail!(
                "-r 0: the resolution factor must be at least 1. Fix: pass -r 1, 2, 4 or 8"
            );
        }
        Ok(LoadOptions {
            resolution_factor: self.resolution,
            nerf_test_split: match self.test_split.as_deref() {
                Some("val") => NerfTestSplit::Val,
                Some("test") => NerfTestSplit::Test,
                _ => NerfTestSplit::TestOrVal,
            },
            frames: self.frames.unwrap_or_default(),
            ..LoadOptions::default()
        })
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    if cli.memory_limit == Some(0) {
        anyhow::bail!("--memory-limit 0: give the device memory to use in MiB (e.g. 4096)");
    }
    let gpu = GpuOptions {
        validation: cli.validation,
        device: cli.device.clone(),
        memory_limit: cli.memory_limit.map(|m| m.saturating_mul(1 << 20)),
        sort_digit_bits: cli.sort_digits.as_deref().map(|b| b.parse()).transpose()?,
    };
    match cli.command {
        Command::Info(a) => info::run(&gpu, &a),
        Command::Match(a) => matching::run(&a),
        Command::Render(a) => render::run(&gpu, &a),
        Command::Bench(a) => bench::run(&gpu, &a),
        Command::Train(a) => train::run(&gpu, &a),
        Command::Eval(a) => eval::run(&gpu, &a),
        Command::Export(a) => export::run(&a),
        Command::Mesh(a) => mesh::run(&gpu, &a),
        Command::Partition(a) => partition::run(&a),
        Command::Merge(a) => merge::run(&a),
        Command::GenerateCity(a) => generate::run(&gpu, &a),
    }
}
