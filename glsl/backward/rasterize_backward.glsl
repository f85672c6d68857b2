// Rasterizer backward (shared body of rasterize_backward.comp and rasterize_backward_cas.comp).
//
// One workgroup per 16×16 tile; each invocation owns PIXELS pixels of it (tile_pixel). Every
// pixel walks its tile's sorted list back to front, from its `last_index` (the forward's last
// contributor + 1) down to entry 0, so all pixels of the workgroup visit the same splat at the
// same time: the splats are staged in shared memory a batch at a time, and each subgroup visits
// those whose reach meets its pixels. Per splat, an invocation sums the gradients of its pixels
// (visit), and the subgroup's sums reach global memory one of two ways (SUBGROUP_ATOMICS,
// below).
//
// Why several pixels per invocation: on a CPU driver (lavapipe) a subgroup is one SIMD loop
// iteration and `if` only masks lanes, so the per-splat reduction, loads and atomics cost the
// same whether a pixel was hit or not; PIXELS = 8 divides that fixed cost by 8. GPUs use
// PIXELS = 1 (one invocation per pixel, the usual occupancy).
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
// With COUNT_PIXELS (specialisation constant 4) the pass also counts, per splat, the pixels it
// contributed to (those past the alpha test and in front of the pixel's last contributor: the
// forward's blended set), added to pixel_count[g] (binding 8, zeroed by the caller): Pixel-GS's
// n_v(i). The count rides in the shared sums as a tenth float (exact: at most 256 per tile).
//
// With ABS_GRAD (specialisation constant 6) the pass also sums, per splat, the absolute values
// of every pixel's mean-gradient terms in NDC units, Σ_pixels |dL/dx_p|·W/2 + |dL/dy_p|·H/2
// (Gaussian Opacity Fields' densification statistic, which Mip-Splatting's official code
// uses), added to abs_grad[g] (binding 12, zeroed by the caller). The sum of signed terms can
// cancel where a Gaussian straddles an edge; the absolute sum cannot. It rides in the shared
// sums after the pixel count.
//
// With EXTRA > 0 (specialisation constant 5; SpacetimeGaussians' full model) every splat also
// carries EXTRA feature channels (binding 9, features[g·EXTRA + c]) blended over a zero
// background like the colour (render/rasterize.comp); dL/d(feature image) is binding 10 and the
// features' gradients are added to g_features[g·EXTRA + c] (binding 11, zeroed by the caller).
// The channels enter dL/dalpha exactly as the colour does, minus a background term.
//
// HAS_FLOAT_ATOMICS (a #define of the including file) says whether the SPIR-V may declare
// the float atomic-add capability; USE_FLOAT_ATOMICS (specialisation constant 2) picks the
// float atomicAdd (1) or a compare-and-swap loop on the bits (0) at pipeline creation.

#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_vote : require
#extension GL_KHR_shader_subgroup_ballot : require
#if HAS_SHUFFLE
#extension GL_KHR_shader_subgroup_shuffle : require
#endif

#extension GL_EXT_control_flow_attributes : require

layout(constant_id = 0) const uint WG_SIZE = 256;  // must be TILE·TILE / PIXELS
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;
layout(constant_id = 2) const uint USE_FLOAT_ATOMICS = 0;
layout(constant_id = 3) const uint PIXELS = 1;  // pixels per invocation: 1, 2, 4, 8 or 16
layout(constant_id = 4) const uint COUNT_PIXELS = 0;  // 1: count contributing pixels per splat
layout(constant_id = 5) const uint EXTRA = 0;  // feature channels beyond the colour
layout(constant_id = 6) const uint ABS_GRAD = 0;  // 1: sum |mean-gradient terms| per splat
const uint EXTRA_N = EXTRA > 0u ? EXTRA : 1u;  // array sizes (EXTRA = 0 never reads them)
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"
#include "splat_reach.glsl"
#include "subgroup_pixels.glsl"

