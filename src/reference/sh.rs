//! Real spherical harmonics up to degree 3, in the sign convention of the 3DGS PLY files
//! (coefficient k multiplies basis function k below; 16 coefficients per colour channel).
//!
//! The basis functions are written as polynomials in the components (x, y, z) of a unit
//! direction. Their gradients are the gradients of those polynomials; the component along the
//! direction itself is removed later by the Jacobian of the normalisation, so polynomials that agree
//! on the sphere (e.g. `2z² − x² − y²` vs `3z² − 1`) give the same final gradient.

/// Degree 0 constant: `1 / (2 √π)`.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;
/// Degree 1 constant: `√3 / (2 √π)`.
pub const SH_C1: f64 = 0.488_602_511_902_919_9;
/// Degree 2 constants.
pub const SH_C2: [f64; 5] = [
    1.092_548_430_592_079_2,
    -1.092_548_430_592_079_2,
    0.315_391_565_252_520_05,
    -1.092_548_430_592_079_2,
    0.546_274_215_296_039_6,
];
/// Degree 3 constants.
pub const SH_C3: [f64; 7] = [
    -0.590_043_589_926_643_5,
    2.890_611_442_640_554,
    -0.457_045_799_464_465_8,
    0.373_176_332_590_115_4,
    -0.457_045_799_464_465_8,
    1.445_305_721_320_277,
    -0.590_043_589_926_643_5,
];

/// Highest SH degree the engine supports.
pub const MAX_SH_DEGREE: usize = 3;
/// Coefficients per channel at the highest degree.
pub const MAX_SH_COEFFS: usize = 16;

/// Number of coefficients per channel used at `degree`: `(degree + 1)²`.
pub fn num_coeffs(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// The 16 basis values at the unit direction `d`; entries beyond `num_coeffs(degree)` are 0.
pub fn basis(degree: usize, d: [f64; 3]) -> [f64; 16] {
    let [x, y, z] = d;
    let mut b = [0.0; 16];
    b[0] = SH_C0;
    if degree >= 1 {
        b[1] = -SH_C1 * y;
        b[2] = SH_C1 * z;
        b[3] = -SH_C1 * x;
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b[4] = SH_C2[0] * x * y;
        b[5] = SH_C2[1] * y * z;
        b[6] = SH_C2[2] * (2.0 * zz - xx - yy);
        b[7] = SH_C2[3] * x * z;
        b[8] = SH_C2[4] * (xx - yy);
    }
    if degree >= 3 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b[9] = SH_C3[0] * y * (3.0 * xx - yy);
        b[10] = SH_C3[1] * x * y * z;
        b[11] = SH_C3[2] * y * (4.0 * zz - xx - yy);
        b[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
        b[13] = SH_C3[4] * x * (4.0 * zz - xx - yy);
        b[14] = SH_C3[5] * z * (xx - yy);
        b[15] = SH_C3[6] * x * (xx - 3.0 * yy);
    }
    b
}

/// Gradient of each basis polynomial with respect to (x, y, z) at `d` (zero beyond the degree).
pub fn basis_gradient(degree: usize, d: [f64; 3]) -> [[f64; 3]; 16] {
    let [x, y, z] = d;
    let mut g = [[0.0; 3]; 16];
    if degree >= 1 {
        g[1] = [0.0, -SH_C1, 0.0];
        g[2] = [0.0, 0.0, SH_C1];
        g[3] = [-SH_C1, 0.0, 0.0];
    }
    if degree >= 2 {
        g[4] = [SH_C2[0] * y, SH_C2[0] * x, 0.0];
        g[5] = [0.0, SH_C2[1] * z, SH_C2[1] * y];
        g[6] = [-2.0 * SH_C2[2] * x, -2.0 * SH_C2[2] * y, 4.0 * SH_C2[2] * z];
        g[7] = [SH_C2[3] * z, 0.0, SH_C2[3] * x];
        g[8] = [2.0 * SH_C2[4] * x, -2.0 * SH_C2[4] * y, 0.0];
    }
    if degree >= 3 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        g[9] = [SH_C3[0] * 6.0 * x * y, SH_C3[0] * 3.0 * (xx - yy), 0.0];
        g[10] = [SH_C3[1] * y * z, SH_C3[1] * x * z, SH_C3[1] * x * y];
        g[11] = [
            SH_C3[2] * -2.0 * x * y,
            SH_C3[2] * (4.0 * zz - xx - 3.0 * yy),
            SH_C3[2] * 8.0 * y * z,
        ];
        g[12] = [
            SH_C3[3] * -6.0 * x * z,
            SH_C3[3] * -6.0 * y * z,
            SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy),
        ];
        g[13] = [
            SH_C3[4] * (4.0 * zz - 3.0 * xx - yy),
            SH_C3[4] * -2.0 * x * y,
            SH_C3[4] * 8.0 * x * z,
        ];
        g[14] = [
            SH_C3[5] * 2.0 * x * z,
            SH_C3[5] * -2.0 * y * z,
            SH_C3[5] * (xx - yy),
        ];
        g[15] = [SH_C3[6] * 3.0 * (xx - yy), SH_C3[6] * -6.0 * x * y, 0.0];
    }
    g
}

/// `Σ_k coeffs[k] · basis_k(d)` per channel: the colour before the +0.5 offset and the clamp.
pub fn eval(degree: usize, coeffs: &[[f64; 3]; 16], d: [f64; 3]) -> [f64; 3] {
    let b = basis(degree, d);
    let mut rgb = [0.0; 3];
    for (bk, ck) in b.iter().zip(coeffs.iter()).take(num_coeffs(degree)) {
        for ch in 0..3 {
            rgb[ch] += bk * ck[ch];
        }
    }
    rgb
}
