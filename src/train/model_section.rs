//! The base model's section of a training run's config: which model trains, with the settings
//! that are its own. [`TrainConfig`](super::config::TrainConfig) holds one as a trait object,
//! so the config, the trainer and `config.json` name no model: a model with settings of its
//! own defines a type for them beside its passes (2DGS's
//! [`SurfelTraining`](super::passes::surfels::SurfelTraining), SpacetimeGaussians'
//! [`SpacetimeTraining`](super::passes::spacetime_settings::SpacetimeTraining)), and its
//! passes read it back with [`TrainConfig::model_settings`](super::config::TrainConfig::model_settings).
//! A model without settings of its own is its name alone ([`NamedModel`]).

use std::any::Any;
use std::fmt::Debug;
use std::sync::Arc;

use crate::render::layout::RenderConstants;
use crate::scene::SceneFrame;

/// One base model's section of a run's config.
pub trait ModelSection: Debug + Send + Sync + Any {
    /// The model's name (`--model NAME`): `config.json` records it, and the model registry
    /// (`models::BaseModel`) finds the model by it.
    fn model_name(&self) -> &'static str;

    /// The section's own settings for `config.json` (`null`: none).
    fn settings_json(&self) -> serde_json::Value {
        serde_json::Value::Null
    }

    /// The keys this model's settings had at the top of `config.json` before the config had a
    /// model section (December 2026): a checkpoint written then has these instead of `model`,
    /// and resuming it compares them ([`crate::train::checkpoint`]).
    fn legacy_json(&self) -> serde_json::Map<String, serde_json::Value> {
        serde_json::Map::new()
    }

    /// The values no run can train with, refused naming the flag that sets each.
    fn validate(&self) -> anyhow::Result<()> {
        Ok(())
    }

    /// The rasterizer constants this model is trained and drawn with (the 3DGS defaults unless
    /// the model filters or clips otherwise).
    fn render_constants(&self) -> RenderConstants {
        RenderConstants::default()
    }

    /// This section with its lengths in world units moved into a scene's training frame
    /// ([`crate::scene::frame`]); `None` when it holds no such length.
    fn in_training_frame(&self, _frame: &SceneFrame) -> Option<Arc<dyn ModelSection>> {
        None
    }

    /// The section as [`Any`], for [`TrainConfig::model_settings`](super::config::TrainConfig::model_settings).
    fn as_any(&self) -> &dyn Any;
}

/// A model without settings of its own: its section is its name (3DGS, Pixel-GS; what sets
/// them apart lives in the shared density settings).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NamedModel(pub &'static str);

impl NamedModel {
    /// 3DGS, the model whose defaults every configuration starts from.
    pub const DEFAULT: NamedModel = NamedModel("3dgs");
}

impl ModelSection for NamedModel {
    fn model_name(&self) -> &'static str {
        self.0
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// Writes `section` into the `config.json` object `j`: `"model": NAME`, and
/// `"model_settings"` when the section has settings of its own.
pub fn write_section(section: &dyn ModelSection, j: &mut serde_json::Value) {
    j["model"] = serde_json::json!(section.model_name());
    let settings = section.settings_json();
    if !settings.is_null() {
        j["model_settings"] = settings;
    }
}
