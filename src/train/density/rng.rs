//! The counter-based RNG of `glsl/density/rng.glsl`: integers bit-identical, the floats by the
//! same formulas in f64 (the GPU's `log`/`cos` are not correctly rounded, so tests compare
//! positions with a tolerance).

fn mix(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x21f0_aaad);
    x ^= x >> 15;
    x = x.wrapping_mul(0x735a_2d97);
    x ^= x >> 15;
    x
}

/// A 32-bit random word that depends only on its four arguments.
pub fn rng_u32(seed: u32, step: u32, index: u32, draw: u32) -> u32 {
    let h = mix(seed ^ 0x9e37_79b9);
    let h = mix(h ^ step);
    let h = mix(h ^ index);
    mix(h ^ draw.wrapping_mul(0x85eb_ca6b))
}

/// Uniform in (0, 1) from the top 24 bits (exactly the GPU's value, which is an f32).
pub fn rng_uniform(seed: u32, step: u32, index: u32, draw: u32) -> f64 {
    ((rng_u32(seed, step, index, draw) >> 8) as f64 + 0.5) / 16_777_216.0
}

/// Standard normal sample `k` (Box–Muller on draws 2k and 2k + 1).
pub fn rng_normal(seed: u32, step: u32, index: u32, k: u32) -> f64 {
    let u1 = rng_uniform(seed, step, index, 2 * k);
    let u2 = rng_uniform(seed, step, index, 2 * k + 1);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// The 32-bit seed the kernels get from a 64-bit one.
pub fn fold_seed(seed: u64) -> u32 {
    (seed as u32) ^ ((seed >> 32) as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_have_unit_variance_and_differ_by_every_counter() {
        let n = 200_000u32;
        let (mut s, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let x = rng_normal(7, 3, i, 1);
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "var {var}");
        let base = rng_u32(1, 2, 3, 4);
        assert_ne!(base, rng_u32(0, 2, 3, 4));
        assert_ne!(base, rng_u32(1, 0, 3, 4));
        assert_ne!(base, rng_u32(1, 2, 0, 4));
        assert_ne!(base, rng_u32(1, 2, 3, 0));
        assert_eq!(base, rng_u32(1, 2, 3, 4));
    }
}