const uint TILE = 16u;
const uint GRAD2D_STRIDE = 9u;
// Floats per (splat, subgroup) in the shared sums: the gradients, the pixel count, the
// absolute-gradient sum, the extra channels' gradients.
const uint ACC_ABS = GRAD2D_STRIDE + COUNT_PIXELS;
const uint ACC_EXTRA = ACC_ABS + ABS_GRAD;
const uint ACC_STRIDE = ACC_EXTRA + EXTRA;

layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Splats { ProjectedSplat splats[]; };
layout(std430, set = 0, binding = 2) readonly buffer TileRanges { uvec2 tile_ranges[]; };
layout(std430, set = 0, binding = 3) readonly buffer SortedIds { uint sorted_ids[]; };
layout(std430, set = 0, binding = 4) readonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 5) readonly buffer LastIndex { uint last_index[]; };
layout(std430, set = 0, binding = 6) readonly buffer DlDImage { float dl_dimage[]; };
layout(std430, set = 0, binding = 7) buffer Grad2dBits { uint grad2d_bits[]; };
layout(std430, set = 0, binding = 8) buffer PixelCount { uint pixel_count[]; };
layout(std430, set = 0, binding = 9) readonly buffer Features { float features[]; };
layout(std430, set = 0, binding = 10) readonly buffer DlDFeatures { float dl_dfeature_image[]; };
layout(std430, set = 0, binding = 11) buffer GFeaturesBits { uint g_features_bits[]; };
layout(std430, set = 0, binding = 12) buffer AbsGradBits { uint abs_grad_bits[]; };
#if HAS_FLOAT_ATOMICS
// The same bindings seen as floats, for the native float atomicAdd.
layout(std430, set = 0, binding = 7) buffer Grad2dFloat { float grad2d_f[]; };
layout(std430, set = 0, binding = 11) buffer GFeaturesFloat { float g_features_f[]; };
layout(std430, set = 0, binding = 12) buffer AbsGradFloat { float abs_grad_f[]; };
#endif

layout(push_constant) uniform Push {
    RenderConstants rc;
    vec4 background;  // xyz used
    uint camera_index;
} pc;

// Adds v to FLOATS[idx] (seen as BITS[idx] for the compare-and-swap path): the native float
// atomicAdd where the device has it and USE_FLOAT_ATOMICS asks for it, else a lock-free loop
// (every failed exchange means another invocation's add succeeded, so it never waits on a
// workgroup that might not be scheduled). One definition for the three outputs below.
#if HAS_FLOAT_ATOMICS
#define FLOAT_ATOMIC_ADD(FLOATS, BITS, idx, v)                                        \
    if (USE_FLOAT_ATOMICS != 0u) {                                                    \
        atomicAdd(FLOATS[idx], v);                                                    \
        return;                                                                       \
    }                                                                                 \
    CAS_ADD(BITS, idx, v)
#else
#define FLOAT_ATOMIC_ADD(FLOATS, BITS, idx, v) CAS_ADD(BITS, idx, v)
#endif
#define CAS_ADD(BITS, idx, v)                                                         \
    uint old = BITS[idx];                                                             \
    for (;;) {                                                                        \
        uint assumed = old;                                                           \
        old = atomicCompSwap(BITS[idx], assumed,                                      \
                             floatBitsToUint(uintBitsToFloat(assumed) + v));          \
        if (old == assumed) break;                                                    \
    }

void atomic_add_float(uint idx, float v) { FLOAT_ATOMIC_ADD(grad2d_f, grad2d_bits, idx, v) }
void atomic_add_feature(uint idx, float v) {
    FLOAT_ATOMIC_ADD(g_features_f, g_features_bits, idx, v)
}
void atomic_add_abs(uint idx, float v) { FLOAT_ATOMIC_ADD(abs_grad_f, abs_grad_bits, idx, v) }

