//! The rules a density step follows and what it reports: the statistic (3DGS's gradient or
//! Pixel-GS's pixel-weighted one), the thresholds (Inria's defaults, checked and formed once as
//! the f32 numbers both the kernels and the host reference compare against), the phase, and the
//! outcome.

use super::growth::BudgetCurve;
use anyhow::{bail, ensure};

/// What the densification statistic averages over the views that saw a Gaussian.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Statistic {
    /// 3DGS: the NDC mean-gradient norm, one vote per view.
    #[default]
    Gradient,
    /// Pixel-GS (docs/algorithms/base-models.md §3): each view weighted by the pixels the Gaussian contributed
    /// to there, its norm also scaled by min(1, (depth / (depth_threshold · extent))²). Needs the
    /// backward's per-splat pixel counts.
    PixelWeighted { depth_threshold: f32 },
}

impl Statistic {
    /// Pixel-GS's depth threshold (relative to the scene extent).
    pub const PIXEL_GS_DEPTH_THRESHOLD: f32 = 0.37;

    pub fn pixel_gs() -> Statistic {
        Statistic::PixelWeighted {
            depth_threshold: Self::PIXEL_GS_DEPTH_THRESHOLD,
        }
    }

    pub fn needs_pixel_counts(&self) -> bool {
        matches!(self, Statistic::PixelWeighted { .. })
    }

    pub fn name(&self) -> &'static str {
        match self {
            Statistic::Gradient => "gradient",
            Statistic::PixelWeighted { .. } => "pixel-weighted",
        }
    }

    /// The accumulate kernel's mode and depth scale 1 / (depth_threshold · extent).
    pub fn kernel_mode(&self, extent: f64) -> anyhow::Result<(u32, f32)> {
        Ok(match *self {
            Statistic::Gradient => (0, 0.0),
            Statistic::PixelWeighted { depth_threshold } => {
                let d = depth_threshold as f64 * extent;
                ensure!(
                    d.is_finite() && d > 0.0,
                    "Pixel-GS depth threshold {depth_threshold} × scene extent {extent} must be \
                     positive and finite (default 0.37)"
                );
                (1, (1.0 / d) as f32)
            }
        })
    }
}

/// The density-control rules (Inria's defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DensityConfig {
    /// Densify when the averaged NDC mean-gradient norm is at least this.
    pub grad_threshold: f32,
    /// Clone below (≤) and split above this fraction of the scene extent (max axis scale).
    pub percent_dense: f64,
    /// Prune below this opacity.
    pub min_opacity: f64,
    /// With `prune_large`, prune when the max axis scale exceeds this fraction of the extent.
    pub max_world_fraction: f64,
    /// Children's scale divisor (the reference's 0.8 · N with N = 2).
    pub split_shrink: f64,
    /// Prune originals whose largest screen radius (px) exceeds this (with `prune_large` only,
    /// as in the reference); `None` = off, which is what the reference effectively does.
    pub screen_size_limit: Option<f32>,
    /// The opacity reset's ceiling.
    pub opacity_reset_value: f64,
    /// Seed of the split samples.
    pub seed: u64,
    pub statistic: Statistic,
    /// Also densify by the absolute-gradient test of Gaussian Opacity Fields, as Mip-Splatting's
    /// official code does (docs/algorithms/base-models.md §2.5): with `ratio` the fraction of Gaussians whose
    /// usual statistic reaches `grad_threshold`, a Gaussian whose averaged absolute gradient
    /// reaches the `(1 − ratio)` quantile of all of them is densified as well. Gradient
    /// statistic only; needs the backward's absolute gradients.
    pub abs_grad: bool,
    /// At most this many Gaussians after a density step ([`budget`](super::budget)): the additions that
    /// exceed their threshold the most are kept, as many as fit. `None`: no cap.
    pub max_gaussians: Option<usize>,
    /// The exact-budget selection ([`growth`](super::growth)): every Gaussian seen since the
    /// last step is a candidate, ranked by its statistic over `grad_threshold` (× a strategy's
    /// per-Gaussian score weight), and each step keeps as many of the best as its curve's target
    /// leaves room for, so the count follows the curve to the budget whatever the threshold.
    /// `None`: candidates are those over the threshold (ADC).
    pub exact_budget: Option<BudgetCurve>,
    /// Rank candidates under a cap by their statistic over their own (scaled) threshold,
    /// the paper's LPM rule: a Gaussian in a zone at 0.6 τ (score 1.2 over τ/2) beats one
    /// outside at 1.1 τ. `false` (the default): one scale for all, the statistic over
    /// `grad_threshold`, times the strategy's score weight.
    pub rank_lowered: bool,
    /// Grow only Gaussians whose centre lies in this region ([`super::region`]; in the
    /// user's frame here, in the training frame once the trainer has moved it): the others are
    /// never cloned nor split. `None`: anywhere.
    pub grow_within: Option<super::region::GrowthRegion>,
}

