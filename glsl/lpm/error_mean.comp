#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// Error map, step 2 of 3: one workgroup adds the partial sums and writes the two normalisation
// factors 1 / (mean + 0.01) (render, ground truth), mean over all pixels and channels.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Scales { float scales[]; };
layout(push_constant) uniform Push { uint groups; uint pixels; };

shared vec2 s_sums[WG_SIZE];

void main() {
    uint tid = gl_LocalInvocationIndex;
    vec2 s = vec2(0.0);
    for (uint g = tid; g < groups; g += WG_SIZE) s += vec2(partials[2u * g], partials[2u * g + 1u]);
    s = subgroupAdd(s);
    if (subgroupElect()) s_sums[gl_SubgroupID] = s;
    barrier();
    if (tid == 0u) {
        vec2 t = vec2(0.0);
        for (uint j = 0u; j < gl_NumSubgroups; j++) t += s_sums[j];
        vec2 mean = t / (3.0 * float(pixels));
        scales[0] = 1.0 / (mean.x + 0.01);
        scales[1] = 1.0 / (mean.y + 0.01);
    }
}