// Two ways to sum a splat's gradients over the tile (specialisation constant 7, SUBGROUP_ATOMICS):
// - 0 (GPUs): each subgroup sums its partial values into shared memory (s_acc), a few splats
//   at a time through one transposing butterfly (visit_group; one subgroupAdd a slot without
//   the shuffles), and after the batch one invocation per (splat, slot) adds the subgroups'
//   sums to global memory: one set of atomics per (tile, splat) pair.
// - 1 (CPU drivers, where a shared-memory access, a reduction or an atomic is a loop over the
//   subgroup's lanes whatever the number of active lanes): each subgroup reduces its sums with
//   a transposing butterfly (subgroup_sums.glsl) and adds them to global memory itself, one
//   slot per lane; the splats of its list are loaded one per lane, SUBGROUP_SIZE at a time, and
//   handed to every lane by shuffles. Per (subgroup, splat) that is 11 shuffles, 7 + 1
//   reductions and two atomic instructions instead of 12 per-lane loads, 9 reductions, 9
//   stores and a share of the zeroing and summing of s_acc (lavapipe, 2 cores, training
//   lund_door at 162×242: 33.8 → 17 ms an iteration; tnt_truck at 245×137: 118 → 60 ms; with
//   the branch-free visit() below, 13.1 and 43 ms).
layout(constant_id = 7) const uint SUBGROUP_ATOMICS = 0;

// Splats per batch. With shared sums, every invocation stages one, and the per-subgroup sums
// of a batch must fit in s_acc (ACC_FLOATS / (subgroups · ACC_STRIDE) splats); without them,
// every invocation stages up to STAGE_ROUNDS (fewer barriers, each a switch between subgroups
// on CPU drivers), as many as fit in STAGE_FLOATS floats of shared memory: a staged splat
// takes 13 + EXTRA floats and a list slot per subgroup (at 48 feature channels and 8 pixels
// an invocation four rounds would need 33 KB, past the 32 KB many devices allow).
const uint ACC_FLOATS = SUBGROUP_ATOMICS != 0u ? 1u : 4608u;
const uint NUM_SG = WG_SIZE / SUBGROUP_SIZE;
const uint BATCH_BY_ACC = ACC_FLOATS / (NUM_SG * ACC_STRIDE);
const uint STAGE_ROUNDS = 4u;
const uint STAGE_FLOATS = 6144u;
const uint BATCH_BY_STAGE = STAGE_FLOATS / (13u + EXTRA + NUM_SG);
const uint BATCH = SUBGROUP_ATOMICS != 0u
                   ? (WG_SIZE * STAGE_ROUNDS < BATCH_BY_STAGE ? WG_SIZE * STAGE_ROUNDS
                                                              : BATCH_BY_STAGE)
                   : (WG_SIZE < BATCH_BY_ACC ? WG_SIZE : BATCH_BY_ACC);


shared uint s_max_last;
shared uint s_id[BATCH];
shared vec4 s_mean_opacity[BATCH];  // mean_x, mean_y, opacity, half width of the reach
shared vec4 s_conic[BATCH];         // a, b, c, half height of the reach
shared vec4 s_rgb[BATCH];           // r, g, b, splat_q_cut
shared float s_feat[BATCH * EXTRA_N];  // [i · EXTRA + c]: the extra channels
// [(splat in batch · NUM_SG + subgroup) · ACC_STRIDE + k]: the subgroup's sums (shared sums
// only).
shared float s_acc[ACC_FLOATS];
// [subgroup · BATCH + i]: the batch entries that may touch the subgroup's pixels, in order.
shared uint s_list[BATCH * NUM_SG];

// Per-pixel state of the invocation's pixels (module scope so that visit() can update it; the
// loops over k are unrolled, so these stay in registers).
vec2 centre[PIXELS];
uint last[PIXELS];
float t[PIXELS];  // transmittance in front of the current splat
vec3 dl_dc[PIXELS];
float dl_df[PIXELS][EXTRA_N];
// t_final · (background · dL/dC): the background's share of dL/dalpha per unit of 1/(1 − alpha).
float tf_bg[PIXELS];
// (What lies behind the current splat) · dL/d(pixel), over the colour and the extra channels,
// per unit of the transmittance in front of it (background excluded: it enters through
// tf_bg). The colour behind enters the gradients only through this product, so one float a
// pixel carries it, updated after each splat.
float behind_dot[PIXELS];

