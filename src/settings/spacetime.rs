//! SpacetimeGaussians: when a Gaussian counts as present in a frame.

/// Temporal weight below which LPM in time treats a Gaussian as absent from the frame (our
/// decision, issue 18): at 5 % of its opacity a Gaussian cannot be what an error region of this
/// frame shows, and densifying or resetting it for that region would act on content that lives
/// at other times. `e^{−u²} ≥ 0.05` keeps `|t − c| ≤ 1.73·e^{s}`.
pub const PRESENT_MIN_WEIGHT: f64 = 0.05;
