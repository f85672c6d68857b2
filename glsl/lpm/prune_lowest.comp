#version 460
// Density-aware pruning, marking half: given the k-th smallest opacity logit among the
// candidates (select_pick.comp, mode 0, rank k − 1: SEL_PREFIX holds its float key and, after
// the last pass, SEL_RANK its rank among the candidates with exactly that key), OR DECIDE_REMOVE
// into the decision of every candidate strictly below it and of SEL_RANK + 1 of the tied ones,
// so exactly k are removed. Which tied candidates go depends on scheduling (ties are rare:
// equal logits only survive until the next optimizer step).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "float_key.glsl"
#include "select_state.glsl"
#include "../density/decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Candidates { uint candidates[]; };
layout(std430, set = 0, binding = 1) readonly buffer Logits { uint logits[]; };
layout(std430, set = 0, binding = 2) readonly buffer State { uint state[]; };
layout(std430, set = 0, binding = 3) buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 4) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
    if (state[SEL_VALID] == 0u) return;
    uint i = linear_index();
    if (i >= count || candidates[i] == 0u) return;
    uint key = float_key(logits[i]);
    uint t = state[SEL_PREFIX];
    bool remove = key < t;
    if (key == t) remove = atomicAdd(counters[2], 1u) <= state[SEL_RANK];
    if (remove) decisions[i] |= DECIDE_REMOVE;
}