// Slots of one invocation's partial sums of a splat, in s_acc's order: the gradients, the
// pixel count, the absolute-gradient sum, the extra channels' gradients. ACC_STRIDE ≤
// PART_MAX (the host refuses more feature channels).
const uint PART_MAX = 64u;

// The invocation's partial sums for the splat (mean, opacity, conic, colour, extra channels f;
// e its entry in the tile's list), updating the pixels' transmittance and what lies behind.
//
// Branch-free per pixel: a skipped pixel (see the skips below) gets alpha = 0 and q = 0, which
// leave t, behind_dot and every sum exactly as they were (x·1, x + 0), so no lane masks are
// needed (each masked assignment is a blend on CPU drivers). The mean and conic gradients are
// linear in q = gauss · dL/dalpha (dL/dpower = opacity · q): the pixels sum q times dx, dy,
// dx², dx·dy, dy², and the splat's constants multiply the sums once.
//
// Returns whether any of the invocation's pixels took part: when none did, every sum is an
// exact zero.
bool visit(vec4 mo, vec3 conic, vec3 rgb, float f[EXTRA_N], uint e, vec2 ndc, bool smooth_mode,
           out float part[PART_MAX]) {
    vec3 g_rgb = vec3(0.0);
    float g_q = 0.0;  // Σ q: dL/d(opacity)
    vec2 s_d = vec2(0.0);  // Σ q·(dx, dy)
    vec3 s_dd = vec3(0.0);  // Σ q·(dx², dx·dy, dy²)
    float n_pixels = 0.0;
    vec2 s_abs = vec2(0.0);  // Σ |q·(conic · d)| per axis
    float g_feat[EXTRA_N];
    [[unroll]] for (uint c = 0u; c < EXTRA; c++) g_feat[c] = 0.0;
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        vec2 d = mo.xy - centre[k];
        vec3 dd = vec3(d.x * d.x, d.x * d.y, d.y * d.y);
        float power = -0.5 * (conic.x * dd.x + conic.z * dd.z) - conic.y * dd.y;
        float gauss = exp(power);
        float raw = mo.z * gauss;
        // Clamp 2: alpha = min(alpha_max, raw); when active it passes no gradient to
        // opacity, conic or mean (not in smooth mode).
        bool clamped = !smooth_mode && raw > pc.rc.alpha_max;
        // Skip 1: entries at or past the pixel's last_index did not reach it.
        // Skip 2: power > 0 cannot happen for a positive definite conic; the forward skips it
        // as a rounding guard, so do we.
        // Skip 3: alpha < alpha_min contributed nothing (not in smooth mode).
        bool skip = e >= last[k] || power > 0.0 || (!smooth_mode && raw < pc.rc.alpha_min);
        float alpha = skip ? 0.0 : (clamped ? pc.rc.alpha_max : raw);
        n_pixels += skip ? 0.0 : 1.0;
        // One division per pixel and splat (divisions are slow on CPUs).
        float inv_one_minus = 1.0 / (1.0 - alpha);
        t[k] *= inv_one_minus;
        float at = alpha * t[k];
        g_rgb += at * dl_dc[k];
        float front = dot(rgb, dl_dc[k]);
        [[unroll]] for (uint c = 0u; c < EXTRA; c++) {
            g_feat[c] += at * dl_df[k][c];
            front += f[c] * dl_df[k][c];
        }
        float diff = front - behind_dot[k];
        float dl_dalpha = t[k] * diff - inv_one_minus * tf_bg[k];
        // Behind the next splat in front: this one over what was behind it.
        behind_dot[k] += alpha * diff;
        float q = (skip || clamped) ? 0.0 : gauss * dl_dalpha;
        g_q += q;
        s_d += q * d;
        s_dd += q * dd;
        if (ABS_GRAD != 0u) {
            s_abs += abs(q * vec2(conic.x * d.x + conic.y * d.y, conic.z * d.y + conic.y * d.x));
        }
    }
    // dL/dpower = opacity · q; dpower/dmean = −(a·dx + b·dy, c·dy + b·dx);
    // dpower/d(a, b, c) = (−½dx², −dx·dy, −½dy²).
    vec2 g_mean = -mo.z * vec2(conic.x * s_d.x + conic.y * s_d.y,
                               conic.z * s_d.y + conic.y * s_d.x);
    vec3 g_conic = -mo.z * vec3(0.5 * s_dd.x, s_dd.y, 0.5 * s_dd.z);
    part[0] = g_mean.x;
    part[1] = g_mean.y;
    part[2] = g_conic.x;
    part[3] = g_conic.y;
    part[4] = g_conic.z;
    part[5] = g_rgb.x;
    part[6] = g_rgb.y;
    part[7] = g_rgb.z;
    part[8] = g_q;
    if (COUNT_PIXELS != 0u) part[GRAD2D_STRIDE] = n_pixels;
    if (ABS_GRAD != 0u) part[ACC_ABS] = mo.z * dot(s_abs, ndc);
    [[unroll]] for (uint c = 0u; c < EXTRA; c++) part[ACC_EXTRA + c] = g_feat[c];
    return n_pixels > 0.0;
}

