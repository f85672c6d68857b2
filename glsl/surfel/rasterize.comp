#version 460
// 2DGS forward step 4: one workgroup per 16×16 tile, PIXELS pixels per invocation. The tile's
// surfels (front to back) are loaded into shared memory a batch at a time; every pixel
// intersects its ray with each surfel's plane, blends colour, depth, normal and distortion,
// records the median depth, and stops before its transmittance would fall under t_min.
// Mirrors src/reference/surfel/raster.rs `composite_pixel`.
//
// Why several pixels per invocation: see glsl/render/rasterize.comp (on a CPU driver the
// per-splat shared loads and loop overhead are paid per subgroup; PIXELS = 8 shares them).
#extension GL_EXT_control_flow_attributes : require
layout(constant_id = 0) const uint WG_SIZE = 256;  // must be 256 / PIXELS
layout(constant_id = 1) const uint PIXELS = 1;     // 1, 2, 4, 8 or 16
layout(local_size_x_id = 0) in;
#include "camera.glsl"
#include "projected.glsl"
#include "surfel.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Proj { Projected projected[]; };
layout(std430, set = 0, binding = 1) readonly buffer Geom { float geom[]; };
layout(std430, set = 0, binding = 2) readonly buffer Ids { uint sorted_ids[]; };
layout(std430, set = 0, binding = 3) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 4) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 6) writeonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 7) writeonly buffer LastIndex { uint last_index[]; };
layout(std430, set = 0, binding = 8) writeonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 9) writeonly buffer MedianIndex { uint median_index[]; };
layout(push_constant) uniform Push {
    SurfelConstants sc;
    uint camera_index;
    float bg_r, bg_g, bg_b;
};

shared vec4 s_h1[WG_SIZE];   // h1, opacity
shared vec4 s_h2[WG_SIZE];   // h2, box centre x
shared vec4 s_h3[WG_SIZE];   // h3, box centre y
shared vec3 s_n[WG_SIZE];    // camera-facing normal
shared vec3 s_rgb[WG_SIZE];
shared uint s_done;

// Pixel k of invocation li as an index into the tile (row-major): consecutive invocations own
// consecutive pixels of a row, so neighbouring lanes stop at similar depths.
uint tile_pixel(uint li, uint k) { return k * WG_SIZE + li; }

void main() {
    Camera cam = cameras[camera_index];
    uint tiles_x = cam.size.z;
    uint tile = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (tile >= tiles_x * cam.size.w) return;  // uniform over the workgroup
    uint li = gl_LocalInvocationIndex;
    bool smooth_mode = (sc.flags & 1u) != 0u;

    vec2 centre[PIXELS];
    float T[PIXELS];
    vec3 color[PIXELS];
    vec3 normal[PIXELS];
    float depth[PIXELS], median[PIXELS], dist[PIXELS], m1[PIXELS], m2[PIXELS];
    uint last[PIXELS], median_at[PIXELS];
    bool done[PIXELS];
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

    uvec2 range = ranges[tile];
    for (uint base = range.x; base < range.y; base += WG_SIZE) {
        // Stop loading once every pixel of the tile is done (the count is workgroup-uniform).
        if (li == 0u) s_done = 0u;
        barrier();
        if (all_done) atomicAdd(s_done, 1u);
        uint e = base + li;
        if (e < range.y) {
            uint g = sorted_ids[e];
            Projected p = projected[g];
            uint o = GEOM_STRIDE * g;
            s_h1[li] = vec4(geom[o], geom[o + 1u], geom[o + 2u], p.opacity);
            s_h2[li] = vec4(geom[o + 3u], geom[o + 4u], geom[o + 5u], p.mean_x);
            s_h3[li] = vec4(geom[o + 6u], geom[o + 7u], geom[o + 8u], p.mean_y);
            s_n[li] = vec3(geom[o + 9u], geom[o + 10u], geom[o + 11u]);
            s_rgb[li] = vec3(p.r, p.g, p.b);
        }
        barrier();
        if (s_done == WG_SIZE) break;
        uint batch = min(WG_SIZE, range.y - base);
        for (uint j = 0u; !all_done && j < batch; j++) {
            vec4 h1 = s_h1[j], h2 = s_h2[j], h3 = s_h3[j];
            // Loaded once for all the invocation's pixels (inside the pixel loop every load
            // would run once per pixel: a loop over the lanes each on CPU drivers).
            vec3 n = s_n[j], rgb = s_rgb[j];
            all_done = true;
            [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
                SurfelHit s;
                if (!done[k] && surfel_sample(sc, h1.xyz, h2.xyz, h3.xyz, vec2(h2.w, h3.w),
                                              h1.w, centre[k], s)) {
                    float next_t = T[k] * (1.0 - s.alpha);
                    // Stop before the surfel that would make the pixel (almost) opaque (the
                    // backward divides by 1 − alpha to walk back).
                    if (!smooth_mode && next_t < sc.t_min) {
                        done[k] = true;
                    } else {
                        float w = s.alpha * T[k];
                        float mz = mapped_depth(sc, s.z);
                        // Distortion: Σ_i w_i Σ_{j<i} w_j (m_i − m_j)², in one pass, with the
                        // weight in front A = 1 − T.
                        dist[k] += (mz * mz * (1.0 - T[k]) + m2[k] - 2.0 * mz * m1[k]) * w;
                        depth[k] += w * s.z;
                        m1[k] += w * mz;
                        m2[k] += w * mz * mz;
                        if (T[k] > 0.5) {
                            median[k] = s.z;
                            median_at[k] = base - range.x + j + 1u;
                        }
                        normal[k] += w * n;
                        color[k] += w * rgb;
                        T[k] = next_t;
                        last[k] = base - range.x + j + 1u;
                    }
                }
                all_done = all_done && done[k];
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
