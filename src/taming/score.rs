//! The blended score, in host maths: how much a Gaussian matters to a few sampled training
//! views, a weighted sum of nine terms each divided by its median, so that no term's units
//! decide the blend. Per view `v` and Gaussian `i` seen there (a positive screen radius):
//!
//! `score_v(i) = view · loss_v · Σ_k w_k · x_k(i) / median_{x_k > 0}(x_k)`
//!
//! with `loss_v = 0.8·L1 + 0.2·(1 − SSIM)` of the view's render against its ground truth and
//! the terms `x_k`: the Gaussian's view-independent gradient statistic, opacity and scale
//! volume (the product of its three scales), its camera depth and screen radius in the view,
//! and what it gave the view's pixels (the contributions pass): the sum of their importance,
//! their number, its blending weights `T·alpha` and its distances to them. A pixel's
//! importance is `mse · L1(pixel) + edge · E(pixel)`, each map scaled to [0, 1] over the view
//! (its min to its max): `L1` the mean absolute error of the three channels, `E` the ground
//! truth's edges (the magnitude of a 3×3 Laplacian of its luma, clamped to [0, 1], the image's
//! border extended). A Gaussian's score is the sum over the views.
//!
//! This is Taming-3DGS's score, in our words and with its published weights
//! ([`ScoreWeights::default`]); what differs is said where it differs (the edge filter's
//! border; the ranking, in `super::strategy`).

/// The weight of each term (Taming-3DGS's published values by default).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoreWeights {
    /// The whole view's factor (with its photometric loss).
    pub view: f64,
    /// The pixel importance's L1-error map.
    pub error_map: f64,
    /// The pixel importance's edge map.
    pub edge_map: f64,
    pub gradient: f64,
    pub opacity: f64,
    pub depth: f64,
    pub radius: f64,
    pub scale: f64,
    /// The summed pixel importance.
    pub importance: f64,
    /// The number of pixels blended into.
    pub pixels: f64,
    /// The summed blending weights.
    pub blend: f64,
    /// The summed distances to the pixel centres.
    pub distance: f64,
}

impl Default for ScoreWeights {
    fn default() -> Self {
        ScoreWeights {
            view: 50.0,
            error_map: 50.0,
            edge_map: 50.0,
            gradient: 25.0,
            opacity: 100.0,
            depth: 5.0,
            radius: 10.0,
            scale: 25.0,
            importance: 10.0,
            pixels: 0.1,
            blend: 50.0,
            distance: 50.0,
        }
    }
}

/// `values` scaled to [0, 1] by their minimum and maximum (all 0 when they are equal or
/// empty); a non-finite value counts as 0.
pub fn min_max_scaled(values: &[f32]) -> Vec<f32> {
    let clean = |v: f32| if v.is_finite() { v } else { 0.0 };
    let (lo, hi) = values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(clean(v)), hi.max(clean(v)))
        });
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return vec![0.0; values.len()];
    }
    values
        .iter()
        .map(|&v| (clean(v) - lo) / (hi - lo))
        .collect()
}

/// The edges of an RGB image (3 floats a pixel, `width × height`): the absolute response of
/// the 3×3 Laplacian (8 at the centre, −1 around) to its luma (0.299 R + 0.587 G + 0.114 B),
/// clamped to [0, 1], with the image's border extended, then scaled by [`min_max_scaled`].
pub fn edge_map(rgb: &[f32], width: usize, height: usize) -> Vec<f32> {
    let luma: Vec<f32> = rgb
        .chunks_exact(3)
        .map(|c| 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2])
        .collect();
    let at = |x: isize, y: isize| {
        let x = x.clamp(0, width as isize - 1) as usize;
        let y = y.clamp(0, height as isize - 1) as usize;
        luma[y * width + x]
    };
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height as isize {
        for x in 0..width as isize {
            let mut around = 0.0;
            for (dx, dy) in [
                (-1, -1),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                around += at(x + dx, y + dy);
            }
            out.push((8.0 * at(x, y) - around).clamp(0.0, 1.0));
        }
    }
    min_max_scaled(&out)
}