// Adds v, the subgroup's sum of slot `slot` for Gaussian g, to its output (zeros add nothing).
void add_slot(uint g, uint slot, float v) {
    if (v == 0.0) return;
    if (slot < GRAD2D_STRIDE) {
        atomic_add_float(g * GRAD2D_STRIDE + slot, v);
    } else if (COUNT_PIXELS != 0u && slot == GRAD2D_STRIDE) {
        atomicAdd(pixel_count[g], uint(v));  // exact: at most 256 a tile
    } else if (ABS_GRAD != 0u && slot == ACC_ABS) {
        atomic_add_abs(g, v);
    } else if (EXTRA != 0u && slot >= ACC_EXTRA) {
        atomic_add_feature(g * EXTRA + slot - ACC_EXTRA, v);
    }
}

#if HAS_SHUFFLE
// Σ over the subgroup of each slot of a splat's partial sums, straight into global memory.
#define SUMS_SLOTS ACC_STRIDE
#define SUMS_PART_MAX PART_MAX
#include "subgroup_sums.glsl"

// The shared-sums path (SUBGROUP_ATOMICS = 0, GPUs) sums GROUP consecutive listed splats with
// one transposing butterfly (subgroup_sums.glsl's TRANSPOSE_LEVEL) over their GROUP · ACC_STRIDE
// slots, in chunks of SUBGROUP_SIZE: at subgroups of 32 and 9 slots, three splats' 27 slots take
// 31 shuffles where nine reductions a splat took 45 each (135), and lane l then stores slot l
// to s_acc with one store instruction instead of three elected lanes storing nine floats each.
// GROUP fills about 32 slots whatever the subgroup size (at lavapipe's 8 the same three splats
// in four chunks, so the GPU's grouping is what the tests run there); at least one splat.
const uint GROUP_TARGET = SUBGROUP_SIZE > 32u ? SUBGROUP_SIZE : 32u;
const uint GROUP = GROUP_TARGET / ACC_STRIDE > 0u ? GROUP_TARGET / ACC_STRIDE : 1u;
const uint GROUP_SLOTS = GROUP * ACC_STRIDE;
const uint GROUP_CHUNKS = (GROUP_SLOTS + SUBGROUP_SIZE - 1u) / SUBGROUP_SIZE;

// The subgroup's sum of slot ch · SUBGROUP_SIZE + l of a group's slots, in lane l (zero past
// GROUP_SLOTS, and everywhere when `any` is false: every slot is then an exact zero, so the
// butterfly is skipped as the per-splat path skips its reductions). Call it with the whole
// subgroup active.
float group_chunk_sum(float grp[GROUP_SLOTS], uint ch, bool any) {
    if (!any) return 0.0;
    uint lane = gl_SubgroupInvocationID;
    float v[SUMS_MAX_SUBGROUP];
    [[unroll]] for (uint i = 0u; i < SUBGROUP_SIZE; i++) {
        uint slot = ch * SUBGROUP_SIZE + i;
        v[i] = slot < GROUP_SLOTS ? grp[min(slot, GROUP_SLOTS - 1u)] : 0.0;
    }
    TRANSPOSE_ALL
    return v[0];
}

