#version 460
// Forward step 3: each tile's [start, end) in the tile-sorted intersection list. Tiles with no
// pair keep the (0, 0) the buffer was cleared to.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Keys { uint keys[]; };
layout(std430, set = 0, binding = 1) buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 2) readonly buffer Counts { uint counts[]; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    uint n = counts[2];
    if (i >= n) return;
    uint tile = keys[i];
    if (i == 0u || keys[i - 1u] != tile) ranges[tile].x = i;
    if (i + 1u == n || keys[i + 1u] != tile) ranges[tile].y = i + 1u;
}
