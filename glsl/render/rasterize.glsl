// Forward step 4 (shared body of rasterize.comp and rasterize_plain.comp): one workgroup per
// 16×16 tile, PIXELS pixels per invocation (tile_pixel).
// The tile's Gaussians (front to back) are loaded into shared memory a batch at a time; every
// pixel blends them in order and stops before its transmittance would fall under t_min. Mirrors src/reference/raster.rs.
//
// EXTRA > 0 (SpacetimeGaussians' full model): every Gaussian also carries EXTRA feature channels
// (binding 7, `features[g·EXTRA + c]`), blended with the same weights as the colour over a zero
// background into `feature_image[pix·EXTRA + c]` (binding 8). The blend weights depend on the
// geometry only, so the extra channels are the colour blend applied to other values.
// DECODE = 1 (with EXTRA = 6; frames that are displayed, not trained on): the epilogue runs the
// full model's decoder (decoder.glsl) on each pixel's blended base colour and features and
// writes the decoded RGB to `image` instead of writing the two images for a separate decoder
// pass, as the official code's test-time rasterizer does: the 6 channels a pixel never
// leave registers, which saves writing and reading them back (24 bytes a pixel each way).
//
// Why several pixels per invocation: on a CPU driver (lavapipe) a subgroup is one SIMD loop
// iteration and `if` only masks lanes, so the shared loads and the loop overhead per splat are
// paid per subgroup; PIXELS = 8 shares them between 8 pixels. GPUs use PIXELS = 1.
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
layout(constant_id = 0) const uint WG_SIZE = 256;  // must be 256 / PIXELS
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;  // must divide WG_SIZE
layout(constant_id = 2) const uint PIXELS = 1;     // 1, 2, 4 or 8
layout(constant_id = 3) const uint EXTRA = 0;      // feature channels beyond the colour
layout(constant_id = 4) const uint DECODE = 0;     // 1: decode in the epilogue (EXTRA = 6)
// Array sizes (an array cannot be empty; EXTRA = 0 never reads them).
const uint EXTRA_N = EXTRA > 0u ? EXTRA : 1u;
layout(local_size_x_id = 0) in;
#include "camera.glsl"
#include "projected.glsl"
#include "splat_reach.glsl"
#include "subgroup_pixels.glsl"
#include "decoder.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Splats { ProjectedSplat splats[]; };
layout(std430, set = 0, binding = 1) readonly buffer Ids { uint sorted_ids[]; };
layout(std430, set = 0, binding = 2) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 3) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 5) writeonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 6) writeonly buffer LastIndex { uint last_index[]; };
layout(std430, set = 0, binding = 7) readonly buffer Features { float features[]; };
layout(std430, set = 0, binding = 8) writeonly buffer FeatureImage { float feature_image[]; };
layout(std430, set = 0, binding = 9) readonly buffer DecoderWeights { float dec_w[]; };
layout(push_constant) uniform Push {
    RenderConstants rc;
    uint camera_index;
    float bg_r, bg_g, bg_b;
    // The first tile of the band of tile rows this dispatch draws (0: the whole frame; frames
    // whose pairs pass one storage binding are drawn band by band).
    uint tile_offset;
};
#include "decoder_forward.glsl"


shared vec4 s_mean_opacity[WG_SIZE];  // mean x, mean y, opacity, unused
shared vec4 s_conic[WG_SIZE];         // a, b, c, power below which alpha < alpha_min
shared vec4 s_rgb[WG_SIZE];           // r, g, b, splat_q_cut
shared vec2 s_reach[WG_SIZE];         // splat_reach
// Splats per batch: at most one per invocation, every subgroup's list must fit in s_list, and
// the batch's extra channels in FEAT_FLOATS (at one pixel an invocation, 48 channels for 256
// splats would take 48 KB, past the 32 KB many devices allow).
const uint LIST_SLOTS = 2048u;
const uint FEAT_FLOATS = 2048u;
const uint NUM_SG = WG_SIZE / SUBGROUP_SIZE;
const uint BATCH_BY_LIST = WG_SIZE < LIST_SLOTS / NUM_SG ? WG_SIZE : LIST_SLOTS / NUM_SG;
const uint BATCH = BATCH_BY_LIST < FEAT_FLOATS / EXTRA_N ? BATCH_BY_LIST : FEAT_FLOATS / EXTRA_N;
shared float s_feat[BATCH * EXTRA_N];  // [i · EXTRA + c]: the extra channels
// [subgroup · BATCH + i]: the batch entries that may touch the subgroup's pixels, in order.
shared uint s_list[LIST_SLOTS];
shared uint s_done;

