#version 460
// Density-aware pruning, marking half: given the k-th smallest opacity logit among the
// candidates (select_pick.comp, mode 0, rank k − 1: SEL_PREFIX holds its float key and, after
// the last pass, SEL_RANK its rank among the candidates with exactly that key), OR DECIDE_REMOVE
// into the decision of every candidate strictly below it and of SEL_RANK + 1 of the tied ones,
// so exactly k are removed. Which tied candidates go depends on scheduling (ties are rare:
// equal logits only survive until the next optimizer step).
// With `all_ties` (the authors' rule: `opacity <= k-th smallest` OR-ed into the prune mask) every
// candidate at or below the key is removed, ties included.
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
layout(push_constant) uniform Push { uint count; uint all_ties; };

void main() {
    if (state[SEL_VALID] == 0u) return;
    uint i = linear_index();
    if (i >= count || candidates[i] == 0u) return;
    uint key = float_key(logits[i]);
    uint t = state[SEL_PREFIX];
    bool remove = key < t;
    if (key == t) remove = all_ties != 0u || atomicAdd(counters[2], 1u) <= state[SEL_RANK];
    // Under `all_ties` a cloned or split candidate goes with its copies: they share its opacity,
    // so the authors' mask (built after densification) holds them too.
    if (!remove) return;
    uint d = decisions[i];
    decisions[i] = all_ties != 0u ? DECIDE_REMOVE : (d | DECIDE_REMOVE);
    // counters[3]: Gaussians this rule removes that ADC kept (its own extra prunes).
    if ((d & DECIDE_REMOVE) == 0u) atomicAdd(counters[3], 1u);
}
