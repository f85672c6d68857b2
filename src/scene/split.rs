//! Train/test split and scene extent.

use super::View;

/// Indices of train and test views when the scene has no explicit split: views sorted by name,
/// every `every`-th one (index % every == 0) held out, as in the Inria reference.
/// `every == 0` or `eval == false` puts every view in train.
pub fn holdout_split(views: &[View], every: usize, eval: bool) -> (Vec<usize>, Vec<usize>) {
    let mut order: Vec<usize> = (0..views.len()).collect();
    order.sort_by(|&a, &b| views[a].name.cmp(&views[b].name));
    let mut train = Vec::new();
    let mut test = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        if eval && every > 0 && k % every == 0 {
            test.push(i);
        } else {
            train.push(i);
        }
    }
    (train, test)
}

/// Mean of the camera centres of `indices` and 1.1 × the largest distance from it (the Inria
/// "nerf normalisation" radius). A single camera gives a tiny but positive extent so that
/// learning rates scaled by it stay finite.
pub fn camera_extent(views: &[View], indices: &[usize]) -> ([f64; 3], f64) {
    if indices.is_empty() {
        return ([0.0; 3], 1.0);
    }
    let centers: Vec<[f64; 3]> = indices.iter().map(|&i| views[i].pose.center()).collect();
    let mut mean = [0.0; 3];
    for c in &centers {
        for k in 0..3 {
            mean[k] += c[k] / centers.len() as f64;
        }
    }
    let max_dist = centers
        .iter()
        .map(|c| {
            ((c[0] - mean[0]).powi(2) + (c[1] - mean[1]).powi(2) + (c[2] - mean[2]).powi(2)).sqrt()
        })
        .fold(0.0f64, f64::max);
    let extent = 1.1 * max_dist;
    (mean, if extent > 0.0 { extent } else { 1e-6 })
}
