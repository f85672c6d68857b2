#version 460
// Planning a frame whose (tile, Gaussian) pairs pass what one storage binding holds: the pairs
// of every row of 16-px tiles, as 64 bits, so that the host can cut the frame into bands of
// whole tile rows whose pairs each fit one binding (`plan_bands` in src/render/bands.rs). The
// same tile choice as gather_tile_counts.comp, row by row; run once per such frame, never in
// training.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
// counts[COUNT_VISIBLE]: the Gaussians the depth sort kept (`COUNT_VISIBLE` in
// src/render/forward.rs).
const uint COUNT_VISIBLE = 4u;
#include "projected.glsl"
#include "splat_reach.glsl"
#include "tile_rows.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Bounds { ProjectedBounds bounds[]; };
layout(std430, set = 0, binding = 1) readonly buffer Ids { uint depth_sorted_ids[]; };
layout(std430, set = 0, binding = 2) readonly buffer Counts { uint counts[]; };
layout(std430, set = 0, binding = 3) readonly buffer Splats { ProjectedSplat splats[]; };
// Per tile row: [2·row] the pairs modulo 2^32, [2·row + 1] how many times that wrapped (zeroed
// before).
layout(std430, set = 0, binding = 4) buffer RowTotals { uint row_totals[]; };
// gather_tile_counts.comp's push constants (the band fields unused: every row counts).
layout(push_constant) uniform Push {
    float alpha_min; uint ellipse; uint smooth_mode; uint row_lo; uint row_hi; uint total_slot;
};

void add(uint row, uint t) {
    uint before = atomicAdd(row_totals[2u * row], t);
    if (before + t < before) atomicAdd(row_totals[2u * row + 1u], 1u);
}

void main() {
    uint s = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (s >= counts[COUNT_VISIBLE]) return;
    uint g = depth_sorted_ids[s];
    ProjectedBounds p = bounds[g];
    uvec2 cols = uvec2(p.tile_min_x, p.tile_max_x);
    bool use_ellipse = ellipse != 0u && cols.x < cols.y;
    RowSpanner rs;
    rs.bounded = false;
    rs.empty = false;
    if (use_ellipse) rs = row_spanner(splats[g], true, alpha_min, smooth_mode != 0u);
    for (uint ty = p.tile_min_y; ty < p.tile_max_y; ty++) {
        uvec2 r = row_tiles(rs, ty, cols);
        if (r.y > r.x) add(ty, r.y - r.x);
    }
}