impl Default for DensityConfig {
    fn default() -> Self {
        Self {
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            min_opacity: 0.005,
            max_world_fraction: 0.1,
            split_shrink: 1.6,
            screen_size_limit: None,
            opacity_reset_value: 0.01,
            seed: 0,
            statistic: Statistic::Gradient,
            abs_grad: false,
            max_gaussians: None,
            exact_budget: None,
            rank_lowered: false,
            grow_within: None,
        }
    }
}

impl DensityConfig {
    /// The most Gaussians the model may ever hold: the cap, or the exact budget's target,
    /// whichever is lower (`None`: no limit).
    pub fn ceiling(&self) -> Option<usize> {
        let exact = self.exact_budget.map(|b| b.target);
        match (self.max_gaussians, exact) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

/// A strategy's say in a density step's ranking, one value per Gaussian: what the budget keeps
/// the best of. Which Gaussians are candidates does not change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScoreInput<T> {
    /// Multiplies each candidate's statistic ratio (a guide's preference: LPM's zones).
    Weight(T),
    /// Is each candidate's score (a ranking of the strategy's own: the blended score of
    /// `crate::taming`).
    Replace(T),
}

impl<T> ScoreInput<T> {
    pub fn values(&self) -> &T {
        match self {
            ScoreInput::Weight(v) | ScoreInput::Replace(v) => v,
        }
    }
}

/// Per-step inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DensifyArgs {
    /// Scene extent (1.1 × the largest camera distance from their mean).
    pub extent: f64,
    /// World-size (and screen-size, when configured) pruning: after the first opacity reset.
    pub prune_large: bool,
    /// The training iteration: keys the split samples.
    pub iteration: u32,
    /// Which half of densify-and-prune this step runs ([`DensitySchedule::phase`]).
    ///
    /// [`DensitySchedule::phase`]: crate::train::schedule::DensitySchedule::phase
    pub phase: DensifyPhase,
}

/// What a density step may do: both clone/split and prune (3DGS), or only one of them
/// (SpacetimeGaussians: its first rounds grow without pruning, the later ones only prune).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DensifyPhase {
    #[default]
    Both,
    /// Clone and split; nothing is pruned (the official code computes the prune mask in these
    /// rounds but does not apply it).
    GrowOnly,
    /// Prune only, and by opacity alone: no Gaussian crosses the gradient threshold, and the
    /// world- and screen-size prunes are off (the official code's later rounds remove only
    /// what is fainter than the floor).
    PruneOnly,
}

/// The f32 thresholds the kernels compare against, formed once on the host (shared by the GPU
/// push constants and the host reference so both test exactly the same numbers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    pub grad_threshold: f32,
    /// ln(percent_dense · extent)
    pub log_clone_max: f32,
    /// logit(min_opacity)
    pub min_opacity_logit: f32,
    /// ln(max_world_fraction · extent)
    pub log_world_max: f32,
    /// ln(split_shrink)
    pub log_split_shrink: f32,
    /// Negative when screen-size pruning is off.
    pub screen_max: f32,
    pub prune_large: bool,
    /// Every seen Gaussian is a candidate, for the exact budget to choose from
    /// ([`DensityConfig::exact_budget`], on a step that grows).
    pub rank_all: bool,
    /// Scores over the scaled threshold ([`DensityConfig::rank_lowered`]).
    pub rank_lowered: bool,
    /// The region growth is held to ([`DensityConfig::grow_within`]) as the kernel takes it:
    /// per band the axis, lo and hi in f32.
    pub region: Option<[f32; 10]>,
}

impl Thresholds {
    /// Whether growth may happen at `p` ([`Thresholds::region`]), computed as `decide.comp`
    /// does: each band's f32 dot product in the same order, without fused operations.
    pub fn grows_at(&self, p: [f32; 3]) -> bool {
        let Some(w) = self.region else {
            return true;
        };
        (0..2).all(|k| {
            let a = &w[5 * k..5 * k + 5];
            let c = a[0] * p[0] + a[1] * p[1] + a[2] * p[2];
            c >= a[3] && c < a[4]
        })
    }
}