// Per-pixel state of the invocation's pixels (module scope so that blend() can update it; the
// loops over k are unrolled, so these stay in registers).
vec2 centre[PIXELS];
float T[PIXELS];
vec3 color[PIXELS];
float feat[PIXELS][EXTRA_N];
uint last[PIXELS];
bool done[PIXELS];

// Blends a splat of the batch (mean, opacity; conic, power cutoff; colour; extra channels) into the
// invocation's pixels that are not done; `index` is its entry in the tile's list + 1. Returns
// whether all the invocation's pixels are done. Branch-free per pixel: a pixel the splat does
// not reach gets weight 0 and keeps T and last (CPU drivers mask every `if`, and each masked
// assignment costs a blend).
bool blend(vec4 mo, vec4 cn, vec3 rgb, float f[EXTRA_N], uint index, bool smooth_mode) {
    bool all = true;
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        vec2 d = mo.xy - centre[k];
        float power = -0.5 * (cn.x * d.x * d.x + cn.z * d.y * d.y) - cn.y * d.x * d.y;
        float alpha = mo.z * exp(power);
        if (!smooth_mode) alpha = min(alpha, rc.alpha_max);  // bounds 1/(1 − alpha) backward
        // power > 0 only happens through rounding for a positive definite conic; a power
        // below the cutoff gives alpha < alpha_min (the exact test follows).
        bool hit = !done[k] && power <= 0.0 && power >= cn.w
                   && (smooth_mode || alpha >= rc.alpha_min);
        float next_t = T[k] * (1.0 - alpha);
        bool stop = hit && !smooth_mode && next_t < rc.t_min;
        bool take = hit && !stop;
        float w = take ? alpha * T[k] : 0.0;
        color[k] += rgb * w;
        [[unroll]] for (uint c = 0u; c < EXTRA; c++) feat[k][c] += f[c] * w;
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

    bool all_done = true;
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        uint q = tile_pixel(li, k);
        uint px = (tile % tiles_x) * 16u + q % 16u, py = (tile / tiles_x) * 16u + q / 16u;
        centre[k] = vec2(float(px) + 0.5, float(py) + 0.5);
        T[k] = 1.0;
        color[k] = vec3(0.0);
        [[unroll]] for (uint c = 0u; c < EXTRA; c++) feat[k][c] = 0.0;
        last[k] = 0u;
        done[k] = !(px < cam.size.x && py < cam.size.y);
        all_done = all_done && done[k];
    }

    vec2 c_lo, c_hi;
    subgroup_pixel_box(centre, c_lo, c_hi);
    bool smooth_mode = (rc.flags & 1u) != 0u;

    uvec2 range = ranges[tile];
    for (uint base = range.x; base < range.y; base += BATCH) {
        // Stop loading once every pixel of the tile is done (the count is workgroup-uniform).
        if (li == 0u) s_done = 0u;
        barrier();
        if (all_done) atomicAdd(s_done, 1u);
        uint k = base + li;
        if (li < BATCH && k < range.y) {
            uint g = sorted_ids[k];
            ProjectedSplat p = splats[g];
            [[unroll]] for (uint c = 0u; c < EXTRA; c++) s_feat[li * EXTRA + c] = features[g * EXTRA + c];
            s_mean_opacity[li] = vec4(p.mean_x, p.mean_y, p.opacity, 0.0);
            // A power this far below ln(alpha_min / opacity) gives alpha < alpha_min with room
            // for rounding, so the pixel can skip exp(); the exact test still follows.
            float cutoff = !smooth_mode ? log(rc.alpha_min / p.opacity) - 1e-3 : -1e30;
            s_conic[li] = vec4(p.conic_a, p.conic_b, p.conic_c, cutoff);
            float q_cut = splat_q_cut(p.opacity, rc.alpha_min, smooth_mode);
            s_rgb[li] = vec4(p.r, p.g, p.b, q_cut);
            s_reach[li] = splat_reach(p.opacity, vec3(p.conic_a, p.conic_b, p.conic_c),
                                      rc.alpha_min, smooth_mode);
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
            bool meets = false;
            if (j < batch) {
                vec2 mean = s_mean_opacity[j].xy;
                meets = reach_meets(mean, s_reach[j], c_lo, c_hi) &&
                        ellipse_meets(mean, s_conic[j].xyz, s_rgb[j].w, c_lo, c_hi);
            }
            uvec4 ballot = subgroupBallot(meets);
            if (meets) s_list[list_base + n_list + subgroupBallotExclusiveBitCount(ballot)] = j;
            n_list += subgroupBallotBitCount(ballot);
        }
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        if (PIXELS > 1u && HAS_SHUFFLE != 0u) {
            // CPU drivers, where a shared-memory load is a loop over the lanes whatever the
            // number of active lanes: lane l loads the chunk's entry l (the last entry again past
            // the list's end) and every lane takes each entry's values from its lane by
            // shuffles. The loops stay uniform over the subgroup (a shuffle must not read an
            // invocation that left), and done pixels change nothing in blend().
            for (uint i0 = 0u; !subgroupAll(all_done) && i0 < n_list; i0 += SUBGROUP_SIZE) {
                uint mine = s_list[list_base + min(i0 + gl_SubgroupInvocationID, n_list - 1u)];
                vec4 l_mo = vec4(s_mean_opacity[mine].xyz, uintBitsToFloat(mine));
                vec4 l_cn = s_conic[mine];
                vec3 l_rgb = s_rgb[mine].rgb;
                float l_f[EXTRA_N];
                [[unroll]] for (uint c = 0u; c < EXTRA; c++) l_f[c] = s_feat[mine * EXTRA + c];
                uint n_chunk = min(SUBGROUP_SIZE, n_list - i0);
                for (uint ii = 0u; !subgroupAll(all_done) && ii < n_chunk; ii++) {
                    vec4 mo = SHUFFLE(l_mo, ii);
                    uint j = floatBitsToUint(mo.w);
                    float f[EXTRA_N];
                    [[unroll]] for (uint c = 0u; c < EXTRA; c++) f[c] = SHUFFLE(l_f[c], ii);
                    all_done = blend(mo, SHUFFLE(l_cn, ii), SHUFFLE(l_rgb, ii), f,
                                     base - range.x + j + 1u, smooth_mode);
                }
            }
        } else {
            for (uint i = 0u; !all_done && i < n_list; i++) {
                uint j = s_list[list_base + i];
                float f[EXTRA_N];
                [[unroll]] for (uint c = 0u; c < EXTRA; c++) f[c] = s_feat[j * EXTRA + c];
                all_done = blend(s_mean_opacity[j], s_conic[j], s_rgb[j].rgb, f,
                                 base - range.x + j + 1u, smooth_mode);
            }
        }
        barrier();
    }
    vec3 out_rgb[PIXELS];
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) out_rgb[k] = color[k] + T[k] * vec3(bg_r, bg_g, bg_b);
    if (DECODE != 0u) {
        // Pixels past the image are decoded too (uniform work) and not written.
        float x[PIXELS][DEC_INPUTS];
        [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
            uint q = tile_pixel(li, k);
            uint px = (tile % tiles_x) * 16u + q % 16u, py = (tile / tiles_x) * 16u + q / 16u;
            // EXTRA = DEC_FEATURES here (the host builds DECODE only so); min() keeps the index
            // inside feat[][EXTRA_N] for the specialisations that never run this branch.
            [[unroll]] for (uint c = 0u; c < DEC_FEATURES; c++) x[k][c] = feat[k][min(c, EXTRA_N - 1u)];
            decoder_view_inputs(x[k], cam, px, py);
        }
        vec3 base[PIXELS];
        [[unroll]] for (uint k = 0u; k < PIXELS; k++) base[k] = out_rgb[k];
        decode_pixels(x, base, out_rgb);
    }
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        uint q = tile_pixel(li, k);
        uint px = (tile % tiles_x) * 16u + q % 16u, py = (tile / tiles_x) * 16u + q / 16u;
        if (px < cam.size.x && py < cam.size.y) {
            uint pix = py * cam.size.x + px;
            image[3u * pix] = out_rgb[k].r;
            image[3u * pix + 1u] = out_rgb[k].g;
            image[3u * pix + 2u] = out_rgb[k].b;
            if (DECODE == 0u) {
                [[unroll]] for (uint c = 0u; c < EXTRA; c++) feature_image[EXTRA * pix + c] = feat[k][c];
            }
            final_t[pix] = T[k];
            last_index[pix] = last[k];
        }
    }
}
