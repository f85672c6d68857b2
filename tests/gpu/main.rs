//! The `gpu` test crate: one binary for the modules below (linking one test binary per
//! file cost most of the suite's build). Each module is one former test file.

#[path = "../support/child_run.rs"]
mod child_run;
#[path = "../support/kernel_fixtures.rs"]
mod kernel_fixtures;

mod adam;
mod backward;
mod bands;
mod clamps;
mod decoder;
mod density;
mod forward;
mod loss;
mod lpips;
mod lpm;
mod mcmc;
mod mip;
mod scale;
mod smoke;
mod sort;
mod spacetime;
mod spacetime_passes;
mod splats_gpu;
mod surfel_backward;
mod surfel_forward;
