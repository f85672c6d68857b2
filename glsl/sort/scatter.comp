#version 460
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_EXT_control_flow_attributes : require
// Radix sort pass, step 3 (scatter): each invocation owns ITEMS consecutive keys of its block,
// so its rank among equal digits is (keys of that digit in earlier invocations) + (earlier keys
// of its own): the pass is stable, which LSD radix sort needs. Per-digit counts of the
// invocations are packed two digits per uint (16-bit fields; a block holds < 65536 keys).
// The workgroup prefix of all RADIX/2 packed words takes a single barrier: subgroup scans, the
// subgroups' totals in shared memory, and each subgroup adds up the totals of the subgroups
// before it. (One barrier-separated scan per word cost 3·RADIX/2 barriers, and on CPU drivers,
// which run a workgroup's subgroups as coroutines, barriers were most of the pass.)
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer KeysIn { uint keys_in[]; };
layout(std430, set = 0, binding = 1) readonly buffer ValsIn { uint vals_in[]; };
layout(std430, set = 0, binding = 2) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, set = 0, binding = 3) writeonly buffer ValsOut { uint vals_out[]; };
layout(std430, set = 0, binding = 4) readonly buffer Hist { uint hist[]; };
layout(std430, set = 0, binding = 5) readonly buffer Count { uint counts[]; };
// drop_keys 1: keys equal to drop_key are left out, as the upsweep left them out of the counts.
layout(push_constant) uniform Push {
    uint count_index; uint shift; uint digit_mask; uint drop_keys; uint drop_key;
};
#include "radix_digit.glsl"
// REORDER = 1 (GPUs, blocks that fit): the block's pairs are first placed in shared memory in
// their sorted order, and then written out by consecutive invocations to consecutive places of
// each digit's run, so a subgroup's stores land in one or two runs (coalesced) instead of one
// place per digit of each of its invocations. CPU drivers sort blocks too large for shared
// memory, and their stores are per-lane anyway: REORDER = 0 writes each key to its place at once.
layout(constant_id = 5) const uint REORDER = 0u;
// One pool of shared memory, used twice: first [subgroup · RADIX/2 + word], each subgroup's
// totals (room for subgroups of size 1); then, with REORDER, the block's keys [e] and values
// [BLOCK_KEYS + e] in sorted order (at 8 keys an invocation and 5-bit digits both take 16 KiB).
const uint TOTALS = WG_SIZE * (RADIX / 2u);
const uint BLOCK_KEYS = REORDER != 0u ? WG_SIZE * ITEMS : 0u;
shared uint pool[TOTALS > 2u * BLOCK_KEYS ? TOTALS : 2u * BLOCK_KEYS];
#define sg_totals pool
// Per digit, where its run starts in the block's order and in the output.
shared uint s_local_start[RADIX];
shared uint s_global_start[RADIX];

