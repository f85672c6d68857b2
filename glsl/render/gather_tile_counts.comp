#version 460
// Forward step 2a: in depth order, how many tiles each Gaussian touches (the input of the scan
// whose exclusive prefix gives every Gaussian its first slot in the intersection list).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "projected.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Proj { Projected projected[]; };
layout(std430, set = 0, binding = 1) readonly buffer Ids { uint depth_sorted_ids[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Touched { uint touched[]; };
layout(std430, set = 0, binding = 3) readonly buffer Counts { uint counts[]; };

void main() {
    uint s = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (s >= counts[0]) return;
    Projected p = projected[depth_sorted_ids[s]];
    // A Gaussian covers at most tiles_x × tiles_y tiles, which fits a uint.
    touched[s] = (p.tile_max_x - p.tile_min_x) * (p.tile_max_y - p.tile_min_y);
}