// Shared sums: visits the listed entries i0 .. i0 + GROUP − 1 of the subgroup's list (those
// below n_list) and stores the subgroup's sums of each into s_acc, lane l the chunk's slot l
// (slot c of the group's splat m). Call it with the whole subgroup active (i0 and n_list
// uniform).
void visit_group(uint i0, uint n_list, uint list_base, uint done, uint max_last, vec2 ndc,
                 bool smooth_mode) {
    float grp[GROUP_SLOTS];
    bool hit = false;
    [[unroll]] for (uint m = 0u; m < GROUP; m++) {
        float part[PART_MAX];
        if (i0 + m < n_list) {
            uint j = s_list[list_base + i0 + m];
            uint e = max_last - 1u - (done + j);
            float f[EXTRA_N];
            [[unroll]] for (uint c = 0u; c < EXTRA; c++) f[c] = s_feat[j * EXTRA + c];
            bool h = visit(s_mean_opacity[j], s_conic[j].xyz, s_rgb[j].xyz, f, e, ndc,
                           smooth_mode, part);
            hit = hit || h;
        } else {
            [[unroll]] for (uint c = 0u; c < ACC_STRIDE; c++) part[c] = 0.0;
        }
        [[unroll]] for (uint c = 0u; c < ACC_STRIDE; c++) grp[m * ACC_STRIDE + c] = part[c];
    }
    bool any = subgroupAny(hit);
    [[unroll]] for (uint ch = 0u; ch < GROUP_CHUNKS; ch++) {
        float sum = group_chunk_sum(grp, ch, any);
        uint slot = ch * SUBGROUP_SIZE + gl_SubgroupInvocationID;
        uint m = slot / ACC_STRIDE;
        if (slot < GROUP_SLOTS && i0 + m < n_list) {
            uint j = s_list[list_base + i0 + m];
            s_acc[(j * NUM_SG + gl_SubgroupID) * ACC_STRIDE + slot % ACC_STRIDE] = sum;
        }
    }
}
#endif

