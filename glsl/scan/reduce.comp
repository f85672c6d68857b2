#version 460
#extension GL_KHR_shader_subgroup_arithmetic : require
// Exclusive scan, level up: each workgroup sums its block of WG_SIZE * ITEMS elements.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Partials { uint partials[]; };
layout(std430, set = 0, binding = 2) readonly buffer Count { uint counts[]; };
layout(push_constant) uniform Push { uint count_index; uint divisor; };
shared uint red_sums[WG_SIZE];

void main() {
    // The element count lives on the GPU (written by an earlier kernel): `count_index` says where,
    // and `divisor` turns it into this level's length (ceil(count / divisor)).
    uint n = (counts[count_index] + divisor - 1u) / divisor;
    uint block = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint base = block * WG_SIZE * ITEMS;
    if (base >= n && block > 0u) return;
    uint s = 0u;
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = base + k * WG_SIZE + gl_LocalInvocationIndex;
        if (i < n) s += data[i];
    }
    s = subgroupAdd(s);
    if (gl_SubgroupInvocationID == 0u) red_sums[gl_SubgroupID] = s;
    barrier();
    if (gl_LocalInvocationIndex == 0u) {
        uint t = 0u;
        for (uint i = 0u; i < gl_NumSubgroups; i++) t += red_sums[i];
        partials[block] = t;
    }
}
