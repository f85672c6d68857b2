#version 460
// SpacetimeGaussians' temporal step, forward: every Gaussian at time t as the still Gaussian
// the 3DGS preprocess draws. Δ = t − c; position μ + m₁Δ + m₂Δ² + m₃Δ³, quaternion q + ωΔ (the
// preprocess normalises it), opacity logit log σ(o) − u² − log(1 − σ(o)e^{−u²}) with
// u = Δ·e^{−s}. Oracle: src/reference/spacetime.rs.
#include "temporal.glsl"

layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Motion { float motion[]; };
layout(std430, set = 0, binding = 2) readonly buffer Rotations { vec4 rotations[]; };
layout(std430, set = 0, binding = 3) readonly buffer Omega { vec4 omega[]; };
layout(std430, set = 0, binding = 4) readonly buffer Opacities { float opacity_logits[]; };
layout(std430, set = 0, binding = 5) readonly buffer TCenter { float t_center[]; };
layout(std430, set = 0, binding = 6) readonly buffer TLogScale { float t_log_scale[]; };
layout(std430, set = 0, binding = 7) writeonly buffer OutPositions { float out_positions[]; };
layout(std430, set = 0, binding = 8) writeonly buffer OutRotations { vec4 out_rotations[]; };
layout(std430, set = 0, binding = 9) writeonly buffer OutOpacities { float out_opacity_logits[]; };
layout(push_constant) uniform Push {
    uint count;
    float t;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    float d = t - t_center[i];
    float d2 = d * d;
    float d3 = d2 * d;
    for (uint k = 0u; k < 3u; k++) {
        out_positions[3u * i + k] = positions[3u * i + k] + motion[9u * i + k] * d
            + motion[9u * i + 3u + k] * d2 + motion[9u * i + 6u + k] * d3;
    }
    out_rotations[i] = rotations[i] + omega[i] * d;
    float u = d * exp(-t_log_scale[i]);
    float u2 = u * u;
    float o = opacity_logits[i];
    out_opacity_logits[i] = -softplus(-o) - u2 - log(one_minus_opacity(o, u2));
}
