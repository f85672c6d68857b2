#version 460
// The logit of the opacity the renderer uses under Mip-Splatting's 3D filter, σ(x)·ρ with
// ρ = sqrt(Π s² / Π (s² + f²)) (projected.glsl's filtered_scales), so LPM's opacity reset
// ranks and caps what is drawn, as ADC's filter-aware reset does (docs/algorithms/base-models.md §2.5–2.6).
// ρ ≤ 1 and σ(x) < 1 keep the product below 1; a product that rounds to 0 gives −inf, which
// float_key orders below every finite logit.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "projected.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Logits { float logits[]; };
layout(std430, set = 0, binding = 1) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 2) readonly buffer Filter3d { float filter3d[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Effective { float effective[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint i = group * WG_SIZE + gl_LocalInvocationIndex;
    if (i >= count) return;
    vec3 s = exp(vec3(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]));
    float rho;
    filtered_scales(s, filter3d[i], rho);
    float p = rho / (1.0 + exp(-logits[i]));
    effective[i] = log(p / (1.0 - p));
}
