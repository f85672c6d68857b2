//! How the higher-order SH coefficients are stored on the GPU: in column planes.
//!
//! Degree 3 gives every Gaussian 45 floats of SH rest (180 bytes): one buffer of them would pass
//! a 128 MiB storage binding (`maxStorageBufferRange` on lavapipe and many mobile GPUs) at about
//! 745k Gaussians, long before device memory runs out. The coefficients are therefore split by
//! column: plane `p` holds rest coefficients `[3p, 3p + 3)` of every Gaussian (9 floats, 36
//! bytes, Gaussian `i` at `i * stride`), as wide as the widest other per-Gaussian buffer (the
//! projected splats, 2DGS's transforms, STGS's motion and features), so the binding limit allows
//! `range / 36` Gaussians (3.7 M on lavapipe, 119 M at 4 GiB), past what the ~1 KB of training
//! state a Gaussian leaves room for.
//!
//! [`GaussianParams::sh_rest`](super::GaussianParams) keeps the logical layout (all coefficients
//! of a Gaussian back to back, `[coef][channel]`); [`split`] and [`merge`] convert. Planes a
//! degree does not use have stride 0. The kernels walk them plane by plane through
//! `glsl/common/sh_rest_planes.glsl` (`sh_rest_plane_coefs` mirrors [`plane_coefs`]; coefficient
//! `j` of plane `p` of Gaussian `i` at `i * stride + 3j`, as [`offset`] says).

/// Column planes of the SH rest coefficients (enough for degree 3's 15 coefficients).
pub const PLANES: usize = 5;
/// Rest coefficients per plane.
pub const COEFS_PER_PLANE: usize = 3;

/// Rest coefficients plane `p` holds for `rest_coeffs` coefficients a Gaussian.
pub fn plane_coefs(rest_coeffs: usize, p: usize) -> usize {
    rest_coeffs
        .saturating_sub(p * COEFS_PER_PLANE)
        .min(COEFS_PER_PLANE)
}

/// Floats per Gaussian of plane `p`.
pub fn plane_stride(rest_coeffs: usize, p: usize) -> usize {
    3 * plane_coefs(rest_coeffs, p)
}

/// Plane and float offset of rest coefficient `k` (channel 0) of Gaussian `i`.
pub fn offset(i: usize, k: usize, rest_coeffs: usize) -> (usize, usize) {
    let p = k / COEFS_PER_PLANE;
    (
        p,
        i * plane_stride(rest_coeffs, p) + 3 * (k - p * COEFS_PER_PLANE),
    )
}

/// The planes of `n` Gaussians' rest coefficients given in the logical layout.
pub fn split(rest: &[f32], n: usize, rest_coeffs: usize) -> [Vec<f32>; PLANES] {
    debug_assert_eq!(rest.len(), n * rest_coeffs * 3);
    std::array::from_fn(|p| {
        let (first, stride) = (3 * p * COEFS_PER_PLANE, plane_stride(rest_coeffs, p));
        let mut out = Vec::with_capacity(n * stride);
        if stride > 0 {
            for row in rest.chunks_exact(rest_coeffs * 3) {
                out.extend_from_slice(&row[first..first + stride]);
            }
        }
        out
    })
}

/// The logical layout of `n` Gaussians' rest coefficients from their planes.
pub fn merge(planes: &[&[f32]], n: usize, rest_coeffs: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(n * rest_coeffs * 3);
    for i in 0..n {
        for (p, plane) in planes.iter().enumerate() {
            let stride = plane_stride(rest_coeffs, p);
            out.extend_from_slice(&plane[i * stride..(i + 1) * stride]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splats::model::sh_rest_coeffs;

    #[test]
    fn planes_cover_every_coefficient_once_and_round_trip() {
        for degree in 0..=3 {
            let r = sh_rest_coeffs(degree);
            let n = 7;
            let logical: Vec<f32> = (0..n * r * 3).map(|x| x as f32).collect();
            let planes = split(&logical, n, r);
            assert_eq!(
                planes.iter().map(Vec::len).sum::<usize>(),
                logical.len(),
                "degree {degree}"
            );
            for i in 0..n {
                for k in 0..r {
                    let (p, o) = offset(i, k, r);
                    for c in 0..3 {
                        assert_eq!(planes[p][o + c], logical[(i * r + k) * 3 + c]);
                    }
                }
            }
            let refs: Vec<&[f32]> = planes.iter().map(Vec::as_slice).collect();
            assert_eq!(merge(&refs, n, r), logical, "degree {degree}");
        }
        assert_eq!(plane_stride(15, 4), 9);
        assert_eq!(plane_stride(8, 1), 9);
        assert_eq!(plane_stride(8, 2), 6);
        assert_eq!(plane_stride(8, 3), 0);
        assert_eq!(plane_stride(0, 0), 0);
        // No plane is wider than 36 bytes a Gaussian, and degree 3 needs every plane.
        assert!((0..PLANES).all(|p| plane_stride(15, p) * 4 <= 36));
        assert_eq!(PLANES * COEFS_PER_PLANE, 15);
    }
}
