#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// Density-aware pruning, counting half: how many Gaussians were densified only because of the
// lowered LPM threshold (DECIDE_LOWERED with a clone or split actually emitted: each adds one
// Gaussian net), and which Gaussians may be pruned to compensate: plain survivors (decision 0),
// so extra pruning never touches a Gaussian ADC already clones, splits or removes.
// counters[0] += lowered, counters[1] += candidates.
// Mode 1 (the authors' pruning, over the model as it stands after densification): every
// Gaussian is a candidate, weighted by its copies after densification (2 when it is cloned or
// split, else 1; a split whose children are pruned at birth counts 1), and counters[1] sums the
// weights.
layout(local_size_x_id = 0) in;
#include "../density/decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Candidates { uint candidates[]; };
layout(std430, set = 0, binding = 2) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { uint count; uint mode; };

void main() {
    uint i = linear_index();
    bool lowered = false;
    uint weight = 0u;
    if (i < count) {
        uint d = decisions[i];
        bool emits = (d & (DECIDE_CLONE | DECIDE_SPLIT)) != 0u;
        lowered = (d & DECIDE_LOWERED) != 0u && emits;
        weight = mode == 1u ? (emits ? 2u : 1u) : (d == 0u ? 1u : 0u);
        candidates[i] = weight;
    }
    uint nl = subgroupAdd(lowered ? 1u : 0u);
    uint nc = subgroupAdd(weight);
    if (subgroupElect()) {
        if (nl != 0u) atomicAdd(counters[0], nl);
        if (nc != 0u) atomicAdd(counters[1], nc);
    }
}
