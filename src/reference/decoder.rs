//! SpacetimeGaussians' full model, in f64: the feature channels blended beside the colour and
//! the per-pixel decoder that turns the 9-channel image into RGB (docs/algorithms/base-models.md §4.3–4.4). The
//! GPU kernels `glsl/spacetime/decode*.comp` and the feature path of the rasterizer copy it.
//!
//! # Feature channels
//! Every Gaussian carries 9 values: base `B` (3, the DC coefficients used raw: no `+0.5`, no
//! clamp, no view dependence), specular feature `S` (3) and time feature `Δ·f_t` (3). They are
//! blended with the colour's weights `αᵢTᵢ` over a **zero** background. The weights depend on
//! the geometry only, so the blend of any channel triple is [`rasterize`] with that triple in
//! place of the colour and a black background, and the geometry's gradient from all nine
//! channels is the sum of the three triples' gradients ([`rasterize_features_backward`]): the
//! rasterizer's reference, reused as it is.
//!
//! # Decoder ("sandwich": no biases, 90 weights shared by every pixel)
//! `x = [S, Tf, o, d]` (12: the two blended features, the camera centre `o` and the unit
//! world-space direction `d` through the pixel centre), `h = ReLU(W₁x)` (6), `y = W₂h` (3),
//! `RGB = σ(B + y)`. Weights flat: `W₁` row-major (6×12, 72 floats) then `W₂` (3×6, 18).
//! Backward per pixel: `δ = ∂L/∂RGB ⊙ RGB(1 − RGB)`; `∂L/∂B = δ`; `∂L/∂W₂ = δhᵀ`;
//! `δ_h = W₂ᵀδ ⊙ [W₁x > 0]` (the ReLU passes no gradient at exactly 0); `∂L/∂W₁ = δ_h xᵀ`;
//! `∂L/∂[S, Tf] = (W₁ᵀδ_h)[0..6]`; the ray gets none.

use anyhow::{ensure, Result};

use super::project::Projected;
use super::raster::{rasterize, RasterOutput, TileBins};
use super::RenderSettings;
use crate::scene::{PinholeCamera, Pose};

pub use crate::splats::decoder_json::{FEATURE_CHANNELS, HIDDEN, INPUTS, OUTPUTS, WEIGHTS};

/// The unit world-space direction through the centre of pixel `(i, j)`.
pub fn ray_direction(camera: &PinholeCamera, pose: &Pose, i: u32, j: u32) -> [f64; 3] {
    let x = (i as f64 + 0.5 - camera.cx) / camera.fx;
    let y = (j as f64 + 0.5 - camera.cy) / camera.fy;
    // World direction = Rᵀ·(x, y, 1) (R: world-to-camera rotation).
    let r = &pose.rotation;
    let d = [0, 1, 2].map(|k| r[0][k] * x + r[1][k] * y + r[2][k]);
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|v| v / n)
}

/// The decoder's input at one pixel.
pub fn decoder_input(features: [f64; 6], origin: [f64; 3], direction: [f64; 3]) -> [f64; INPUTS] {
    let mut x = [0.0; INPUTS];
    x[..6].copy_from_slice(&features);
    x[6..9].copy_from_slice(&origin);
    x[9..].copy_from_slice(&direction);
    x
}

fn hidden_pre(w: &[f64], x: &[f64; INPUTS]) -> [f64; HIDDEN] {
    std::array::from_fn(|r| (0..INPUTS).map(|c| w[r * INPUTS + c] * x[c]).sum())
}

fn sigmoid(v: f64) -> f64 {
    1.0 / (1.0 + (-v).exp())
}

/// `σ(B + W₂ ReLU(W₁x))`.
pub fn decode(w: &[f64], base: [f64; 3], x: &[f64; INPUTS]) -> [f64; 3] {
    let pre = hidden_pre(w, x);
    let h = pre.map(|v| v.max(0.0));
    let w2 = &w[HIDDEN * INPUTS..];
    std::array::from_fn(|o| {
        let y: f64 = (0..HIDDEN).map(|c| w2[o * HIDDEN + c] * h[c]).sum();
        sigmoid(base[o] + y)
    })
}

