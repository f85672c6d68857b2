#version 460
#extension GL_KHR_shader_subgroup_basic : require
// Radix sort pass, step 1 (reduce): per block of WG_SIZE * ITEMS keys, the histogram of the
// RADIX_BITS-bit digit at `shift`, stored digit-major (hist[digit * blocks + block]) so that one
// exclusive scan of the whole array yields every block's scatter offset for every digit.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Keys { uint keys[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Hist { uint hist[]; };
layout(std430, set = 0, binding = 2) buffer Count { uint counts[]; };
layout(push_constant) uniform Push {
    uint count_index;
    uint hist_len_index;
    uint shift;
    uint digit_mask;
    uint drop_keys;  // 1: keys equal to drop_key are left out (not counted)
    uint drop_key;
};
#include "radix_digit.glsl"
shared uint block_hist[RADIX];

void main() {
    uint n = counts[count_index];
    uint blocks = (n + WG_SIZE * ITEMS - 1u) / (WG_SIZE * ITEMS);
    uint block = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (block == 0u && gl_LocalInvocationIndex == 0u) counts[hist_len_index] = RADIX * blocks;
    if (block >= blocks) return;
    if (gl_LocalInvocationIndex < RADIX) block_hist[gl_LocalInvocationIndex] = 0u;
    barrier();
    uint base = block * WG_SIZE * ITEMS;
    // The bound stops at the last key (uniform over the workgroup): CPU drivers run a masked
    // `if` at full cost, so a block past the end would otherwise cost as much as a full one.
    for (uint k = 0u; k < ITEMS && base + k * WG_SIZE < n; k++) {
        uint i = base + k * WG_SIZE + gl_LocalInvocationIndex;
        if (i < n) {
            uint key = keys[i];
            if (!DROPS || drop_keys == 0u || key != drop_key) {
                atomicAdd(block_hist[radix_digit(key, shift, digit_mask)], 1u);
            }
        }
    }
    barrier();
    if (gl_LocalInvocationIndex < RADIX) {
        hist[gl_LocalInvocationIndex * blocks + block] = block_hist[gl_LocalInvocationIndex];
    }
}
