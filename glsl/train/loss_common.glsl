// Shared by the loss kernels (L1 + SSIM, forward and backward).
//
// The blurs are separable 11-tap passes. Each invocation produces SEG consecutive outputs along
// the blur direction from SEG + 10 inputs held in registers, so every input is loaded once per
// invocation instead of 11 times: on a CPU driver (lavapipe) loads and stores are per-lane
// gathers and dominate, while the multiply-adds run on full SIMD width. Adjacent invocations
// take adjacent rows (horizontal passes) or columns (vertical passes), so the image-border tests,
// which depend only on the position along the blur, are uniform across a subgroup.
//
// The blurred maps live in three buffers, one per colour channel (so that each stays under the
// device's storage-binding limit at large image sizes), planar inside: map m of channel c at
// pixel p is `maps_c[m * W * H + p]`.

layout(push_constant) uniform Push {
    uint width;
    uint height;
    uint gt_offset;   // first pixel of this image in the ground-truth buffer
    uint loss_slot;   // loss_out[3 * loss_slot + {0, 1, 2}] = L1, SSIM, total
    float bg_r;
    float bg_g;
    float bg_b;
    float ssim_weight;
    float inv_n;      // 1 / (W * H * 3)
    uint partial_count;
};

// SSIM window: 11 taps of a Gaussian with sigma 1.5, normalised to sum 1 (ssim_window() in
// src/metrics.rs computes the same numbers in f64).
const int R = 5;
const float GAUSS[11] = float[11](
    1.028380084e-03, 7.598758135e-03, 3.600077213e-02, 1.093606895e-01, 2.130055377e-01,
    2.660117249e-01,
    2.130055377e-01, 1.093606895e-01, 3.600077213e-02, 7.598758135e-03, 1.028380084e-03);
// Outputs per invocation along the blur direction.
const int SEG = 16;

// L1's subgradient is 0 where render and ground truth agree to within L1_TIE. The ground
// truth's composite over the background is itself rounded, differently by each device (a GPU may
// fuse its multiply-add, or unpack the bytes with a reciprocal), so an exact match rendered on
// one device reads as ±1 ulp on another; the band, far below the 1/255 step of 8-bit colour,
// makes such a match a tie everywhere. metrics::L1_TIE is the same number.
const float L1_TIE = 1e-6;

vec3 l1_sign(vec3 d) {
    return mix(sign(d), vec3(0.0), lessThanEqual(abs(d), vec3(L1_TIE)));
}

const float C1 = 0.0001;
const float C2 = 0.0009;

uint tile_group_index() {
    return gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
}
