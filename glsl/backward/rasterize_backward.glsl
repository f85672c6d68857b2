// Rasterizer backward (shared body of rasterize_backward.comp and rasterize_backward_cas.comp).
//
// One 16×16 workgroup per tile, one invocation per pixel (1-D local index, pixel (i % 16,
// i / 16) of the tile). Every pixel walks its tile's sorted list back to front, from its
// `last_index` (the forward's last contributor + 1) down to entry 0, so all pixels of the
// workgroup visit the same splat at the same time: the splats are staged in shared memory a
// batch at a time, and the per-pixel gradients of one splat are summed over the subgroup
// before one invocation adds them to global memory.
//
// Per splat the pixel repeats the forward's decisions exactly (see src/reference/raster.rs):
//   power = −½(a·dx² + c·dy²) − b·dx·dy; skip when power > 0 (rounding guard);
//   alpha = min(alpha_max, opacity·exp(power)); skip when alpha < alpha_min;
//   in smooth mode neither the alpha_min skip nor the alpha_max clamp applies.
// The transmittance in front of a splat is recovered as T / (1 − alpha) from the stored
// final T: the forward stops before T drops below t_min and alpha ≤ alpha_max = 0.99, so the
// division is bounded.
//
// Output: grad2d[g·9 + k], k = 0..8: dL/d(mean_x, mean_y, conic_a, conic_b, conic_c, r, g, b,
// opacity), accumulated atomically (the caller zeroes the buffer first).
//
// HAS_FLOAT_ATOMICS (a #define of the including file) says whether the SPIR-V may declare
// the float atomic-add capability; USE_FLOAT_ATOMICS (specialisation constant 2) picks the
// float atomicAdd (1) or a compare-and-swap loop on the bits (0) at pipeline creation.

#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_vote : require

layout(constant_id = 0) const uint WG_SIZE = 256;  // must be TILE·TILE = 256
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;
layout(constant_id = 2) const uint USE_FLOAT_ATOMICS = 0;
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"

const uint TILE = 16u;
const uint GRAD2D_STRIDE = 9u;

layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer ProjectedBuf { Projected projected[]; };
layout(std430, set = 0, binding = 2) readonly buffer TileRanges { uvec2 tile_ranges[]; };
layout(std430, set = 0, binding = 3) readonly buffer SortedIds { uint sorted_ids[]; };
layout(std430, set = 0, binding = 4) readonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 5) readonly buffer LastIndex { uint last_index[]; };
layout(std430, set = 0, binding = 6) readonly buffer DlDImage { float dl_dimage[]; };
layout(std430, set = 0, binding = 7) buffer Grad2dBits { uint grad2d_bits[]; };
#if HAS_FLOAT_ATOMICS
// The same binding seen as floats, for the native float atomicAdd.
layout(std430, set = 0, binding = 7) buffer Grad2dFloat { float grad2d_f[]; };
#endif

layout(push_constant) uniform Push {
    RenderConstants rc;
    vec4 background;  // xyz used
    uint camera_index;
} pc;

void atomic_add_float(uint idx, float v) {
#if HAS_FLOAT_ATOMICS
    if (USE_FLOAT_ATOMICS != 0u) {
        atomicAdd(grad2d_f[idx], v);
        return;
    }
#endif
    // Lock-free: every failed exchange means another invocation's add succeeded, so the loop
    // never waits on a workgroup that might not be scheduled.
    uint old = grad2d_bits[idx];
    for (;;) {
        uint assumed = old;
        old = atomicCompSwap(grad2d_bits[idx], assumed,
                             floatBitsToUint(uintBitsToFloat(assumed) + v));
        if (old == assumed) break;
    }
}

shared uint s_max_last;
shared uint s_id[WG_SIZE];
shared vec4 s_mean_opacity[WG_SIZE];  // mean_x, mean_y, opacity, -
shared vec4 s_conic[WG_SIZE];         // a, b, c, -
shared vec4 s_rgb[WG_SIZE];           // r, g, b, -

