//! The layers of torchvision's AlexNet `features` that LPIPS taps: convolution + ReLU as
//! im2col + sgemm (`matrixmultiply`), and the 3×3 stride-2 max-pool, on the CPU with rayon.
//!
//! Feature maps are stored pixel-major (HWC: `[(y·W + x)·C + c]`) so that one output pixel's
//! im2col row is a few contiguous copies (one per kernel row), a block of output rows is a
//! contiguous slice (safe to hand to a rayon task), and the per-pixel channel normalisation of
//! LPIPS reads contiguous memory. Convolutions are cross-correlations, as in PyTorch.

use rayon::prelude::*;

/// A feature map, pixel-major: `data[(y * w + x) * c + ch]`.
#[derive(Debug, Clone)]
pub struct Map {
    pub w: usize,
    pub h: usize,
    pub c: usize,
    pub data: Vec<f32>,
}

/// One Conv2d (+ the ReLU that always follows it in AlexNet `features`).
#[derive(Debug, Clone)]
pub struct Conv {
    pub cin: usize,
    pub cout: usize,
    pub k: usize,
    pub stride: usize,
    pub pad: usize,
    /// The weights as the right-hand sgemm operand: `[((ky·k + kx)·cin + ci)·cout + co]`.
    wt: Vec<f32>,
    bias: Vec<f32>,
}

/// Output pixels per rayon task, roughly: enough work per sgemm call to amortise packing, small
/// enough that the im2col block (pixels × k²·cin floats, ≤ 3.5 MB for conv4) stays cache-friendly.
const PIXELS_PER_TASK: usize = 256;
/// Fewer output pixels than this per task and the per-call packing of the weights (k²·cin ×
/// cout floats, repacked by every sgemm call) costs more than the split gains: small maps (the
/// last three convolutions of a ~250 px image) run as one task, and the two images of a pair
/// still run side by side.
const MIN_PIXELS_PER_TASK: usize = 128;

impl Conv {
    /// From PyTorch's `[cout][cin][ky][kx]` weight and `[cout]` bias.
    pub fn from_torch(
        cout: usize,
        cin: usize,
        k: usize,
        stride: usize,
        pad: usize,
        weight: &[f32],
        bias: Vec<f32>,
    ) -> Conv {
        assert_eq!(weight.len(), cout * cin * k * k);
        assert_eq!(bias.len(), cout);
        let mut wt = vec![0.0f32; weight.len()];
        for co in 0..cout {
            for ci in 0..cin {
                for ky in 0..k {
                    for kx in 0..k {
                        wt[((ky * k + kx) * cin + ci) * cout + co] =
                            weight[((co * cin + ci) * k + ky) * k + kx];
                    }
                }
            }
        }
        Conv {
            cin,
            cout,
            k,
            stride,
            pad,
            wt,
            bias,
        }
    }

    /// Output size along one axis for input size `n`, `None` if the kernel does not fit.
    pub fn out_size(&self, n: usize) -> Option<usize> {
        (n + 2 * self.pad)
            .checked_sub(self.k)
            .map(|r| r / self.stride + 1)
    }

