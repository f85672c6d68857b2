//! The Gaussian budget's host rule (`train::density::budget`) on constructed steps: which
//! additions are dropped, in which order, what each drop saves, and the tie rule the kernel
//! shares (`glsl/density/budget.comp`).

use lpmsplat::train::density::budget::{after_count, apply_cut, budget_cut, is_dropped};
use lpmsplat::train::density::{DECIDE_CLONE, DECIDE_LOWERED, DECIDE_REMOVE, DECIDE_SPLIT};

const C: u32 = DECIDE_CLONE;
const S: u32 = DECIDE_SPLIT;
const R: u32 = DECIDE_REMOVE;
const L: u32 = DECIDE_LOWERED;

#[test]
fn the_lowest_scores_go_first_and_ties_keep_the_lower_index() {
    // Gaussians 0..6: a kept one, a pruned one, clones and splits with scores.
    let d = [0, R, C, S, C | L, S, C];
    let scores = [0.0, 0.0, 3.0, 1.5, 1.2, 1.5, 1.5];
    // 1 + 0 + 2 + 2 + 2 + 2 + 2 = 11.
    assert_eq!(after_count(&d), 11);
    assert_eq!(budget_cut(&d, &scores, 11), None, "the step fits");
    // Two too many: 4 (1.2) goes, then among the three at 1.5 the highest index, 6.
    let cut = budget_cut(&d, &scores, 9).unwrap();
    assert_eq!(
        (cut.score, cut.index, cut.dropped, cut.after),
        (1.5, 6, 2, 9)
    );
    let mut got = d;
    apply_cut(&mut got, &scores, &cut);
    assert_eq!(
        got,
        [0, R, C, S, 0, S, 0],
        "the lowered bit goes with the clone"
    );
    assert_eq!(after_count(&got), 9);
    // The tie rule: at the cut's score, indices at or after it are dropped.
    assert!(is_dropped(1.5, 6, &cut) && !is_dropped(1.5, 5, &cut) && !is_dropped(1.6, 9, &cut));
    assert!(is_dropped(1.4, 0, &cut));
}

#[test]
fn a_split_whose_original_is_pruned_anyway_saves_two() {
    // Dropping the split of a pruned original removes both children and keeps nothing.
    let d = [S | R, C, 0];
    let scores = [1.0, 2.0, 0.0];
    assert_eq!(after_count(&d), 2 + 2 + 1);
    let cut = budget_cut(&d, &scores, 4).unwrap();
    assert_eq!((cut.index, cut.dropped, cut.after), (0, 1, 3));
    let mut got = d;
    apply_cut(&mut got, &scores, &cut);
    assert_eq!(got, [R, C, 0]);
    // A kept split's original comes back: dropping it saves one.
    let d = [S, 0];
    let cut = budget_cut(&d, &[1.0, 0.0], 2).unwrap();
    assert_eq!(cut.after, 2);
}

#[test]
fn survivors_above_the_cap_drop_every_addition_and_infinite_scores_go_last() {
    let d = [0, 0, 0, C, C];
    let scores = [0.0, 0.0, 0.0, f32::INFINITY, 2.0];
    let cut = budget_cut(&d, &scores, 2).unwrap();
    // Five survivors (the clones' originals stay) and two clones: 7.
    assert_eq!(
        (cut.dropped, cut.after),
        (2, 5),
        "five survivors stay above a cap of 2"
    );
    assert_eq!((cut.score, cut.index), (f32::INFINITY, 3));
    let mut got = d;
    apply_cut(&mut got, &scores, &cut);
    assert_eq!(got, [0; 5]);
    let cut = budget_cut(&d, &scores, 6).unwrap();
    assert_eq!(
        (cut.score, cut.index, cut.after),
        (2.0, 4, 6),
        "+∞ outranks 2"
    );
}
