#version 460
#extension GL_EXT_control_flow_attributes : require
// SSIM forward, pass 2: vertical 11-tap blur of the five moment maps, then per pixel and channel
// the SSIM value S and its partial derivatives with respect to the blurred moments μx, E[x²],
// E[xy] (the three maps the backward blurs again). Also the per-workgroup sums of |x − y| and S,
// reduced in a fixed order so the loss is the same bits for the same input. Invocation = one
// column segment of SEG pixels; adjacent invocations take adjacent columns.
layout(constant_id = 0) const uint WG_SIZE = 32;
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
    uint px = gl_WorkGroupID.x * WG_SIZE + lid;
    int y0 = int(gl_WorkGroupID.y) * SEG;
    bool col_ok = px < width;
    uint n = width * height;

    float l1_sum = 0.0;
    float ssim_sum = 0.0;
    [[unroll]] for (uint c = 0u; c < 3u; c++) {
        float mom[5][SEG];
        [[unroll]] for (int o = 0; o < SEG; o++) {
            [[unroll]] for (uint m = 0u; m < 5u; m++) mom[m][o] = 0.0;
        }
        [[unroll]] for (int j = 0; j < SEG + 2 * R; j++) {
            int sy = y0 + j - R;
            float v[5] = float[5](0.0, 0.0, 0.0, 0.0, 0.0);
            if (col_ok && sy >= 0 && sy < int(height)) {
                uint src = uint(sy) * width + px;
                [[unroll]] for (uint m = 0u; m < 5u; m++) v[m] = load(c, m * n + src);
            }
            [[unroll]] for (int o = 0; o < SEG; o++) {
                int t = j - o;
                if (t >= 0 && t <= 2 * R) {
                    float g = GAUSS[t];
                    [[unroll]] for (uint m = 0u; m < 5u; m++) mom[m][o] += g * v[m];
                }
            }
        }
        [[unroll]] for (int o = 0; o < SEG; o++) {
            int py = y0 + o;
            if (col_ok && py < int(height)) {
                uint pix = uint(py) * width + px;
                float ux = mom[0][o], uy = mom[1][o];
                float sxx = mom[2][o] - ux * ux;
                float syy = mom[3][o] - uy * uy;
                float sxy = mom[4][o] - ux * uy;
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
    }
    [[unroll]] for (int o = 0; o < SEG; o++) {
        int py = y0 + o;
        if (col_ok && py < int(height)) {
            uint pix = uint(py) * width + px;
            vec3 d = abs(load_render(pix) - load_gt(pix));
            l1_sum += d.r + d.g + d.b;
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