void main() {
    Camera cam = cameras[pc.camera_index];
    uint width = cam.size.x, height = cam.size.y, tiles_x = cam.size.z, tiles_y = cam.size.w;
    uint tile = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    // Uniform over the workgroup: spare groups of the dispatch leave together.
    if (tile >= tiles_x * tiles_y) return;

    uint li = gl_LocalInvocationIndex;
    uvec2 range = tile_ranges[tile];
    uint list_len = range.y > range.x ? range.y - range.x : 0u;
    bool smooth_mode = (pc.rc.flags & 1u) != 0u;

    uint my_max_last = 0u;
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        uint q = tile_pixel(li, k);
        uint px = (tile % tiles_x) * TILE + q % TILE;
        uint py = (tile / tiles_x) * TILE + q / TILE;
        bool inside = px < width && py < height;
        uint pix = py * width + px;
        centre[k] = vec2(float(px) + 0.5, float(py) + 0.5);
        // A last_index past the tile's list would read other tiles' entries: clamp (bad input).
        last[k] = inside ? min(last_index[pix], list_len) : 0u;
        float tf = inside ? final_t[pix] : 1.0;
        dl_dc[k] = inside ? vec3(dl_dimage[3u * pix], dl_dimage[3u * pix + 1u],
                                 dl_dimage[3u * pix + 2u])
                          : vec3(0.0);
        tf_bg[k] = tf * dot(pc.background.xyz, dl_dc[k]);
        t[k] = tf;
        behind_dot[k] = 0.0;
        [[unroll]] for (uint c = 0u; c < EXTRA; c++) {
            dl_df[k][c] = inside ? dl_dfeature_image[EXTRA * pix + c] : 0.0;
        }
        my_max_last = max(my_max_last, last[k]);
    }

    if (li == 0u) s_max_last = 0u;
    barrier();
    // Entries at or past the subgroup's largest last_index touch none of its pixels: the
    // subgroup starts each batch after them (a loop bound, which skips work even where `if`
    // only masks lanes).
    uint sg_max_last = subgroupMax(my_max_last);
    vec2 c_lo, c_hi;
    subgroup_pixel_box(centre, c_lo, c_hi);
    atomicMax(s_max_last, sg_max_last);
    barrier();
    uint max_last = s_max_last;
    // NDC units of a pixel-space mean gradient (as preprocess_backward's view_grad_norm).
    vec2 ndc = 0.5 * vec2(float(width), float(height));
    uint lane = gl_SubgroupInvocationID;

    for (uint done = 0u; done < max_last; done += BATCH) {
        uint batch = min(BATCH, max_last - done);
        barrier();  // the previous batch (splats and sums) has been consumed by every invocation
        for (uint i = li; i < batch; i += WG_SIZE) {
            uint e = max_last - 1u - (done + i);
            uint g = sorted_ids[range.x + e];
            ProjectedSplat p = splats[g];
            s_id[i] = g;
            vec2 reach = splat_reach(p.opacity, vec3(p.conic_a, p.conic_b, p.conic_c),
                                      pc.rc.alpha_min, smooth_mode);
            s_mean_opacity[i] = vec4(p.mean_x, p.mean_y, p.opacity, reach.x);
            s_conic[i] = vec4(p.conic_a, p.conic_b, p.conic_c, reach.y);
            float q_cut = splat_q_cut(p.opacity, pc.rc.alpha_min, smooth_mode);
            s_rgb[i] = vec4(p.r, p.g, p.b, q_cut);
            [[unroll]] for (uint c = 0u; c < EXTRA; c++) s_feat[i * EXTRA + c] = features[g * EXTRA + c];
        }
        barrier();
        // Entries e >= sg_max_last (j < j_first) are skipped; with shared sums they get zeros.
        uint j_first = min(batch, max_last - done - min(sg_max_last, max_last - done));
        if (SUBGROUP_ATOMICS == 0u) {
            for (uint j = lane; j < j_first; j += gl_SubgroupSize) {
                uint a = (j * NUM_SG + gl_SubgroupID) * ACC_STRIDE;
                for (uint c = 0u; c < ACC_STRIDE; c++) s_acc[a + c] = 0.0;
            }
        }
        // Compact (in order) the entries from j_first on whose reach meets the subgroup's box;
        // with shared sums the others get zeros.
        uint list_base = gl_SubgroupID * BATCH;
        uint n_list = 0u;
        for (uint j0 = j_first; j0 < batch; j0 += gl_SubgroupSize) {
            uint j = j0 + lane;
            bool meets = false;
            if (j < batch) {
                vec4 mo = s_mean_opacity[j];
                vec2 reach = vec2(mo.w, s_conic[j].w);
                meets = reach_meets(mo.xy, reach, c_lo, c_hi) &&
                        ellipse_meets(mo.xy, s_conic[j].xyz, s_rgb[j].w, c_lo, c_hi);
            }
            uvec4 ballot = subgroupBallot(meets);
            if (meets) {
                s_list[list_base + n_list + subgroupBallotExclusiveBitCount(ballot)] = j;
            } else if (SUBGROUP_ATOMICS == 0u && j < batch) {
                uint a = (j * NUM_SG + gl_SubgroupID) * ACC_STRIDE;
                for (uint c = 0u; c < ACC_STRIDE; c++) s_acc[a + c] = 0.0;
            }
            n_list += subgroupBallotBitCount(ballot);
        }
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        float part[PART_MAX];
#if HAS_SHUFFLE
        if (SUBGROUP_ATOMICS != 0u) {
            for (uint i0 = 0u; i0 < n_list; i0 += SUBGROUP_SIZE) {
                // Lane l loads the chunk's entry l (the last entry again past the list's end);
                // every lane then takes each entry's values from its lane.
                uint mine = s_list[list_base + min(i0 + lane, n_list - 1u)];
                vec4 l_mo = vec4(s_mean_opacity[mine].xyz, uintBitsToFloat(mine));
                vec4 l_conic = vec4(s_conic[mine].xyz, uintBitsToFloat(s_id[mine]));
                vec3 l_rgb = s_rgb[mine].xyz;
                float l_f[EXTRA_N];
                [[unroll]] for (uint c = 0u; c < EXTRA; c++) l_f[c] = s_feat[mine * EXTRA + c];
                uint n_chunk = min(SUBGROUP_SIZE, n_list - i0);
                for (uint ii = 0u; ii < n_chunk; ii++) {
                    vec4 mo = subgroupShuffle(l_mo, ii);
                    vec4 conic = subgroupShuffle(l_conic, ii);
                    vec3 rgb = subgroupShuffle(l_rgb, ii);
                    float f[EXTRA_N];
                    [[unroll]] for (uint c = 0u; c < EXTRA; c++) f[c] = subgroupShuffle(l_f[c], ii);
                    uint j = floatBitsToUint(mo.w);
                    uint e = max_last - 1u - (done + j);
                    visit(mo, conic.xyz, rgb, f, e, ndc, smooth_mode, part);
                    add_sums_transposed(part, floatBitsToUint(conic.w));
                }
            }
        } else
#endif
        {
#if HAS_SHUFFLE
            for (uint i0 = 0u; i0 < n_list; i0 += GROUP) {
                visit_group(i0, n_list, list_base, done, max_last, ndc, smooth_mode);
            }
#else
            for (uint i = 0u; i < n_list; i++) {
                uint j = s_list[list_base + i];
                uint e = max_last - 1u - (done + j);
                float f[EXTRA_N];
                [[unroll]] for (uint c = 0u; c < EXTRA; c++) f[c] = s_feat[j * EXTRA + c];
                bool hit = visit(s_mean_opacity[j], s_conic[j].xyz, s_rgb[j].xyz, f, e, ndc,
                                 smooth_mode, part);
                // The box test lists splats that may still miss every pixel of the subgroup
                // (past their last contributors, or under alpha_min there): their sums are
                // zeros without the ACC_STRIDE reductions (five shuffles each at a subgroup of
                // 32), as gsplat skips a warp's reduction when no lane is valid (visit_group
                // skips its butterfly alike). Not in the per-lane-atomics path above: there the
                // vote measured slower on lavapipe (Truck -r 4, rasterize backward 76 / 86 ms →
                // 95 / 89 ms, 2026-11-27), and so did grouping its splats (lund_door -r 8,
                // 47 / 50 ms → 67 / 61 ms, 2026-11-27).
                if (subgroupAny(hit)) {
                    [[unroll]] for (uint c = 0u; c < ACC_STRIDE; c++) part[c] = subgroupAdd(part[c]);
                }
                if (subgroupElect()) {
                    uint a = (j * NUM_SG + gl_SubgroupID) * ACC_STRIDE;
                    [[unroll]] for (uint c = 0u; c < ACC_STRIDE; c++) s_acc[a + c] = part[c];
                }
            }
#endif
            barrier();
            // One invocation per (splat, slot) of the batch: the subgroups' sums of the slot,
            // then its atomic. Consecutive invocations read consecutive floats of s_acc, and
            // every invocation takes part, where one invocation per splat (64 a batch at 9
            // slots) left three quarters of the workgroup idle and read s_acc at a stride of
            // 72 floats (8 lanes to a bank).
            for (uint t = li; t < batch * ACC_STRIDE; t += WG_SIZE) {
                uint j = t / ACC_STRIDE, c = t % ACC_STRIDE;
                float sum = 0.0;
                for (uint sg = 0u; sg < NUM_SG; sg++) sum += s_acc[(j * NUM_SG + sg) * ACC_STRIDE + c];
                add_slot(s_id[j], c, sum);
            }
        }
    }
}
