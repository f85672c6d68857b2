// 2DGS rasterizer backward (shared body of rasterize_backward.comp and
// rasterize_backward_cas.comp). Mirrors src/reference/surfel/backward.rs `pixel_backward`.
//
// One workgroup per 16×16 tile; each invocation owns PIXELS pixels. Every pixel walks its
// tile's list back to front from its `last_index`, so all pixels of the workgroup visit the
// same surfel at the same time: surfels are staged in shared memory a batch at a time. Per
// surfel an invocation sums its pixels' gradients; with SUBGROUP_ATOMICS = 0 (GPUs) the
// subgroup sums those (a transposing butterfly, or subgroupAdd without shuffles) into shared
// memory, and after the batch one invocation per (surfel, slot) adds the subgroups' sums to
// global memory (18 atomics per (tile, surfel) pair at most; zero sums are not added). With SUBGROUP_ATOMICS = 1 (CPU drivers, several pixels an
// invocation) each subgroup adds its own sums through the transposing butterfly of
// subgroup_sums.glsl, and takes each surfel from the lane that loaded it by shuffles (every
// shared-memory load, reduction and atomic is a loop over the lanes there; see
// ../backward/rasterize_backward.glsl); there each subgroup also visits only the surfels
// whose reach (surfel_reach) meets the box of its pixels and that lie before the last
// contributor of one of them: the others add nothing to any of its pixels.
//
// Every output is a function of the blend weights w_i = alpha_i T_i and per-surfel values, so
// per surfel the pixel forms g = ∂L/∂w at fixed values (colour, alpha map, background, depth,
// normal, distortion with the pixel's final totals A, M1, M2 — exact, see the reference), then
// ∂L/∂alpha = T·g − (Σ_{behind} g_i w_i)/(1 − alpha), keeping that sum back to front. The
// transmittance in front is recovered as T/(1 − alpha) from the stored final T (bounded: the
// forward stops before T < t_min and alpha ≤ alpha_max).
//
// Per surfel the pixel repeats the forward's decisions (surfel_sample): skipped pairs, the
// object-space vs low-pass branch, the alpha clamp (no gradient to the kernel or opacity when
// active), the median contributor (gets the median depth's gradient). The low-pass branch's
// hit depth still depends on (u, v): its gradient goes through them (exact; the official code
// drops that part).
//
// Output: the 18 gradients of surfel g, dL/d(h1 (3), h2 (3), h3 (3), box centre (2), rgb (3),
// opacity, normal (3)), as slots 0..17, accumulated atomically (the caller zeroes them first)
// into two buffers of 9 floats a surfel (36 bytes): slots 0..8 into grad_rows[g·9 + k], slots
// 9..17 into grad_rest[g·9 + k − 9]. One buffer of 72 bytes a surfel would be the widest
// per-surfel buffer of the engine and pass a 128 MiB storage binding at 1.86 M surfels.
//
// HAS_FLOAT_ATOMICS (a #define of the including file) says whether the SPIR-V may declare the
// float atomic-add capability; USE_FLOAT_ATOMICS (specialisation constant 2) picks the float
// atomicAdd (1) or a compare-and-swap loop on the bits (0) at pipeline creation.

#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_EXT_control_flow_attributes : require
#if HAS_SHUFFLE
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_KHR_shader_subgroup_ballot : require
#endif

layout(constant_id = 0) const uint WG_SIZE = 256;  // must be 256 / PIXELS
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;
layout(constant_id = 2) const uint USE_FLOAT_ATOMICS = 0;
layout(constant_id = 3) const uint PIXELS = 1;  // 1, 2, 4, 8 or 16
// 1: per-subgroup sums straight into global memory (needs HAS_SHUFFLE); 0: through s_acc.
layout(constant_id = 4) const uint SUBGROUP_ATOMICS = 0;
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"
#include "surfel.glsl"
#include "splat_reach.glsl"
#include "subgroup_pixels.glsl"

