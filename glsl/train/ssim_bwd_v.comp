#version 460
#extension GL_EXT_control_flow_attributes : require
// SSIM backward, pass 2 and the loss gradient: vertical blur of the three horizontally blurred
// derivative maps per channel, then
//   N·dSSIM/dx = G*dS/dμx + 2x·G*dS/dE[x²] + y·G*dS/dE[xy]
//   dL/dx      = ((1 − w)·sign(x − y) − w·N·dSSIM/dx) / N
// with sign 0 inside the tie band |x − y| ≤ L1_TIE (loss_common.glsl), written over the whole gradient image. Invocation = one column segment of SEG pixels.
layout(constant_id = 0) const uint WG_SIZE = 32;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) readonly buffer In0 { float in0[]; };
layout(std430, set = 0, binding = 3) readonly buffer In1 { float in1[]; };
layout(std430, set = 0, binding = 4) readonly buffer In2 { float in2[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Grad { float grad[]; };
#include "image_io.glsl"

vec3 load(uint i) {
    return vec3(in0[i], in1[i], in2[i]);
}

void main() {
    uint px = gl_WorkGroupID.x * WG_SIZE + gl_LocalInvocationID.x;
    int y0 = int(gl_WorkGroupID.y) * SEG;
    if (px >= width) return;
    uint n = width * height;
    vec3 acc[3][SEG];
    [[unroll]] for (int o = 0; o < SEG; o++) {
        [[unroll]] for (uint m = 0u; m < 3u; m++) acc[m][o] = vec3(0.0);
    }
    [[unroll]] for (int j = 0; j < SEG + 2 * R; j++) {
        int sy = y0 + j - R;
        vec3 v[3] = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
        if (sy >= 0 && sy < int(height)) {
            uint src = uint(sy) * width + px;
            [[unroll]] for (uint m = 0u; m < 3u; m++) v[m] = load(m * n + src);
        }
        [[unroll]] for (int o = 0; o < SEG; o++) {
            int t = j - o;
            if (t >= 0 && t <= 2 * R) {
                float g = GAUSS[t];
                [[unroll]] for (uint m = 0u; m < 3u; m++) acc[m][o] += g * v[m];
            }
        }
    }
    [[unroll]] for (int o = 0; o < SEG; o++) {
        int py = y0 + o;
        if (py < int(height)) {
            uint pix = uint(py) * width + px;
            vec3 x = load_render(pix);
            vec3 y = load_gt(pix);
            vec3 d_ssim = acc[0][o] + 2.0 * x * acc[1][o] + y * acc[2][o];
            vec3 g = ((1.0 - ssim_weight) * l1_sign(x - y) - ssim_weight * d_ssim) * inv_n;
            grad[pix * 3u] = g.r;
            grad[pix * 3u + 1u] = g.g;
            grad[pix * 3u + 2u] = g.b;
        }
    }
}
