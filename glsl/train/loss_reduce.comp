#version 460
#extension GL_EXT_control_flow_attributes : require
// Final loss reduction: one workgroup sums the per-tile partials of ssim_fwd_v in a fixed order
// (strided serial sums, then a tree), so the same input always gives the same bits, and writes
// L1, SSIM and the total loss into the caller's slot.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Partials { float partials[]; };
layout(std430, set = 0, binding = 1) writeonly buffer LossOut { float loss_out[]; };

shared float red_l1[WG_SIZE];
shared float red_ssim[WG_SIZE];

void main() {
    uint lid = gl_LocalInvocationIndex;
    float l1 = 0.0, ssim = 0.0;
    for (uint i = lid; i < partial_count; i += WG_SIZE) {
        l1 += partials[2u * i];
        ssim += partials[2u * i + 1u];
    }
    red_l1[lid] = l1;
    red_ssim[lid] = ssim;
    barrier();
    for (uint s = WG_SIZE / 2u; s > 0u; s >>= 1u) {
        if (lid < s) {
            red_l1[lid] += red_l1[lid + s];
            red_ssim[lid] += red_ssim[lid + s];
        }
        barrier();
    }
    if (lid == 0u) {
        float l1_mean = red_l1[0] * inv_n;
        float ssim_mean = red_ssim[0] * inv_n;
        loss_out[3u * loss_slot] = l1_mean;
        loss_out[3u * loss_slot + 1u] = ssim_mean;
        loss_out[3u * loss_slot + 2u] =
            (1.0 - ssim_weight) * l1_mean + ssim_weight * (1.0 - ssim_mean);
    }
}
