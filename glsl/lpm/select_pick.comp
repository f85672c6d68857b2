#version 460
// Radix selection, picking pass `pass`: one workgroup finds the bin holding each rank in the
// histogram of this pass, appends it to the prefix and makes the rank relative to that bin.
//
// Pass 0 also sets the ranks:
// - mode 0 (interpolated quantile, `regions::quantile`): n = `n`, ranks `rank_lo` and
//   min(rank_lo + 1, n − 1); after pass 3 the threshold is a + frac·(b − a) in f32 (a, b the two
//   order statistics; the CPU interpolates in f64 and rounds once, so the two can differ by one
//   ulp, which changes a count only if b lies within that ulp of the threshold).
// - mode 1 (upper share, the opacity reset): n = the elements counted by pass 0,
//   k = ⌊n · top_num / top_den⌋ exactly in integers (top_den ≤ 65536), defined when k > 0, one
//   rank n − k: the k-th largest value. The threshold is that value.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "float_key.glsl"
#include "select_state.glsl"
layout(std430, set = 0, binding = 0) buffer State { uint state[]; };
layout(std430, set = 0, binding = 1) readonly buffer Hist { uint hist[]; };
layout(push_constant) uniform Push {
    uint pass;
    uint mode;
    uint n;
    uint rank_lo;
    float frac;
    uint top_num;
    uint top_den;
    uint ranks;
};

shared uint s_hist[2u * RADIX];

void main() {
    uint tid = gl_LocalInvocationIndex;
    for (uint b = tid; b < 2u * RADIX; b += WG_SIZE) s_hist[b] = hist[pass * 2u * RADIX + b];
    barrier();
    if (tid != 0u) return;
    if (pass == 0u) {
        uint total = n;
        uint r0 = 0u;
        uint r1 = 0u;
        bool valid;
        if (mode == 0u) {
            valid = n > 0u;
            r0 = rank_lo;
            r1 = min(rank_lo + 1u, n - 1u);
        } else {
            total = 0u;
            for (uint b = 0u; b < RADIX; b++) total += s_hist[b];
            // ⌊total · num / den⌋ without 64-bit: total = q·den + r, so it is q·num + ⌊r·num/den⌋.
            uint q = total / top_den;
            uint r = total - q * top_den;
            uint k = q * top_num + (r * top_num) / top_den;
            valid = k > 0u && k <= total;
            r0 = valid ? total - k : 0u;
            r1 = r0;
        }
        state[SEL_N] = total;
        state[SEL_VALID] = valid ? 1u : 0u;
        state[SEL_RANK] = r0;
        state[SEL_RANK + 1u] = r1;
        state[SEL_PREFIX] = 0u;
        state[SEL_PREFIX + 1u] = 0u;
    }
    if (state[SEL_VALID] == 0u) return;
    uint shift = 24u - 8u * pass;
    for (uint w = 0u; w < ranks; w++) {
        uint rank = state[SEL_RANK + w];
        uint below = 0u;
        for (uint b = 0u; b < RADIX; b++) {
            uint h = s_hist[w * RADIX + b];
            if (rank < below + h) {
                state[SEL_PREFIX + w] |= b << shift;
                state[SEL_RANK + w] = rank - below;
                break;
            }
            below += h;
        }
    }
    if (pass == 3u) {
        float a = uintBitsToFloat(key_bits(state[SEL_PREFIX]));
        if (mode == 0u) {
            float b = uintBitsToFloat(key_bits(state[SEL_PREFIX + 1u]));
            precise float t = frac == 0.0 ? a : a + frac * (b - a);
            state[SEL_THRESHOLD] = floatBitsToUint(t);
        } else {
            state[SEL_THRESHOLD] = floatBitsToUint(a);
        }
    }
}