/// One pixel's decoder gradients: `(∂L/∂B, ∂L/∂[S, Tf])`, with `∂L/∂W` added into `dl_dw`.
pub fn decode_backward(
    w: &[f64],
    base: [f64; 3],
    x: &[f64; INPUTS],
    dl_drgb: [f64; 3],
    dl_dw: &mut [f64],
) -> ([f64; 3], [f64; 6]) {
    let rgb = decode(w, base, x);
    let pre = hidden_pre(w, x);
    let h = pre.map(|v| v.max(0.0));
    let w2 = &w[HIDDEN * INPUTS..];
    let delta: [f64; 3] = std::array::from_fn(|o| dl_drgb[o] * rgb[o] * (1.0 - rgb[o]));
    for o in 0..OUTPUTS {
        for c in 0..HIDDEN {
            dl_dw[HIDDEN * INPUTS + o * HIDDEN + c] += delta[o] * h[c];
        }
    }
    let delta_h: [f64; HIDDEN] = std::array::from_fn(|c| {
        if pre[c] > 0.0 {
            (0..OUTPUTS).map(|o| w2[o * HIDDEN + c] * delta[o]).sum()
        } else {
            0.0
        }
    });
    for r in 0..HIDDEN {
        for c in 0..INPUTS {
            dl_dw[r * INPUTS + c] += delta_h[r] * x[c];
        }
    }
    let dl_dfeat =
        std::array::from_fn(|c| (0..HIDDEN).map(|r| w[r * INPUTS + c] * delta_h[r]).sum());
    (delta, dl_dfeat)
}

/// The decoded image (`[r, g, b]` per pixel) of a blended base image and feature image.
pub fn decode_image(
    w: &[f64],
    base: &[[f64; 3]],
    features: &[[f64; 6]],
    camera: &PinholeCamera,
    pose: &Pose,
) -> Vec<[f64; 3]> {
    let origin = pose.center();
    (0..base.len())
        .map(|pix| {
            let (i, j) = (pix as u32 % camera.width, pix as u32 / camera.width);
            let x = decoder_input(features[pix], origin, ray_direction(camera, pose, i, j));
            decode(w, base[pix], &x)
        })
        .collect()
}

/// The decoder's backward over an image: `(∂L/∂B per pixel, ∂L/∂[S, Tf] per pixel, ∂L/∂W)`.
pub fn decode_image_backward(
    w: &[f64],
    base: &[[f64; 3]],
    features: &[[f64; 6]],
    camera: &PinholeCamera,
    pose: &Pose,
    dl_drgb: &[[f64; 3]],
) -> (Vec<[f64; 3]>, Vec<[f64; 6]>, Vec<f64>) {
    let origin = pose.center();
    let mut dl_dw = vec![0.0; WEIGHTS];
    let (mut db, mut df) = (Vec::new(), Vec::new());
    for pix in 0..base.len() {
        let (i, j) = (pix as u32 % camera.width, pix as u32 / camera.width);
        let x = decoder_input(features[pix], origin, ray_direction(camera, pose, i, j));
        let (b, f) = decode_backward(w, base[pix], &x, dl_drgb[pix], &mut dl_dw);
        db.push(b);
        df.push(f);
    }
    (db, df, dl_dw)
}

/// `projected` with the colour of every Gaussian replaced by channels `3k..3k + 3` of its
/// features (`features[g·channels + c]`), unclamped.
fn with_triple(
    projected: &[Projected],
    features: &[f64],
    channels: usize,
    k: usize,
) -> Vec<Projected> {
    projected
        .iter()
        .enumerate()
        .map(|(g, p)| Projected {
            rgb: std::array::from_fn(|c| features[g * channels + 3 * k + c]),
            rgb_clamped: [false; 3],
            ..*p
        })
        .collect()
}

