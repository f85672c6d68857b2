//! 2DGS's section of a run's config ([`SurfelTraining`]): its regularisers' weights and start
//! iterations, which [`super::surfels`]' passes read.

use std::any::Any;

use crate::render::surfel::regularise::RegulariserWeights;
use crate::train::model_section::ModelSection;

/// 2DGS's training settings (official `arguments/__init__.py`, `train.py`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfelTraining {
    /// λ of the normal consistency (0.05), active for iterations > `normal_from` (7000).
    pub normal_weight: f32,
    pub normal_from: u32,
    /// λ of the depth distortion (0 in the official code; its DTU script uses 1000), active
    /// for iterations > `distortion_from` (3000).
    pub distortion_weight: f32,
    pub distortion_from: u32,
    /// The surface depth: 0 the expected depth (official default), 1 the median (DTU, TnT).
    pub depth_ratio: f32,
}

impl Default for SurfelTraining {
    fn default() -> Self {
        Self {
            normal_weight: 0.05,
            normal_from: 7000,
            distortion_weight: 0.0,
            distortion_from: 3000,
            depth_ratio: 0.0,
        }
    }
}

impl SurfelTraining {
    /// The regularisers' weights at `iteration`.
    pub fn weights_at(&self, iteration: u32) -> RegulariserWeights {
        RegulariserWeights {
            normal: if iteration > self.normal_from {
                self.normal_weight
            } else {
                0.0
            },
            distortion: if iteration > self.distortion_from {
                self.distortion_weight
            } else {
                0.0
            },
            depth_ratio: self.depth_ratio,
        }
    }
}
impl ModelSection for SurfelTraining {
    fn model_name(&self) -> &'static str {
        "2dgs"
    }

    fn settings_json(&self) -> serde_json::Value {
        serde_json::json!({
            "normal_weight": self.normal_weight, "normal_from": self.normal_from,
            "distortion_weight": self.distortion_weight, "distortion_from": self.distortion_from,
            "depth_ratio": self.depth_ratio,
        })
    }

    fn legacy_json(&self) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::from_iter([("surfels".to_string(), self.settings_json())])
    }

    fn validate(&self) -> anyhow::Result<()> {
        use anyhow::ensure;
        ensure!(
            self.normal_weight >= 0.0 && self.distortion_weight >= 0.0,
            "--lambda-normal {} and --lambda-dist {} must be ≥ 0",
            self.normal_weight,
            self.distortion_weight
        );
        ensure!(
            (0.0..=1.0).contains(&self.depth_ratio),
            "--depth-ratio {} must lie in [0, 1] (0: expected depth, 1: median depth)",
            self.depth_ratio
        );
        Ok(())
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
