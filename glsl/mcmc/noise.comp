#version 460
// MCMC's position noise (SGLD), after the optimizer step: Gaussian i moves by
// amount · gate(o) · Σ ε, Σ = R diag(s²) Rᵀ its covariance, ε ~ N(0, I) from the counter RNG
// keyed by (seed, iteration, i, axis), gate(o) = 1 / (1 + exp(k (o − t))) so that only the faint
// wander (src/reference/mcmc.rs is the oracle). A quaternion with |q|² < 1e-24 reads as the
// identity (as in render).
layout(local_size_x_id = 0) in;
#include "../density/rng.glsl"
layout(std430, set = 0, binding = 0) buffer Pos { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 2) readonly buffer Rot { float rotations[]; };
layout(std430, set = 0, binding = 3) readonly buffer Opacity { float opacity_logits[]; };
layout(push_constant) uniform Push {
    uint count;
    uint seed;
    uint step;
    float amount;
    float gate_k;
    float gate_t;
};

mat3 rotation_of(vec4 q) {
    float n2 = dot(q, q);
    if (!(n2 >= 1e-24)) return mat3(1.0);
    q /= sqrt(n2);
    float w = q.x, x = q.y, y = q.z, z = q.w;
    // Column-major: mat3(col0, col1, col2).
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
        2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
        2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
}

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    if (i >= count) return;
    float o = 1.0 / (1.0 + exp(-opacity_logits[i]));
    float gate = 1.0 / (1.0 + exp(gate_k * (o - gate_t)));
    float g = amount * gate;
    // A gate of 0 (every opaque Gaussian) moves nothing: skip the matrix.
    if (!(g != 0.0)) return;
    vec3 e = vec3(rng_normal(seed, step, i, 0u), rng_normal(seed, step, i, 1u),
                  rng_normal(seed, step, i, 2u));
    mat3 r = rotation_of(vec4(rotations[4u * i], rotations[4u * i + 1u], rotations[4u * i + 2u],
                              rotations[4u * i + 3u]));
    vec3 s2 = exp(2.0 * vec3(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]));
    vec3 d = g * (r * (s2 * (transpose(r) * e)));
    positions[3u * i] += d.x;
    positions[3u * i + 1u] += d.y;
    positions[3u * i + 2u] += d.z;
}
