#version 460
// SpacetimeGaussians' angular-velocity split, the selection (official oursfull.py
// `zero_omegabymotion`, once at its iteration 8001; the masks follow in the same step): a Gaussian is marked when it moves
// (Σ|m₁| > motion_above), is mid-sized (scale_lo < its largest scale < scale_hi) and is opaque
// (σ(o) > opacity_above); every unmarked Gaussian's angular velocity becomes 0. From then on
// "ω = 0" is the mark (omega_masks.comp): density control carries ω with every Gaussian, so
// the mark follows pruning, clones and appends without a buffer of its own.
// Oracle: src/reference/spacetime.rs `omega_marked`.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Motion { float motion[]; };
layout(std430, set = 0, binding = 1) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 2) readonly buffer Opacities { float opacity_logits[]; };
layout(std430, set = 0, binding = 3) buffer Omega { vec4 omega[]; };
layout(push_constant) uniform Push {
    uint count;
    float motion_above;
    float scale_lo;
    float scale_hi;
    float opacity_above;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    float m1 = abs(motion[9u * i]) + abs(motion[9u * i + 1u]) + abs(motion[9u * i + 2u]);
    float s = exp(max(max(log_scales[3u * i], log_scales[3u * i + 1u]), log_scales[3u * i + 2u]));
    float opacity = 1.0 / (1.0 + exp(-opacity_logits[i]));
    bool marked = m1 > motion_above && s > scale_lo && s < scale_hi && opacity > opacity_above;
    if (!marked) omega[i] = vec4(0.0);
}
