//! Exact k-nearest-neighbour distances for point clouds, used to size the initial Gaussians.
//!
//! A kd-tree rather than a uniform grid: SfM clouds are dense on surfaces with far outliers,
//! which leaves a grid with a few huge cells. The tree is implicit (a heap over ranges of one
//! permuted point array, split at the median of the widest axis), built and queried in parallel
//! with rayon, and queried in tree order so that neighbouring queries touch the same memory.

use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};

use rayon::prelude::*;

/// Ranges this small are scanned linearly.
const LEAF: usize = 8;
/// Ranges larger than this are built on two rayon tasks.
const PARALLEL_BUILD: usize = 1 << 14;

/// A static kd-tree over 3D points.
pub struct KdTree {
    /// The points permuted into tree order, with their index in the input.
    items: Vec<([f64; 3], u32)>,
    /// Split axis of each internal node, heap-indexed (children of `k` are `2k+1`, `2k+2`).
    axes: Vec<u8>,
    /// Split coordinate of each internal node: the left child's points are <= it, the right
    /// child's >= it. (Kept apart from the points, which the children's builds reorder.)
    splits: Vec<f64>,
}

impl KdTree {
    /// Builds the tree. Points must be finite (NaN coordinates give meaningless answers, not
    /// errors) and fewer than 2³² of them.
    pub fn build(points: &[[f64; 3]]) -> KdTree {
        let mut items: Vec<([f64; 3], u32)> = points
            .par_iter()
            .enumerate()
            .map(|(i, &p)| (p, i as u32))
            .collect();
        // Depth at which every range holds at most LEAF points; nodes above it are internal.
        let mut depth = 0u32;
        while items.len().div_ceil(1usize << depth) > LEAF {
            depth += 1;
        }
        let nodes = 1usize << depth;
        let axes: Vec<AtomicU8> = (0..nodes).map(|_| AtomicU8::new(0)).collect();
        let splits: Vec<AtomicU64> = (0..nodes).map(|_| AtomicU64::new(0)).collect();
        build_node(&mut items, 0, &axes, &splits);
        KdTree {
            items,
            axes: axes.into_iter().map(AtomicU8::into_inner).collect(),
            splits: splits
                .into_iter()
                .map(|s| f64::from_bits(s.into_inner()))
                .collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.items.len()
    }

    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// The squared distances from `query` to its `k` nearest points, ascending, into `out`
    /// (cleared first). The point with input index `exclude`, if any, is skipped — by index, so
    /// a duplicate of the query still counts, at distance 0. Fewer than `k` are returned when the
    /// tree holds fewer points.
    pub fn nearest_sq_dists(
        &self,
        query: [f64; 3],
        exclude: Option<usize>,
        k: usize,
        out: &mut Vec<f64>,
    ) {
        out.clear();
        if k == 0 || self.items.is_empty() {
            return;
        }
        let skip = exclude.map_or(u64::MAX, |e| e as u64);
        self.search(0, 0, self.items.len(), &query, skip, k, out);
    }

    #[allow(clippy::too_many_arguments)]
    fn search(
        &self,
        node: usize,
        lo: usize,
        hi: usize,
        q: &[f64; 3],
        skip: u64,
        k: usize,
        best: &mut Vec<f64>,
    ) {
        if hi - lo <= LEAF {
            for (p, id) in &self.items[lo..hi] {
                if *id as u64 == skip {
                    continue;
                }
                let d = sq_dist(p, q);
                if best.len() < k {
                    let at = best.partition_point(|&b| b <= d);
                    best.insert(at, d);
                } else if d < best[k - 1] {
                    best.pop();
                    let at = best.partition_point(|&b| b <= d);
                    best.insert(at, d);
                }
            }
            return;
        }
        let mid = lo + (hi - lo) / 2;
        let axis = self.axes[node] as usize;
        let diff = q[axis] - self.splits[node];
        // Left holds coordinates <= the split value, right >= it, so the far side is at least
        // |diff| away along this axis.
        let (near, far) = if diff < 0.0 {
            ((2 * node + 1, lo, mid), (2 * node + 2, mid, hi))
        } else {
            ((2 * node + 2, mid, hi), (2 * node + 1, lo, mid))
        };
        self.search(near.0, near.1, near.2, q, skip, k, best);
        if best.len() < k || diff * diff < best[k - 1] {
            self.search(far.0, far.1, far.2, q, skip, k, best);
        }
    }
}

fn sq_dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

fn build_node(items: &mut [([f64; 3], u32)], node: usize, axes: &[AtomicU8], splits: &[AtomicU64]) {
    let n = items.len();
    if n <= LEAF {
        return;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for (p, _) in items.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    axes[node].store(axis as u8, Ordering::Relaxed);
    let mid = n / 2;
    items.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]));
    splits[node].store(items[mid].0[axis].to_bits(), Ordering::Relaxed);
    let (left, right) = items.split_at_mut(mid);
    if n > PARALLEL_BUILD {
        rayon::join(
            || build_node(left, 2 * node + 1, axes, splits),
            || build_node(right, 2 * node + 2, axes, splits),
        );
    } else {
        build_node(left, 2 * node + 1, axes, splits);
        build_node(right, 2 * node + 2, axes, splits);
    }
}

/// For every point, the mean squared distance to its `k` nearest other points (or to all
/// `n − 1` others when there are fewer than `k`). A point with no other point (`n = 1`) gets
/// 0.0, the value of an empty mean; callers that care special-case it. Duplicates are neighbours
/// at distance 0.
pub fn mean_sq_dist_knn(points: &[[f64; 3]], k: usize) -> Vec<f64> {
    let tree = KdTree::build(points);
    let mut out = vec![0.0; points.len()];
    let per_item: Vec<f64> = tree
        .items
        .par_iter()
        .with_min_len(1024)
        .map_init(
            || Vec::with_capacity(k + 1),
            |best, (p, id)| {
                tree.nearest_sq_dists(*p, Some(*id as usize), k, best);
                if best.is_empty() {
                    0.0
                } else {
                    best.iter().sum::<f64>() / best.len() as f64
                }
            },
        )
        .collect();
    for ((_, id), m) in tree.items.iter().zip(per_item) {
        out[*id as usize] = m;
    }
    out
}