/// The feature image, `[pix·channels + c]`: the channels blended like the colour over a black
/// background (`channels` a multiple of 3).
pub fn rasterize_features(
    projected: &[Projected],
    bins: &TileBins,
    camera: &PinholeCamera,
    features: &[f64],
    channels: usize,
    settings: &RenderSettings,
) -> Result<Vec<f64>> {
    ensure!(
        channels.is_multiple_of(3) && features.len() == projected.len() * channels,
        "reference features: {} values for {} Gaussians of {channels} channels (a multiple of 3)",
        features.len(),
        projected.len()
    );
    let n = camera.width as usize * camera.height as usize;
    let mut out = vec![0.0; n * channels];
    for k in 0..channels / 3 {
        let p = with_triple(projected, features, channels, k);
        let r = rasterize(&p, bins, camera, [0.0; 3], settings)?;
        for (pix, rgb) in r.image.iter().enumerate() {
            out[pix * channels + 3 * k..pix * channels + 3 * k + 3].copy_from_slice(rgb);
        }
    }
    Ok(out)
}

/// The gradients the feature channels add: the geometry's (mean2d, conic, opacity; the `rgb`
/// field holds zeros) and the features' own, `[g·channels + c]`, from `dL/d(feature image)`.
/// `raster` is the colour pass's output (the weights are the same).
pub fn rasterize_features_backward(
    projected: &[Projected],
    bins: &TileBins,
    raster: &RasterOutput,
    features: &[f64],
    channels: usize,
    settings: &RenderSettings,
    dl_dfeatures: &[f64],
) -> Result<(super::backward::ProjectedGrads, Vec<f64>)> {
    let n_pix = raster.width as usize * raster.height as usize;
    ensure!(
        dl_dfeatures.len() == n_pix * channels,
        "reference features backward: {} gradients for {n_pix} pixels of {channels} channels",
        dl_dfeatures.len()
    );
    let mut geometry = super::backward::ProjectedGrads::zeros(projected.len());
    let mut grads = vec![0.0; projected.len() * channels];
    for k in 0..channels / 3 {
        let p = with_triple(projected, features, channels, k);
        let dl: Vec<[f64; 3]> = (0..n_pix)
            .map(|pix| std::array::from_fn(|c| dl_dfeatures[pix * channels + 3 * k + c]))
            .collect();
        let g = super::backward::rasterize_backward(&p, bins, raster, [0.0; 3], settings, &dl)?;
        for i in 0..projected.len() {
            for c in 0..3 {
                grads[i * channels + 3 * k + c] = g.rgb[i][c];
            }
            for c in 0..2 {
                geometry.mean2d[i][c] += g.mean2d[i][c];
            }
            for c in 0..3 {
                geometry.conic[i][c] += g.conic[i][c];
            }
            geometry.opacity[i] += g.opacity[i];
        }
    }
    Ok((geometry, grads))
}

/// A Gaussian's feature channels at time `t` (temporal centre `c`): `[f_spec, (t − c)·f_t]`.
pub fn time_features(f_spec: [f64; 3], f_t: [f64; 3], t: f64, c: f64) -> [f64; 6] {
    let d = t - c;
    [
        f_spec[0],
        f_spec[1],
        f_spec[2],
        d * f_t[0],
        d * f_t[1],
        d * f_t[2],
    ]
}

/// The backward of [`time_features`] (`t − c` detached): `(∂L/∂f_spec, ∂L/∂f_t)`.
pub fn time_features_backward(dl: [f64; 6], t: f64, c: f64) -> ([f64; 3], [f64; 3]) {
    let d = t - c;
    ([dl[0], dl[1], dl[2]], [d * dl[3], d * dl[4], d * dl[5]])
}