/// A view's pixel importance from its render and ground truth (RGB, 3 floats a pixel) and
/// the ground truth's [`edge_map`].
pub fn pixel_importance(
    render: &[f32],
    truth: &[f32],
    edges: &[f32],
    w: &ScoreWeights,
) -> Vec<f32> {
    let l1: Vec<f32> = render
        .chunks_exact(3)
        .zip(truth.chunks_exact(3))
        .map(|(a, b)| ((a[0] - b[0]).abs() + (a[1] - b[1]).abs() + (a[2] - b[2]).abs()) / 3.0)
        .collect();
    min_max_scaled(&l1)
        .iter()
        .zip(edges)
        .map(|(&e, &g)| (w.error_map * e as f64 + w.edge_map * g as f64) as f32)
        .collect()
}

/// `weight · v / m` for each positive finite `v`, where `m` is the median of those values
/// (the lower of the two middle ones for an even count); 0 for every other value.
pub fn median_scaled(weight: f64, values: &[f32]) -> Vec<f64> {
    let mut positive: Vec<f32> = values
        .iter()
        .copied()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    if positive.is_empty() || weight == 0.0 {
        return vec![0.0; values.len()];
    }
    let mid = (positive.len() - 1) / 2;
    let (_, m, _) = positive.select_nth_unstable_by(mid, f32::total_cmp);
    let m = *m as f64;
    values
        .iter()
        .map(|&v| {
            if v.is_finite() && v > 0.0 {
                weight * v as f64 / m
            } else {
                0.0
            }
        })
        .collect()
}

/// The view-independent terms, one value a Gaussian.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelTerms {
    /// The densification statistic (gradient sum over views seen, 0 where never seen).
    pub gradient: Vec<f32>,
    pub opacity: Vec<f32>,
    /// The product of the three scales.
    pub scale: Vec<f32>,
}

/// One view's terms, one value a Gaussian (0 where it is not seen: `radius` 0).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ViewTerms {
    /// `0.8·L1 + 0.2·(1 − SSIM)` of the view's render.
    pub loss: f64,
    pub depth: Vec<f32>,
    pub radius: Vec<f32>,
    pub importance: Vec<f32>,
    pub pixels: Vec<f32>,
    pub blend: Vec<f32>,
    pub distance: Vec<f32>,
}

/// The model's terms scaled by their medians (they do not change from view to view).
pub fn model_part(model: &ModelTerms, w: &ScoreWeights) -> Vec<f64> {
    let parts = [
        median_scaled(w.gradient, &model.gradient),
        median_scaled(w.opacity, &model.opacity),
        median_scaled(w.scale, &model.scale),
    ];
    (0..model.opacity.len())
        .map(|i| parts.iter().map(|p| p[i]).sum())
        .collect()
}

