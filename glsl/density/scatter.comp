#version 460
// Moves one per-Gaussian buffer (rows of `stride` floats) into the new layout: survivors to
// their scanned index, clones to the clone block, split children (two adjacent rows per parent)
// to the children block. Mode 0 copies the parent's row everywhere (parameters); mode 1 copies
// survivors and writes zeros for every new Gaussian (Adam moments); mode 2 skips the children
// (positions and log-scales, which split.comp writes).
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 2) readonly buffer Src { float src[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Dst { float dst[]; };
layout(push_constant) uniform Push { uint count; uint stride; uint mode; };

void put_row(uint i, uint to, bool zero) {
    for (uint k = 0u; k < stride; k++) dst[to * stride + k] = zero ? 0.0 : src[i * stride + k];
}

void main() {
    uint i = linear_index();
    if (i >= count) return;
    uint d = decisions[i];
    if (decide_keeps(d)) put_row(i, offsets[i], false);
    if ((d & DECIDE_CLONE) != 0u) put_row(i, offsets[count + i], mode == 1u);
    if ((d & DECIDE_SPLIT) != 0u && mode != 2u) {
        uint c = offsets[2u * count + i];
        put_row(i, c, mode == 1u);
        put_row(i, c + 1u, mode == 1u);
    }
}
