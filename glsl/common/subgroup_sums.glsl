// A subgroup's sums of per-invocation partial values, slot by slot, added to global memory with
// as few cross-lane operations and memory instructions as possible. CPU drivers (lavapipe) run
// every reduction, shared-memory access and atomic as a loop over the subgroup's lanes whatever
// the number of active lanes, so nine reductions and nine elected stores cost eighteen such
// loops where a transposing butterfly needs SUBGROUP_SIZE − 1 shuffles and one atomic
// instruction in which every lane adds a different slot.
//
// The including file defines, before the #include:
//   SUMS_SLOTS     number of slots (a constant or specialisation-constant expression);
//   SUMS_PART_MAX  the size of the partial-value array (a constant ≥ SUMS_SLOTS);
//   void add_slot(uint g, uint slot, float v)  adds the subgroup's sum v of `slot` for item g
//                  (called with several lanes at once, each with its own slot);
// and the subgroup shuffle extension, and SUBGROUP_SIZE as a specialisation constant equal to
// the device's subgroup size (a power of two ≤ 64).

// One level of the transposing butterfly over v[0 .. 2H): the lanes with bit H set keep the
// upper half of the slots and receive their partner's (lane ^ H) upper half, the others the
// lower half, so v[0 .. H) then holds sums over lane pairs of H slots chosen by bit H.
#define TRANSPOSE_LEVEL(H)                                                             \
    if (SUBGROUP_SIZE > (H)) {                                                         \
        bool upper = (lane & (H)) != 0u;                                               \
        [[unroll]] for (uint i = 0u; i < (H); i++) {                                   \
            float keep = upper ? v[i + (H)] : v[i];                                    \
            float send = upper ? v[i] : v[i + (H)];                                    \
            v[i] = keep + subgroupShuffleXor(send, (H));                               \
        }                                                                              \
    }
// The whole butterfly over v[0 .. SUBGROUP_SIZE): lane l ends with the subgroup's sum of slot l
// in v[0].
#define TRANSPOSE_ALL                                                                  \
    TRANSPOSE_LEVEL(32u) TRANSPOSE_LEVEL(16u) TRANSPOSE_LEVEL(8u) TRANSPOSE_LEVEL(4u)  \
    TRANSPOSE_LEVEL(2u) TRANSPOSE_LEVEL(1u)
const uint SUMS_MAX_SUBGROUP = 64u;
const uint SUMS_FULL_CHUNKS = (SUMS_SLOTS) / SUBGROUP_SIZE;
const uint SUMS_REM = (SUMS_SLOTS) - SUMS_FULL_CHUNKS * SUBGROUP_SIZE;
// Remainders of at least this many slots go through one more butterfly, padded with zeros
// (SUBGROUP_SIZE − 1 shuffles for all of them); fewer are reduced one at a time. Measured on
// lavapipe (subgroup 8): 7 slots (SpacetimeGaussians' full model) padded, its rasterizer
// backward ~15 % faster; 2 slots (2DGS) no clear difference, so they stay reductions.
#ifndef SUMS_PAD_FROM
#define SUMS_PAD_FROM 3u
#endif
const uint SUMS_CHUNKS = SUMS_FULL_CHUNKS + (SUMS_REM >= (SUMS_PAD_FROM) ? 1u : 0u);
const uint SUMS_TAIL = SUMS_REM >= (SUMS_PAD_FROM) ? 0u : SUMS_REM;

// Σ over the subgroup of part[c] for every slot c < SUMS_SLOTS, handed to add_slot(g, c, ·):
// every chunk of SUBGROUP_SIZE slots (the last padded with zeros) by the butterfly, after
// which lane l holds the sum of the chunk's slot l, and one add_slot of all lanes with a
// slot; a short remainder by one reduction a slot and one add_slot of the first lanes. Call it
// with the whole subgroup active.
void add_sums_transposed(float part[SUMS_PART_MAX], uint g) {
    uint lane = gl_SubgroupInvocationID;
    [[unroll]] for (uint chunk = 0u; chunk < SUMS_CHUNKS; chunk++) {
        float v[SUMS_MAX_SUBGROUP];
        [[unroll]] for (uint i = 0u; i < SUBGROUP_SIZE; i++) {
            uint c = chunk * SUBGROUP_SIZE + i;
            v[i] = c < (SUMS_SLOTS) ? part[min(c, (SUMS_PART_MAX) - 1u)] : 0.0;
        }
        TRANSPOSE_ALL
        uint slot = chunk * SUBGROUP_SIZE + lane;
        if (slot < (SUMS_SLOTS)) add_slot(g, slot, v[0]);
    }
    if (SUMS_TAIL > 0u) {
        float mine = 0.0;
        [[unroll]] for (uint r = 0u; r < SUMS_TAIL; r++) {
            float sum = subgroupAdd(part[SUMS_FULL_CHUNKS * SUBGROUP_SIZE + r]);
            mine = lane == r ? sum : mine;
        }
        if (lane < SUMS_TAIL) add_slot(g, SUMS_FULL_CHUNKS * SUBGROUP_SIZE + lane, mine);
    }
}
