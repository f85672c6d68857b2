//! Everything that decides what LPM does: its settings (docs/algorithms/lpm.md's numbers by default, the
//! authors' rules as one preset), their checks, and their JSON for config.json and checkpoints.

use std::path::PathBuf;

use crate::lpm::pairing::RegionKeypoints;
use crate::lpm::region_units::RegionUnit;
use crate::lpm::reset_settings::{OpacityResetSettings, FLAG_IN_BALL};
use crate::lpm::{
    ConeRadius, MatchSettings, NeighbourChoice, RegionSettings, ZoneGeometry, ZoneSettings,
};

/// Everything that decides what LPM does (docs/algorithms/lpm.md's numbers by default).
#[derive(Debug, Clone, PartialEq)]
pub struct LpmConfig {
    /// LPM runs at iterations `from < t < until` that are multiples of `interval` and are also
    /// densify iterations (it is fused with the density step).
    pub interval: u32,
    pub from: u32,
    pub until: u32,
    /// Gradient-threshold multiplier inside zones.
    pub threshold_ratio: f32,
    /// What a zone's candidate's score is multiplied by when a budget ranks the candidates
    /// (every score on one scale, the statistic over ADC's own threshold): LPM's say in *where*
    /// a budget goes, never in how big it is. 1: zones do not rank; the paper's rule (ranking
    /// over the lowered threshold, `DensityConfig::rank_lowered`) is `1 / threshold_ratio`.
    pub zone_weight: f32,
    /// Add a Gaussian at the centre of sparse zones.
    pub add_points: bool,
    /// Reset the opacity of the Gaussians in front of zones.
    pub reset: bool,
    /// A zone with fewer Gaussians inside than this gets a new one.
    pub add_below: u32,
    /// Opacity of added Gaussians.
    pub add_opacity: f64,
    pub regions: RegionSettings,
    pub reset_settings: OpacityResetSettings,
    pub zones: ZoneSettings,
    pub matching: MatchSettings,
    /// Seed of the per-step neighbour pick.
    pub seed: u64,
    /// Dump PNGs of every LPM step here.
    pub debug_dir: Option<PathBuf>,
    /// The LPM opacity reset runs at iterations `from < t < until` that are multiples of this,
    /// whether or not the density step runs there (the authors' own `reset_interval`: 100, 200
    /// suggested indoors).
    pub reset_interval: u32,
    /// Density-aware pruning after the lowered-threshold densification.
    pub prune: PruneMode,
    /// The radius of the in-front cone (and, with `reset_settings.threshold_set ==
    /// FLAG_IN_BALL`, of the ball whose opacities give the reset threshold).
    pub cone: ConeRadius,
    /// On a density step where LPM finds no zone, skip ADC as well (the authors' code: its
    /// densify-and-prune only runs when a zone exists); the iteration's optimizer step then
    /// runs as on any other iteration. Off: global ADC runs on every density step.
    pub skip_adc_without_zone: bool,
    /// Which matched keypoints speak for an error region (default: all in its box, as the
    /// paper and the authors; or only those on its own error blocks).
    pub region_keypoints: RegionKeypoints,
    /// Drop zones whose radius exceeds this many scene extents (`None`: keep every zone). On
    /// Truck at full size (H100, 2026-11-27) 24 of 144 steps had a zone wider than the scene
    /// (up to 8.3 extents: keypoints of a region spanning near and far surfaces), and those
    /// steps made 84 % of the run's opacity resets and 81 % of its lowered-threshold
    /// densifications: a zone that holds most of the model is global, not localized.
    pub max_zone_radius: Option<f64>,
    /// Zones wider than this many scene extents still lower the threshold, count their
    /// Gaussians and get points added, but the opacity reset ignores them: nothing counts as in
    /// front of them or in their ball (`None`: every zone resets). Their Gaussians still count
    /// in the threshold's set ([`FLAG_INSIDE`](crate::lpm::reset_settings::FLAG_INSIDE)). On Truck
    /// `-r 4` (seed 12) one step whose zone was 3.8 extents wide reset 24 % of the model's
    /// opacities and cost 1.46 dB for a while (docs/results/lpm.md); dropping such zones
    /// altogether (`max_zone_radius`) also loses what their lowered threshold adds.
    pub reset_max_zone_radius: Option<f64>,
    /// What one zone is built from: a connected component of error blocks (the paper), one
    /// block, or the random-blocks control.
    pub region_unit: RegionUnit,
    /// Zones holding more than this share of the model's Gaussians are dropped (counted by the
    /// membership pass; `None`: no limit). A zone that holds a tenth of the model is not local.
    pub max_zone_share: Option<f64>,
    /// With a strategy that moves dead Gaussians (MCMC): the largest share of a step's dead
    /// Gaussians moved onto surface samples inside the local zones (the SfM points the view
    /// observes there, coloured from the ground truth, `lpm::surface`) instead of onto live
    /// Gaussians. 0: none. Needs local zones from SfM tracks; elsewhere there are no samples.
    pub surface_share: f64,
}