    /// ReLU(conv(x) + bias).
    pub fn forward_relu(&self, x: &Map) -> Map {
        assert_eq!(x.c, self.cin);
        let ow = self.out_size(x.w).expect("image too small for the kernel");
        let oh = self.out_size(x.h).expect("image too small for the kernel");
        let (k, cin, cout) = (self.k, self.cin, self.cout);
        let kk = k * k * cin;
        let mut out = vec![0.0f32; ow * oh * cout];
        // Whole output rows per task; at least ~4 tasks per thread when the map allows it.
        let tasks_wanted = 4 * rayon::current_num_threads();
        let rows = (PIXELS_PER_TASK / ow)
            .min(oh.div_ceil(tasks_wanted))
            .max(MIN_PIXELS_PER_TASK.div_ceil(ow))
            .max(1);
        out.par_chunks_mut(rows * ow * cout)
            .enumerate()
            .for_each_init(Vec::new, |col: &mut Vec<f32>, (task, block)| {
                let npix = block.len() / cout;
                let p0 = task * rows * ow;
                col.clear();
                col.resize(npix * kk, 0.0);
                self.im2col(x, p0, ow, col);
                for px in block.chunks_exact_mut(cout) {
                    px.copy_from_slice(&self.bias);
                }
                // SAFETY: col is npix×kk, wt is kk×cout, block is npix×cout, all row-major and
                // dense; the strides below describe exactly those layouts.
                unsafe {
                    matrixmultiply::sgemm(
                        npix,
                        kk,
                        cout,
                        1.0,
                        col.as_ptr(),
                        kk as isize,
                        1,
                        self.wt.as_ptr(),
                        cout as isize,
                        1,
                        1.0,
                        block.as_mut_ptr(),
                        cout as isize,
                        1,
                    );
                }
                for v in block.iter_mut() {
                    *v = v.max(0.0);
                }
            });
        Map {
            w: ow,
            h: oh,
            c: cout,
            data: out,
        }
    }

    /// Fills `col` (`npix × k²·cin`, zeroed) with the receptive fields of output pixels
    /// `p0 .. p0 + npix` (row-major over an output of width `ow`). Padding stays zero. For one
    /// kernel row, the in-bounds part of the field is a contiguous run of the input row.
    fn im2col(&self, x: &Map, p0: usize, ow: usize, col: &mut [f32]) {
        let (k, cin) = (self.k, self.cin);
        let kk = k * k * cin;
        let pad = self.pad as isize;
        for (p, row) in col.chunks_exact_mut(kk).enumerate() {
            let (oy, ox) = ((p0 + p) / ow, (p0 + p) % ow);
            let x0 = (ox * self.stride) as isize - pad;
            // Kernel columns kx in [kx0, kx1) land inside the image.
            let kx0 = (-x0).max(0) as usize;
            let kx1 = ((x.w as isize - x0).min(k as isize)).max(0) as usize;
            if kx0 >= kx1 {
                continue;
            }
            for ky in 0..k {
                let iy = (oy * self.stride + ky) as isize - pad;
                if iy < 0 || iy >= x.h as isize {
                    continue;
                }
                let src = (iy as usize * x.w + (x0 + kx0 as isize) as usize) * cin;
                let n = (kx1 - kx0) * cin;
                let dst = (ky * k + kx0) * cin;
                row[dst..dst + n].copy_from_slice(&x.data[src..src + n]);
            }
        }
    }
}

/// Output size of the 3×3 stride-2 max-pool (no padding, floor mode) for input size `n`.
pub fn pool_size(n: usize) -> Option<usize> {
    n.checked_sub(3).map(|r| r / 2 + 1)
}

/// `MaxPool2d(kernel_size=3, stride=2)` (no padding, floor mode).
pub fn max_pool_3s2(x: &Map) -> Map {
    let ow = pool_size(x.w).expect("map too small to pool");
    let oh = pool_size(x.h).expect("map too small to pool");
    let c = x.c;
    let mut out = vec![0.0f32; ow * oh * c];
    out.par_chunks_mut(ow * c)
        .enumerate()
        .for_each(|(oy, row)| {
            for ox in 0..ow {
                let dst = &mut row[ox * c..(ox + 1) * c];
                dst.fill(f32::NEG_INFINITY);
                for dy in 0..3 {
                    for dx in 0..3 {
                        let s = ((2 * oy + dy) * x.w + 2 * ox + dx) * c;
                        for (d, &v) in dst.iter_mut().zip(&x.data[s..s + c]) {
                            *d = d.max(v);
                        }
                    }
                }
            }
        });
    Map {
        w: ow,
        h: oh,
        c,
        data: out,
    }
}
