#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_EXT_control_flow_attributes : require
// Radix sort pass, step 3 (scatter) for 8-bit digits, ranked by subgroup ballots. The 4- and
// 5-bit scatter (scatter.comp) keeps a counter per digit in every invocation's registers; 256
// digits do not fit there, so here each key finds the keys of its subgroup that share its digit
// with RADIX_BITS ballots (one per digit bit), and each subgroup keeps its per-digit counts in
// shared memory. Byte digits sort 31-bit depths in 4 passes instead of 7 and 13-bit tile ids in
// 2 instead of 3.
//
// Stability, which LSD radix sort needs: subgroup s owns the keys [s · ITEMS · S, (s + 1) ·
// ITEMS · S) of the block (S: the subgroup's size), read in ITEMS rounds of S consecutive keys
// (lane l takes key r · S + l of round r, coalesced). A key's place among the block's keys of its
// digit is (those keys in earlier subgroups) + (in earlier rounds of its subgroup) + (in lower
// lanes of its round), which is its place in the input order.
//
// The block is then ordered in shared memory and written out by consecutive invocations to
// consecutive places of each digit's run (coalesced), as scatter.comp does with REORDER.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
// The smallest subgroup the device may run (minSubgroupSize): the per-subgroup counters are
// sized for the most subgroups a workgroup can have. The subgroup size itself is read at run
// time (gl_SubgroupSize), never assumed.
layout(constant_id = 5) const uint MIN_SUBGROUP = 8;
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
#include "workgroup_scan.glsl"

const uint MAX_SUBGROUPS = WG_SIZE / MIN_SUBGROUP;
const uint BLOCK_KEYS = WG_SIZE * ITEMS;
// Per subgroup, two digits' counts a word (16-bit fields: a subgroup holds at most
// ITEMS · 128 < 65536 keys), word w of subgroup s at [w · MAX_SUBGROUPS + s]. Leaders of two
// digits sharing a word may add in the same round, hence atomics.
const uint COUNTER_WORDS = (RADIX / 2u) * MAX_SUBGROUPS;
// One pool of shared memory, used twice: the counters, then the block's keys [e] and values
// [BLOCK_KEYS + e] in sorted order.
shared uint pool[COUNTER_WORDS > 2u * BLOCK_KEYS ? COUNTER_WORDS : 2u * BLOCK_KEYS];
// Per digit, where its run starts in the block's order and in the output.
shared uint s_local_start[RADIX];
shared uint s_global_start[RADIX];

// A rank that marks a key this invocation does not place (past the end, or dropped).
const uint NO_KEY = 0xFFFFFFFFu;

void main() {
    uint n = counts[count_index];
    uint blocks = (n + BLOCK_KEYS - 1u) / BLOCK_KEYS;
    uint block = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (block >= blocks) return;
    uint li = gl_LocalInvocationIndex;
    for (uint w = li; w < COUNTER_WORDS; w += WG_SIZE) pool[w] = 0u;
    barrier();

    uint sg = gl_SubgroupID;
    uint lane = gl_SubgroupInvocationID;
    uint sg_first = block * BLOCK_KEYS + sg * ITEMS * gl_SubgroupSize;
    bool dropping = DROPS && drop_keys != 0u;
    uint key[ITEMS];
    uint rank[ITEMS];
    [[unroll]] for (uint r = 0u; r < ITEMS; r++) {
        uint i = sg_first + r * gl_SubgroupSize + lane;
        bool live = i < n;
        uint k = live ? keys_in[i] : 0u;
        live = live && !(dropping && k == drop_key);
        uint d = radix_digit(k, shift, digit_mask);
        // The live lanes whose digit equals this lane's, bit by bit (the digit's unused high
        // bits in a narrower last pass are 0 in every lane and select nobody out).
        uvec4 peers = subgroupBallot(live);
        [[unroll]] for (uint b = 0u; b < RADIX_BITS; b++) {
            bool set = ((d >> b) & 1u) != 0u;
            uvec4 with_bit = subgroupBallot(set);
            peers &= set ? with_bit : ~with_bit;
        }
        uint word = (d >> 1u) * MAX_SUBGROUPS + sg;
        uint field = (d & 1u) * 16u;
        uint earlier = live ? (pool[word] >> field) & 0xFFFFu : 0u;
        uint ahead = subgroupBallotExclusiveBitCount(peers);
        uint same = subgroupBallotBitCount(peers);
        // Every lane has read its counter before the digit's last lane adds the round's keys.
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        if (live && ahead + 1u == same) atomicAdd(pool[word], same << field);
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        key[r] = k;
        rank[r] = live ? earlier + ahead : NO_KEY;
    }
    barrier();

    // Invocation t < RADIX / 2 owns digits 2t and 2t + 1: the exclusive prefix of their counts
    // over the subgroups, in place, and their totals in the block.
    uint pair_total = 0u;
    if (li < RADIX / 2u) {
        for (uint s = 0u; s < gl_NumSubgroups; s++) {
            uint c = pool[li * MAX_SUBGROUPS + s];
            pool[li * MAX_SUBGROUPS + s] = pair_total;
            pair_total += c;
        }
    }
    uint even_total = pair_total & 0xFFFFu;
    uint kept;
    uint even_start = workgroup_exclusive_scan(even_total + (pair_total >> 16u), kept);
    if (li < RADIX / 2u) {
        s_local_start[2u * li] = even_start;
        s_local_start[2u * li + 1u] = even_start + even_total;
        s_global_start[2u * li] = hist[(2u * li) * blocks + block];
        s_global_start[2u * li + 1u] = hist[(2u * li + 1u) * blocks + block];
    }
    barrier();
    uint place[ITEMS];
    [[unroll]] for (uint r = 0u; r < ITEMS; r++) {
        uint d = radix_digit(key[r], shift, digit_mask);
        uint field = (d & 1u) * 16u;
        uint before = (pool[(d >> 1u) * MAX_SUBGROUPS + sg] >> field) & 0xFFFFu;
        place[r] = rank[r] == NO_KEY ? NO_KEY : s_local_start[d] + before + rank[r];
    }
    // The counters are read: the pool can take the keys.
    barrier();
    [[unroll]] for (uint r = 0u; r < ITEMS; r++) {
        if (place[r] != NO_KEY) {
            pool[place[r]] = key[r];
            pool[BLOCK_KEYS + place[r]] = vals_in[sg_first + r * gl_SubgroupSize + lane];
        }
    }
    barrier();
    // Invocation i writes the block's sorted entries i, i + WG_SIZE, ...: entry e of digit d's
    // run goes to that run's start in the output + (e − the run's start in the block).
    for (uint e = li; e < kept; e += WG_SIZE) {
        uint k = pool[e];
        uint d = radix_digit(k, shift, digit_mask);
        uint dst = s_global_start[d] + (e - s_local_start[d]);
        keys_out[dst] = k;
        vals_out[dst] = pool[BLOCK_KEYS + e];
    }
}