/// The largest share of the model one local zone may hold ([`LpmConfig::with_local_zones`]).
pub const LOCAL_MAX_ZONE_SHARE: f64 = 0.01;

/// Density-aware pruning (docs/algorithms/lpm.md step 8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum PruneMode {
    /// The authors' code: k = the Gaussians densified only because of the lowered threshold;
    /// over the model after densification (clones and split children included, faint ones too)
    /// every Gaussian whose opacity is at or below the k-th smallest is pruned, OR-ed with ADC's
    /// own prune (so it largely overlaps the faint-Gaussian prune).
    #[default]
    Authors,
    /// Remove exactly k more Gaussians: the k faintest of those ADC keeps untouched.
    Additive,
    /// No extra pruning.
    Off,
}

impl PruneMode {
    pub fn parse(s: &str) -> anyhow::Result<PruneMode> {
        Ok(match s {
            "authors" => PruneMode::Authors,
            "additive" => PruneMode::Additive,
            "off" => PruneMode::Off,
            other => anyhow::bail!(
                "LPM pruning {other:?} is unknown. Fix: choose authors, additive or off"
            ),
        })
    }
    pub fn name(&self) -> &'static str {
        match self {
            PruneMode::Authors => "authors",
            PruneMode::Additive => "additive",
            PruneMode::Off => "off",
        }
    }
}

impl Default for LpmConfig {
    fn default() -> Self {
        Self {
            interval: 100,
            from: 500,
            until: 15_000,
            threshold_ratio: 0.5,
            zone_weight: 1.5,
            add_points: true,
            reset: true,
            add_below: 3,
            add_opacity: 0.1,
            regions: RegionSettings::default(),
            // The authors' top 70 % (k = int(0.7 n)) rather than docs/algorithms/lpm.md's 0.7 quantile: the
            // paper's reading was never measured to help, so the authors' rule is the default.
            reset_settings: OpacityResetSettings {
                quantile: 0.3,
                ..OpacityResetSettings::default()
            },
            zones: ZoneSettings::default(),
            matching: MatchSettings::default(),
            seed: 0,
            debug_dir: None,
            reset_interval: 100,
            prune: PruneMode::Authors,
            // The cone through the error region: on Truck at full size (H200, seed 0) it led ADC
            // by +0.06 / +0.06 / +0.11 dB at 7k / 14k / 21k, where the bounding cone had been
            // -0.73 / -0.03 at 7k / 15k with twice the resets; at -r 4 it was above the bounding
            // cone on both seeds measured (docs/results/gpu.md, "LPM at full size").
            cone: ConeRadius::Region,
            skip_adc_without_zone: false,
            region_keypoints: RegionKeypoints::Box,
            max_zone_radius: None,
            reset_max_zone_radius: None,
            region_unit: RegionUnit::Components,
            max_zone_share: None,
            surface_share: 0.0,
        }
    }
}

