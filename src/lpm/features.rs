//! A classical detector, descriptor and matcher for scenes without SfM tracks.
//!
//! Detector: FAST-9 on the 16-pixel Bresenham circle of radius 3 over a lightly smoothed
//! grayscale image (σ = 1), scored by the Harris response, 3×3 non-maximum suppression, the
//! strongest `max_keypoints` kept. Orientation: intensity centroid in a disc of radius 15.
//! Descriptor: steered BRIEF, 256 intensity comparisons of point pairs drawn once from a fixed-seed
//! isotropic Gaussian (σ = 31/5, clipped to the disc) rotated to the keypoint's orientation, on a
//! more strongly smoothed image (σ = 2, so single-pixel noise does not flip bits), bilinear
//! samples. Single scale: neighbour views (≤ 45° apart, similar distances) rarely change scale by
//! more than the descriptor tolerates, and a pyramid would cost time for little gain here.
//! Matching: brute-force Hamming distance, Lowe's ratio test on the first direction and mutual
//! nearest neighbours; the epipolar filter runs after (see `epipolar`).

use crate::scene::Image;
use rand::SeedableRng;
use rand_distr_free::gaussian;

/// Detector/descriptor/matcher settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureSettings {
    /// FAST threshold on intensities in [0, 1].
    pub fast_threshold: f32,
    pub max_keypoints: usize,
    /// Best distance must be below `ratio` × second best.
    pub ratio: f32,
    /// Matches with a larger Hamming distance (of 256) are dropped.
    pub max_hamming: u32,
}

impl Default for FeatureSettings {
    fn default() -> Self {
        Self {
            fast_threshold: 0.05,
            max_keypoints: 3000,
            ratio: 0.8,
            max_hamming: 80,
        }
    }
}

/// Keypoints with descriptors of one image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Features {
    /// (x, y) in pixels, pixel centres at +0.5.
    pub xy: Vec<[f32; 2]>,
    pub descriptors: Vec<[u64; 4]>,
}

const PATCH_RADIUS: f32 = 15.0;
const BORDER: i32 = 20;

/// A grayscale image, row-major.
struct Gray {
    w: usize,
    h: usize,
    v: Vec<f32>,
}

impl Gray {
    fn from_image(img: &Image) -> Gray {
        let (w, h) = (img.width as usize, img.height as usize);
        let v = img
            .rgb
            .chunks_exact(3)
            .take(w * h)
            .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
            .collect();
        Gray { w, h, v }
    }
    fn at(&self, x: i32, y: i32) -> f32 {
        let x = x.clamp(0, self.w as i32 - 1) as usize;
        let y = y.clamp(0, self.h as i32 - 1) as usize;
        self.v[y * self.w + x]
    }
    fn bilinear(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i32, y0 as i32);
        let a = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let b = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        a * (1.0 - fy) + b * fy
    }
    /// Separable Gaussian blur, borders clamped.
    fn blur(&self, sigma: f32) -> Gray {
        let r = (3.0 * sigma).ceil() as i32;
        let k: Vec<f32> = (-r..=r)
            .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
            .collect();
        let norm: f32 = k.iter().sum();
        let k: Vec<f32> = k.iter().map(|x| x / norm).collect();
        let mut tmp = vec![0.0; self.v.len()];
        for y in 0..self.h as i32 {
            for x in 0..self.w as i32 {
                tmp[y as usize * self.w + x as usize] = (-r..=r)
                    .map(|i| k[(i + r) as usize] * self.at(x + i, y))
                    .sum();
            }
        }
        let t = Gray {
            w: self.w,
            h: self.h,
            v: tmp,
        };
        let mut out = vec![0.0; self.v.len()];
        for y in 0..self.h as i32 {
            for x in 0..self.w as i32 {
                out[y as usize * self.w + x as usize] =
                    (-r..=r).map(|i| k[(i + r) as usize] * t.at(x, y + i)).sum();
            }
        }
        Gray {
            w: self.w,
            h: self.h,
            v: out,
        }
    }
}

/// Minimal normal sampling (Box–Muller), so no extra crate is needed for the BRIEF pattern.
mod rand_distr_free {
    use rand::Rng;
    pub fn gaussian(rng: &mut impl Rng) -> f32 {
        let u1: f64 = rng.gen_range(f64::MIN_POSITIVE..1.0);
        let u2: f64 = rng.gen();
        ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
    }
}

/// The 256 BRIEF point pairs (fixed for the life of the format: changing them changes every
/// descriptor, so the cache version must change with them).
fn brief_pattern() -> &'static [[f32; 4]; 256] {
    static PATTERN: std::sync::OnceLock<[[f32; 4]; 256]> = std::sync::OnceLock::new();
    PATTERN.get_or_init(|| {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(0xb21e_f256);
        let sigma = 31.0 / 5.0;
        let mut sample = || loop {
            let (x, y) = (gaussian(&mut rng) * sigma, gaussian(&mut rng) * sigma);
            if x * x + y * y <= (PATCH_RADIUS - 1.0) * (PATCH_RADIUS - 1.0) {
                return [x, y];
            }
        };
        let mut p = [[0.0; 4]; 256];
        for e in p.iter_mut() {
            let (a, b) = (sample(), sample());
            *e = [a[0], a[1], b[0], b[1]];
        }
        p
    })
}

