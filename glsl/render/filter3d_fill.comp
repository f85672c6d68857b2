#version 460
// Mip-Splatting's 3D filter, pass 2 of 2: Gaussians no training camera sees (−1 from
// filter3d_depth.comp) get the largest filter of the seen ones, as the official code does
// (0 when none is seen: no smoothing).
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) buffer Filter { float filter3d[]; };
layout(std430, set = 0, binding = 1) readonly buffer SeenMax { uint seen_max[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    if (filter3d[i] < 0.0) filter3d[i] = uintBitsToFloat(seen_max[0]);
}
