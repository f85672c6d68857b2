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
use crate::models::BaseModel;
use crate::scene::image_source::TrainImages;
use crate::scene::{images, Image, Scene};
use crate::taming::{BlendConfig, BlendedScore};
use crate::train::strategy::{DensityStrategy, Primitive};
use crate::train::trainer::{TrainConfig, Trainer};

/// The shape of the primitives a run trains (2DGS's surfels or 3D Gaussians), as its base
/// model says.
pub fn primitive_of(config: &TrainConfig) -> Primitive {
    BaseModel::of(config).model().primitive()
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

/// What a run's density strategy is built on, LPM aside.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Base {
    /// The trainer's own ADC (with or without an exact budget).
    Adc,
    Mcmc(McmcConfig),
    /// The exact-budget ADC ranked by the blended score.
    Blend(BlendConfig),
}

impl Base {
    /// MCMC when `mcmc` is given, else the blended score when `blend` is, else ADC.
    pub fn of(mcmc: Option<McmcConfig>, blend: Option<BlendConfig>) -> Base {
        match (mcmc, blend) {
            (Some(m), _) => Base::Mcmc(m),
            (None, Some(b)) => Base::Blend(b),
            (None, None) => Base::Adc,
        }
    }
}

/// The strategy of a run of `config` on `base` and/or LPM (`lpm`), or `None` for the trainer's
/// own ADC: MCMC or the blended score alone, LPM around ADC, or LPM guiding either.
pub fn assemble(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    train_images: &TrainImages,
    config: &TrainConfig,
    lpm: Option<LpmConfig>,
    base: Base,
    cache_dir: &Path,
) -> anyhow::Result<Option<Box<dyn DensityStrategy>>> {
    if let Base::Blend(_) = base {
        anyhow::ensure!(
            config.density.exact_budget.is_some(),
            "the blended score ranks the exact-budget ADC's candidates. Fix: --strategy \
             adc-exact --budget N with --budget-score blend"
        );
        anyhow::ensure!(
            {
                let model = BaseModel::of(config).model();
                model.primitive() == Primitive::Gaussian
                    && !model.is_spacetime()
                    && config.render_constants()
                        == crate::render::layout::RenderConstants::default()
            },
            "the blended score draws its views with the plain 3D Gaussian renderer, not this \
             model's (2DGS, SpacetimeGaussians and Mip-Splatting render otherwise). Fix: \
             --budget-score gradient, or --model 3dgs / pixel-gs"
        );
    }
    if let Some(c) = lpm.as_ref().filter(|c| c.surface_share > 0.0) {
        anyhow::ensure!(
            matches!(base, Base::Mcmc(_)),
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
    let base: Option<Box<dyn DensityStrategy>> = match base {
        Base::Mcmc(c) => Some(Box::new(McmcStrategy::new(ctx, c, primitive_of(config))?)),
        Base::Blend(b) => Some(Box::new(BlendedScore::new(
            ctx,
            scene,
            train_images.clone(),
            b,
        )?)),
        Base::Adc => None,
    };
    Ok(match (lpm, base) {
        (Some(c), base) => {
            let lpm = build_lpm(ctx, scene, train_images, c, cache_dir)?;
            Some(match base {
                Some(m) => Box::new(lpm.wrapping(m)),
                None => Box::new(lpm),
            })
        }
        (None, base) => base,
    })
}

/// The run's MCMC strategy, on its own or guided by LPM; `None` for the other strategies.
pub fn mcmc_of(trainer: &Trainer) -> Option<&McmcStrategy> {
    trainer.strategy_as::<McmcStrategy>().or_else(|| {
        let lpm = trainer.strategy_as::<LpmStrategy>()?;
        lpm.inner().as_any().downcast_ref::<McmcStrategy>()
    })
}

/// The run's blended-score strategy, on its own or guided by LPM; `None` for the others.
pub fn blended_of(trainer: &Trainer) -> Option<&BlendedScore> {
    trainer.strategy_as::<BlendedScore>().or_else(|| {
        let lpm = trainer.strategy_as::<LpmStrategy>()?;
        lpm.inner().as_any().downcast_ref::<BlendedScore>()
    })
}
