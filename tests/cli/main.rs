//! The `cli` test crate: one binary for the modules below (linking one test binary per
//! file cost most of the suite's build). Each module is one former test file.

#[path = "../support/cli_support.rs"]
mod cli_support;

mod bench;
mod buffer_widths;
mod front_door;
mod generate_city;
mod partition;
mod partition_slurm;
mod render_scales;
mod viewer_formats;
