//! A start above the Gaussian budget drawn down to it (`train --budget` below the initial
//! count, `--budget-draw`): which of the initial Gaussians a run keeps, and how big the kept
//! ones start.
//!
//! Every strategy grows from its start, so a start above the budget could only be cut at the
//! first density step, after the optimizer had fitted Gaussians that are then thrown away; the
//! draw happens before the first iteration instead.
//!
//! - `random`: a uniform draw without replacement. An SfM cloud is dense where features were
//!   (a textured foreground) and sparse elsewhere, and a uniform draw keeps those proportions:
//!   a quarter of the points leaves a quarter of a sparse background's few.
//! - `spread`: one Gaussian from each cell of a grid as fine as the budget allows (the
//!   smallest cell edge whose occupied cells number at most the budget, found by bisection
//!   on the cloud's own bounding box, so no length is in world units), then a uniform draw
//!   of the rest from the points not yet taken. Sparse regions keep their points; dense ones
//!   are thinned.
//!
//! Either way the initial scales were set from the whole cloud's neighbour distances, which
//! a thinned cloud no longer has: [`refit_scales`] scales each kept Gaussian by how much its
//! neighbours moved away, keeping its shape (a model's own initial anisotropy, such as a
//! surfel's flat axis).

use rand::seq::SliceRandom;
use rand::SeedableRng;

use super::init::{INIT_NEIGHBOURS, MIN_MEAN_SQ_DIST};
use super::knn::mean_sq_dist_knn;
use super::model::GaussianParams;

/// How a start above the budget is drawn down to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Draw {
    /// Uniformly at random: the cloud's density kept everywhere alike.
    #[default]
    Random,
    /// One from each cell of the finest grid the budget allows, the rest at random: sparse
    /// regions keep their points.
    Spread,
    /// Nothing drawn: the run starts from every initial Gaussian and the strategy removes the
    /// least opaque along the densify window until the budget (MCMC only: its curve falls).
    Keep,
}

impl Draw {
    pub fn name(self) -> &'static str {
        match self {
            Draw::Random => "random",
            Draw::Spread => "spread",
            Draw::Keep => "keep",
        }
    }
}

/// Bisection steps on the cell edge (relative to the bounding box's longest side): 2⁻⁴⁰ of
/// it, far below any spacing an f32 cloud resolves.
const BISECTION_STEPS: usize = 40;

/// The rows (ascending, distinct) of `budget` of `positions`, drawn by `draw` (seeded). All
/// of them when `budget` is at least their number.
pub fn draw_rows(positions: &[[f32; 3]], budget: usize, seed: u64, draw: Draw) -> Vec<usize> {
    let n = positions.len();
    if budget >= n || draw == Draw::Keep {
        return (0..n).collect();
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed ^ 0x6275_6467_6574_5f69);
    let mut rows = match draw {
        // (Keep returned every row above.)
        Draw::Random | Draw::Keep => rand::seq::index::sample(&mut rng, n, budget).into_vec(),
        Draw::Spread => spread_rows(positions, budget, &mut rng),
    };
    rows.sort_unstable();
    rows
}

/// Each point's grid cell at edge `edge` from corner `lo`.
fn cell(p: &[f32; 3], lo: [f64; 3], edge: f64) -> [i64; 3] {
    [0, 1, 2].map(|a| ((p[a] as f64 - lo[a]) / edge).floor() as i64)
}

/// The number of distinct cells the points occupy at edge `edge`.
fn occupied(positions: &[[f32; 3]], lo: [f64; 3], edge: f64) -> usize {
    let mut keys: Vec<[i64; 3]> = positions.iter().map(|p| cell(p, lo, edge)).collect();
    keys.sort_unstable();
    keys.dedup();
    keys.len()
}

fn spread_rows(positions: &[[f32; 3]], budget: usize, rng: &mut rand_pcg::Pcg64) -> Vec<usize> {
    let n = positions.len();
    if budget == 0 {
        return Vec::new();
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f64);
            hi[a] = hi[a].max(p[a] as f64);
        }
    }
    let side = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    // The smallest edge (to bisection precision) whose occupied cells fit the budget: at
    // twice the box's side every point shares one cell, which fits any budget of one or more.
    let (mut fine, mut coarse) = (0.0_f64, 2.0 * side.max(f64::MIN_POSITIVE));
    for _ in 0..BISECTION_STEPS {
        let mid = 0.5 * (fine + coarse);
        if mid > 0.0 && occupied(positions, lo, mid) <= budget {
            coarse = mid;
        } else {
            fine = mid;
        }
    }
    // One point a cell, chosen at random within it: shuffle, then keep each cell's first.
    let mut order: Vec<usize> = (0..n).collect();
    order.shuffle(rng);
    let mut keyed: Vec<([i64; 3], usize, usize)> = order
        .iter()
        .enumerate()
        .map(|(rank, &i)| (cell(&positions[i], lo, coarse), rank, i))
        .collect();
    keyed.sort_unstable();
    let mut taken = vec![false; n];
    let mut rows = Vec::with_capacity(budget);
    for (k, e) in keyed.iter().enumerate() {
        if k == 0 || keyed[k - 1].0 != e.0 {
            taken[e.2] = true;
            rows.push(e.2);
        }
    }
    // The rest uniformly from the points not taken (in the shuffled order).
    rows.extend(
        order
            .iter()
            .copied()
            .filter(|&i| !taken[i])
            .take(budget - rows.len()),
    );
    rows
}

