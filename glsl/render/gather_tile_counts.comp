#version 460
// Forward step 2a: in depth order, how many tiles each Gaussian is paired with (the input of the scan
// whose exclusive prefix gives every Gaussian its first slot in the intersection list), and
// the frame's total as 64 bits: the scan's 32-bit total wraps past 2^32 pairs, and the host
// must tell such a frame from a small one to refuse it clearly rather than draw garbage.
// Only the tile rows [row_lo, row_hi) count: a frame whose pairs pass one storage binding is
// drawn in bands of tile rows, each with its own total (slot `total_slot`).
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
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
layout(std430, set = 0, binding = 2) writeonly buffer Touched { uint touched[]; };
layout(std430, set = 0, binding = 3) readonly buffer Counts { uint counts[]; };
// Per band: [2·slot] the total modulo 2^32, [2·slot + 1] how many times adding to it wrapped
// (zeroed per frame).
layout(std430, set = 0, binding = 4) buffer PairTotal { uint pair_total[]; };
layout(std430, set = 0, binding = 5) readonly buffer Splats { ProjectedSplat splats[]; };
// ellipse: pair only the tiles row_tiles keeps (1) or the whole rectangle (0).
layout(push_constant) uniform Push {
    float alpha_min; uint ellipse; uint smooth_mode; uint row_lo; uint row_hi; uint total_slot;
};

void main() {
    uint s = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    uint t = 0u;
    if (s < counts[COUNT_VISIBLE]) {
        uint g = depth_sorted_ids[s];
        ProjectedBounds p = bounds[g];
        uvec2 cols = uvec2(p.tile_min_x, p.tile_max_x);
        uint y0 = max(p.tile_min_y, row_lo), y1 = max(min(p.tile_max_y, row_hi), y0);
        if (ellipse == 0u || cols.x >= cols.y) {
            // A Gaussian covers at most tiles_x × tiles_y tiles, which fits a uint.
            t = (cols.y - cols.x) * (y1 - y0);
        } else {
            RowSpanner rs = row_spanner(splats[g], true, alpha_min, smooth_mode != 0u);
            for (uint ty = y0; ty < y1; ty++) {
                uvec2 r = row_tiles(rs, ty, cols);
                t += r.y - r.x;
            }
        }
        touched[s] = t;
    }
    // A subgroup's sum fits a uint (subgroup size × tiles of one frame); one atomic a subgroup.
    uint sum = subgroupAdd(t);
    if (subgroupElect() && sum > 0u) {
        uint before = atomicAdd(pair_total[2u * total_slot], sum);
        if (before + sum < before) atomicAdd(pair_total[2u * total_slot + 1u], 1u);
    }
}