const uint TILE = 16u;
const uint GRAD_STRIDE = 18u;  // slots a surfel
const uint GRAD_HALF = 9u;     // floats a surfel in each of grad_rows and grad_rest

layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Splats { ProjectedSplat splats[]; };
layout(std430, set = 0, binding = 2) readonly buffer Geom { float geom[]; };
layout(std430, set = 0, binding = 3) readonly buffer TileRanges { uvec2 tile_ranges[]; };
layout(std430, set = 0, binding = 4) readonly buffer SortedIds { uint sorted_ids[]; };
layout(std430, set = 0, binding = 5) readonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 6) readonly buffer LastIndex { uint last_index[]; };
layout(std430, set = 0, binding = 7) readonly buffer MedianIndex { uint median_index[]; };
layout(std430, set = 0, binding = 8) readonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 9) readonly buffer DlDImage { float dl_dimage[]; };
// Per pixel, MAP_GRADS_STRIDE floats: dL/d(alpha, depth numerator, median depth, normal (3),
// distortion), the last unused.
layout(std430, set = 0, binding = 10) readonly buffer DlDMaps { float dl_dmaps[]; };
layout(std430, set = 0, binding = 13) readonly buffer Normals { float normals[]; };
layout(std430, set = 0, binding = 11) buffer GradRowsBits { uint grad_rows_bits[]; };
layout(std430, set = 0, binding = 12) buffer GradRestBits { uint grad_rest_bits[]; };
#if HAS_FLOAT_ATOMICS
layout(std430, set = 0, binding = 11) buffer GradRowsFloat { float grad_rows_f[]; };
layout(std430, set = 0, binding = 12) buffer GradRestFloat { float grad_rest_f[]; };
#endif

layout(push_constant) uniform Push {
    SurfelConstants sc;
    vec4 background;  // xyz used
    uint camera_index;
} pc;

const uint MAP_GRADS_STRIDE = 8u;

// Adds v to grad_rest[idx] (`rest`) or grad_rows[idx].
void atomic_add_float(bool rest, uint idx, float v) {
#if HAS_FLOAT_ATOMICS
    if (USE_FLOAT_ATOMICS != 0u) {
        if (rest) {
            atomicAdd(grad_rest_f[idx], v);
        } else {
            atomicAdd(grad_rows_f[idx], v);
        }
        return;
    }
#endif
    // Lock-free: every failed exchange means another invocation's add succeeded.
    uint old = rest ? grad_rest_bits[idx] : grad_rows_bits[idx];
    for (;;) {
        uint assumed = old;
        uint sum = floatBitsToUint(uintBitsToFloat(assumed) + v);
        old = rest ? atomicCompSwap(grad_rest_bits[idx], assumed, sum)
                   : atomicCompSwap(grad_rows_bits[idx], assumed, sum);
        if (old == assumed) break;
    }
}

// Adds the subgroup's sum v of slot `slot` for surfel g (zeros add nothing).
void add_slot(uint g, uint slot, float v) {
    bool rest = slot >= GRAD_HALF;
    if (v != 0.0) atomic_add_float(rest, g * GRAD_HALF + (rest ? slot - GRAD_HALF : slot), v);
}
#if HAS_SHUFFLE
#define SUMS_SLOTS GRAD_STRIDE
#define SUMS_PART_MAX GRAD_STRIDE
#include "subgroup_sums.glsl"
#endif

// Surfels per batch: the per-subgroup sums of a batch must fit in s_acc (without them, one
// per invocation as well).
const uint ACC_FLOATS = SUBGROUP_ATOMICS != 0u ? 1u : 4608u;
const uint NUM_SG = WG_SIZE / SUBGROUP_SIZE;
const uint BATCH_BY_ACC = SUBGROUP_ATOMICS != 0u ? WG_SIZE : ACC_FLOATS / (NUM_SG * GRAD_STRIDE);
const uint BATCH = WG_SIZE < BATCH_BY_ACC ? WG_SIZE : BATCH_BY_ACC;