/// `init` drawn down to `budget` Gaussians by `draw` (seeded), whole rows in their order;
/// with `refit` (a model whose scales came from its points, not a trained one) each kept
/// Gaussian's scales follow its new spacing ([`refit_scales`]). A model within the budget, or
/// a budget of 0, is returned as it is.
pub fn draw_down(
    init: GaussianParams,
    budget: usize,
    seed: u64,
    draw: Draw,
    refit: bool,
) -> GaussianParams {
    if budget >= init.len() || budget == 0 || draw == Draw::Keep {
        return init;
    }
    let rows = draw_rows(&init.positions, budget, seed, draw);
    let mut drawn = init.select_rows(&rows);
    if refit {
        refit_scales(&mut drawn, &init.positions, &rows);
    }
    drawn
}

/// Rescales each Gaussian of `drawn` (rows `rows` of a model at `before`) by how far its
/// nearest neighbours moved: every log scale of a Gaussian gains `½ ln(d²_after / d²_before)`,
/// where `d²` is the mean squared distance to its [`INIT_NEIGHBOURS`] nearest neighbours in
/// the whole cloud and among the kept ones. Its shape (the ratios of its axes) is kept.
pub fn refit_scales(drawn: &mut GaussianParams, before: &[[f32; 3]], rows: &[usize]) {
    if drawn.len() < 2 || before.len() < 2 {
        return;
    }
    let wide =
        |p: &[[f32; 3]]| -> Vec<[f64; 3]> { p.iter().map(|x| x.map(|v| v as f64)).collect() };
    let after = mean_sq_dist_knn(&wide(&drawn.positions), INIT_NEIGHBOURS);
    let whole = mean_sq_dist_knn(&wide(before), INIT_NEIGHBOURS);
    for (g, &i) in rows.iter().enumerate() {
        let ratio = after[g].max(MIN_MEAN_SQ_DIST) / whole[i].max(MIN_MEAN_SQ_DIST);
        let gain = (0.5 * ratio.ln()) as f32;
        for s in &mut drawn.log_scales[g] {
            *s += gain;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn numbered(n: usize) -> GaussianParams {
        // SH degree 1: nine rest coefficients a Gaussian, each its row number.
        GaussianParams {
            sh_degree: 1,
            positions: (0..n).map(|i| [i as f32, 0.0, 0.0]).collect(),
            log_scales: vec![[0.0; 3]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![0.0; n],
            sh_dc: vec![[0.0; 3]; n],
            sh_rest: (0..n).flat_map(|i| [i as f32; 9]).collect(),
            extra: Vec::new(),
        }
    }

    #[test]
    fn a_start_above_the_budget_is_drawn_down_to_it_whole_rows_in_order() {
        let p = numbered(100);
        let q = draw_down(p.clone(), 30, 7, Draw::Random, false);
        assert_eq!(q.len(), 30);
        let rows: Vec<usize> = q.positions.iter().map(|x| x[0] as usize).collect();
        assert!(
            rows.windows(2).all(|w| w[0] < w[1]),
            "distinct, in order: {rows:?}"
        );
        for (k, &r) in rows.iter().enumerate() {
            assert!(q.sh_rest[9 * k..9 * k + 9].iter().all(|&v| v == r as f32));
        }
        assert_eq!(
            q,
            draw_down(p.clone(), 30, 7, Draw::Random, false),
            "seeded"
        );
        assert_ne!(q, draw_down(p.clone(), 30, 8, Draw::Random, false));
        assert_eq!(draw_down(p.clone(), 100, 7, Draw::Random, false), p);
        assert_eq!(draw_down(p.clone(), 500, 7, Draw::Random, false), p);
    }

    /// 900 points in a ball of radius 0.01 at the origin and 100 on a line 10 long.
    fn crowd_and_line() -> Vec<[f32; 3]> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let mut p: Vec<[f32; 3]> = (0..900)
            .map(|_| {
                let u: [f32; 3] = rand::Rng::gen(&mut rng);
                u.map(|v| 0.01 * (v - 0.5))
            })
            .collect();
        p.extend((0..100).map(|i| [1.0 + 0.1 * i as f32, 0.0, 0.0]));
        p
    }

    #[test]
    fn a_spread_draw_keeps_sparse_regions_a_random_one_thins_them_alike() {
        let p = crowd_and_line();
        for draw in [Draw::Random, Draw::Spread] {
            let rows = draw_rows(&p, 200, 5, draw);
            assert_eq!(rows.len(), 200, "{draw:?}");
            assert!(
                rows.windows(2).all(|w| w[0] < w[1]),
                "{draw:?}: distinct, in order"
            );
            assert_eq!(rows, draw_rows(&p, 200, 5, draw), "{draw:?}: seeded");
            assert_ne!(rows, draw_rows(&p, 200, 6, draw), "{draw:?}");
            let line = rows.iter().filter(|&&r| r >= 900).count();
            match draw {
                // Expected 20 of the line's 100.
                Draw::Random => assert!((5..=40).contains(&line), "{line}"),
                // Every line point is its own cell long before the crowd's cells number 100.
                Draw::Spread => assert_eq!(line, 100),
                Draw::Keep => unreachable!("not in the loop"),
            }
        }
        // Keep draws nothing: every row, and the model as it was.
        assert_eq!(
            draw_rows(&p, 200, 5, Draw::Keep),
            (0..1000).collect::<Vec<_>>()
        );
        assert_eq!(
            draw_rows(&p, 1000, 5, Draw::Spread),
            (0..1000).collect::<Vec<_>>()
        );
        assert_eq!(draw_rows(&p, 1, 5, Draw::Spread).len(), 1);
        assert!(draw_rows(&p, 0, 5, Draw::Spread).is_empty());
    }

    #[test]
    fn a_spread_draw_of_a_uniform_grid_takes_one_point_a_block() {
        // 16³ points on a unit lattice, budget 8³: the finest grid with at most 512 occupied
        // cells has edge 2, so every 2×2×2 block gives exactly one point.
        let p: Vec<[f32; 3]> = (0..4096)
            .map(|i| [(i % 16) as f32, ((i / 16) % 16) as f32, (i / 256) as f32])
            .collect();
        let rows = draw_rows(&p, 512, 1, Draw::Spread);
        let mut blocks: Vec<[i32; 3]> = rows.iter().map(|&r| p[r].map(|v| v as i32 / 2)).collect();
        blocks.sort_unstable();
        blocks.dedup();
        assert_eq!(blocks.len(), 512);
    }

    #[test]
    fn refitting_scales_follows_the_thinned_spacing_and_keeps_the_shape() {
        // A lattice of spacing 1 with every third point kept: each kept Gaussian's scales
        // match its neighbours in the kept cloud, its flat axis stays 10× thinner.
        let before: Vec<[f32; 3]> = (0..1000)
            .map(|i| [(i % 10) as f32, ((i / 10) % 10) as f32, (i / 100) as f32])
            .collect();
        let wide: Vec<[f64; 3]> = before.iter().map(|x| x.map(|v| v as f64)).collect();
        let d0 = mean_sq_dist_knn(&wide, INIT_NEIGHBOURS);
        let mut m = crate::splats::init::from_sfm_points(&wide, &vec![[0; 3]; 1000], 0).unwrap();
        // An anisotropic start (a model's own rule): the third axis 10× thinner.
        for s in &mut m.log_scales {
            s[2] -= 10f32.ln();
        }
        let rows: Vec<usize> = (0..1000).filter(|i| i % 3 == 0).collect();
        let mut drawn = m.select_rows(&rows);
        let kept: Vec<[f64; 3]> = rows.iter().map(|&r| wide[r]).collect();
        let d1 = mean_sq_dist_knn(&kept, INIT_NEIGHBOURS);
        refit_scales(&mut drawn, &before, &rows);
        for (g, &r) in rows.iter().enumerate() {
            let want = 0.5 * d1[g].ln() as f32;
            assert!((drawn.log_scales[g][0] - want).abs() < 1e-5, "{g}");
            assert!((drawn.log_scales[g][1] - want).abs() < 1e-5, "{g}");
            let thin = drawn.log_scales[g][2] - drawn.log_scales[g][0];
            assert!((thin + 10f32.ln()).abs() < 1e-5, "{g}: shape kept");
            assert!(d1[g] > d0[r], "{g}: thinned, so farther apart");
        }
    }
}