impl Thresholds {
    pub fn new(cfg: &DensityConfig, args: &DensifyArgs) -> anyhow::Result<Self> {
        if !(args.extent > 0.0 && args.extent.is_finite()) {
            bail!(
                "density control: scene extent is {}; it must be a positive finite distance (1.1 × the largest camera distance from the cameras' mean)",
                args.extent
            );
        }
        let positive = |name: &str, v: f64| -> anyhow::Result<()> {
            if !(v > 0.0 && v.is_finite()) {
                bail!("density control: {name} is {v}; it must be positive and finite");
            }
            Ok(())
        };
        positive("percent_dense", cfg.percent_dense)?;
        positive("max_world_fraction", cfg.max_world_fraction)?;
        if !(cfg.min_opacity > 0.0 && cfg.min_opacity < 1.0) {
            bail!(
                "density control: min_opacity is {}; it must be in (0, 1) (default 0.005)",
                cfg.min_opacity
            );
        }
        if !(cfg.split_shrink >= 1.0 && cfg.split_shrink.is_finite()) {
            bail!(
                "density control: split_shrink is {}; it must be ≥ 1 (default 1.6)",
                cfg.split_shrink
            );
        }
        if !cfg.grad_threshold.is_finite() {
            bail!("density control: grad_threshold is not finite");
        }
        let screen_max = match cfg.screen_size_limit {
            Some(px) if !(px >= 0.0 && px.is_finite()) => {
                bail!("density control: screen_size_limit is {px}; it must be ≥ 0 px")
            }
            Some(px) if args.prune_large => px,
            _ => -1.0,
        };
        let p = cfg.min_opacity;
        let (grows, prunes) = match args.phase {
            DensifyPhase::Both => (true, true),
            DensifyPhase::GrowOnly => (true, false),
            DensifyPhase::PruneOnly => (false, true),
        };
        // A phase turns its other half off through the thresholds themselves: no gradient
        // norm reaches +∞ (nor does a lowered one, ∞ × ratio), no logit lies below −∞.
        Ok(Self {
            grad_threshold: if grows {
                cfg.grad_threshold
            } else {
                f32::INFINITY
            },
            log_clone_max: (cfg.percent_dense * args.extent).ln() as f32,
            min_opacity_logit: if prunes {
                (p / (1.0 - p)).ln() as f32
            } else {
                f32::NEG_INFINITY
            },
            log_world_max: (cfg.max_world_fraction * args.extent).ln() as f32,
            log_split_shrink: cfg.split_shrink.ln() as f32,
            // Size prunes belong to 3DGS's combined step only: a grow-only round prunes
            // nothing, a prune-only round (SpacetimeGaussians' later rounds) only the faint.
            screen_max: if grows && prunes { screen_max } else { -1.0 },
            prune_large: args.prune_large && grows && prunes,
            rank_all: cfg.exact_budget.is_some() && grows,
            rank_lowered: cfg.rank_lowered,
            region: cfg.grow_within.map(|r| r.kernel_words()),
        })
    }
}

/// The opacity reset's ceiling as a logit.
pub fn reset_logit(cfg: &DensityConfig) -> anyhow::Result<f32> {
    let p = cfg.opacity_reset_value;
    if !(p > 0.0 && p < 1.0) {
        bail!("density control: opacity_reset_value is {p}; it must be in (0, 1) (default 0.01)");
    }
    Ok((p / (1.0 - p)).ln() as f32)
}

/// What a step did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DensifyOutcome {
    pub before: usize,
    pub after: usize,
    /// Originals carried over (so `before − kept` were pruned or split).
    pub kept: usize,
    pub clones: usize,
    /// Children emitted (two per split parent).
    pub split_children: usize,
    /// The state now has a larger capacity: per-Gaussian buffers owned elsewhere (gradients,
    /// projected, …) must grow to `capacity` too.
    pub grew: bool,
    pub capacity: usize,
    /// The strategy left the model and its statistics untouched on this density iteration (the
    /// authors' LPM skips ADC when it finds no zone): the iteration's optimizer step still runs.
    pub skipped: bool,
    /// Clones and splits the Gaussian budget dropped ([`DensityConfig::max_gaussians`]).
    pub budget_dropped: usize,
}

impl DensifyOutcome {
    /// A step that changed nothing (`skipped`).
    pub fn unchanged(count: usize, capacity: usize) -> DensifyOutcome {
        DensifyOutcome {
            before: count,
            after: count,
            kept: count,
            clones: 0,
            split_children: 0,
            grew: false,
            capacity,
            skipped: true,
            budget_dropped: 0,
        }
    }
}
