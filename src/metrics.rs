//! Image metrics on the CPU in f64: PSNR, SSIM, L1, and the reference of the training loss
//! `(1 − w)·L1 + w·(1 − SSIM)` with its analytic gradient (the oracle of the GPU loss kernels).
//!
//! Images are `&[f32]` RGB interleaved, `[(y·W + x)·3 + c]`, values nominally in [0, 1].
//!
//! SSIM follows the usual 3DGS definition: an 11×11 Gaussian window with σ = 1.5 (weights
//! normalised to sum 1), applied as a "same"-size convolution with zeros outside the image (like
//! `conv2d(padding = 5)`; the window is *not* renormalised at the borders), C1 = 0.01²,
//! C2 = 0.03², computed per channel and averaged over every pixel and the three channels.

use crate::error::InputError;
use anyhow::Result;
use rayon::prelude::*;

/// Window radius: 11 taps.
pub const SSIM_RADIUS: usize = 5;
/// Window standard deviation in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
pub const SSIM_C1: f64 = 0.01 * 0.01;
pub const SSIM_C2: f64 = 0.03 * 0.03;

/// The normalised 1D Gaussian taps; the 2D window is their outer product.
pub fn ssim_window() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut g = [0.0; 2 * SSIM_RADIUS + 1];
    for (i, v) in g.iter_mut().enumerate() {
        let d = i as f64 - SSIM_RADIUS as f64;
        *v = (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= s);
    g
}

fn bad(field: &str, problem: String, fix: &str) -> anyhow::Error {
    InputError::new("<in-memory image>", field, problem, fix).into()
}

/// Checks that `a` and `b` are both W×H RGB images with W, H > 0.
fn check_pair(a: &[f32], b: &[f32], w: usize, h: usize) -> Result<()> {
    if w == 0 || h == 0 {
        return Err(bad(
            "width/height",
            format!("the image is {w}×{h}, which has no pixels"),
            "pass an image with at least one pixel",
        ));
    }
    let n = w
        .checked_mul(h)
        .and_then(|p| p.checked_mul(3))
        .ok_or_else(|| {
            bad(
                "width/height",
                format!("{w}×{h} overflows"),
                "use a smaller image",
            )
        })?;
    for (name, img) in [("first image", a), ("second image", b)] {
        if img.len() != n {
            return Err(bad(
                name,
                format!("has {} values but a {w}×{h} RGB image needs {n}", img.len()),
                "pass interleaved RGB images of the stated size",
            ));
        }
    }
    Ok(())
}

/// Checks two RGB images of any (equal, non-zero) size.
fn check_same_len(a: &[f32], b: &[f32]) -> Result<()> {
    if a.is_empty() || !a.len().is_multiple_of(3) {
        return Err(bad(
            "first image",
            format!("has {} values, not a non-zero multiple of 3", a.len()),
            "pass a non-empty interleaved RGB image",
        ));
    }
    if a.len() != b.len() {
        return Err(bad(
            "second image",
            format!("has {} values but the first has {}", b.len(), a.len()),
            "compare images of the same size",
        ));
    }
    Ok(())
}

/// Mean absolute difference over pixels and channels.
pub fn l1(a: &[f32], b: &[f32]) -> Result<f64> {
    check_same_len(a, b)?;
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| (x as f64 - y as f64).abs())
        .sum();
    Ok(s / a.len() as f64)
}

/// PSNR in dB for images in [0, 1]: `10·log10(1 / MSE)` with the MSE over pixels and channels.
/// Identical images give `f64::INFINITY` (MSE = 0), which callers averaging PSNRs over a test
/// set should treat specially.
pub fn psnr(a: &[f32], b: &[f32]) -> Result<f64> {
    check_same_len(a, b)?;
    let se: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| {
            let d = x as f64 - y as f64;
            d * d
        })
        .sum();
    let mse = se / a.len() as f64;
    Ok(if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    })
}

/// Planar channel `c` of an interleaved RGB image.
fn channel(img: &[f32], c: usize) -> Vec<f64> {
    img.iter().skip(c).step_by(3).map(|&v| v as f64).collect()
}

