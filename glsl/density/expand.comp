#version 460
// Turns decisions into the three slot counts that one exclusive scan turns into destinations:
// slots[i] = kept (0/1), slots[count + i] = clones (0/1), slots[2·count + i] = split children
// (0/2). Scanned as one array of 3·count, slot i's prefix is the survivor's new index, the clone
// block starts after all survivors and the children after all clones; the total is the new count.
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Slots { uint slots[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
    uint i = linear_index();
    if (i >= count) return;
    uint d = decisions[i];
    slots[i] = decide_keeps(d) ? 1u : 0u;
    slots[count + i] = (d & DECIDE_CLONE) != 0u ? 1u : 0u;
    slots[2u * count + i] = (d & DECIDE_SPLIT) != 0u ? 2u : 0u;
    // The scan reads its element count from the GPU.
    if (i == 0u) counts[0] = 3u * count;
}
