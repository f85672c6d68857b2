#version 460
// SSIM backward, pass 1: horizontal 11-tap blur of the three derivative maps per channel
// (dS/dμx, dS/dE[x²], dS/dE[xy]). The window is symmetric and zero-padded, so the adjoint of
// the forward blur is the same blur. Shared-memory tile with a 5-pixel halo, as in ssim_fwd_h.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint TILE_W = 64;
layout(constant_id = 3) const uint TILE_H = 4;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer In0 { float in0[]; };
layout(std430, set = 0, binding = 1) readonly buffer In1 { float in1[]; };
layout(std430, set = 0, binding = 2) readonly buffer In2 { float in2[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out0 { float out0[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Out1 { float out1[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Out2 { float out2[]; };

const uint SW = TILE_W + 2u * uint(R);
const uint PLANE = SW * TILE_H;
shared float tile[9u * PLANE];

float load(uint c, uint i) {
    if (c == 0u) return in0[i];
    if (c == 1u) return in1[i];
    return in2[i];
}

void store(uint c, uint i, float v) {
    if (c == 0u) out0[i] = v;
    else if (c == 1u) out1[i] = v;
    else out2[i] = v;
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    int x0 = int(gl_WorkGroupID.x * TILE_W) - R;
    uint y0 = gl_WorkGroupID.y * TILE_H;
    uint n = width * height;
    for (uint i = lid; i < PLANE; i += WG_SIZE) {
        int gx = x0 + int(i % SW);
        uint gy = y0 + i / SW;
        bool ok = gx >= 0 && gx < int(width) && gy < height;
        uint src = gy * width + uint(gx);
        for (uint c = 0u; c < 3u; c++) {
            for (uint m = 0u; m < 3u; m++) {
                tile[(c * 3u + m) * PLANE + i] = ok ? load(c, m * n + src) : 0.0;
            }
        }
    }
    barrier();
    uint lx = lid % TILE_W;
    uint ly = lid / TILE_W;
    uint px = gl_WorkGroupID.x * TILE_W + lx;
    uint py = y0 + ly;
    if (px >= width || py >= height) return;
    float acc[9] = float[9](0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    uint base = ly * SW + lx;
    for (int k = 0; k < 11; k++) {
        float g = GAUSS[k];
        for (uint q = 0u; q < 9u; q++) acc[q] += g * tile[q * PLANE + base + uint(k)];
    }
    uint pix = py * width + px;
    for (uint c = 0u; c < 3u; c++) {
        for (uint m = 0u; m < 3u; m++) store(c, m * n + pix, acc[c * 3u + m]);
    }
}
