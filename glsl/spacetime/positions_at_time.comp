#version 460
// SpacetimeGaussians for LPM in time: every Gaussian's centre at time t, μ + m₁Δ + m₂Δ² + m₃Δ³
// with Δ = t − c (the same arithmetic as temporal.comp, so a zone tests the centre the frame
// drew), or NaN for a Gaussian that is absent at t: its temporal weight e^{−u²}, u = Δ·e^{−s},
// below min_weight. NaN fails every comparison of zone_membership.comp, so an absent Gaussian
// is neither inside nor in front of any zone, and is not counted. Oracle:
// src/reference/spacetime.rs (frame_position).
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Motion { float motion[]; };
layout(std430, set = 0, binding = 2) readonly buffer TCenter { float t_center[]; };
layout(std430, set = 0, binding = 3) readonly buffer TLogScale { float t_log_scale[]; };
layout(std430, set = 0, binding = 4) writeonly buffer OutPositions { float out_positions[]; };
layout(push_constant) uniform Push {
    uint count;
    float t;
    // −ln(min_weight): present while u² ≤ this.
    float max_u2;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    float d = t - t_center[i];
    float u = d * exp(-t_log_scale[i]);
    // A NaN u² (it cannot arise from finite inputs) compares false: absent.
    bool present = u * u <= max_u2;
    float d2 = d * d;
    float d3 = d2 * d;
    for (uint k = 0u; k < 3u; k++) {
        float x = positions[3u * i + k] + motion[9u * i + k] * d + motion[9u * i + 3u + k] * d2
            + motion[9u * i + 6u + k] * d3;
        out_positions[3u * i + k] = present ? x : uintBitsToFloat(0x7fc00000u);
    }
}