/// Adds view `v`'s score to `score` (one a Gaussian), given [`model_part`]'s values.
pub fn add_view(score: &mut [f64], model_part: &[f64], view: &ViewTerms, w: &ScoreWeights) {
    let parts = [
        median_scaled(w.depth, &view.depth),
        median_scaled(w.radius, &view.radius),
        median_scaled(w.importance, &view.importance),
        median_scaled(w.pixels, &view.pixels),
        median_scaled(w.blend, &view.blend),
        median_scaled(w.distance, &view.distance),
    ];
    let factor = w.view * view.loss;
    for (i, s) in score.iter_mut().enumerate() {
        if view.radius[i] > 0.0 {
            *s += factor * (model_part[i] + parts.iter().map(|p| p[i]).sum::<f64>());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn min_max_scaling_spans_zero_to_one_and_flat_maps_are_zero() {
        assert_eq!(min_max_scaled(&[2.0, 4.0, 3.0]), vec![0.0, 1.0, 0.5]);
        assert_eq!(min_max_scaled(&[5.0, 5.0]), vec![0.0, 0.0]);
        assert_eq!(min_max_scaled(&[f32::NAN, 1.0, 2.0]), vec![0.0, 0.5, 1.0]);
        assert!(min_max_scaled(&[]).is_empty());
    }

    #[test]
    fn the_median_scales_positive_values_and_zeroes_the_rest() {
        // Positives 1, 2, 4, 8: the lower middle is 2.
        let v = median_scaled(3.0, &[4.0, 0.0, 1.0, -1.0, 8.0, f32::NAN, 2.0]);
        assert_eq!(v, vec![6.0, 0.0, 1.5, 0.0, 12.0, 0.0, 3.0]);
        assert_eq!(median_scaled(3.0, &[0.0, -2.0]), vec![0.0, 0.0]);
        assert_eq!(median_scaled(0.0, &[1.0]), vec![0.0]);
    }

    #[test]
    fn edges_are_where_the_luma_steps() {
        // A 6×4 image, black on the left half and white on the right.
        let (w, h) = (6, 4);
        let rgb: Vec<f32> = (0..w * h)
            .flat_map(|p| {
                let v = if p % w >= 3 { 1.0 } else { 0.0 };
                [v, v, v]
            })
            .collect();
        let e = edge_map(&rgb, w, h);
        for y in 0..h {
            let row = &e[y * w..(y + 1) * w];
            // The white column next to the step responds (8 − 5 = 3, clamped to 1); the dark
            // one is negative (clamped to 0); flat regions give 0.
            assert_eq!(row, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], "row {y}");
        }
        // A flat image has no edges at all.
        assert!(edge_map(&vec![0.3; 3 * w * h], w, h)
            .iter()
            .all(|&v| v == 0.0));
    }

    #[test]
    fn pixel_importance_blends_the_scaled_error_and_edges() {
        let w = ScoreWeights::default();
        let render = [0.0, 0.0, 0.0, 0.3, 0.3, 0.3, 0.6, 0.6, 0.6];
        let truth = [0.0; 9];
        let edges = [1.0, 0.0, 0.5];
        let p = pixel_importance(&render, &truth, &edges, &w);
        assert_eq!(p, vec![50.0, 25.0, 75.0]);
    }

    #[test]
    fn a_view_adds_only_to_the_gaussians_it_sees() {
        let w = ScoreWeights {
            view: 2.0,
            gradient: 1.0,
            opacity: 0.0,
            scale: 0.0,
            depth: 0.0,
            radius: 0.0,
            importance: 1.0,
            pixels: 0.0,
            blend: 0.0,
            distance: 0.0,
            ..Default::default()
        };
        let model = ModelTerms {
            gradient: vec![1.0, 2.0, 3.0],
            opacity: vec![0.5; 3],
            scale: vec![1.0; 3],
        };
        let part = model_part(&model, &w);
        assert_eq!(part, vec![0.5, 1.0, 1.5]);
        let view = ViewTerms {
            loss: 0.25,
            depth: vec![1.0, 0.0, 2.0],
            radius: vec![3.0, 0.0, 1.0],
            importance: vec![4.0, 0.0, 2.0],
            pixels: vec![1.0, 0.0, 1.0],
            blend: vec![0.1, 0.0, 0.1],
            distance: vec![1.0, 0.0, 1.0],
        };
        let mut score = vec![0.0; 3];
        add_view(&mut score, &part, &view, &w);
        // Importance medians: positives 2, 4 → 2; factor 2 · 0.25 = 0.5.
        assert_eq!(score, vec![0.5 * (0.5 + 2.0), 0.0, 0.5 * (1.5 + 1.0)]);
        add_view(&mut score, &part, &view, &w);
        assert_eq!(score, vec![2.5, 0.0, 2.5]);
    }
}
