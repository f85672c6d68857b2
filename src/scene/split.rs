//! Train/test split and scene extent.

use std::path::Path;

use super::View;
use crate::error::bad_input;

/// A scene folder may name its test views in this file, one view name a line (blank lines and
/// lines starting with `#` skipped): every other view trains. `partition` writes one into each
/// block, so a block holds out exactly the whole scene's test views it sees, whatever its own
/// holdout order would pick.
pub const TEST_VIEWS_FILE: &str = "test_views.txt";

/// The split `root/test_views.txt` lists, if the file exists (`eval == false` puts every view
/// in train). A name that is no view, or one listed twice, is an error naming the line.
pub fn listed_split(
    root: &Path,
    views: &[View],
    eval: bool,
) -> anyhow::Result<Option<(Vec<usize>, Vec<usize>)>> {
    let path = root.join(TEST_VIEWS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let text = crate::error::read_text(
        &path,
        "write one view name a line, or remove the file to hold out every 8th view",
    )?;
    let index: std::collections::HashMap<&str, usize> = views
        .iter()
        .enumerate()
        .map(|(i, v)| (v.name.as_str(), i))
        .collect();
    let mut is_test = vec![false; views.len()];
    for (k, line) in text.lines().enumerate() {
        let name = line.trim();
        if name.is_empty() || name.starts_with('#') {
            continue;
        }
        let Some(&i) = index.get(name) else {
            return bad_input(
                &path,
                format!("line {}", k + 1),
                format!("'{name}' is not a view of the scene"),
                "name views as the scene lists them (e.g. images.txt's NAME column), or remove \
                 the line",
            );
        };
        if std::mem::replace(&mut is_test[i], true) {
            return bad_input(
                &path,
                format!("line {}", k + 1),
                format!("'{name}' is listed twice"),
                "remove the repeated line",
            );
        }
    }
    let mut order: Vec<usize> = (0..views.len()).collect();
    order.sort_by(|&a, &b| views[a].name.cmp(&views[b].name));
    let (test, train): (Vec<usize>, Vec<usize>) =
        order.into_iter().partition(|&i| eval && is_test[i]);
    Ok(Some((train, test)))
}

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

/// The point nearest, in the least-squares sense, to the optical axes of the views in
/// `indices`: where an object-centred capture looks. `None` when the axes are (nearly)
/// parallel, as in a forward-facing capture, and no such point is defined.
pub fn axes_convergence_point(views: &[View], indices: &[usize]) -> Option<[f64; 3]> {
    // Minimise Σ |(I − d dᵀ)(p − c)|²: the normal equations are (Σ P) p = Σ P c with
    // P = I − d dᵀ, the projector orthogonal to the axis d.
    let mut a = [[0.0f64; 3]; 3];
    let mut b = [0.0f64; 3];
    for &i in indices {
        let c = views[i].pose.center();
        let d = views[i].pose.optical_axis();
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if n.is_nan() || n <= 0.0 {
            continue;
        }
        let d = d.map(|v| v / n);
        for r in 0..3 {
            for k in 0..3 {
                let p = if r == k { 1.0 } else { 0.0 } - d[r] * d[k];
                a[r][k] += p;
                b[r] += p * c[k];
            }
        }
    }
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&a);
    // Σ P has eigenvalues in [0, n]; parallel axes leave one near 0, so compare the
    // determinant with the scale of the matrix cubed.
    let scale = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
    if d.is_nan() || d.abs() <= 1e-6 * scale.powi(3) {
        return None;
    }
    // Cramer's rule.
    let mut p = [0.0; 3];
    for (col, v) in p.iter_mut().enumerate() {
        let mut m = a;
        for r in 0..3 {
            m[r][col] = b[r];
        }
        *v = det(&m) / d;
    }
    p.iter().all(|v| v.is_finite()).then_some(p)
}
