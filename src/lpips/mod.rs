//! LPIPS (Zhang et al., CVPR 2018), AlexNet trunk with the v0.1 linear heads: the perceptual
//! metric of the LPM paper's tables, on the CPU (rayon + `matrixmultiply` sgemm).
//!
//! It reproduces `lpips.LPIPS(net='alex', version='0.1', lpips=True, spatial=False)` called
//! with `normalize=True` on images in [0, 1] (lpips 0.1.4, `lpips/lpips.py` and
//! `lpips/pretrained_networks.py`):
//!
//! 1. `x ← 2x − 1`, then the ScalingLayer `(x − shift) / scale`, shift = (−.030, −.088, −.188),
//!    scale = (.458, .448, .450) — both as float32, in that order of operations.
//! 2. torchvision AlexNet `features[0..12]`: conv1 (64×3×11×11, stride 4, pad 2) + ReLU → tap 1,
//!    max-pool 3/2, conv2 (192×64×5×5, pad 2) + ReLU → tap 2, max-pool 3/2, conv3 (384, 3×3,
//!    pad 1) + ReLU → tap 3, conv4 (256) + ReLU → tap 4, conv5 (256) + ReLU → tap 5. The third
//!    max-pool (`features[12]`) comes after the last tap, so lpips never runs it.
//! 3. Per tap: each pixel's channel vector divided by (its L2 norm + 1e-10), the squared
//!    difference of the two images' vectors, the 1×1 linear head (no bias; dropout is off in
//!    eval mode), the spatial mean; the result is the sum over the five taps.
//!
//! Convolutions run in f32 (like PyTorch's float32 model); normalisation, heads and means in f64.
//! The two images go through the network in lock-step (`rayon::join` per layer), and each tap is
//! reduced to its distance before the next layer, so memory stays at about two layers' maps.

mod alexnet;
pub mod scores;
pub mod weights;

use crate::error::InputError;
use alexnet::{max_pool_3s2, Conv, Map};
use anyhow::Result;
use rayon::prelude::*;
use std::path::Path;
use weights::SafeTensors;

/// lpips' ScalingLayer constants (float32 buffers in PyTorch).
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// `lpips.normalize_tensor`'s epsilon, added to the norm (not under the square root).
const NORM_EPS: f64 = 1e-10;

/// Channels of the five taps (= input channels of the five linear heads).
pub const TAP_CHANNELS: [usize; 5] = [64, 192, 384, 256, 256];

/// The smallest image side AlexNet's taps accept: conv1 gives ⌊(n − 7)/4⌋ + 1 pixels, and each
/// of the two pools before tap 5 needs ≥ 3 input pixels, so conv1 must give ≥ 7, i.e. n ≥ 31.
/// (lpips fails on 30, see `tests/data/lpips/expected.json`.)
pub const MIN_SIDE: usize = 31;

/// (torchvision index in `features`, out channels, in channels, kernel, stride, padding).
const CONVS: [(usize, usize, usize, usize, usize, usize); 5] = [
    (0, 64, 3, 11, 4, 2),
    (3, 192, 64, 5, 1, 2),
    (6, 384, 192, 3, 1, 1),
    (8, 256, 384, 3, 1, 1),
    (10, 256, 256, 3, 1, 1),
];

/// The LPIPS network: AlexNet's five convolutions and the five linear heads.
#[derive(Debug, Clone)]
pub struct Lpips {
    convs: Vec<Conv>,
    heads: [Vec<f64>; 5],
}

impl Lpips {
    /// Loads AlexNet features + the 5 linear heads from a safetensors file (F32 tensors
    /// `features.{0,3,6,8,10}.{weight,bias}` and `lin{0..4}.weight`, shapes checked strictly),
    /// as written by `scripts/convert_lpips_weights.py`.
    pub fn load(path: &Path) -> Result<Lpips> {
        let st = SafeTensors::open(path)?;
        let finite = |name: &str, v: &[f32]| -> Result<()> {
            match v.iter().position(|x| !x.is_finite()) {
                None => Ok(()),
                Some(i) => Err(InputError::new(
                    path,
                    format!("tensor {name:?}"),
                    format!("value {i} is {}", v[i]),
                    weights::WEIGHTS_FIX,
                )
                .into()),
            }
        };
        let mut convs = Vec::with_capacity(5);
        for (idx, cout, cin, k, stride, pad) in CONVS {
            let wname = format!("features.{idx}.weight");
            let bname = format!("features.{idx}.bias");
            let w = st.f32(&wname, &[cout, cin, k, k])?;
            let b = st.f32(&bname, &[cout])?;
            finite(&wname, &w)?;
            finite(&bname, &b)?;
            convs.push(Conv::from_torch(cout, cin, k, stride, pad, &w, b));
        }
        let mut heads: [Vec<f64>; 5] = Default::default();
        for (i, head) in heads.iter_mut().enumerate() {
            let name = format!("lin{i}.weight");
            let w = st.f32(&name, &[1, TAP_CHANNELS[i], 1, 1])?;
            finite(&name, &w)?;
            *head = w.iter().map(|&v| v as f64).collect();
        }
        Ok(Lpips { convs, heads })
    }

    /// LPIPS distance between two RGB images, `&[f32]` interleaved `[(y*w + x)*3 + c]`, values
    /// in \[0, 1\] (mapped internally to \[−1, 1\] as lpips does with normalize=True), same size w×h.
    pub fn distance(&self, a: &[f32], b: &[f32], w: usize, h: usize) -> Result<f64> {
        Ok(self.distance_per_tap(a, b, w, h)?.iter().sum())
    }

