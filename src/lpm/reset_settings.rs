//! What the LPM opacity reset and zone membership share between the GPU passes
//! ([`super::gpu`]) and their CPU oracle ([`crate::reference::lpm_membership`]): the membership
//! flag bits, the reset's settings and what a reset reports.

/// Bit 0 of a Gaussian's membership flags: its centre is inside at least one zone.
pub const FLAG_INSIDE: u32 = 1;
/// Bit 1: its centre is in front of at least one zone.
pub const FLAG_IN_FRONT: u32 = 2;
/// Bit 2: its centre is within the cone radius of a zone's centre (the set whose opacities give
/// the reset threshold under the authors' rules).
pub const FLAG_IN_BALL: u32 = 4;

/// Denominator of the reset share on the GPU: the share is applied in whole basis points.
pub const SHARE_DENOMINATOR: u32 = 10_000;

/// The LPM opacity reset (docs/algorithms/lpm.md step 8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpacityResetSettings {
    /// Among the n Gaussians inside zones, the k = ⌊n·(1 − quantile)⌋ highest opacities are at or
    /// above the threshold: the threshold is the k-th largest opacity (the `quantile` in the
    /// nearest-rank sense). No reset when k = 0. The share 1 − quantile is rounded to whole basis
    /// points. 0.7 follows docs/algorithms/lpm.md; the authors' code (`topk` of int(0.7·n)) is quantile 0.3.
    pub quantile: f64,
    /// The opacity given to reset Gaussians.
    pub opacity: f64,
    /// The membership flag of the Gaussians whose opacities give the threshold:
    /// [`FLAG_INSIDE`] (inside a zone, docs/algorithms/lpm.md) or [`FLAG_IN_BALL`] (within the zone's cone radius
    /// of its centre: the authors' code, a ball of the box's smallest half-extent).
    pub threshold_set: u32,
}

impl Default for OpacityResetSettings {
    fn default() -> Self {
        Self {
            quantile: 0.7,
            opacity: 0.01,
            threshold_set: FLAG_INSIDE,
        }
    }
}

impl OpacityResetSettings {
    /// 1 − quantile in basis points (and a check of the threshold set).
    pub fn top_basis_points(&self) -> anyhow::Result<u32> {
        anyhow::ensure!(
            self.threshold_set == FLAG_INSIDE || self.threshold_set == FLAG_IN_BALL,
            "LPM opacity reset: threshold set {} is neither FLAG_INSIDE nor FLAG_IN_BALL",
            self.threshold_set
        );
        anyhow::ensure!(
            self.quantile.is_finite() && (0.0..=1.0).contains(&self.quantile),
            "LPM opacity reset: quantile {} is outside [0, 1]; use a value such as 0.7",
            self.quantile
        );
        Ok(((1.0 - self.quantile) * SHARE_DENOMINATOR as f64).round() as u32)
    }

    /// logit(opacity), rounded once to f32.
    pub fn reset_logit(&self) -> anyhow::Result<f32> {
        anyhow::ensure!(
            self.opacity > 0.0 && self.opacity < 1.0,
            "LPM opacity reset: opacity {} is outside (0, 1); use a value such as 0.01",
            self.opacity
        );
        Ok((self.opacity / (1.0 - self.opacity)).ln() as f32)
    }
}

/// What one opacity reset did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OpacityResetStats {
    /// Gaussians inside at least one zone.
    pub inside: u32,
    /// The threshold logit (`None`: nothing inside, or k = 0, so no reset).
    pub threshold_logit: Option<f32>,
    /// Gaussians whose opacity was reset.
    pub reset: u32,
}