const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// FAST-9: 9 contiguous circle pixels all brighter than centre + t or all darker than centre − t.
fn is_fast_corner(g: &Gray, x: i32, y: i32, t: f32) -> bool {
    let c = g.at(x, y);
    let mut state = [0i8; 16];
    for (s, (dx, dy)) in state.iter_mut().zip(CIRCLE) {
        let p = g.at(x + dx, y + dy);
        *s = if p > c + t {
            1
        } else if p < c - t {
            -1
        } else {
            0
        };
    }
    for sign in [1i8, -1] {
        let mut run = 0;
        for i in 0..32 {
            if state[i % 16] == sign {
                run += 1;
                if run >= 9 {
                    return true;
                }
            } else {
                run = 0;
            }
        }
    }
    false
}

/// Harris response with a 7×7 box window over central-difference gradients.
fn harris(g: &Gray, x: i32, y: i32) -> f32 {
    let (mut a, mut b, mut c) = (0.0f32, 0.0f32, 0.0f32);
    for dy in -3..=3 {
        for dx in -3..=3 {
            let (px, py) = (x + dx, y + dy);
            let ix = 0.5 * (g.at(px + 1, py) - g.at(px - 1, py));
            let iy = 0.5 * (g.at(px, py + 1) - g.at(px, py - 1));
            a += ix * ix;
            b += ix * iy;
            c += iy * iy;
        }
    }
    a * c - b * b - 0.04 * (a + c) * (a + c)
}

/// Detects keypoints and computes their descriptors. An image too small or without texture gives
/// no features (not an error).
pub fn detect_and_describe(img: &Image, s: &FeatureSettings) -> Features {
    let (w, h) = (img.width as i32, img.height as i32);
    if w <= 2 * BORDER || h <= 2 * BORDER || img.rgb.len() < 3 * (w * h) as usize {
        return Features::default();
    }
    let gray = Gray::from_image(img);
    let detect = gray.blur(1.0);
    let smooth = gray.blur(2.0);

    let mut score = vec![0.0f32; (w * h) as usize];
    for y in BORDER..h - BORDER {
        for x in BORDER..w - BORDER {
            if is_fast_corner(&detect, x, y, s.fast_threshold) {
                score[(y * w + x) as usize] = harris(&detect, x, y).max(f32::MIN_POSITIVE);
            }
        }
    }
    let mut cands: Vec<(f32, i32, i32)> = Vec::new();
    for y in BORDER..h - BORDER {
        for x in BORDER..w - BORDER {
            let sc = score[(y * w + x) as usize];
            if sc <= 0.0 {
                continue;
            }
            let is_max = (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    let o = score[((y + dy) * w + x + dx) as usize];
                    (dx == 0 && dy == 0) || o < sc || (o == sc && (dy, dx) > (0, 0))
                })
            });
            if is_max {
                cands.push((sc, x, y));
            }
        }
    }
    cands.sort_by(|a, b| b.0.total_cmp(&a.0).then((a.2, a.1).cmp(&(b.2, b.1))));
    cands.truncate(s.max_keypoints);

    let pattern = brief_pattern();
    let mut out = Features::default();
    for &(_, x, y) in &cands {
        // Intensity-centroid orientation.
        let (mut m10, mut m01) = (0.0f32, 0.0f32);
        let r = PATCH_RADIUS as i32;
        for dy in -r..=r {
            for dx in -r..=r {
                if dx * dx + dy * dy <= r * r {
                    let v = smooth.at(x + dx, y + dy);
                    m10 += dx as f32 * v;
                    m01 += dy as f32 * v;
                }
            }
        }
        let theta = m01.atan2(m10);
        let (sn, cs) = theta.sin_cos();
        let mut d = [0u64; 4];
        for (i, p) in pattern.iter().enumerate() {
            let rot =
                |px: f32, py: f32| (x as f32 + cs * px - sn * py, y as f32 + sn * px + cs * py);
            let (ax, ay) = rot(p[0], p[1]);
            let (bx, by) = rot(p[2], p[3]);
            if smooth.bilinear(ax, ay) < smooth.bilinear(bx, by) {
                d[i / 64] |= 1 << (i % 64);
            }
        }
        out.xy.push([x as f32 + 0.5, y as f32 + 0.5]);
        out.descriptors.push(d);
    }
    out
}

fn hamming(a: &[u64; 4], b: &[u64; 4]) -> u32 {
    (0..4).map(|i| (a[i] ^ b[i]).count_ones()).sum()
}

/// Best and second-best distances and the best index of `d` among `set`.
fn nearest(d: &[u64; 4], set: &[[u64; 4]]) -> Option<(usize, u32, u32)> {
    let mut best = (usize::MAX, u32::MAX, u32::MAX);
    for (j, e) in set.iter().enumerate() {
        let h = hamming(d, e);
        if h < best.1 {
            best = (j, h, best.1);
        } else if h < best.2 {
            best.2 = h;
        }
    }
    (best.0 != usize::MAX).then_some(best)
}

/// Mutual nearest neighbours passing the ratio test (on A's side) and `max_hamming`: index pairs
/// (into `a`, into `b`).
pub fn match_features(a: &Features, b: &Features, s: &FeatureSettings) -> Vec<(usize, usize)> {
    let back: Vec<Option<usize>> = b
        .descriptors
        .iter()
        .map(|d| nearest(d, &a.descriptors).map(|n| n.0))
        .collect();
    let mut out = Vec::new();
    for (i, d) in a.descriptors.iter().enumerate() {
        let Some((j, best, second)) = nearest(d, &b.descriptors) else {
            continue;
        };
        if best > s.max_hamming {
            continue;
        }
        if second != u32::MAX && best as f32 >= s.ratio * second as f32 {
            continue;
        }
        if back[j] == Some(i) {
            out.push((i, j));
        }
    }
    out
}
