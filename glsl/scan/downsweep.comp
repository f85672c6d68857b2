#version 460
#extension GL_KHR_shader_subgroup_arithmetic : require
// Exclusive scan, level down: scans each block of WG_SIZE * ITEMS elements in place, adding the
// block's offset from the (already scanned) partials of the level above. With `has_partials`
// = 0 the single block is the whole array (the top level), and its total goes to `total_out`.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) readonly buffer Partials { uint partials[]; };
layout(std430, set = 0, binding = 2) buffer Count { uint counts[]; };
layout(push_constant) uniform Push { uint count_index; uint divisor; uint has_partials; uint total_index; };
#include "workgroup_scan.glsl"

void main() {
    uint n = (counts[count_index] + divisor - 1u) / divisor;
    uint block = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint base = block * WG_SIZE * ITEMS;
    if (base >= n && block > 0u) return;
    uint running = has_partials != 0u ? partials[block] : 0u;
    // Each invocation owns ITEMS consecutive elements, so one workgroup scan per block suffices.
    uint first = base + gl_LocalInvocationIndex * ITEMS;
    uint local[ITEMS];
    uint s = 0u;
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k;
        uint v = i < n ? data[i] : 0u;
        local[k] = s;
        s += v;
    }
    uint total;
    uint prefix = workgroup_exclusive_scan(s, total) + running;
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k;
        if (i < n) data[i] = prefix + local[k];
    }
    if (has_partials == 0u && gl_LocalInvocationIndex == 0u && total_index != 0xFFFFFFFFu) {
        counts[total_index] = total;
    }
}