void main() {
    uint n = counts[count_index];
    uint blocks = (n + WG_SIZE * ITEMS - 1u) / (WG_SIZE * ITEMS);
    uint block = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (block >= blocks) return;
    uint first = block * WG_SIZE * ITEMS + gl_LocalInvocationIndex * ITEMS;
    // This invocation's keys: ITEMS but in the last block. The loops below stop there, not at
    // ITEMS with a masked test: CPU drivers run a masked body at full cost, and a subgroup's
    // invocations hold consecutive keys, so every subgroup but one skips or runs them whole.
    uint owned = first < n ? min(ITEMS, n - first) : 0u;

    // The per-digit arrays are only ever indexed by unrolled loop counters: a digit selects its
    // slot by comparison. Indexing them by the digit itself would put them in memory (spilled
    // on GPUs, one scalar access per lane on CPU drivers), which cost more than these selects.
    uint packed[RADIX / 2u];
    [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) packed[d2] = 0u;
    for (uint k = 0u; k < owned; k++) {
        uint key = keys_in[first + k];
        uint d = radix_digit(key, shift, digit_mask);
        // A dropped key counts for no digit.
        uint one = DROPS && drop_keys != 0u && key == drop_key ? 0u : 1u;
        one <<= ((d & 1u) * 16u);
        [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
            packed[d2] += (d >> 1u) == d2 ? one : 0u;
        }
    }
    uint inclusive[RADIX / 2u];
    [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
        inclusive[d2] = subgroupInclusiveAdd(packed[d2]);
    }
    if (gl_SubgroupInvocationID == gl_SubgroupSize - 1u) {
        [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
            sg_totals[gl_SubgroupID * (RADIX / 2u) + d2] = inclusive[d2];
        }
    }
    barrier();
    uint before[RADIX / 2u];
    [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) before[d2] = 0u;
    // Uniform over the subgroup: a loop, so CPU drivers really skip it for subgroup 0.
    for (uint sg = 0u; sg < gl_SubgroupID; sg++) {
        [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
            before[d2] += sg_totals[sg * (RADIX / 2u) + d2];
        }
    }
    // Where each digit's keys of this invocation go: in the output, or (REORDER) in the
    // block's sorted order, whose digit runs start at the block's exclusive prefix of the
    // digits' totals (every subgroup's totals summed; 16-bit fields cannot overflow, a block
    // holds < 65536 keys).
    uint start[RADIX];
    uint kept = 0u;
    if (REORDER != 0u) {
        uint total[RADIX / 2u];
        [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) total[d2] = 0u;
        for (uint sg = 0u; sg < gl_NumSubgroups; sg++) {
            [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
                total[d2] += sg_totals[sg * (RADIX / 2u) + d2];
            }
        }
        [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
            start[2u * d2] = kept;
            kept += total[d2] & 0xFFFFu;
            start[2u * d2 + 1u] = kept;
            kept += total[d2] >> 16u;
        }
        uint li = gl_LocalInvocationIndex;
        if (li < RADIX) {
            uint mine = 0u;
            [[unroll]] for (uint r = 0u; r < RADIX; r++) mine = li == r ? start[r] : mine;
            s_local_start[li] = mine;
            s_global_start[li] = hist[li * blocks + block];
        }
    } else {
        [[unroll]] for (uint r = 0u; r < RADIX; r++) start[r] = hist[r * blocks + block];
    }
    uint offsets[RADIX];
    [[unroll]] for (uint d2 = 0u; d2 < RADIX / 2u; d2++) {
        uint prefix = before[d2] + inclusive[d2] - packed[d2];
        offsets[2u * d2] = (prefix & 0xFFFFu) + start[2u * d2];
        offsets[2u * d2 + 1u] = (prefix >> 16u) + start[2u * d2 + 1u];
    }
    // The pool's totals are read: it can take the keys.
    if (REORDER != 0u) barrier();
    for (uint k = 0u; k < owned; k++) {
        uint i = first + k;
        uint key = keys_in[i];
        if (DROPS && drop_keys != 0u && key == drop_key) continue;
        uint d = radix_digit(key, shift, digit_mask);
        uint dst = 0u;
        [[unroll]] for (uint r = 0u; r < RADIX; r++) {
            bool mine = d == r;
            dst += mine ? offsets[r] : 0u;
            offsets[r] += mine ? 1u : 0u;
        }
        if (REORDER != 0u) {
            pool[dst] = key;
            pool[BLOCK_KEYS + dst] = vals_in[i];
        } else {
            keys_out[dst] = key;
            vals_out[dst] = vals_in[i];
        }
    }
    if (REORDER != 0u) {
        barrier();
        // Invocation i writes the block's sorted entries i, i + WG_SIZE, ...: entry e of digit
        // d's run goes to that run's start in the output + (e − the run's start in the block).
        for (uint e = gl_LocalInvocationIndex; e < kept; e += WG_SIZE) {
            uint key = pool[e];
            uint d = radix_digit(key, shift, digit_mask);
            uint dst = s_global_start[d] + (e - s_local_start[d]);
            keys_out[dst] = key;
            vals_out[dst] = pool[BLOCK_KEYS + e];
        }
    }
}
