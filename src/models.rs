//! Base models: what a model changes in a training run, applied to the trainer's config.
//!
//! Today's models share the 3DGS parameter groups and PLY layout; they differ in the
//! densification statistic (Pixel-GS, BASE_MODELS.md §3) or in the renderer's filters
//! (Mip-Splatting, §2: a non-optimised per-Gaussian 3D filter the trainer recomputes, and the
//! 2D Mip filter). 2DGS's surfels and SpacetimeGS are not built yet.

use crate::train::density::Statistic;
use crate::train::trainer::TrainConfig;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum BaseModel {
    /// 3D Gaussian Splatting (Kerbl et al. 2023), the Inria defaults.
    #[default]
    Gaussians3d,
    /// Pixel-GS (Zhang et al., ECCV 2024): the densification statistic weighted by the pixels
    /// each Gaussian covers per view, with the depth factor on the statistic only; everything
    /// else as 3DGS (the official code's defaults).
    PixelGs,
    /// Mip-Splatting (Yu et al., CVPR 2024): the 3D smoothing filter and the 2D Mip filter,
    /// with the paper's densification (3DGS's gradient test).
    MipSplatting,
}

impl BaseModel {
    pub const ALL: [BaseModel; 3] = [
        BaseModel::Gaussians3d,
        BaseModel::PixelGs,
        BaseModel::MipSplatting,
    ];

    pub fn parse(s: &str) -> anyhow::Result<BaseModel> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "--model {s:?} is unknown. Fix: choose one of {}",
                    Self::ALL.map(|m| m.name()).join(", ")
                )
            })
    }

    /// The CLI name.
    pub fn name(&self) -> &'static str {
        match self {
            BaseModel::Gaussians3d => "3dgs",
            BaseModel::PixelGs => "pixel-gs",
            BaseModel::MipSplatting => "mip-splatting",
        }
    }

    /// The rasterizer constants its renders use (eval, render, viewers of an exported PLY).
    pub fn render_constants(&self) -> crate::render::layout::RenderConstants {
        crate::render::layout::RenderConstants::for_mip(*self == BaseModel::MipSplatting)
    }

    /// Sets what this model changes in `config` (leaves the rest, the 3DGS defaults or the
    /// user's flags, alone).
    pub fn configure(&self, config: &mut TrainConfig) {
        config.density.statistic = match self {
            BaseModel::Gaussians3d | BaseModel::MipSplatting => Statistic::Gradient,
            BaseModel::PixelGs => Statistic::pixel_gs(),
        };
        config.mip_filters = *self == BaseModel::MipSplatting;
    }

    /// The model a config trains (the inverse of [`BaseModel::configure`]).
    pub fn of(config: &TrainConfig) -> BaseModel {
        match (config.density.statistic, config.mip_filters) {
            (_, true) => BaseModel::MipSplatting,
            (Statistic::Gradient, false) => BaseModel::Gaussians3d,
            (Statistic::PixelWeighted { .. }, false) => BaseModel::PixelGs,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_configure_is_inverted_by_of() {
        for m in BaseModel::ALL {
            assert_eq!(BaseModel::parse(m.name()).unwrap(), m);
            let mut c = TrainConfig::default();
            m.configure(&mut c);
            assert_eq!(BaseModel::of(&c), m);
        }
        let e = BaseModel::parse("mip").unwrap_err().to_string();
        assert!(
            e.contains("3dgs, pixel-gs, mip-splatting") && e.contains("Fix"),
            "{e}"
        );
    }
}
