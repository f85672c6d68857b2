//! The Gaussian model: host-side parameters, PLY in/out (Inria layout), `.splat` out (web viewers), initialisation.
//!
//! The GPU parameter buffers are filled from [`GaussianParams`]; this module keeps to plain
//! host arrays.

pub mod budget_draw;
pub mod decoder_json;
pub mod gpu;
pub mod init;
pub mod knn;
pub mod model;
pub mod ply;
pub mod sh_planes;
pub mod splat_file;

pub use init::{from_sfm, from_sfm_points, random_init};
pub use model::{ExtraGroup, ExtraValues, GaussianParams, ParamField, MAX_SH_DEGREE, SH_C0};
pub use ply::{
    ply_comments, read_ply, read_ply_with_degree, require_nonempty, write_ply,
    write_ply_with_comments,
};
pub use splat_file::write_splat;
