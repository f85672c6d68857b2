//! MCMC as a density strategy (3D Gaussian Splatting as Markov Chain Monte Carlo, Kheradmand et
//! al. 2024): the Gaussians are samples that the optimizer moves, not a set that grows by rules.
//!
//! - Every refinement (the schedule's densify iterations): each *dead* Gaussian (opacity ≤
//!   `min_opacity`) is moved onto a live one drawn ∝ opacity, and the source and its copies share
//!   its opacity and scale so that the stack renders as the one did ([`plan`]); then the model
//!   grows to the budget curve's target ([`crate::train::density::growth`], 5 % a step by
//!   default) by copying Gaussians drawn ∝ opacity the same way. Nothing is pruned, nothing is
//!   split by a gradient threshold, and there is no opacity reset: the count is the curve's.
//! - Every optimizer step: the opacity and scale regularisers' gradients are added before the
//!   step, and after it each Gaussian's centre takes a step of noise shaped by its own
//!   covariance and gated to the faint ones (stochastic-gradient Langevin dynamics): faint
//!   Gaussians explore, opaque ones stay where the loss holds them.
//!
//! The host reads the opacities back once per refinement (4 bytes a Gaussian) to plan; the
//! kernels apply the plan (`glsl/mcmc/`), each checked against `crate::reference::mcmc`.
//!
//! The noise's size is `position_lr · noise_lr · Σ / extent²`: in the training frame (extent 1)
//! exactly the peers' `lr · noise_lr · Σ` for a scene of scale 1, and independent of the units
//! the scene was given in (their product has units of length³).

pub mod config;
pub mod gpu;
pub mod plan;
pub mod strategy;

pub use config::McmcConfig;
pub use strategy::{McmcEvent, McmcStrategy};
