//! Mip-Splatting (Yu et al., CVPR 2024): 3DGS with the 3D smoothing filter the trainer
//! recomputes and the 2D Mip filter in the rasterizer, densified by 3DGS's gradient test
//! (docs/algorithms/base-models.md §2).

use std::any::Any;

use super::model::Model;
use crate::render::layout::RenderConstants;
use crate::train::density::Statistic;
use crate::train::model_section::ModelSection;
use crate::train::passes::ModelTraining;
use crate::train::trainer::TrainConfig;

pub struct MipSplatting;

/// The 3D-Gaussian passes (the defaults); its filters come with its section's constants.
impl ModelTraining for MipSplatting {}

impl Model for MipSplatting {
    fn name(&self) -> &'static str {
        "mip-splatting"
    }

    fn configure(&self, config: &mut TrainConfig) {
        super::still_gaussians(config, Statistic::Gradient, MipFilters);
    }
}

/// Mip-Splatting's section: its filters, the 2D Mip filter (eps2d 0.1 with the opacity
/// compensation) and the 3D smoothing filter (which comes with the 2D filter's bit,
/// [`RenderConstants::MIP_2D`]: the 3D-Gaussian passes recompute it after every density step and every 100 iterations after
/// densification, as the official code; the opacity reset acts on the filtered opacity).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MipFilters;

impl ModelSection for MipFilters {
    fn model_name(&self) -> &'static str {
        MipSplatting.name()
    }

    fn legacy_json(&self) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::from_iter([("mip_filters".to_string(), serde_json::json!(true))])
    }

    fn render_constants(&self) -> RenderConstants {
        RenderConstants::for_mip(true)
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