impl LpmConfig {
    /// The authors' code's rules exactly (docs/algorithms/lpm.md step 6–9, "Authors' code"): box zones from
    /// perimeter rays, the in-front cone and the reset's threshold set on a ball of the box's
    /// smallest half-extent, the top 70 % of those opacities (k = ⌊0.7 n⌋), pruning OR-ed into
    /// ADC's mask, no point addition, and no ADC on steps without a zone.
    pub fn authors() -> LpmConfig {
        let mut c = LpmConfig {
            add_points: false,
            prune: PruneMode::Authors,
            cone: ConeRadius::SmallestHalfExtent,
            skip_adc_without_zone: true,
            ..LpmConfig::default()
        };
        c.zones.geometry = ZoneGeometry::AuthorsBox;
        c.reset_settings.threshold_set = FLAG_IN_BALL;
        c.matching.neighbours.choice = NeighbourChoice::Random;
        c
    }

    /// Zones local by construction (`--lpm-zone local`): one zone per error block, the
    /// [`ZoneGeometry::Local`] slab (depths of matches seen at ≥ 2° of parallax, their 20–80 %
    /// quantiles ± 5 %), and no zone holding more than 1 % of the model.
    pub fn with_local_zones(mut self) -> LpmConfig {
        self.zones.geometry = ZoneGeometry::Local;
        self.region_unit = RegionUnit::Blocks;
        self.max_zone_share = Some(LOCAL_MAX_ZONE_SHARE);
        self
    }

    /// Whether LPM's density part runs at `iteration` (the trainer also requires a densify
    /// iteration).
    pub fn runs_at(&self, iteration: u32) -> bool {
        self.interval > 0
            && iteration > self.from
            && iteration < self.until
            && iteration.is_multiple_of(self.interval)
    }

    /// Whether LPM's opacity reset runs at `iteration`.
    pub fn resets_at(&self, iteration: u32) -> bool {
        self.reset
            && self.reset_interval > 0
            && iteration > self.from
            && iteration < self.until
            && iteration.is_multiple_of(self.reset_interval)
    }

    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.threshold_ratio > 0.0 && self.threshold_ratio.is_finite(),
            "LPM threshold ratio {} (--lpm-threshold-ratio) must be positive and finite. Fix: \
             pass e.g. 0.5 (halves the gradient threshold inside zones) or 1 (keeps ADC's)",
            self.threshold_ratio
        );
        anyhow::ensure!(
            self.zone_weight > 0.0 && self.zone_weight.is_finite(),
            "LPM zone weight {} (--lpm-zone-weight) must be positive and finite. Fix: pass e.g. \
             1.5 (a zone's candidate counts half as much again under a budget) or 1 (zones do \
             not rank)",
            self.zone_weight
        );
        anyhow::ensure!(
            self.add_opacity > 0.0 && self.add_opacity < 1.0,
            "LPM added-point opacity {} must lie in (0, 1)",
            self.add_opacity
        );
        anyhow::ensure!(
            self.regions.quantile.is_finite() && (0.0..=1.0).contains(&self.regions.quantile),
            "LPM error quantile {} must lie in [0, 1] (default 0.4)",
            self.regions.quantile
        );
        anyhow::ensure!(
            self.regions.block <= 256,
            "LPM block size {} (--lpm-block) must lie in 1..=256 pixels, or 0 for the default (16 \
             pixels at 1 megapixel, scaled with the image's diagonal)",
            self.regions.block
        );
        anyhow::ensure!(
            self.reset_interval > 0 || !self.reset,
            "LPM reset interval 0 (--lpm-reset-interval): use a positive interval, or \
             --lpm-no-reset to turn the reset off"
        );
        anyhow::ensure!(
            self.regions.keep_fraction.is_finite()
                && (0.0..1.0).contains(&self.regions.keep_fraction),
            "LPM block fraction {} (--lpm-block-fraction) must lie in [0, 1) (default 0.85: a block is kept when more \
             than 85 % of its pixels are error pixels)",
            self.regions.keep_fraction
        );
        if let Some(r) = self.max_zone_radius {
            anyhow::ensure!(
                r > 0.0 && r.is_finite(),
                "LPM largest zone radius {r} (--lpm-max-zone-radius) must be a positive number \
                 of scene extents (1 drops the zones wider than the scene)"
            );
        }
        if let Some(r) = self.reset_max_zone_radius {
            anyhow::ensure!(
                r > 0.0 && r.is_finite(),
                "LPM largest resetting zone radius {r} (--lpm-reset-max-zone-radius) must be a \
                 positive number of scene extents (1: zones wider than the scene reset nothing)"
            );
        }
        if let Some(share) = self.max_zone_share {
            anyhow::ensure!(
                share > 0.0 && share <= 1.0,
                "LPM largest zone share {share} (--lpm-max-zone-share) must lie in (0, 1]. Fix: \
                 pass e.g. 0.01 (no zone holds more than 1 % of the model's Gaussians)"
            );
        }
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.surface_share),
            "LPM surface share {} (--lpm-surface-share) must lie in [0, 1]. Fix: pass e.g. 0.5 \
             (up to half of each MCMC refinement's dead Gaussians move onto the local zones' \
             surface samples) or 0 (none)",
            self.surface_share
        );
        self.reset_settings.top_basis_points()?;
        self.reset_settings.reset_logit()?;
        Ok(())
    }

    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "interval": self.interval, "from": self.from, "until": self.until,
            "threshold_ratio": self.threshold_ratio, "zone_weight": self.zone_weight,
            "add_points": self.add_points,
            "reset": self.reset, "add_below": self.add_below, "add_opacity": self.add_opacity,
            "error_quantile": self.regions.quantile, "block": self.regions.block,
            "keep_fraction": self.regions.keep_fraction,
            "reset_quantile": self.reset_settings.quantile,
            "reset_opacity": self.reset_settings.opacity,
            "reset_threshold_set": if self.reset_settings.threshold_set == FLAG_IN_BALL {
                "ball"
            } else {
                "inside"
            },
            "reset_interval": self.reset_interval,
            "prune": self.prune.name(),
            "cone_radius": format!("{:?}", self.cone),
            "skip_adc_without_zone": self.skip_adc_without_zone,
            "zone_geometry": format!("{:?}", self.zones.geometry),
            "zone_margin": self.zones.margin,
            "neighbour_angle_deg": self.matching.neighbours.max_angle_deg,
            "neighbours": self.matching.neighbours.choice.name(),
            "region_keypoints": self.region_keypoints.name(),
            "max_zone_radius": self.max_zone_radius,
            "reset_max_zone_radius": self.reset_max_zone_radius,
            "region_unit": self.region_unit.name(),
            "max_zone_share": self.max_zone_share,
            "min_parallax_deg": self.zones.min_parallax_deg,
            "band_quantiles": [self.zones.band_quantiles.0, self.zones.band_quantiles.1],
            "band_margin": self.zones.band_margin,
            "surface_share": self.surface_share,
        })
    }
}

