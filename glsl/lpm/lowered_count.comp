#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// Density-aware pruning, counting half: how many Gaussians were densified only because of the
// lowered LPM threshold (DECIDE_LOWERED with a clone or split actually emitted: each adds one
// Gaussian net), and which Gaussians may be pruned to compensate: plain survivors (decision 0),
// so extra pruning never touches a Gaussian ADC already clones, splits or removes.
// counters[0] += lowered, counters[1] += candidates.
layout(local_size_x_id = 0) in;
#include "../density/decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Candidates { uint candidates[]; };
layout(std430, set = 0, binding = 2) buffer Counters { uint counters[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
    uint i = linear_index();
    bool lowered = false;
    bool cand = false;
    if (i < count) {
        uint d = decisions[i];
        lowered = (d & DECIDE_LOWERED) != 0u && (d & (DECIDE_CLONE | DECIDE_SPLIT)) != 0u;
        cand = d == 0u;
        candidates[i] = cand ? 1u : 0u;
    }
    uint nl = subgroupAdd(lowered ? 1u : 0u);
    uint nc = subgroupAdd(cand ? 1u : 0u);
    if (subgroupElect()) {
        if (nl != 0u) atomicAdd(counters[0], nl);
        if (nc != 0u) atomicAdd(counters[1], nc);
    }
}
