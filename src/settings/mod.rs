//! The constants and settings the GPU kernels and their f64 oracles (`crate::reference`) both
//! follow: the rasterizers' thresholds and clamps, Mip-Splatting's filter constants, the
//! spacetime presence weight. They live below both, so production code reads them here and
//! never reaches into an oracle for a number (docs/clamps.md explains each value).

pub mod mip;
pub mod raster;
pub mod spacetime;
pub mod surfel;
