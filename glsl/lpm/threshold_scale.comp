#version 460
// Per-Gaussian multiplier of the densification gradient threshold (docs/algorithms/lpm.md step 8): `ratio`
// (0.5 by default) for Gaussians whose centre lies inside an error zone, 1 elsewhere, so the
// lowered threshold reaches ADC's decide.comp through its ordinary threshold-scale input; and
// the score weight a budget ranks candidates by: `weight` inside zones, 1 elsewhere.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "zone.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Flags { uint flags[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Scale { float scale[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Weight { float weight_out[]; };
layout(push_constant) uniform Push { uint count; float ratio; float weight; };

void main() {
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint i = group * WG_SIZE + gl_LocalInvocationIndex;
    if (i >= count) return;
    bool inside = (flags[i] & FLAG_INSIDE) != 0u;
    scale[i] = inside ? ratio : 1.0;
    weight_out[i] = inside ? weight : 1.0;
}
