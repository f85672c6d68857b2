//! The `inputs` test crate: one binary for the modules below (linking one test binary per
//! file cost most of the suite's build). Each module is one former test file.

#[path = "../support/colmap_support.rs"]
mod colmap_support;
#[path = "../support/fuzz_support.rs"]
mod fuzz_support;

mod colmap;
mod colmap_bad_input;
mod colmap_undistort;
mod decoder_file;
mod fuzz_readers;
mod images;
mod init;
mod inputs_that_lie;
mod lpm_matching;
mod lpm_shared_data;
mod ply;
mod ply_models;
mod scene_frames;
mod transforms;
mod triangulated_init;
mod video_scenes;