void main() {
    Camera cam = cameras[pc.camera_index];
    uint width = cam.size.x, height = cam.size.y, tiles_x = cam.size.z, tiles_y = cam.size.w;
    uint tile = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    // Uniform over the workgroup: spare groups of the dispatch leave together.
    if (tile >= tiles_x * tiles_y) return;

    uint li = gl_LocalInvocationIndex;
    uint px = (tile % tiles_x) * TILE + li % TILE;
    uint py = (tile / tiles_x) * TILE + li / TILE;
    bool inside = px < width && py < height;
    uint pix = py * width + px;

    uvec2 range = tile_ranges[tile];
    uint list_len = range.y > range.x ? range.y - range.x : 0u;
    // A last_index past the tile's list would read other tiles' entries: clamp (bad input).
    uint last = inside ? min(last_index[pix], list_len) : 0u;
    float t_final = inside ? final_t[pix] : 1.0;
    vec3 dl_dc = inside ? vec3(dl_dimage[3u * pix], dl_dimage[3u * pix + 1u],
                               dl_dimage[3u * pix + 2u])
                        : vec3(0.0);
    float bg_dot = dot(pc.background.xyz, dl_dc);
    bool smooth_mode = pc.rc.smooth_mode != 0u;

    if (li == 0u) s_max_last = 0u;
    barrier();
    atomicMax(s_max_last, last);
    barrier();
    uint max_last = s_max_last;

    float t = t_final;
    // Colour of everything behind the current splat per unit of the transmittance in front of
    // it (background excluded: it enters through t_final).
    vec3 behind = vec3(0.0);
    float next_alpha = 0.0;
    vec3 next_rgb = vec3(0.0);

    for (uint done = 0u; done < max_last; done += WG_SIZE) {
        uint batch = min(WG_SIZE, max_last - done);
        barrier();  // the previous batch has been consumed by every invocation
        if (li < batch) {
            uint k = max_last - 1u - (done + li);
            uint g = sorted_ids[range.x + k];
            Projected p = projected[g];
            s_id[li] = g;
            s_mean_opacity[li] = vec4(p.mean_x, p.mean_y, p.opacity, 0.0);
            s_conic[li] = vec4(p.conic_a, p.conic_b, p.conic_c, 0.0);
            s_rgb[li] = vec4(p.r, p.g, p.b, 0.0);
        }
        barrier();
        for (uint j = 0u; j < batch; j++) {
            uint k = max_last - 1u - (done + j);
            vec2 g_mean = vec2(0.0);
            vec3 g_conic = vec3(0.0);
            vec3 g_rgb = vec3(0.0);
            float g_opacity = 0.0;
            bool hit = false;
            if (k < last) {
                vec4 mo = s_mean_opacity[j];
                vec3 conic = s_conic[j].xyz;
                vec2 d = mo.xy - vec2(float(px) + 0.5, float(py) + 0.5);
                float power = -0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y)
                              - conic.y * d.x * d.y;
                // Clamp/skip 1: power > 0 cannot happen for a positive definite conic; the
                // forward skips it as a rounding guard, so do we.
                if (power <= 0.0) {
                    float gauss = exp(power);
                    float raw = mo.z * gauss;
                    // Clamp 2: alpha = min(alpha_max, raw); when active it passes no gradient
                    // to opacity, conic or mean (not in smooth mode).
                    bool clamped = !smooth_mode && raw > pc.rc.alpha_max;
                    float alpha = clamped ? pc.rc.alpha_max : raw;
                    // Skip 3: alpha < alpha_min contributed nothing (not in smooth mode).
                    if (smooth_mode || alpha >= pc.rc.alpha_min) {
                        hit = true;
                        vec3 rgb = s_rgb[j].xyz;
                        float one_minus = 1.0 - alpha;
                        t /= one_minus;
                        behind = next_alpha * next_rgb + (1.0 - next_alpha) * behind;
                        g_rgb = alpha * t * dl_dc;
                        float dl_dalpha = dot((rgb - behind) * t, dl_dc)
                                          - t_final / one_minus * bg_dot;
                        next_alpha = alpha;
                        next_rgb = rgb;
                        if (!clamped) {
                            g_opacity = gauss * dl_dalpha;
                            float dl_dpower = mo.z * gauss * dl_dalpha;
                            g_mean = dl_dpower * vec2(-conic.x * d.x - conic.y * d.y,
                                                      -conic.z * d.y - conic.y * d.x);
                            g_conic = dl_dpower * vec3(-0.5 * d.x * d.x, -d.x * d.y,
                                                       -0.5 * d.y * d.y);
                        }
                    }
                }
            }
            // Subgroup-uniform branch: the pixels of this subgroup that touched the splat are
            // summed before a single invocation does the nine atomics.
            if (subgroupAny(hit)) {
                vec2 s_mean = subgroupAdd(g_mean);
                vec3 s_con = subgroupAdd(g_conic);
                vec3 s_col = subgroupAdd(g_rgb);
                float s_op = subgroupAdd(g_opacity);
                if (subgroupElect()) {
                    uint base = s_id[j] * GRAD2D_STRIDE;
                    atomic_add_float(base + 0u, s_mean.x);
                    atomic_add_float(base + 1u, s_mean.y);
                    atomic_add_float(base + 2u, s_con.x);
                    atomic_add_float(base + 3u, s_con.y);
                    atomic_add_float(base + 4u, s_con.z);
                    atomic_add_float(base + 5u, s_col.x);
                    atomic_add_float(base + 6u, s_col.y);
                    atomic_add_float(base + 7u, s_col.z);
                    atomic_add_float(base + 8u, s_op);
                }
            }
        }
    }
}
