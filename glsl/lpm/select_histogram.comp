#version 460
// Radix selection, counting pass `pass` (0..3, most significant byte first): histogram of byte
// (3 − pass) of the float keys of the elements whose higher bytes equal the prefix found so far,
// for one or two ranks at once. Elements take part when `flag_mask` is 0 or when
// `flags[i] & flag_mask` is non-zero. Exact: the selected key is the true order statistic.
// With `weighted` (and a non-zero mask) an element counts flags[i] times: the selection is then
// over a multiset (the authors' density-aware pruning ranks the model after densification, where
// a cloned or split Gaussian's opacity appears twice).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 16;
layout(local_size_x_id = 0) in;
#include "float_key.glsl"
#include "select_state.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Values { uint values[]; };
layout(std430, set = 0, binding = 1) readonly buffer Flags { uint flags[]; };
layout(std430, set = 0, binding = 2) readonly buffer State { uint state[]; };
layout(std430, set = 0, binding = 3) buffer Hist { uint hist[]; };
layout(push_constant) uniform Push { uint count; uint pass; uint flag_mask; uint ranks; uint weighted; };

shared uint s_hist[2u * RADIX];

void main() {
    // Uniform over the workgroup: an undefined selection (no element) needs no further pass.
    if (pass > 0u && state[SEL_VALID] == 0u) return;
    uint tid = gl_LocalInvocationIndex;
    for (uint b = tid; b < 2u * RADIX; b += WG_SIZE) s_hist[b] = 0u;
    barrier();
    uint shift = 24u - 8u * pass;
    uint mask = pass == 0u ? 0u : (0xFFFFFFFFu << (shift + 8u));
    uint p0 = state[SEL_PREFIX] & mask;
    uint p1 = state[SEL_PREFIX + 1u] & mask;
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint first = group * WG_SIZE * ITEMS + tid;
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k * WG_SIZE;
        if (i >= count) break;
        if (flag_mask != 0u && (flags[i] & flag_mask) == 0u) continue;
        uint w = (weighted != 0u && flag_mask != 0u) ? flags[i] : 1u;
        uint key = float_key(values[i]);
        uint bin = (key >> shift) & (RADIX - 1u);
        if ((key & mask) == p0) atomicAdd(s_hist[bin], w);
        if (ranks > 1u && (key & mask) == p1) atomicAdd(s_hist[RADIX + bin], w);
    }
    barrier();
    for (uint b = tid; b < ranks * RADIX; b += WG_SIZE) {
        uint h = s_hist[b];
        if (h != 0u) atomicAdd(hist[pass * 2u * RADIX + b], h);
    }
}
