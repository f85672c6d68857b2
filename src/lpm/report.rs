//! What LPM did: one step's report (metrics.json's per-step telemetry, `bench trade`) and the
//! run's totals.

use crate::train::strategy::StrategyEvent;

/// What one LPM step did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LpmStepReport {
    pub iteration: u32,
    pub view: usize,
    pub reference: Option<usize>,
    pub regions: usize,
    pub paired: usize,
    pub zones: usize,
    /// The error-region block side used at this step (pixels).
    pub block: u32,
    /// Zone radii relative to the scene extent (bounding radius / extent): mean and largest,
    /// over the zones kept.
    pub radius_mean: f64,
    pub radius_max: f64,
    /// Zones dropped as wider than `max_zone_radius` scene extents.
    pub wide: usize,
    /// Zones kept but ignored by the opacity reset, as wider than `reset_max_zone_radius`.
    pub no_reset: usize,
    /// Zones dropped as holding more than `max_zone_share` of the model.
    pub too_full: usize,
    /// The largest share of the model one kept zone holds.
    pub inside_max_share: f64,
    /// Gaussian centres inside zones, summed over the zones (before densification).
    pub inside: u64,
    /// Gaussians densified only because of the lowered threshold.
    pub lowered: u32,
    /// Extra (density-aware) prunes: Gaussians removed by that rule that ADC kept.
    pub pruned: u32,
    /// Gaussians whose opacity LPM reset.
    pub reset: u32,
    pub added: u32,
    /// Surface samples offered to the guided strategy (`surface_share`; MCMC moves dead
    /// Gaussians onto some of them, its own events say how many).
    pub surface_samples: usize,
    /// ADC was skipped (no zone, `skip_adc_without_zone`).
    pub skipped_adc: bool,
    /// This step ran only the opacity reset (a reset iteration without LPM's density part).
    pub reset_only: bool,
    pub seconds: f64,
}

impl LpmStepReport {
    /// The count and the radii (relative to the scene extent) of the zones kept.
    pub fn set_zone_sizes(&mut self, radii: impl Iterator<Item = f32>, extent: f64) {
        let rel: Vec<f64> = radii.map(|r| r as f64 / extent.max(1e-30)).collect();
        self.zones = rel.len();
        (self.radius_mean, self.radius_max) = match rel.len() {
            0 => (0.0, 0.0),
            n => (
                rel.iter().sum::<f64>() / n as f64,
                rel.iter().copied().fold(0.0, f64::max),
            ),
        };
    }

    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "iteration": self.iteration, "view": self.view, "reference": self.reference,
            "regions": self.regions, "paired": self.paired, "zones": self.zones,
            "block": self.block, "radius_mean_rel": self.radius_mean,
            "radius_max_rel": self.radius_max, "wide_dropped": self.wide,
            "no_reset_zones": self.no_reset, "too_full_dropped": self.too_full,
            "inside_max_share": self.inside_max_share, "inside": self.inside,
            "lowered": self.lowered, "pruned_extra": self.pruned, "opacity_reset": self.reset,
            "added": self.added, "surface_samples": self.surface_samples,
            "skipped_adc": self.skipped_adc, "reset_only": self.reset_only,
            "seconds": self.seconds,
        })
    }
}

impl StrategyEvent for LpmStepReport {
    fn to_json(&self) -> serde_json::Value {
        LpmStepReport::to_json(self)
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// Sums over the run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LpmTotals {
    pub steps: u32,
    pub steps_with_zones: u32,
    /// Error regions found, and how many of them were paired with a region of the neighbour
    /// view; each pair makes one zone (so `zones` ≤ `paired` ≤ `regions`).
    pub regions: u64,
    pub paired: u64,
    pub zones: u64,
    pub lowered: u64,
    pub pruned: u64,
    pub reset: u64,
    pub added: u64,
    /// Gaussian centres inside zones (summed over steps and zones).
    pub inside: u64,
    /// Mean over all zones of their radius relative to the scene extent.
    pub radius_mean: f64,
    pub radius_max: f64,
    /// Zones dropped as wider than `max_zone_radius`.
    pub wide: u64,
    /// Zones the opacity reset ignored (wider than `reset_max_zone_radius`).
    pub no_reset: u64,
    /// Zones dropped as holding more than `max_zone_share` of the model.
    pub too_full: u64,
    /// The largest share of the model one kept zone held, over the run.
    pub inside_max_share: f64,
    /// Density steps whose ADC was skipped (no zone).
    pub skipped_adc: u32,
    pub seconds: f64,
}

impl LpmTotals {
    /// The totals for `metrics.json`, with LPM's share of a run of `iterations` that took
    /// `train_seconds`.
    pub fn to_json(&self, train_seconds: f64, iterations: u32) -> serde_json::Value {
        serde_json::json!({
            "steps": self.steps, "steps_with_zones": self.steps_with_zones,
            "regions": self.regions, "paired": self.paired, "zones": self.zones,
            "lowered": self.lowered, "pruned_extra": self.pruned, "opacity_reset": self.reset,
            "added": self.added, "inside": self.inside, "radius_mean_rel": self.radius_mean,
            "radius_max_rel": self.radius_max, "wide_dropped": self.wide,
            "no_reset_zones": self.no_reset, "too_full_dropped": self.too_full,
            "inside_max_share": self.inside_max_share, "skipped_adc": self.skipped_adc, "seconds": self.seconds,
            "share_of_training": self.seconds / train_seconds.max(1e-12),
            "ms_per_iteration": 1e3 * self.seconds / iterations.max(1) as f64,
        })
    }

    pub(crate) fn add(&mut self, r: &LpmStepReport) {
        self.steps += 1;
        self.steps_with_zones += (r.zones > 0) as u32;
        if r.zones > 0 {
            let before = self.zones as f64;
            self.radius_mean = (self.radius_mean * before + r.radius_mean * r.zones as f64)
                / (before + r.zones as f64);
        }
        self.radius_max = self.radius_max.max(r.radius_max);
        self.inside += r.inside;
        self.skipped_adc += r.skipped_adc as u32;
        self.regions += r.regions as u64;
        self.paired += r.paired as u64;
        self.zones += r.zones as u64;
        self.wide += r.wide as u64;
        self.no_reset += r.no_reset as u64;
        self.too_full += r.too_full as u64;
        self.inside_max_share = self.inside_max_share.max(r.inside_max_share);
        self.lowered += r.lowered as u64;
        self.pruned += r.pruned as u64;
        self.reset += r.reset as u64;
        self.added += r.added as u64;
        self.seconds += r.seconds;
    }
}
