#version 460
// Forward step 2b: one (tile, Gaussian) pair per paired tile (tile_rows.glsl), written in depth
// order at the Gaussian's scanned offset. The key holds only the tile id: a later stable sort by tile keeps
// the depth order inside each tile. Writes past `capacity` are dropped and the host regrows the
// buffers from the frame's 64-bit total (gather_tile_counts.comp), or refuses a frame past what
// one binding of pairs holds (tools then draw the frame in bands of tile rows, this kernel
// emitting one band's rows [row_lo, row_hi)); the scan's 32-bit total in counts[1] only bounds
// the writes.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
// counts[COUNT_VISIBLE]: the Gaussians the depth sort kept (`COUNT_VISIBLE` in
// src/render/forward.rs); the culled ones were dropped from the depth order.
const uint COUNT_VISIBLE = 4u;
#include "projected.glsl"
#include "splat_reach.glsl"
#include "tile_rows.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Bounds { ProjectedBounds bounds[]; };
layout(std430, set = 0, binding = 1) readonly buffer Ids { uint depth_sorted_ids[]; };
layout(std430, set = 0, binding = 2) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Keys { uint keys[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Vals { uint vals[]; };
layout(std430, set = 0, binding = 5) buffer Counts { uint counts[]; };
layout(std430, set = 0, binding = 6) readonly buffer Splats { ProjectedSplat splats[]; };
// The same tile choice as gather_tile_counts.comp (its push constants, then these).
layout(push_constant) uniform Push {
    float alpha_min; uint ellipse; uint smooth_mode; uint row_lo; uint row_hi; uint total_slot;
    uint capacity; uint tiles_x;
};

void main() {
    uint s = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    // counts[2] = the number of pairs actually stored: what the tile sort and ranges read.
    if (s == 0u) counts[2] = min(counts[1], capacity);
    if (s >= counts[COUNT_VISIBLE]) return;
    uint g = depth_sorted_ids[s];
    ProjectedBounds p = bounds[g];
    uint slot = offsets[s];
    uvec2 cols = uvec2(p.tile_min_x, p.tile_max_x);
    bool use_ellipse = ellipse != 0u && cols.x < cols.y;
    RowSpanner rs;
    rs.bounded = false;
    rs.empty = false;
    if (use_ellipse) rs = row_spanner(splats[g], true, alpha_min, smooth_mode != 0u);
    uint y0 = max(p.tile_min_y, row_lo), y1 = min(p.tile_max_y, row_hi);
    for (uint ty = y0; ty < y1; ty++) {
        uvec2 r = row_tiles(rs, ty, cols);
        for (uint tx = r.x; tx < r.y; tx++) {
            if (slot >= capacity) return;
            keys[slot] = ty * tiles_x + tx;
            vals[slot] = g;
            slot++;
        }
    }
}
