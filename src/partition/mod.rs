//! Training past one device: a scene cut into overlapping blocks on its ground plane
//! ([`plan`]), each block an ordinary scene folder ([`blocks`]) that `train` reads unchanged,
//! Slurm job scripts that train the blocks as one job array and merge them after it
//! ([`slurm`]), and the merge of the blocks' models into one ([`merge`]).
//!
//! The steps, and why each is where it is, are in `docs/partition.md`.

pub mod assign;
pub mod blocks;
pub mod coarse;
pub mod grid;
pub mod ground;
pub mod masks;
pub mod merge;
pub mod plan;
pub mod slurm;

pub use plan::{make_plan, GridChoice, PartitionOptions, Plan, Targets};
