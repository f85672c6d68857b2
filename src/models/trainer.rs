//! The trainer for a config, its base model picked by the registry: `Trainer::new`,
//! `Trainer::resume` and `Trainer::restore` hand [`BaseModel::of`]'s model to the trainer's
//! `with_model` constructors. They live here, not beside the trainer, because the trainer may
//! not name the models (they depend on it).

use std::path::Path;
use std::sync::Arc;

use super::BaseModel;
use crate::gpu::GpuContext;
use crate::scene::image_source::TrainImages;
use crate::scene::Scene;
use crate::splats::GaussianParams;
use crate::train::checkpoint::Checkpoint;
use crate::train::trainer::{TrainConfig, Trainer};

impl Trainer {
    /// Sets up training of `init` on the training views of `scene` (image `k` of
    /// `train_images` is that of `scene.train[k]`: a `&Vec<Image>` in memory, or
    /// [`TrainImages::streamed`] from the files), as the base model `config` trains.
    pub fn new(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        init: &GaussianParams,
        config: TrainConfig,
    ) -> anyhow::Result<Self> {
        let model = BaseModel::of(&config).model();
        Self::with_model(ctx, scene, train_images, init, config, model)
    }

    /// A trainer continuing the run saved in the checkpoint at `path` on `scene`, which must
    /// be the scene it was trained on, with the same configuration (only `iterations` may
    /// differ).
    pub fn resume(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        config: TrainConfig,
        path: &Path,
    ) -> anyhow::Result<Self> {
        let model = BaseModel::of(&config).model();
        Self::resume_with_model(ctx, scene, train_images, config, path, model)
    }

    /// As [`Trainer::resume`] from a checkpoint already in memory (`path` is named in errors).
    pub fn restore(
        ctx: &Arc<GpuContext>,
        scene: &Scene,
        train_images: impl Into<TrainImages>,
        config: TrainConfig,
        ck: &Checkpoint,
        path: &Path,
    ) -> anyhow::Result<Self> {
        let model = BaseModel::of(&config).model();
        Self::restore_with_model(ctx, scene, train_images, config, ck, path, model)
    }
}
