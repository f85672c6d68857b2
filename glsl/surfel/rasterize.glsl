// 2DGS forward step 4 (shared body of rasterize.comp and rasterize_plain.comp): one workgroup
// per 16×16 tile, PIXELS pixels per invocation (tile_pixel). The tile's surfels (front to back)
// are loaded into shared memory a batch at a time; every pixel intersects its ray with each
// surfel's plane, blends colour, depth, normal and distortion, records the median depth, and
// stops before its transmittance would fall under t_min. Mirrors
// src/reference/surfel/raster.rs `composite_pixel`.
//
// Each subgroup visits only the batch's surfels whose reach (surfel_reach: the box outside which
// alpha < alpha_min) meets the box of its own pixels, in order; a skipped surfel would have
// added nothing to any of them. Why several pixels per invocation, and why the surfels are
// handed from lane to lane by shuffles on CPU drivers: see glsl/render/rasterize.glsl.
#extension GL_EXT_control_flow_attributes : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_vote : require
#if HAS_SHUFFLE
#extension GL_KHR_shader_subgroup_shuffle : require
#define SHUFFLE(x, i) subgroupShuffle(x, i)
#else
#define SHUFFLE(x, i) (x)  // never taken: PIXELS > 1 needs the shuffles
#endif
layout(constant_id = 0) const uint WG_SIZE = 256;        // must be 256 / PIXELS
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;   // must divide WG_SIZE
layout(constant_id = 2) const uint PIXELS = 1;           // 1, 2, 4, 8 or 16
layout(local_size_x_id = 0) in;
#include "camera.glsl"
#include "projected.glsl"
#include "surfel.glsl"
#include "splat_reach.glsl"
#include "subgroup_pixels.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Splats { ProjectedSplat splats[]; };
layout(std430, set = 0, binding = 1) readonly buffer Geom { float geom[]; };
layout(std430, set = 0, binding = 2) readonly buffer Ids { uint sorted_ids[]; };
layout(std430, set = 0, binding = 3) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 4) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 6) writeonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 7) writeonly buffer LastIndex { uint last_index[]; };
layout(std430, set = 0, binding = 8) writeonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 9) writeonly buffer MedianIndex { uint median_index[]; };
layout(std430, set = 0, binding = 10) readonly buffer Normals { float normals[]; };
layout(push_constant) uniform Push {
    SurfelConstants sc;
    uint camera_index;
    float bg_r, bg_g, bg_b;
    // The first tile of the band of tile rows this dispatch draws (0: the whole frame; frames
    // whose pairs pass one storage binding are drawn band by band).
    uint tile_offset;
};


shared vec4 s_h1[WG_SIZE];   // h1, opacity
shared vec4 s_h2[WG_SIZE];   // h2, box centre x
shared vec4 s_h3[WG_SIZE];   // h3, box centre y
shared vec4 s_nr[WG_SIZE];   // camera-facing normal, red
shared vec4 s_gb[WG_SIZE];   // green, blue, surfel_reach
// Surfels per batch: every subgroup's list must fit in s_list.
const uint LIST_SLOTS = 2048u;
const uint NUM_SG = WG_SIZE / SUBGROUP_SIZE;
const uint BATCH = WG_SIZE < LIST_SLOTS / NUM_SG ? WG_SIZE : LIST_SLOTS / NUM_SG;
// [subgroup · BATCH + i]: the batch entries that may touch the subgroup's pixels, in order.
shared uint s_list[LIST_SLOTS];
shared uint s_done;

// Per-pixel state of the invocation's pixels (module scope so that blend() can update it; the
// loops over k are unrolled, so these stay in registers).
vec2 centre[PIXELS];
float T[PIXELS];
vec3 color[PIXELS];
vec3 normal[PIXELS];
float depth[PIXELS], median[PIXELS], dist[PIXELS], m1[PIXELS], m2[PIXELS];
uint last[PIXELS], median_at[PIXELS];
bool done[PIXELS];

