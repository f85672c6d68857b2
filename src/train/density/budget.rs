//! A cap on the number of Gaussians (`train --max-gaussians N`): a density step whose clones
//! and splits would end with more than N Gaussians keeps only the additions that exceed their
//! own threshold the most, as many as fit. Each candidate's score is its statistic over the
//! threshold it crossed (`decide.comp`; the larger of the gradient's and, with
//! `--densify-abs-grad`, the absolute gradient's ratio), so under LPM a Gaussian in a zone is
//! measured against its lowered threshold: at the cap the strategies compete for the same
//! room, which makes their results comparable at one count. Ties go to the lower index. The
//! prunes of the step are not traded for room: the cap bounds the count after the step.
//!
//! The cut is found on the host from the step's decisions and scores (read back once per
//! density step, and the scores only when the cap binds) and applied by
//! `glsl/density/budget.comp`, which [`apply_cut`] mirrors.

use super::{DECIDE_CLONE, DECIDE_LOWERED, DECIDE_REMOVE, DECIDE_SPLIT};

/// The additions a step drops: every clone or split whose `(score, index)` is not above
/// `(score, index)` in the order "higher score first, then lower index" ([`is_dropped`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BudgetCut {
    pub score: f32,
    pub index: u32,
    /// Additions dropped.
    pub dropped: usize,
    /// The count after the step with them dropped (at most the cap, unless the step's
    /// survivors alone exceed it).
    pub after: usize,
}

/// Whether the decision word adds Gaussians (a clone or a split).
pub fn adds(d: u32) -> bool {
    d & (DECIDE_CLONE | DECIDE_SPLIT) != 0
}

/// The count after a step with these decisions: survivors, clones, two children a split.
pub fn after_count(decisions: &[u32]) -> usize {
    decisions
        .iter()
        .map(|&d| {
            let kept = d & (DECIDE_REMOVE | DECIDE_SPLIT) == 0;
            kept as usize + (d & DECIDE_CLONE != 0) as usize + 2 * (d & DECIDE_SPLIT != 0) as usize
        })
        .sum()
}

/// How much dropping Gaussian `d`'s addition lowers the count: a clone 1; a split 1 (its
/// original stays), or 2 when the original is removed anyway (pruned as well).
fn saved(d: u32) -> usize {
    if d & DECIDE_SPLIT != 0 && d & DECIDE_REMOVE != 0 {
        2
    } else {
        1
    }
}

/// The cut that brings a step's count to at most `cap`, dropping the lowest-scoring additions
/// first (`None` when the step fits). Scores are compared by [`f32::total_cmp`] (the kernel
/// writes no NaN: a candidate's score is finite or +∞).
pub fn budget_cut(decisions: &[u32], scores: &[f32], cap: usize) -> Option<BudgetCut> {
    let mut after = after_count(decisions);
    if after <= cap {
        return None;
    }
    let mut order: Vec<u32> = (0..decisions.len() as u32)
        .filter(|&i| adds(decisions[i as usize]))
        .collect();
    // Lowest score first; among equal scores the higher index goes first.
    order.sort_by(|&a, &b| {
        scores[a as usize]
            .total_cmp(&scores[b as usize])
            .then(b.cmp(&a))
    });
    let mut dropped = 0;
    let mut cut = None;
    for &i in &order {
        if after <= cap {
            break;
        }
        after -= saved(decisions[i as usize]);
        dropped += 1;
        cut = Some((scores[i as usize], i));
    }
    cut.map(|(score, index)| BudgetCut {
        score,
        index,
        dropped,
        after,
    })
}

/// Whether an addition with `score` at `index` is dropped by `cut` (the kernel's test).
pub fn is_dropped(score: f32, index: u32, cut: &BudgetCut) -> bool {
    score < cut.score || (score == cut.score && index >= cut.index)
}

/// `budget.comp` on the host: the dropped additions lose their clone, split and lowered bits
/// (a dropped split keeps its original unless the original is pruned anyway).
pub fn apply_cut(decisions: &mut [u32], scores: &[f32], cut: &BudgetCut) {
    for (i, d) in decisions.iter_mut().enumerate() {
        if adds(*d) && is_dropped(scores[i], i as u32, cut) {
            *d &= !(DECIDE_CLONE | DECIDE_SPLIT | DECIDE_LOWERED);
        }
    }
}
