#version 460
// The Gaussian budget (src/train/density/budget.rs, whose `apply_cut` mirrors this): the
// additions at or below the host's cut in the order "higher score first, then lower index"
// lose their clone, split and lowered bits. A dropped split keeps its original unless the
// original is pruned anyway (its remove bit stays).
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Scores { float scores[]; };
layout(push_constant) uniform Push {
    uint count;
    float cut_score;
    uint cut_index;
};

void main() {
    uint i = linear_index();
    if (i >= count) return;
    uint d = decisions[i];
    bool adds = (d & (DECIDE_CLONE | DECIDE_SPLIT)) != 0u;
    float s = scores[i];
    if (adds && (s < cut_score || (s == cut_score && i >= cut_index))) {
        decisions[i] = d & ~(DECIDE_CLONE | DECIDE_SPLIT | DECIDE_LOWERED);
    }
}