/// Same-size zero-padded separable Gaussian blur of a planar W×H map, rows in parallel.
/// Every output sums its taps in window order from 0.0 and skips the taps outside the image, so
/// the result does not depend on how rows are shared out (an evaluation's SSIM is the same on
/// any machine).
fn blur(src: &[f64], w: usize, h: usize, g: &[f64]) -> Vec<f64> {
    let r = SSIM_RADIUS;
    let mut tmp = vec![0.0; w * h];
    tmp.par_chunks_mut(w)
        .zip(src.par_chunks(w))
        .for_each(|(out, row)| {
            // Tap by tap over the outputs it reaches: each output still adds its taps in
            // window order, and the inner loop vectorises.
            for (k, gk) in g.iter().enumerate() {
                let lo = r.saturating_sub(k);
                let hi = (w + r).saturating_sub(k).min(w);
                if lo < hi {
                    let s = &row[lo + k - r..hi + k - r];
                    for (o, v) in out[lo..hi].iter_mut().zip(s) {
                        *o += gk * v;
                    }
                }
            }
        });
    let mut out = vec![0.0; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, o)| {
        for (k, gk) in g.iter().enumerate() {
            let yy = y as isize + k as isize - r as isize;
            if yy >= 0 && (yy as usize) < h {
                let t = &tmp[yy as usize * w..(yy as usize + 1) * w];
                for (ox, tx) in o.iter_mut().zip(t) {
                    *ox += gk * tx;
                }
            }
        }
    });
    out
}

/// Per-pixel SSIM of one channel and its partial derivatives with respect to the blurred
/// moments μx, E[x²] and E[xy] (the three maps the backward blurs).
struct ChannelSsim {
    map: Vec<f64>,
    d_mu: Vec<f64>,
    d_xx: Vec<f64>,
    d_xy: Vec<f64>,
}

/// The blurred moments μx, μy, E[x²], E[y²], E[xy] of one channel, one map each.
fn blurred_moments(x: &[f64], y: &[f64], w: usize, h: usize, g: &[f64]) -> [Vec<f64>; 5] {
    let sq = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).collect::<Vec<_>>();
    [
        blur(x, w, h, g),
        blur(y, w, h, g),
        blur(&sq(x, x), w, h, g),
        blur(&sq(y, y), w, h, g),
        blur(&sq(x, y), w, h, g),
    ]
}

/// SSIM's factors at pixel `i`: S = A1·A2 / (B1·B2) with σx² = E[x²] − μx² and
/// σxy = E[xy] − μx·μy; returns (A1, A2, B1, B2).
fn ssim_factors(m: &[Vec<f64>; 5], i: usize) -> (f64, f64, f64, f64) {
    let (ux, uy) = (m[0][i], m[1][i]);
    let sxx = m[2][i] - ux * ux;
    let syy = m[3][i] - uy * uy;
    let sxy = m[4][i] - ux * uy;
    (
        2.0 * ux * uy + SSIM_C1,
        2.0 * sxy + SSIM_C2,
        ux * ux + uy * uy + SSIM_C1,
        sxx + syy + SSIM_C2,
    )
}

fn channel_ssim(x: &[f64], y: &[f64], w: usize, h: usize, g: &[f64]) -> ChannelSsim {
    let m = blurred_moments(x, y, w, h, g);
    let n = w * h;
    let mut out = ChannelSsim {
        map: vec![0.0; n],
        d_mu: vec![0.0; n],
        d_xx: vec![0.0; n],
        d_xy: vec![0.0; n],
    };
    for i in 0..n {
        let (ux, uy) = (m[0][i], m[1][i]);
        let (a1, a2, b1, b2) = ssim_factors(&m, i);
        let s = a1 * a2 / (b1 * b2);
        out.map[i] = s;
        out.d_mu[i] = 2.0 * uy * (a2 - a1) / (b1 * b2) - 2.0 * ux * s * (1.0 / b1 - 1.0 / b2);
        out.d_xx[i] = -s / b2;
        out.d_xy[i] = 2.0 * a1 / (b1 * b2);
    }
    out
}