impl LpmConfig {
    /// The settings a checkpoint records and a resumed run must match: [`LpmConfig::to_json`]
    /// without the settings added after checkpoints existed while they hold the value every
    /// earlier build used (the random neighbour pick, a region's whole box), so a checkpoint
    /// written before they existed resumes under the same rules and one trained with the other
    /// value is still told apart.
    pub fn checkpoint_json(&self) -> serde_json::Value {
        let mut j = self.to_json();
        if let Some(o) = j.as_object_mut() {
            if self.matching.neighbours.choice == NeighbourChoice::Random {
                o.remove("neighbours");
            }
            if self.region_keypoints == RegionKeypoints::Box {
                o.remove("region_keypoints");
            }
            if self.max_zone_radius.is_none() {
                o.remove("max_zone_radius");
            }
            if self.reset_max_zone_radius.is_none() {
                o.remove("reset_max_zone_radius");
            }
            // Settings of 2026-12-02: absent from older checkpoints, which ran with these values.
            if self.region_unit == RegionUnit::Components {
                o.remove("region_unit");
            }
            if self.max_zone_share.is_none() {
                o.remove("max_zone_share");
            }
            // Of 2026-12-07: older checkpoints moved no dead Gaussian onto surface samples.
            if self.surface_share == 0.0 {
                o.remove("surface_share");
            }
            if self.zones.geometry != ZoneGeometry::Local {
                for k in ["min_parallax_deg", "band_quantiles", "band_margin"] {
                    o.remove(k);
                }
            }
        }
        j
    }
}
