//! Mip-Splatting's 3D smoothing filter constants (docs/algorithms/base-models.md §2.2).

/// The 3D filter's variance scale (hard-coded 0.2 in the official code).
pub const FILTER_SCALE: f64 = 0.2;
/// Cameras closer than this (camera z) do not count.
pub const MIN_DEPTH: f64 = 0.2;
/// A projection up to this fraction of the image past an edge still counts.
pub const FRUSTUM_MARGIN: f64 = 0.15;