    /// The five per-tap terms whose sum is [`Lpips::distance`] (lpips' `retPerLayer=True`).
    pub fn distance_per_tap(&self, a: &[f32], b: &[f32], w: usize, h: usize) -> Result<[f64; 5]> {
        check_images(a, b, w, h)?;
        let (mut xa, mut xb) = rayon::join(|| scale_input(a, w, h), || scale_input(b, w, h));
        let mut out = [0.0; 5];
        for (tap, conv) in self.convs.iter().enumerate() {
            if tap == 1 || tap == 2 {
                (xa, xb) = rayon::join(|| max_pool_3s2(&xa), || max_pool_3s2(&xb));
            }
            (xa, xb) = rayon::join(|| conv.forward_relu(&xa), || conv.forward_relu(&xb));
            out[tap] = tap_distance(&xa, &xb, &self.heads[tap]);
        }
        Ok(out)
    }
}

fn bad_image(field: &str, problem: String, fix: &str) -> anyhow::Error {
    InputError::new("<in-memory image>", field, problem, fix).into()
}

/// Sizes, lengths and finiteness of the inputs.
fn check_images(a: &[f32], b: &[f32], w: usize, h: usize) -> Result<()> {
    if w < MIN_SIDE || h < MIN_SIDE {
        return Err(bad_image(
            "width/height",
            format!(
                "the images are {w}×{h} px, but LPIPS' AlexNet needs at least \
                 {MIN_SIDE}×{MIN_SIDE} (a stride-4 11×11 convolution and two 3×3 stride-2 \
                 max-pools must leave at least one pixel)"
            ),
            "compare larger images (a lower downscale factor)",
        ));
    }
    let n = w
        .checked_mul(h)
        .and_then(|p| p.checked_mul(3))
        .ok_or_else(|| {
            bad_image(
                "width/height",
                format!("{w}×{h} overflows"),
                "use a smaller image",
            )
        })?;
    for (name, img) in [("first image", a), ("second image", b)] {
        if img.len() != n {
            return Err(bad_image(
                name,
                format!("has {} values but a {w}×{h} RGB image needs {n}", img.len()),
                "pass two RGB images of the same size, interleaved [(y*w + x)*3 + c]",
            ));
        }
        if let Some(i) = img.iter().position(|v| !v.is_finite()) {
            return Err(bad_image(
                name,
                format!(
                    "value {i} (pixel {}, channel {}) is {}",
                    i / 3,
                    i % 3,
                    img[i]
                ),
                "pass finite values in [0, 1]",
            ));
        }
    }
    Ok(())
}

/// `[0,1]` → `[−1,1]` → ScalingLayer, in float32 with PyTorch's order of operations.
fn scale_input(img: &[f32], w: usize, h: usize) -> Map {
    let data = img
        .chunks_exact(3)
        .flat_map(|px| {
            (0..3).map(move |c| {
                let x = 2.0f32 * px[c] - 1.0;
                (x - SHIFT[c]) / SCALE[c]
            })
        })
        .collect();
    Map { w, h, c: 3, data }
}

/// The spatial mean over pixels of `Σ_c head_c · (â_c − b̂_c)²`, â = a / (‖a‖ + eps).
/// Partial sums per block of pixels are added in a fixed order, so the result is deterministic.
fn tap_distance(a: &Map, b: &Map, head: &[f64]) -> f64 {
    let c = a.c;
    debug_assert_eq!(head.len(), c);
    const PIXELS: usize = 1024;
    let partial: Vec<f64> = a
        .data
        .par_chunks(PIXELS * c)
        .zip(b.data.par_chunks(PIXELS * c))
        .map(|(ba, bb)| {
            let mut sum = 0.0f64;
            for (pa, pb) in ba.chunks_exact(c).zip(bb.chunks_exact(c)) {
                let na = pa
                    .iter()
                    .map(|&v| (v as f64) * (v as f64))
                    .sum::<f64>()
                    .sqrt();
                let nb = pb
                    .iter()
                    .map(|&v| (v as f64) * (v as f64))
                    .sum::<f64>()
                    .sqrt();
                let (ia, ib) = (1.0 / (na + NORM_EPS), 1.0 / (nb + NORM_EPS));
                let mut s = 0.0f64;
                for ((&va, &vb), &wc) in pa.iter().zip(pb).zip(head) {
                    let d = va as f64 * ia - vb as f64 * ib;
                    s += wc * d * d;
                }
                sum += s;
            }
            sum
        })
        .collect();
    partial.iter().sum::<f64>() / (a.w * a.h) as f64
}

#[cfg(test)]
mod tests {
    use super::alexnet::pool_size;
    use super::*;

    /// MIN_SIDE is the smallest side for which every tap has at least one pixel.
    #[test]
    fn min_side_is_derived_from_the_layers() {
        let fits = |n: usize| {
            let c1 = Conv::from_torch(1, 1, 11, 4, 2, &[0.0; 121], vec![0.0]);
            c1.out_size(n)
                .and_then(pool_size)
                .and_then(pool_size)
                .is_some_and(|s| s >= 1)
        };
        assert!(fits(MIN_SIDE));
        assert!((1..MIN_SIDE).all(|n| !fits(n)));
    }
}
