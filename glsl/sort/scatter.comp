#version 460
#extension GL_KHR_shader_subgroup_arithmetic : require
// Radix sort pass, step 3 (scatter): each invocation owns ITEMS consecutive keys of its block,
// so its rank among equal digits is (keys of that digit in earlier invocations) + (earlier keys
// of its own): the pass is stable, which LSD radix sort needs. Per-digit counts of the
// invocations are packed two digits per uint (16-bit fields; a block holds < 65536 keys) and
// scanned over the workgroup.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer KeysIn { uvec2 keys_in[]; };
layout(std430, set = 0, binding = 1) readonly buffer ValsIn { uint vals_in[]; };
layout(std430, set = 0, binding = 2) writeonly buffer KeysOut { uvec2 keys_out[]; };
layout(std430, set = 0, binding = 3) writeonly buffer ValsOut { uint vals_out[]; };
layout(std430, set = 0, binding = 4) readonly buffer Hist { uint hist[]; };
layout(std430, set = 0, binding = 5) readonly buffer Count { uint counts[]; };
layout(push_constant) uniform Push { uint count_index; uint shift; };
#include "radix_digit.glsl"
#include "workgroup_scan.glsl"

void main() {
    uint n = counts[count_index];
    uint blocks = (n + WG_SIZE * ITEMS - 1u) / (WG_SIZE * ITEMS);
    uint block = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (block >= blocks) return;
    uint first = block * WG_SIZE * ITEMS + gl_LocalInvocationIndex * ITEMS;

    uint packed[RADIX / 2u];
    for (uint d = 0u; d < RADIX / 2u; d++) packed[d] = 0u;
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k;
        if (i < n) {
            uint d = radix_digit(keys_in[i], shift);
            packed[d >> 1u] += 1u << ((d & 1u) * 16u);
        }
    }
    uint offsets[RADIX];
    for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
        uint total;
        uint prefix = workgroup_exclusive_scan(packed[d2], total);
        offsets[2u * d2] = (prefix & 0xFFFFu) + hist[(2u * d2) * blocks + block];
        offsets[2u * d2 + 1u] = (prefix >> 16u) + hist[(2u * d2 + 1u) * blocks + block];
    }
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k;
        if (i < n) {
            uvec2 key = keys_in[i];
            uint d = radix_digit(key, shift);
            uint dst = offsets[d];
            offsets[d] = dst + 1u;
            keys_out[dst] = key;
            vals_out[dst] = vals_in[i];
        }
    }
}
