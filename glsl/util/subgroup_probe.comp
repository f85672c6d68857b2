#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// Smoke test of the GPU layer: per element, writes x * scale + the inclusive subgroup prefix sum
// of x, and records the subgroup size the shader actually ran with (checked against the device).
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer In { uint xs[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Out { uint ys[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Info { uint subgroup_size; };
layout(push_constant) uniform Push { uint count; uint scale; };
void main() {
    uint i = gl_GlobalInvocationID.x;
    uint x = i < count ? xs[i] : 0u;
    uint prefix = subgroupInclusiveAdd(x);
    if (i < count) ys[i] = x * scale + prefix;
    if (i == 0u) subgroup_size = gl_SubgroupSize;
}
