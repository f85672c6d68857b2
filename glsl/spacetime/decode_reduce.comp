#version 460
// SpacetimeGaussians' full model: the decoder's weight gradients, one workgroup per weight
// summing the per-workgroup rows of decode_backward.comp (strided per invocation, then the
// subgroups in order: a fixed order, so repeated runs give the same bits), times `scale`. With
// `accumulate` that is added to the gradient already there (two-view batches: each view adds
// its gradient / 2), else it replaces it.
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require

layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;  // must divide WG_SIZE
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Partial { float partial[]; };
layout(std430, set = 0, binding = 1) buffer Grads { float grads[]; };
layout(push_constant) uniform Push {
    uint rows;      // workgroups of the backward
    uint weights;   // floats per row
    uint accumulate;
    float scale;
};

shared float s_sum[WG_SIZE / SUBGROUP_SIZE];

void main() {
    uint k = gl_WorkGroupID.x;
    if (k >= weights) return;  // uniform over the workgroup
    float s = 0.0;
    for (uint r = gl_LocalInvocationIndex; r < rows; r += gl_WorkGroupSize.x) {
        s += partial[r * weights + k];
    }
    s = subgroupAdd(s);
    if (subgroupElect()) s_sum[gl_SubgroupID] = s;
    barrier();
    if (gl_LocalInvocationIndex == 0u) {
        float total = 0.0;
        for (uint sg = 0u; sg < gl_WorkGroupSize.x / SUBGROUP_SIZE; sg++) total += s_sum[sg];
        grads[k] = accumulate != 0u ? grads[k] + scale * total : scale * total;
    }
}
