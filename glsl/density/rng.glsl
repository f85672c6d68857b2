// Counter-based random numbers: a pure function of (seed, step, Gaussian, draw), so a density
// step gives the same children for a seed whatever the dispatch order. Mirrors
// `src/train/density/rng.rs` bit for bit (integer part) and formula for formula (floats).
uint rng_mix(uint x) {
    x ^= x >> 16;
    x *= 0x21f0aaadu;
    x ^= x >> 15;
    x *= 0x735a2d97u;
    x ^= x >> 15;
    return x;
}

uint rng_u32(uint seed, uint step, uint index, uint draw) {
    uint h = rng_mix(seed ^ 0x9e3779b9u);
    h = rng_mix(h ^ step);
    h = rng_mix(h ^ index);
    return rng_mix(h ^ (draw * 0x85ebca6bu));
}

// Uniform in (0, 1): the top 24 bits, offset by half a step, so log() never sees 0.
float rng_uniform(uint seed, uint step, uint index, uint draw) {
    return (float(rng_u32(seed, step, index, draw) >> 8) + 0.5) * (1.0 / 16777216.0);
}

// Standard normal sample `k` (Box–Muller, cosine branch; draws 2k and 2k + 1).
float rng_normal(uint seed, uint step, uint index, uint k) {
    float u1 = rng_uniform(seed, step, index, 2u * k);
    float u2 = rng_uniform(seed, step, index, 2u * k + 1u);
    return sqrt(-2.0 * log(u1)) * cos(6.28318530717958647 * u2);
}