/// The SSIM map, interleaved like the images (`[(y·W + x)·3 + c]`).
pub fn ssim_map(a: &[f32], b: &[f32], w: usize, h: usize) -> Result<Vec<f64>> {
    check_pair(a, b, w, h)?;
    let g = ssim_window();
    let mut out = vec![0.0; w * h * 3];
    for c in 0..3 {
        let s = channel_ssim(&channel(a, c), &channel(b, c), w, h, &g);
        for (i, v) in s.map.into_iter().enumerate() {
            out[i * 3 + c] = v;
        }
    }
    Ok(out)
}

/// Mean SSIM over pixels and channels (1 for identical images): [`ssim_map`]'s mean, summed in
/// its order, without the gradient maps and with the channels in parallel (every evaluation
/// computes it for each test view: 0.3-0.4 s a 979×546 view when it was serial).
pub fn ssim(a: &[f32], b: &[f32], w: usize, h: usize) -> Result<f64> {
    check_pair(a, b, w, h)?;
    let g = ssim_window();
    let maps: Vec<Vec<f64>> = (0..3)
        .into_par_iter()
        .map(|c| channel_ssim_map(&channel(a, c), &channel(b, c), w, h, &g))
        .collect();
    let mut sum = 0.0;
    for i in 0..w * h {
        for m in &maps {
            sum += m[i];
        }
    }
    Ok(sum / (w * h * 3) as f64)
}

/// The per-pixel SSIM of one channel alone ([`channel_ssim`]'s `map`, the same arithmetic).
fn channel_ssim_map(x: &[f64], y: &[f64], w: usize, h: usize, g: &[f64]) -> Vec<f64> {
    let m = blurred_moments(x, y, w, h, g);
    (0..w * h)
        .map(|i| {
            let (a1, a2, b1, b2) = ssim_factors(&m, i);
            a1 * a2 / (b1 * b2)
        })
        .collect()
}

/// The terms of the training loss.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossTerms {
    pub l1: f64,
    pub ssim: f64,
    /// `(1 − w)·l1 + w·(1 − ssim)`.
    pub total: f64,
}

/// Where render and ground truth agree to within this, L1's subgradient is 0 (a tie): the
/// ground truth's composite over the background is rounded differently by each device, so an
/// exact match on one reads as ±1 ulp on another (glsl/train/loss_common.glsl, `L1_TIE`).
pub const L1_TIE: f64 = 1e-6_f32 as f64;

/// Reference loss `(1 − w)·L1 + w·(1 − SSIM)` of `render` against `gt` and its gradient with
/// respect to `render` (interleaved like the image). The L1 subgradient is 0 within [`L1_TIE`]
/// of render == gt.
pub fn loss_terms_and_grad(
    render: &[f32],
    gt: &[f32],
    w: usize,
    h: usize,
    ssim_weight: f64,
) -> Result<(LossTerms, Vec<f64>)> {
    check_pair(render, gt, w, h)?;
    if !(0.0..=1.0).contains(&ssim_weight) {
        return Err(bad(
            "ssim_weight",
            format!("{ssim_weight} is outside [0, 1]"),
            "use a weight between 0 and 1 (3DGS uses 0.2)",
        ));
    }
    let g = ssim_window();
    let n = (w * h * 3) as f64;
    let mut grad = vec![0.0; w * h * 3];
    let mut ssim_sum = 0.0;
    let mut l1_sum = 0.0;
    for c in 0..3 {
        let x = channel(render, c);
        let y = channel(gt, c);
        let s = channel_ssim(&x, &y, w, h, &g);
        ssim_sum += s.map.iter().sum::<f64>();
        // The window is symmetric, so the adjoint of the zero-padded blur is the same blur.
        let bm = blur(&s.d_mu, w, h, &g);
        let bxx = blur(&s.d_xx, w, h, &g);
        let bxy = blur(&s.d_xy, w, h, &g);
        for i in 0..w * h {
            let d = x[i] - y[i];
            l1_sum += d.abs();
            let sign = if d.abs() <= L1_TIE { 0.0 } else { d.signum() };
            let d_ssim = bm[i] + 2.0 * x[i] * bxx[i] + y[i] * bxy[i];
            grad[i * 3 + c] = ((1.0 - ssim_weight) * sign - ssim_weight * d_ssim) / n;
        }
    }
    let l1 = l1_sum / n;
    let ssim = ssim_sum / n;
    let terms = LossTerms {
        l1,
        ssim,
        total: (1.0 - ssim_weight) * l1 + ssim_weight * (1.0 - ssim),
    };
    Ok((terms, grad))
}

