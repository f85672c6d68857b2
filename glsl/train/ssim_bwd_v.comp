#version 460
// SSIM backward, pass 2 and the loss gradient: vertical blur of the three horizontally blurred
// derivative maps per channel, then
//   dSSIM/dx = (G*dS/dμx + 2x·G*dS/dE[x²] + y·G*dS/dE[xy]) / N
//   dL/dx    = ((1 − w)·sign(x − y) − w·N·dSSIM/dx) / N
// written over the whole gradient image (every pixel, every channel).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint TILE_W = 16;
layout(constant_id = 3) const uint TILE_H = 16;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) readonly buffer In0 { float in0[]; };
layout(std430, set = 0, binding = 3) readonly buffer In1 { float in1[]; };
layout(std430, set = 0, binding = 4) readonly buffer In2 { float in2[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Grad { float grad[]; };
#include "image_io.glsl"

const uint SH = TILE_H + 2u * uint(R);
const uint PLANE = SH * TILE_W;
shared float tile[3u * PLANE];

float load(uint c, uint i) {
    if (c == 0u) return in0[i];
    if (c == 1u) return in1[i];
    return in2[i];
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    uint lx = lid % TILE_W;
    uint ly = lid / TILE_W;
    uint x0 = gl_WorkGroupID.x * TILE_W;
    int y0 = int(gl_WorkGroupID.y * TILE_H) - R;
    uint px = x0 + lx;
    uint py = gl_WorkGroupID.y * TILE_H + ly;
    bool inside = px < width && py < height;
    uint n = width * height;
    uint pix = py * width + px;
    vec3 x = vec3(0.0), y = vec3(0.0);
    if (inside) {
        x = load_render(pix);
        y = load_gt(pix);
    }
    for (uint c = 0u; c < 3u; c++) {
        if (c > 0u) barrier();
        for (uint i = lid; i < PLANE; i += WG_SIZE) {
            uint gx = x0 + i % TILE_W;
            int gy = y0 + int(i / TILE_W);
            bool ok = gx < width && gy >= 0 && gy < int(height);
            uint src = uint(gy) * width + gx;
            for (uint m = 0u; m < 3u; m++) {
                tile[m * PLANE + i] = ok ? load(c, m * n + src) : 0.0;
            }
        }
        barrier();
        if (inside) {
            float b0 = 0.0, b1 = 0.0, b2 = 0.0;
            for (int k = 0; k < 11; k++) {
                uint j = (ly + uint(k)) * TILE_W + lx;
                float g = GAUSS[k];
                b0 += g * tile[j];
                b1 += g * tile[PLANE + j];
                b2 += g * tile[2u * PLANE + j];
            }
            float d_ssim = b0 + 2.0 * x[c] * b1 + y[c] * b2;
            grad[pix * 3u + c] =
                ((1.0 - ssim_weight) * sign(x[c] - y[c]) - ssim_weight * d_ssim) * inv_n;
        }
    }
}
