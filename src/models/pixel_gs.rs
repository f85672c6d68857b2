//! Pixel-GS (Zhang et al., ECCV 2024): 3DGS with the densification statistic weighted by the
//! pixels each Gaussian covers per view, the depth factor on the statistic only (the official
//! code's defaults; docs/algorithms/base-models.md §3).

use super::model::Model;
use super::options::ModelSetting;
use crate::train::density::Statistic;
use crate::train::model_section::NamedModel;
use crate::train::passes::ModelTraining;
use crate::train::trainer::TrainConfig;

pub struct PixelGs;

/// The 3D-Gaussian passes (the defaults).
impl ModelTraining for PixelGs {}

impl Model for PixelGs {
    fn name(&self) -> &'static str {
        "pixel-gs"
    }

    fn configure(&self, config: &mut TrainConfig) {
        super::still_gaussians(config, Statistic::pixel_gs(), NamedModel(self.name()));
    }

    /// Its statistic counts pixels; the absolute-gradient test is not combined with it.
    fn settings(&self) -> &'static [ModelSetting] {
        &[]
    }
}
