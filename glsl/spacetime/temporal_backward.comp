#version 460
// SpacetimeGaussians' temporal step, backward: the still Gaussian's gradients (from the 3DGS
// preprocess backward) to the temporal parameters'. Δ is detached in the motion and rotation
// (the official computation), so the temporal centre and scale learn only through the opacity.
// `accumulate` adds into the gradient buffers (several views per step) instead of writing.
// Oracle: src/reference/spacetime.rs `instant_backward`.
#include "temporal.glsl"

layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Opacities { float opacity_logits[]; };
layout(std430, set = 0, binding = 1) readonly buffer TCenter { float t_center[]; };
layout(std430, set = 0, binding = 2) readonly buffer TLogScale { float t_log_scale[]; };
layout(std430, set = 0, binding = 3) readonly buffer DPositionsT { float d_positions_t[]; };
layout(std430, set = 0, binding = 4) readonly buffer DRotationsT { vec4 d_rotations_t[]; };
layout(std430, set = 0, binding = 5) readonly buffer DOpacitiesT { float d_opacity_t[]; };
layout(std430, set = 0, binding = 6) buffer DPositions { float d_positions[]; };
layout(std430, set = 0, binding = 7) buffer DMotion { float d_motion[]; };
layout(std430, set = 0, binding = 8) buffer DRotations { vec4 d_rotations[]; };
layout(std430, set = 0, binding = 9) buffer DOmega { vec4 d_omega[]; };
layout(std430, set = 0, binding = 10) buffer DOpacities { float d_opacity_logits[]; };
layout(std430, set = 0, binding = 11) buffer DTCenter { float d_t_center[]; };
layout(std430, set = 0, binding = 12) buffer DTLogScale { float d_t_log_scale[]; };
layout(push_constant) uniform Push {
    uint count;
    float t;
    uint accumulate;
};

// What a gradient adds to: its current value when accumulating, else 0 (selected, not multiplied:
// a buffer's old contents may be anything, NaN included, when the pass overwrites).
#define PRIOR(type, name) type prior_##name(uint j) { return accumulate != 0u ? name[j] : type(0.0); }
PRIOR(float, d_motion)
PRIOR(float, d_positions)
PRIOR(vec4, d_rotations)
PRIOR(vec4, d_omega)
PRIOR(float, d_opacity_logits)
PRIOR(float, d_t_center)
PRIOR(float, d_t_log_scale)

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    float d = t - t_center[i];
    float power = 1.0;
    for (uint j = 0u; j < 3u; j++) {
        power *= d;
        for (uint k = 0u; k < 3u; k++) {
            uint m = 9u * i + 3u * j + k;
            d_motion[m] = prior_d_motion(m) + power * d_positions_t[3u * i + k];
        }
    }
    for (uint k = 0u; k < 3u; k++) {
        d_positions[3u * i + k] = prior_d_positions(3u * i + k) + d_positions_t[3u * i + k];
    }
    vec4 dq = d_rotations_t[i];
    d_rotations[i] = prior_d_rotations(i) + dq;
    d_omega[i] = prior_d_omega(i) + dq * d;
    float inv_scale = exp(-t_log_scale[i]);
    float u = d * inv_scale;
    float u2 = u * u;
    float o = opacity_logits[i];
    float dl = d_opacity_t[i] / one_minus_opacity(o, u2);
    float sig_neg = 1.0 / (1.0 + exp(o));
    d_opacity_logits[i] = prior_d_opacity_logits(i) + dl * sig_neg;
    d_t_center[i] = prior_d_t_center(i) + dl * 2.0 * u * inv_scale;
    d_t_log_scale[i] = prior_d_t_log_scale(i) + dl * 2.0 * u2;
}
