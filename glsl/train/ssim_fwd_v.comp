#version 460
// SSIM forward, pass 2: vertical 11-tap blur of the five moment maps, then per pixel and channel
// the SSIM value S and its partial derivatives with respect to the blurred moments μx, E[x²],
// E[xy] (the three maps the backward blurs again). Also the per-workgroup sums of |x − y| and S,
// reduced in a fixed order so the loss is the same bits for the same input.
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
layout(std430, set = 0, binding = 5) writeonly buffer Out0 { float out0[]; };
layout(std430, set = 0, binding = 6) writeonly buffer Out1 { float out1[]; };
layout(std430, set = 0, binding = 7) writeonly buffer Out2 { float out2[]; };
layout(std430, set = 0, binding = 8) writeonly buffer Partials { float partials[]; };
#include "image_io.glsl"

const uint SH = TILE_H + 2u * uint(R);
const uint PLANE = SH * TILE_W;
shared float tile[5u * PLANE];
shared float red_l1[WG_SIZE];
shared float red_ssim[WG_SIZE];

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
    uint lx = lid % TILE_W;
    uint ly = lid / TILE_W;
    uint x0 = gl_WorkGroupID.x * TILE_W;
    int y0 = int(gl_WorkGroupID.y * TILE_H) - R;
    uint px = x0 + lx;
    uint py = gl_WorkGroupID.y * TILE_H + ly;
    bool inside = px < width && py < height;
    uint n = width * height;
    uint pix = py * width + px;

    float l1_sum = 0.0;
    float ssim_sum = 0.0;
    if (inside) {
        vec3 d = load_render(pix) - load_gt(pix);
        l1_sum = abs(d.r) + abs(d.g) + abs(d.b);
    }
    for (uint c = 0u; c < 3u; c++) {
        if (c > 0u) barrier();  // the previous channel's reads are done before overwriting
        for (uint i = lid; i < PLANE; i += WG_SIZE) {
            uint gx = x0 + i % TILE_W;
            int gy = y0 + int(i / TILE_W);
            bool ok = gx < width && gy >= 0 && gy < int(height);
            uint src = uint(gy) * width + gx;
            for (uint m = 0u; m < 5u; m++) {
                tile[m * PLANE + i] = ok ? load(c, m * n + src) : 0.0;
            }
        }
        barrier();
        if (inside) {
            float mom[5] = float[5](0.0, 0.0, 0.0, 0.0, 0.0);
            for (int k = 0; k < 11; k++) {
                uint j = (ly + uint(k)) * TILE_W + lx;
                float g = GAUSS[k];
                for (uint m = 0u; m < 5u; m++) mom[m] += g * tile[m * PLANE + j];
            }
            float ux = mom[0], uy = mom[1];
            float sxx = mom[2] - ux * ux;
            float syy = mom[3] - uy * uy;
            float sxy = mom[4] - ux * uy;
            float a1 = 2.0 * ux * uy + C1;
            float a2 = 2.0 * sxy + C2;
            float b1 = ux * ux + uy * uy + C1;
            float b2 = sxx + syy + C2;
            float inv_b = 1.0 / (b1 * b2);
            float s = a1 * a2 * inv_b;
            ssim_sum += s;
            // S = A1·A2 / (B1·B2), with σx² = E[x²] − μx² and σxy = E[xy] − μx·μy.
            store(c, pix, 2.0 * uy * (a2 - a1) * inv_b - 2.0 * ux * s * (1.0 / b1 - 1.0 / b2));
            store(c, n + pix, -s / b2);
            store(c, 2u * n + pix, 2.0 * a1 * inv_b);
        }
    }

    red_l1[lid] = l1_sum;
    red_ssim[lid] = ssim_sum;
    barrier();
    for (uint s = WG_SIZE / 2u; s > 0u; s >>= 1u) {
        if (lid < s) {
            red_l1[lid] += red_l1[lid + s];
            red_ssim[lid] += red_ssim[lid + s];
        }
        barrier();
    }
    if (lid == 0u) {
        uint g = tile_group_index();
        partials[2u * g] = red_l1[0];
        partials[2u * g + 1u] = red_ssim[0];
    }
}
