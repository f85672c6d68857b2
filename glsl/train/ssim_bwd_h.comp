#version 460
#extension GL_EXT_control_flow_attributes : require
// SSIM backward, pass 1: horizontal 11-tap blur of the three derivative maps per channel
// (dS/dμx, dS/dE[x²], dS/dE[xy]). The window is symmetric and zero-padded, so the adjoint of the
// forward blur is the same blur. Invocation = one row segment of SEG pixels.
layout(constant_id = 0) const uint WG_SIZE = 32;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer In0 { float in0[]; };
layout(std430, set = 0, binding = 1) readonly buffer In1 { float in1[]; };
layout(std430, set = 0, binding = 2) readonly buffer In2 { float in2[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out0 { float out0[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Out1 { float out1[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Out2 { float out2[]; };

vec3 load(uint i) {
    return vec3(in0[i], in1[i], in2[i]);
}

void store(uint i, vec3 v) {
    out0[i] = v.r;
    out1[i] = v.g;
    out2[i] = v.b;
}

void main() {
    uint py = gl_WorkGroupID.x * WG_SIZE + gl_LocalInvocationID.x;
    int x0 = int(gl_WorkGroupID.y) * SEG;
    if (py >= height) return;
    uint row = py * width;
    uint n = width * height;
    vec3 acc[3][SEG];
    [[unroll]] for (int o = 0; o < SEG; o++) {
        [[unroll]] for (uint m = 0u; m < 3u; m++) acc[m][o] = vec3(0.0);
    }
    [[unroll]] for (int j = 0; j < SEG + 2 * R; j++) {
        int sx = x0 + j - R;
        vec3 v[3] = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
        if (sx >= 0 && sx < int(width)) {
            [[unroll]] for (uint m = 0u; m < 3u; m++) v[m] = load(m * n + row + uint(sx));
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
        int px = x0 + o;
        if (px < int(width)) {
            [[unroll]] for (uint m = 0u; m < 3u; m++) store(m * n + row + uint(px), acc[m][o]);
        }
    }
}
