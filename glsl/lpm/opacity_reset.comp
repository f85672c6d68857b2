#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// LPM opacity reset (docs/algorithms/lpm.md step 8): every Gaussian in front of a zone (FLAG_IN_FRONT) whose
// opacity logit is at or above the selected threshold (select_pick.comp, mode 1, over the logits of
// the Gaussians inside zones) gets `reset_logit`. Comparing logits is comparing opacities (the
// sigmoid is increasing); both sides compare float keys, so the order is total (NaN included).
// Adam moments are left as they are, as in the authors' code.
// With Mip-Splatting's 3D filter (`filtered`), the threshold was selected among the effective
// logits (effective_logits.comp) and the rule acts on the drawn opacity σ(x)·ρ: a reset
// Gaussian's stored opacity becomes σ(reset_logit) / ρ (at most 1 − 1e-6, the model's sigmoid
// clamp), so that it draws at the reset opacity.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "zone.glsl"
#include "float_key.glsl"
#include "select_state.glsl"
#include "projected.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Flags { uint flags[]; };
layout(std430, set = 0, binding = 1) buffer Logits { float logits[]; };
layout(std430, set = 0, binding = 2) buffer State { uint state[]; };
layout(std430, set = 0, binding = 3) readonly buffer Effective { float effective[]; };
layout(std430, set = 0, binding = 4) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 5) readonly buffer Filter3d { float filter3d[]; };
layout(push_constant) uniform Push { uint count; float reset_logit; uint filtered; };

void main() {
    if (state[SEL_VALID] == 0u) return;  // uniform: no Gaussian inside a zone, or k = 0
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint i = group * WG_SIZE + gl_LocalInvocationIndex;
    uint threshold = state[SEL_PREFIX];
    bool reset = false;
    if (i < count) {
        float ranked = filtered != 0u ? effective[i] : logits[i];
        reset = (flags[i] & FLAG_IN_FRONT) != 0u && float_key(floatBitsToUint(ranked)) >= threshold;
    }
    if (reset) {
        if (filtered != 0u) {
            vec3 s = exp(vec3(log_scales[3u * i], log_scales[3u * i + 1u],
                              log_scales[3u * i + 2u]));
            float rho;
            filtered_scales(s, filter3d[i], rho);
            float p = min((1.0 / (1.0 + exp(-reset_logit))) / rho, 1.0 - 1e-6);
            logits[i] = log(p / (1.0 - p));
        } else {
            logits[i] = reset_logit;
        }
    }
    uint n = subgroupAdd(reset ? 1u : 0u);
    if (subgroupElect() && n != 0u) atomicAdd(state[SEL_RESET], n);
}