shared uint s_max_last;
shared uint s_id[BATCH];
shared vec4 s_h1[BATCH];  // h1, opacity
shared vec4 s_h2[BATCH];  // h2, box centre x
shared vec4 s_h3[BATCH];  // h3, box centre y
shared vec3 s_n[BATCH];
shared vec3 s_rgb[BATCH];
shared vec2 s_reach[BATCH];  // surfel_reach
// With SUBGROUP_ATOMICS: [subgroup · BATCH + i], the batch entries each subgroup visits.
shared uint s_list[SUBGROUP_ATOMICS != 0u ? NUM_SG * BATCH : 1u];
// [(surfel in batch · NUM_SG + subgroup) · GRAD_STRIDE + k]: the subgroup's sums.
shared float s_acc[ACC_FLOATS];

// Per-pixel state of the invocation's pixels (module scope so that visit() can update it; the
// loops over k are unrolled, so these stay in registers).
vec2 centre[PIXELS];
uint last[PIXELS], median_at[PIXELS];
float t[PIXELS];
vec3 dl_dc[PIXELS], dl_dn[PIXELS];
// dL/d(alpha map) + the background's −bg·dL/dC per unit weight; depth; median; distortion.
float g_const[PIXELS], dl_dd[PIXELS], dl_dmed[PIXELS], dl_ddist[PIXELS];
float total_w[PIXELS], m1[PIXELS], m2[PIXELS];
float behind[PIXELS];  // Σ over surfels behind of g_i·w_i

// One surfel (list entry e) at the invocation's pixels, back to front: updates their walk-back
// state and returns the invocation's part of the surfel's gradients (GRAD_STRIDE slots).
// Branch-free per pixel (CPU drivers run both sides of every `if`): a pixel the surfel does not
// reach gets alpha 0 and finite stand-ins for the hit (depth 1, uv 0, p₃ 1), so every term it
// adds is an exact 0 and its transmittance is multiplied by exactly 1.
void visit(SurfelConstants sc, vec4 h1, vec4 h2, vec4 h3, vec3 n, vec3 rgb, uint e,
           float dm_dz_num, out float part[GRAD_STRIDE]) {
    vec2 mc = vec2(h2.w, h3.w);
    float opacity = h1.w;
    vec3 g_h1 = vec3(0.0), g_h2 = vec3(0.0), g_h3 = vec3(0.0), g_rgb = vec3(0.0);
    vec3 g_n = vec3(0.0);
    vec2 g_m = vec2(0.0);
    float g_op = 0.0;
    [[unroll]] for (uint k = 0u; k < PIXELS; k++) {
        SurfelHit s;
        bool hit = surfel_sample(sc, h1.xyz, h2.xyz, h3.xyz, mc, opacity, centre[k], s)
                   && e < last[k];
        float alpha = hit ? s.alpha : 0.0;
        float z = hit ? s.z : 1.0;
        vec2 uv = hit ? s.uv : vec2(0.0);
        vec3 sa = hit ? s.a : vec3(0.0), sc3 = hit ? s.c : vec3(0.0);
        float pz = hit ? s.p.z : 1.0;
        float gauss = hit ? s.gauss : 0.0;
        float inv_one_minus = 1.0 / (1.0 - alpha);
        t[k] *= inv_one_minus;
        float w = alpha * t[k];
        float mz = mapped_depth(sc, z);
        float g_w = dot(dl_dc[k], rgb) + g_const[k] + dl_dd[k] * z
                    + dot(dl_dn[k], n)
                    + dl_ddist[k] * (mz * mz * total_w[k] + m2[k] - 2.0 * mz * m1[k]);
        float dl_dalpha = t[k] * g_w - behind[k] * inv_one_minus;
        behind[k] += g_w * w;
        g_rgb += w * dl_dc[k];
        g_n += w * dl_dn[k];
        float dl_dz = w * dl_dd[k]
                      + dl_ddist[k] * 2.0 * w * (mz * total_w[k] - m1[k])
                          * dm_dz_num / (z * z);
        dl_dz += hit && e + 1u == median_at[k] ? dl_dmed[k] : 0.0;
        // Clamp: an alpha clamped at alpha_max passes nothing to the kernel or opacity.
        bool kernel = hit && !s.alpha_clamped;
        bool lowpass = hit && s.lowpass;
        g_op += kernel ? gauss * dl_dalpha : 0.0;
        float dl_drho = kernel ? -0.5 * gauss * opacity * dl_dalpha : 0.0;
        g_m += lowpass ? dl_drho * 2.0 * sc.filter_inv_square * (mc - centre[k]) : vec2(0.0);
        vec2 dl_duv = lowpass ? vec2(0.0) : 2.0 * uv * dl_drho;
        // z = u h31 + v h32 + h33; (u, v) = p.xy / p.z; p = a × c.
        dl_duv += dl_dz * h3.xy;
        vec3 dl_dh3 = dl_dz * vec3(uv, 1.0);
        vec3 dl_dp = vec3(dl_duv, -dot(dl_duv, uv)) / pz;
        vec3 dl_da = cross(sc3, dl_dp);
        vec3 dl_dcc = cross(dl_dp, sa);
        dl_dh3 += centre[k].x * dl_da + centre[k].y * dl_dcc;
        g_h1 -= dl_da;
        g_h2 -= dl_dcc;
        g_h3 += dl_dh3;
    }
    part = float[GRAD_STRIDE](
        g_h1.x, g_h1.y, g_h1.z, g_h2.x, g_h2.y, g_h2.z, g_h3.x, g_h3.y, g_h3.z,
        g_m.x, g_m.y, g_rgb.x, g_rgb.y, g_rgb.z, g_op, g_n.x, g_n.y, g_n.z);
}

