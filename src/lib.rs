//! lpmsplat: a Vulkan compute engine (on `ash`) that trains 3D Gaussian Splatting scenes and
//! implements Localized Point Management (LPM, CVPR 2025).
//!
//! Dependencies flow one way: `gpu`, `scene` → `splats` → render → train → `lpm`, `models`
//! → `triangulated_init` → CLI. The trainer is generic over a density strategy (`train::strategy`: ADC, or LPM
//! wrapping it); a base model (`models`) sets what it changes in the training config.

pub mod bench;
pub mod error;
pub mod gpu;
pub mod initial;
pub mod lpips;
pub mod lpm;
pub mod mcmc;
pub mod mesh;
pub mod metrics;
pub mod models;
pub mod partition;
pub mod plot;
pub mod reference;
pub mod render;
pub mod scene;
pub mod settings;
pub mod splats;
pub mod strategies;
pub mod synthetic;
pub mod taming;
pub mod train;
pub mod triangulated_init;

/// Embedded SPIR-V, one constant per `glsl/**/*.comp` (see `build.rs`).
pub mod shaders {
    include!(concat!(env!("OUT_DIR"), "/shaders.rs"));
}