// Blends one surfel (h1 + opacity, h2 + box centre x, h3 + box centre y, normal + red,
// green/blue) into the invocation's pixels that are not done; `index` is its entry in the
// tile's list + 1. Returns whether all the invocation's pixels are done. Branch-free per pixel,
// as in glsl/render/rasterize.glsl: a pixel the surfel does not reach gets weight 0 (and a
// finite stand-in depth, so that 0 · m(z) stays 0) and keeps its state.
bool blend(vec4 h1, vec4 h2, vec4 h3, vec4 nr, vec2 gb, uint index, bool smooth_mode) {
    bool all = true;
    vec3 rgb = vec3(nr.w, gb);
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        SurfelHit s;
        bool hit = surfel_sample(sc, h1.xyz, h2.xyz, h3.xyz, vec2(h2.w, h3.w), h1.w, centre[k], s)
                   && !done[k];
        float alpha = hit ? s.alpha : 0.0;
        float next_t = T[k] * (1.0 - alpha);
        // Stop before the surfel that would make the pixel (almost) opaque (the backward
        // divides by 1 − alpha to walk back).
        bool stop = hit && !smooth_mode && next_t < sc.t_min;
        bool take = hit && !stop;
        float w = take ? alpha * T[k] : 0.0;
        float z = take ? s.z : 1.0;
        float mz = mapped_depth(sc, z);
        // Distortion: Σ_i w_i Σ_{j<i} w_j (m_i − m_j)², in one pass, with the weight in front
        // A = 1 − T.
        dist[k] += (mz * mz * (1.0 - T[k]) + m2[k] - 2.0 * mz * m1[k]) * w;
        depth[k] += w * z;
        m1[k] += w * mz;
        m2[k] += w * mz * mz;
        bool median_here = take && T[k] > 0.5;
        median[k] = median_here ? z : median[k];
        median_at[k] = median_here ? index : median_at[k];
        normal[k] += w * nr.xyz;
        color[k] += w * rgb;
        T[k] = take ? next_t : T[k];
        last[k] = take ? index : last[k];
        done[k] = done[k] || stop;
        all = all && done[k];
    }
    return all;
}

