//! The `train` test crate: one binary for the modules below (linking one test binary per
//! file cost most of the suite's build). Each module is one former test file.

#[path = "../support/child_run.rs"]
mod child_run;
#[path = "../support/cli_support.rs"]
mod cli_support;
#[path = "../support/sphere_rig.rs"]
mod sphere_rig;

mod ahead;
mod batch;
mod budget;
mod end_to_end;
mod frames;
mod guided_sampling;
mod image_cache;
mod lpm_train;
mod mesh_2dgs;
mod mesh_tsdf;
mod omega_freeze;
mod spacetime;
mod spacetime_density;
mod train_2dgs;
mod world_culls;