/// [`loss_terms_and_grad`] returning only the total loss and the gradient.
pub fn loss_and_grad(
    render: &[f32],
    gt: &[f32],
    w: usize,
    h: usize,
    ssim_weight: f64,
) -> Result<(f64, Vec<f64>)> {
    let (t, g) = loss_terms_and_grad(render, gt, w, h, ssim_weight)?;
    Ok((t.total, g))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_is_normalised_and_symmetric() {
        let g = ssim_window();
        assert!((g.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        for i in 0..g.len() {
            assert_eq!(g[i], g[g.len() - 1 - i]);
        }
        assert!(g[5] > g[4] && g[4] > g[3]);
    }

    #[test]
    fn psnr_of_known_mse() {
        // MSE 0.01 everywhere → 20 dB.
        let a = vec![0.5f32; 12];
        let b: Vec<f32> = a
            .iter()
            .enumerate()
            .map(|(i, v)| if i % 2 == 0 { v + 0.1 } else { v - 0.1 })
            .collect();
        let p = psnr(&a, &b).unwrap();
        assert!((p - 20.0).abs() < 1e-5, "{p}");
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
    }

    /// The blur against a direct 2D sum of the window's outer product over the taps inside the
    /// image, and `ssim` against the mean of `ssim_map` bit for bit, on images narrower and
    /// wider than the window (rows with and without an interior).
    #[test]
    fn blur_and_ssim_match_their_direct_forms() {
        let g = ssim_window();
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for (w, h) in [(1, 1), (7, 3), (11, 12), (37, 23)] {
            let src: Vec<f64> = (0..w * h).map(|_| rnd() as f64).collect();
            let got = blur(&src, w, h, &g);
            let r = SSIM_RADIUS as isize;
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let mut want = 0.0;
                    for dy in -r..=r {
                        for dx in -r..=r {
                            let (xx, yy) = (x + dx, y + dy);
                            if xx >= 0 && yy >= 0 && xx < w as isize && yy < h as isize {
                                want += g[(dy + r) as usize]
                                    * g[(dx + r) as usize]
                                    * src[yy as usize * w + xx as usize];
                            }
                        }
                    }
                    let v = got[y as usize * w + x as usize];
                    assert!(
                        (v - want).abs() < 1e-14,
                        "{w}x{h} ({x}, {y}): {v} vs {want}"
                    );
                }
            }
            let a: Vec<f32> = (0..w * h * 3).map(|_| rnd()).collect();
            let b: Vec<f32> = a.iter().map(|v| (v + 0.2 * rnd()).min(1.0)).collect();
            let m = ssim_map(&a, &b, w, h).unwrap();
            let mean = m.iter().sum::<f64>() / m.len() as f64;
            assert_eq!(ssim(&a, &b, w, h).unwrap().to_bits(), mean.to_bits());
        }
    }

    #[test]
    fn bad_sizes_are_errors() {
        let a = vec![0.0f32; 12];
        assert!(ssim(&a, &a, 0, 4).is_err());
        assert!(ssim(&a, &a, 2, 3).is_err());
        assert!(ssim(&a, &a[..9], 2, 2).is_err());
        assert!(psnr(&a, &a[..9]).is_err());
        assert!(psnr(&[], &[]).is_err());
        assert!(l1(&a[..10], &a[..10]).is_err());
        assert!(loss_and_grad(&a, &a, 2, 2, 1.5).is_err());
        let msg = format!("{}", ssim(&a, &a[..9], 2, 2).unwrap_err());
        assert!(msg.contains("second image") && msg.contains("Fix"), "{msg}");
    }
}