void main() {
    Camera cam = cameras[pc.camera_index];
    uint width = cam.size.x, height = cam.size.y, tiles_x = cam.size.z, tiles_y = cam.size.w;
    uint tile = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (tile >= tiles_x * tiles_y) return;  // uniform over the workgroup

    uint li = gl_LocalInvocationIndex;
    uvec2 range = tile_ranges[tile];
    uint list_len = range.y > range.x ? range.y - range.x : 0u;
    SurfelConstants sc = pc.sc;

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
        median_at[k] = inside ? median_index[pix] : 0u;
        t[k] = inside ? final_t[pix] : 1.0;
        total_w[k] = 1.0 - t[k];
        dl_dc[k] = vec3(0.0); dl_dn[k] = vec3(0.0);
        g_const[k] = 0.0; dl_dd[k] = 0.0; dl_dmed[k] = 0.0; dl_ddist[k] = 0.0;
        m1[k] = 0.0; m2[k] = 0.0;
        if (inside) {
            dl_dc[k] = vec3(dl_dimage[3u * pix], dl_dimage[3u * pix + 1u], dl_dimage[3u * pix + 2u]);
            uint o = MAP_GRADS_STRIDE * pix;
            g_const[k] = dl_dmaps[o] - dot(pc.background.xyz, dl_dc[k]);
            dl_dd[k] = dl_dmaps[o + 1u];
            dl_dmed[k] = dl_dmaps[o + 2u];
            dl_dn[k] = vec3(dl_dmaps[o + 3u], dl_dmaps[o + 4u], dl_dmaps[o + 5u]);
            dl_ddist[k] = dl_dmaps[o + 6u];
            m1[k] = maps[MAPS_STRIDE * pix + 6u];
            m2[k] = maps[MAPS_STRIDE * pix + 7u];
        }
        behind[k] = 0.0;
        my_max_last = max(my_max_last, last[k]);
    }

    if (li == 0u) s_max_last = 0u;
    barrier();
    uint sub_max_last = subgroupMax(my_max_last);
    atomicMax(s_max_last, sub_max_last);
    barrier();
    uint max_last = s_max_last;
    float dm_dz_num = sc.far * sc.near / (sc.far - sc.near);
    vec2 c_lo, c_hi;
    subgroup_pixel_box(centre, c_lo, c_hi);

    for (uint done = 0u; done < max_last; done += BATCH) {
        uint batch = min(BATCH, max_last - done);
        barrier();  // the previous batch has been consumed by every invocation
        if (li < batch) {
            uint e = max_last - 1u - (done + li);
            uint g = sorted_ids[range.x + e];
            ProjectedSplat p = splats[g];
            uint o = GEOM_STRIDE * g;
            vec3 h1 = vec3(geom[o], geom[o + 1u], geom[o + 2u]);
            vec3 h2 = vec3(geom[o + 3u], geom[o + 4u], geom[o + 5u]);
            vec3 h3 = vec3(geom[o + 6u], geom[o + 7u], geom[o + 8u]);
            s_id[li] = g;
            s_h1[li] = vec4(h1, p.opacity);
            s_h2[li] = vec4(h2, p.mean_x);
            s_h3[li] = vec4(h3, p.mean_y);
            s_n[li] = vec3(normals[3u * g], normals[3u * g + 1u], normals[3u * g + 2u]);
            s_rgb[li] = vec3(p.r, p.g, p.b);
            s_reach[li] = surfel_reach(sc, h1, h2, h3, vec2(p.mean_x, p.mean_y), p.opacity);
        }
        barrier();
#if HAS_SHUFFLE
        if (SUBGROUP_ATOMICS != 0u) {
            // Compact (in back-to-front order) the entries this subgroup's pixels can see:
            // before one of their last contributors, with a reach that meets their box.
            uint list_base = gl_SubgroupID * BATCH;
            uint n_list = 0u;
            for (uint j0 = 0u; j0 < batch; j0 += gl_SubgroupSize) {
                uint j = j0 + gl_SubgroupInvocationID;
                bool meets = j < batch && max_last - 1u - (done + j) < sub_max_last &&
                             reach_meets(vec2(s_h2[j].w, s_h3[j].w), s_reach[j], c_lo, c_hi);
                uvec4 ballot = subgroupBallot(meets);
                if (meets) s_list[list_base + n_list + subgroupBallotExclusiveBitCount(ballot)] = j;
                n_list += subgroupBallotBitCount(ballot);
            }
            subgroupMemoryBarrierShared();
            subgroupBarrier();
            // Lane l loads entry i0 + l of each chunk of the list (the last entry again past its
            // end) and every lane takes the entry's values by shuffles; the loops are uniform
            // over the subgroup, as the shuffles and the butterfly need.
            for (uint i0 = 0u; i0 < n_list; i0 += SUBGROUP_SIZE) {
                uint mine = s_list[list_base + min(i0 + gl_SubgroupInvocationID, n_list - 1u)];
                vec4 l_h1 = s_h1[mine], l_h2 = s_h2[mine], l_h3 = s_h3[mine];
                vec4 l_n = vec4(s_n[mine], uintBitsToFloat(s_id[mine]));
                vec4 l_rgb = vec4(s_rgb[mine], uintBitsToFloat(mine));
                uint n_chunk = min(SUBGROUP_SIZE, n_list - i0);
                for (uint ii = 0u; ii < n_chunk; ii++) {
                    vec4 n4 = subgroupShuffle(l_n, ii);
                    vec4 rgbj = subgroupShuffle(l_rgb, ii);
                    uint e = max_last - 1u - (done + floatBitsToUint(rgbj.w));
                    float part[GRAD_STRIDE];
                    visit(sc, subgroupShuffle(l_h1, ii), subgroupShuffle(l_h2, ii),
                          subgroupShuffle(l_h3, ii), n4.xyz, rgbj.xyz, e, dm_dz_num, part);
                    add_sums_transposed(part, floatBitsToUint(n4.w));
                }
            }
            continue;
        }
#endif
        for (uint j = 0u; j < batch; j++) {
            uint e = max_last - 1u - (done + j);
            float part[GRAD_STRIDE];
            visit(sc, s_h1[j], s_h2[j], s_h3[j], s_n[j], s_rgb[j], e, dm_dz_num, part);
#if HAS_SHUFFLE
            // The subgroup's sums through the transposing butterfly of subgroup_sums.glsl, in
            // chunks of SUBGROUP_SIZE slots: lane l ends with slot l's sum and stores it (one
            // store instruction). At subgroups of 32 the 18 slots take 31 shuffles, where the
            // reductions below take 90 (five a slot) and an elected lane stores 18 floats.
            uint lane = gl_SubgroupInvocationID;
            uint a = (j * NUM_SG + gl_SubgroupID) * GRAD_STRIDE;
            [[unroll]] for (uint ch = 0u; ch < (GRAD_STRIDE + SUBGROUP_SIZE - 1u) / SUBGROUP_SIZE; ch++) {
                float v[SUMS_MAX_SUBGROUP];
                [[unroll]] for (uint i = 0u; i < SUBGROUP_SIZE; i++) {
                    uint slot = ch * SUBGROUP_SIZE + i;
                    v[i] = slot < GRAD_STRIDE ? part[min(slot, GRAD_STRIDE - 1u)] : 0.0;
                }
                TRANSPOSE_ALL
                uint slot = ch * SUBGROUP_SIZE + lane;
                if (slot < GRAD_STRIDE) s_acc[a + slot] = v[0];
            }
#else
            vec3 g_h1 = subgroupAdd(vec3(part[0], part[1], part[2]));
            vec3 g_h2 = subgroupAdd(vec3(part[3], part[4], part[5]));
            vec3 g_h3 = subgroupAdd(vec3(part[6], part[7], part[8]));
            vec2 g_m = subgroupAdd(vec2(part[9], part[10]));
            vec3 g_rgb = subgroupAdd(vec3(part[11], part[12], part[13]));
            float g_op = subgroupAdd(part[14]);
            vec3 g_n = subgroupAdd(vec3(part[15], part[16], part[17]));
            if (subgroupElect()) {
                uint a = (j * NUM_SG + gl_SubgroupID) * GRAD_STRIDE;
                s_acc[a + 0u] = g_h1.x; s_acc[a + 1u] = g_h1.y; s_acc[a + 2u] = g_h1.z;
                s_acc[a + 3u] = g_h2.x; s_acc[a + 4u] = g_h2.y; s_acc[a + 5u] = g_h2.z;
                s_acc[a + 6u] = g_h3.x; s_acc[a + 7u] = g_h3.y; s_acc[a + 8u] = g_h3.z;
                s_acc[a + 9u] = g_m.x; s_acc[a + 10u] = g_m.y;
                s_acc[a + 11u] = g_rgb.x; s_acc[a + 12u] = g_rgb.y; s_acc[a + 13u] = g_rgb.z;
                s_acc[a + 14u] = g_op;
                s_acc[a + 15u] = g_n.x; s_acc[a + 16u] = g_n.y; s_acc[a + 17u] = g_n.z;
            }
#endif
        }
        barrier();
        // One invocation per (surfel, slot) of the batch: the subgroups' sums of the slot, then
        // its atomic; every invocation takes part, where one invocation per surfel (32 a batch
        // at 18 slots) left seven eighths of the workgroup idle.
        for (uint t = li; t < batch * GRAD_STRIDE; t += WG_SIZE) {
            uint j = t / GRAD_STRIDE, c = t % GRAD_STRIDE;
            float sum = 0.0;
            for (uint sg = 0u; sg < NUM_SG; sg++) sum += s_acc[(j * NUM_SG + sg) * GRAD_STRIDE + c];
            add_slot(s_id[j], c, sum);
        }
    }
}
