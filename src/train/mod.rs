//! Training on the GPU: the loss, the optimiser and its schedules, adaptive density control,
//! the training data, the base models' passes (`passes`) and the trainer loop.

pub mod adam;
pub mod batch;
pub mod checkpoint;
pub mod config;
pub mod data;
pub mod density;
pub mod image_cache;
pub mod loss;
pub mod loss_mask;
pub mod model_section;
pub mod nan_check;
pub mod passes;
pub mod schedule;
pub mod strategy;
pub mod trainer;
