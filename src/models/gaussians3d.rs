//! 3D Gaussian Splatting (Kerbl et al. 2023) with the Inria defaults: every default of
//! [`Model`] is its.

use super::model::Model;
use crate::train::density::Statistic;
use crate::train::model_section::NamedModel;
use crate::train::passes::ModelTraining;
use crate::train::trainer::TrainConfig;

pub struct Gaussians3d;

/// The 3D-Gaussian passes (the defaults).
impl ModelTraining for Gaussians3d {}

impl Model for Gaussians3d {
    fn name(&self) -> &'static str {
        "3dgs"
    }

    fn configure(&self, config: &mut TrainConfig) {
        super::still_gaussians(config, Statistic::Gradient, NamedModel(self.name()));
    }
}
