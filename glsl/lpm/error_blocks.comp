#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// LPM step 2 input: per block × block tile of the error map (row-major, blocks_x per row, the
// image zero-padded to whole blocks), how many pixels have an error strictly above the threshold
// (the quantile selected by select_pick.comp, mode 0). One workgroup per block; the counts are
// what `BlockMask::from_error_counts` takes.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "select_state.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Error { float error[]; };
layout(std430, set = 0, binding = 1) readonly buffer State { uint state[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push { uint width; uint height; uint block; uint blocks_x; uint blocks; };

shared uint s_counts[WG_SIZE];

void main() {
    uint tid = gl_LocalInvocationIndex;
    uint b = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (b >= blocks) return;  // uniform over the workgroup
    float threshold = uintBitsToFloat(state[SEL_THRESHOLD]);
    uint x0 = (b % blocks_x) * block;
    uint y0 = (b / blocks_x) * block;
    uint c = 0u;
    for (uint k = tid; k < block * block; k += WG_SIZE) {
        uint x = x0 + k % block;
        uint y = y0 + k / block;
        if (x < width && y < height && error[y * width + x] > threshold) c++;
    }
    c = subgroupAdd(c);
    if (subgroupElect()) s_counts[gl_SubgroupID] = c;
    barrier();
    if (tid == 0u) {
        uint t = 0u;
        for (uint j = 0u; j < gl_NumSubgroups; j++) t += s_counts[j];
        counts[b] = t;
    }
}
