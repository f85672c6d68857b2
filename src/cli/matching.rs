//! `match`: extract and cache LPM correspondences for every neighbour pair of the training views.

use super::SceneArgs;
use anyhow::Context as _;
use clap::Args;
use lpmsplat::lpm::{self, MatchSettings, MatchSource};
use lpmsplat::scene::{images, Scene};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct MatchArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Folder for the cache file (default: the scene folder).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Correspondence source: auto (SfM tracks when present, else features), tracks, features.
    #[arg(long, default_value = "auto", value_parser = ["auto", "tracks", "features"])]
    pub source: String,
    /// Largest optical-axis angle between neighbour views, degrees (90 suggested indoors).
    #[arg(long, default_value_t = 45.0)]
    pub neighbour_angle: f64,
    /// Neighbour views kept per training view.
    #[arg(long, default_value_t = 3)]
    pub neighbours: usize,
    /// Symmetric epipolar distance threshold for feature matches, pixels.
    #[arg(long, default_value_t = 3.0)]
    pub epipolar_px: f64,
    /// Which views within the angle become neighbours: random (the paper's pick, `train --lpm`'s
    /// default) or overlap (most shared SfM tracks, else the nearest camera centres).
    #[arg(long, default_value = "random", value_parser = ["random", "overlap"])]
    pub neighbour_choice: String,
    /// Seed of the random neighbour pick.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Rebuild even when a valid cache exists (e.g. after replacing image files in place).
    #[arg(long)]
    pub rematch: bool,
}

pub fn run(args: &MatchArgs) -> anyhow::Result<()> {
    let opts = args.scene.load_options()?;
    let scene = Scene::load(&args.scene.scene, &opts)?;
    let mut settings = MatchSettings {
        source: match args.source.as_str() {
            "tracks" => MatchSource::Tracks,
            "features" => MatchSource::Features,
            _ => MatchSource::Auto,
        },
        epipolar_threshold_px: args.epipolar_px,
        ..MatchSettings::default()
    };
    if !(args.neighbour_angle > 0.0 && args.neighbour_angle <= 180.0) {
        anyhow::bail!(
            "--neighbour-angle {}: must be in (0, 180] degrees",
            args.neighbour_angle
        );
    }
    settings.neighbours.max_angle_deg = args.neighbour_angle;
    settings.neighbours.max_neighbours = args.neighbours;
    settings.neighbours.seed = args.seed;
    settings.neighbours.choice = lpm::NeighbourChoice::parse(&args.neighbour_choice)?;
    let dir = args.out.clone().unwrap_or_else(|| scene.root.clone());
    std::fs::create_dir_all(&dir)
        .with_context(|| format!("{}: cannot create the output folder", dir.display()))?;
    let cache = dir.join(lpm::CACHE_FILE_NAME);
    if args.rematch && cache.exists() {
        std::fs::remove_file(&cache)
            .with_context(|| format!("{}: cannot remove the old cache", cache.display()))?;
    }
    let loader = |i: usize| -> anyhow::Result<images::Image> {
        Ok(images::load_images(&scene, &[i])?.remove(0))
    };
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("matching");
    let (_corr, summary) = lpm::load_or_build(&scene, &settings, &cache, &loader, Some(&bar))?;
    bar.finish_and_clear();
    println!("{summary}");
    println!("cache: {}", cache.display());
    Ok(())
}