void main() {
    Camera cam = cameras[camera_index];
    uint tiles_x = cam.size.z;
    uint tile = tile_offset + gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (tile >= tiles_x * cam.size.w) return;  // uniform over the workgroup
    uint li = gl_LocalInvocationIndex;
    bool smooth_mode = (sc.flags & 1u) != 0u;

    bool all_done = true;
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        uint q = tile_pixel(li, k);
        uint px = (tile % tiles_x) * 16u + q % 16u, py = (tile / tiles_x) * 16u + q / 16u;
        centre[k] = vec2(float(px) + 0.5, float(py) + 0.5);
        T[k] = 1.0;
        color[k] = vec3(0.0);
        normal[k] = vec3(0.0);
        depth[k] = 0.0; median[k] = 0.0; dist[k] = 0.0; m1[k] = 0.0; m2[k] = 0.0;
        last[k] = 0u; median_at[k] = 0u;
        done[k] = !(px < cam.size.x && py < cam.size.y);
        all_done = all_done && done[k];
    }
    vec2 c_lo, c_hi;
    subgroup_pixel_box(centre, c_lo, c_hi);

    uvec2 range = ranges[tile];
    for (uint base = range.x; base < range.y; base += BATCH) {
        // Stop loading once every pixel of the tile is done (the count is workgroup-uniform).
        if (li == 0u) s_done = 0u;
        barrier();
        if (all_done) atomicAdd(s_done, 1u);
        uint e = base + li;
        if (li < BATCH && e < range.y) {
            uint g = sorted_ids[e];
            ProjectedSplat p = splats[g];
            uint o = GEOM_STRIDE * g;
            vec3 h1 = vec3(geom[o], geom[o + 1u], geom[o + 2u]);
            vec3 h2 = vec3(geom[o + 3u], geom[o + 4u], geom[o + 5u]);
            vec3 h3 = vec3(geom[o + 6u], geom[o + 7u], geom[o + 8u]);
            s_h1[li] = vec4(h1, p.opacity);
            s_h2[li] = vec4(h2, p.mean_x);
            s_h3[li] = vec4(h3, p.mean_y);
            s_nr[li] = vec4(normals[3u * g], normals[3u * g + 1u], normals[3u * g + 2u], p.r);
            vec2 reach = surfel_reach(sc, h1, h2, h3, vec2(p.mean_x, p.mean_y), p.opacity);
            s_gb[li] = vec4(p.g, p.b, reach);
        }
        barrier();
        if (s_done == WG_SIZE) break;
        uint batch = min(BATCH, range.y - base);
        // Compact (in order) the entries whose reach meets the subgroup's box: the loop below
        // visits only those (a loop bound skips work even where `if` only masks lanes).
        uint list_base = gl_SubgroupID * BATCH;
        uint n_list = 0u;
        for (uint j0 = 0u; !subgroupAll(all_done) && j0 < batch; j0 += gl_SubgroupSize) {
            uint j = j0 + gl_SubgroupInvocationID;
            bool meets = j < batch &&
                         reach_meets(vec2(s_h2[j].w, s_h3[j].w), s_gb[j].zw, c_lo, c_hi);
            uvec4 ballot = subgroupBallot(meets);
            if (meets) s_list[list_base + n_list + subgroupBallotExclusiveBitCount(ballot)] = j;
            n_list += subgroupBallotBitCount(ballot);
        }
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        if (PIXELS > 1u && HAS_SHUFFLE != 0u) {
            // CPU drivers: lane l loads the chunk's entry l (the last entry again past the
            // list's end) and every lane takes each entry's values from its lane by shuffles;
            // the loops stay uniform over the subgroup (a shuffle must not read an invocation
            // that left), and done pixels change nothing in blend().
            for (uint i0 = 0u; !subgroupAll(all_done) && i0 < n_list; i0 += SUBGROUP_SIZE) {
                uint mine = s_list[list_base + min(i0 + gl_SubgroupInvocationID, n_list - 1u)];
                vec4 l_h1 = s_h1[mine], l_h2 = s_h2[mine], l_h3 = s_h3[mine];
                vec4 l_nr = s_nr[mine];
                vec3 l_gbj = vec3(s_gb[mine].xy, uintBitsToFloat(mine));
                uint n_chunk = min(SUBGROUP_SIZE, n_list - i0);
                for (uint ii = 0u; !subgroupAll(all_done) && ii < n_chunk; ii++) {
                    vec3 gbj = SHUFFLE(l_gbj, ii);
                    uint j = floatBitsToUint(gbj.z);
                    all_done = blend(SHUFFLE(l_h1, ii), SHUFFLE(l_h2, ii), SHUFFLE(l_h3, ii),
                                     SHUFFLE(l_nr, ii), gbj.xy, base - range.x + j + 1u,
                                     smooth_mode);
                }
            }
        } else {
            for (uint i = 0u; !all_done && i < n_list; i++) {
                uint j = s_list[list_base + i];
                all_done = blend(s_h1[j], s_h2[j], s_h3[j], s_nr[j], s_gb[j].xy,
                                 base - range.x + j + 1u, smooth_mode);
            }
        }
        barrier();
    }
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        uint q = tile_pixel(li, k);
        uint px = (tile % tiles_x) * 16u + q % 16u, py = (tile / tiles_x) * 16u + q / 16u;
        if (px < cam.size.x && py < cam.size.y) {
            uint pix = py * cam.size.x + px;
            image[3u * pix] = color[k].r + T[k] * bg_r;
            image[3u * pix + 1u] = color[k].g + T[k] * bg_g;
            image[3u * pix + 2u] = color[k].b + T[k] * bg_b;
            final_t[pix] = T[k];
            last_index[pix] = last[k];
            median_index[pix] = median_at[k];
            uint o = MAPS_STRIDE * pix;
            maps[o] = depth[k];
            maps[o + 1u] = median[k];
            maps[o + 2u] = normal[k].x;
            maps[o + 3u] = normal[k].y;
            maps[o + 4u] = normal[k].z;
            maps[o + 5u] = dist[k];
            maps[o + 6u] = m1[k];
            maps[o + 7u] = m2[k];
        }
    }
}
