//! Base models: what a model changes in a training run, applied to the trainer's config.
//!
//! Today's models share the 3DGS parameter groups, renderer and PLY layout; they differ in the
//! densification statistic (Pixel-GS, BASE_MODELS.md §3). A model that changes the render
//! (Mip-Splatting's filters, 2DGS's surfels) is not built yet.

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
}

impl BaseModel {
    pub const ALL: [BaseModel; 2] = [BaseModel::Gaussians3d, BaseModel::PixelGs];

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
        }
    }

    /// Sets what this model changes in `config` (leaves the rest, the 3DGS defaults or the
    /// user's flags, alone).
    pub fn configure(&self, config: &mut TrainConfig) {
        config.density.statistic = match self {
            BaseModel::Gaussians3d => Statistic::Gradient,
            BaseModel::PixelGs => Statistic::pixel_gs(),
        };
    }

    /// The model a config trains (the inverse of [`BaseModel::configure`]).
    pub fn of(config: &TrainConfig) -> BaseModel {
        match config.density.statistic {
            Statistic::Gradient => BaseModel::Gaussians3d,
            Statistic::PixelWeighted { .. } => BaseModel::PixelGs,
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
        assert!(e.contains("3dgs, pixel-gs") && e.contains("Fix"), "{e}");
    }
}
