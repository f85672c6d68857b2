//! The density strategy a run asks for, assembled from its parts: ADC (the trainer's own, when
//! nothing else is asked for), MCMC, and LPM as a guide around either. `train` and
//! `bench trade` both build their runs' strategies here, so the pairing of a guide with what it
//! guides is written once.

use std::path::Path;
use std::sync::Arc;

use crate::gpu::GpuContext;
use crate::lpm;
use crate::lpm::config::LpmConfig;
use crate::lpm::strategy::LpmStrategy;
use crate::mcmc::{McmcConfig, McmcStrategy};
use crate::scene::image_source::TrainImages;
use crate::scene::{images, Image, Scene};
use crate::train::strategy::{DensityStrategy, Primitive};
use crate::train::trainer::{TrainConfig, Trainer};

/// The shape of the primitives a run trains (2DGS's surfels or 3D Gaussians).
pub fn primitive_of(config: &TrainConfig) -> Primitive {
    match config.surfels.is_some() {
        true => Primitive::Surfel,
        false => Primitive::Gaussian,
    }
}

/// Builds the LPM state for a trainer: correspondences from the cache in `cache_dir` (built and
/// written there when missing or stale), their summary printed.
pub fn build_lpm(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    train_images: &TrainImages,
    config: LpmConfig,
    cache_dir: &Path,
) -> anyhow::Result<LpmStrategy> {
    let loader = |i: usize| -> anyhow::Result<Image> {
        match scene.train.iter().position(|&v| v == i) {
            Some(k) => train_images.source.load(k),
            None => Ok(images::load_images(scene, &[i])?.remove(0)),
        }
    };
    let cache = cache_dir.join(lpm::CACHE_FILE_NAME);
    let (corr, summary) = lpm::load_or_build(scene, &config.matching, &cache, &loader, None)?;
    eprintln!("LPM correspondences: {summary}");
    LpmStrategy::new(ctx, scene, train_images.clone(), corr, config)
}

/// The strategy of a run of `config` with `mcmc` and/or LPM (`lpm`), or `None` for the
/// trainer's own ADC: MCMC alone, LPM around ADC, or LPM guiding MCMC.
pub fn assemble(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    train_images: &TrainImages,
    config: &TrainConfig,
    lpm: Option<LpmConfig>,
    mcmc: Option<McmcConfig>,
    cache_dir: &Path,
) -> anyhow::Result<Option<Box<dyn DensityStrategy>>> {
    if let Some(c) = lpm.as_ref().filter(|c| c.surface_share > 0.0) {
        anyhow::ensure!(
            mcmc.is_some(),
            "LPM surface share {} (--lpm-surface-share) moves MCMC's dead Gaussians onto the \
             zones' surface samples; this run has no MCMC. Fix: add --strategy mcmc --budget N, \
             or drop --lpm-surface-share",
            c.surface_share
        );
        anyhow::ensure!(
            c.zones.geometry == crate::lpm::ZoneGeometry::Local,
            "LPM surface share {} (--lpm-surface-share) takes its samples from local zones' SfM \
             points. Fix: add --lpm-zone local, or drop --lpm-surface-share",
            c.surface_share
        );
    }
    let mcmc = match mcmc {
        Some(c) => Some(McmcStrategy::new(ctx, c, primitive_of(config))?),
        None => None,
    };
    Ok(match (lpm, mcmc) {
        (Some(c), mcmc) => {
            let lpm = build_lpm(ctx, scene, train_images, c, cache_dir)?;
            Some(match mcmc {
                Some(m) => Box::new(lpm.wrapping(Box::new(m))),
                None => Box::new(lpm),
            })
        }
        (None, Some(m)) => Some(Box::new(m)),
        (None, None) => None,
    })
}

/// The run's MCMC strategy, on its own or guided by LPM; `None` for the other strategies.
pub fn mcmc_of(trainer: &Trainer) -> Option<&McmcStrategy> {
    trainer.strategy_as::<McmcStrategy>().or_else(|| {
        let lpm = trainer.strategy_as::<LpmStrategy>()?;
        lpm.inner().as_any().downcast_ref::<McmcStrategy>()
    })
}
