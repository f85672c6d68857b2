//! Mip-Splatting (Yu et al., CVPR 2024): 3DGS with the 3D smoothing filter the trainer
//! recomputes and the 2D Mip filter in the rasterizer, densified by 3DGS's gradient test
//! (docs/algorithms/base-models.md §2).

use super::model::Model;
use crate::train::density::Statistic;
use crate::train::passes::ModelTraining;
use crate::train::trainer::TrainConfig;

pub struct MipSplatting;

/// The 3D-Gaussian passes (the defaults).
impl ModelTraining for MipSplatting {}

impl Model for MipSplatting {
    fn name(&self) -> &'static str {
        "mip-splatting"
    }

    fn configure(&self, config: &mut TrainConfig) {
        super::still_gaussians(config, Statistic::Gradient, true);
    }

    fn trains(&self, config: &TrainConfig) -> bool {
        super::is_still_gaussians(config) && config.mip_filters
    }
}
