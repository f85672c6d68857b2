#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// Error map, step 1 of 3: per workgroup, the sums of all channels of the render and of the
// composited ground truth (partials[2g], partials[2g + 1]); error_mean.comp adds them up. A
// two-level tree in f32 (not atomics) keeps the result deterministic.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 8;
layout(local_size_x_id = 0) in;
#include "ground_truth.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Render { float render[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Partials { float partials[]; };
layout(push_constant) uniform Push { uint pixels; uint gt_offset; float bg_r; float bg_g; float bg_b; };

shared vec2 s_sums[WG_SIZE];

void main() {
    uint tid = gl_LocalInvocationIndex;
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint first = group * WG_SIZE * ITEMS + tid;
    vec3 bg = vec3(bg_r, bg_g, bg_b);
    vec2 s = vec2(0.0);
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k * WG_SIZE;
        if (i >= pixels) break;
        vec3 g = ground_truth(gt[gt_offset + i], bg);
        s += vec2(render[3u * i] + render[3u * i + 1u] + render[3u * i + 2u], g.r + g.g + g.b);
    }
    s = subgroupAdd(s);
    if (subgroupElect()) s_sums[gl_SubgroupID] = s;
    barrier();
    if (tid == 0u) {
        vec2 t = vec2(0.0);
        for (uint j = 0u; j < gl_NumSubgroups; j++) t += s_sums[j];
        partials[2u * group] = t.x;
        partials[2u * group + 1u] = t.y;
    }
}
