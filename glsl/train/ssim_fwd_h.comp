#version 460
#extension GL_EXT_control_flow_attributes : require
// SSIM forward, pass 1: horizontal 11-tap blur of x, y, x², y², xy for each channel, where x is
// the render and y the ground truth composited over the background; zero padding (pixels outside
// the image contribute 0). Invocation = one row segment of SEG pixels; adjacent invocations take
// adjacent rows.
layout(constant_id = 0) const uint WG_SIZE = 32;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Out0 { float out0[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out1 { float out1[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Out2 { float out2[]; };
#include "image_io.glsl"

void store(uint m, uint pix, vec3 v) {
    uint i = m * width * height + pix;
    out0[i] = v.r;
    out1[i] = v.g;
    out2[i] = v.b;
}

void main() {
    uint py = gl_WorkGroupID.x * WG_SIZE + gl_LocalInvocationID.x;
    int x0 = int(gl_WorkGroupID.y) * SEG;
    if (py >= height) return;
    uint row = py * width;
    vec3 mx[SEG], my[SEG], exx[SEG], eyy[SEG], exy[SEG];
    [[unroll]] for (int o = 0; o < SEG; o++) {
        mx[o] = vec3(0.0);
        my[o] = vec3(0.0);
        exx[o] = vec3(0.0);
        eyy[o] = vec3(0.0);
        exy[o] = vec3(0.0);
    }
    [[unroll]] for (int j = 0; j < SEG + 2 * R; j++) {
        int sx = x0 + j - R;
        vec3 a = vec3(0.0), b = vec3(0.0);
        if (sx >= 0 && sx < int(width)) {
            a = load_render(row + uint(sx));
            b = load_gt(row + uint(sx));
        }
        vec3 aa = a * a, bb = b * b, ab = a * b;
        [[unroll]] for (int o = 0; o < SEG; o++) {
            int t = j - o;
            if (t >= 0 && t <= 2 * R) {
                float g = GAUSS[t];
                mx[o] += g * a;
                my[o] += g * b;
                exx[o] += g * aa;
                eyy[o] += g * bb;
                exy[o] += g * ab;
            }
        }
    }
    [[unroll]] for (int o = 0; o < SEG; o++) {
        int px = x0 + o;
        if (px < int(width)) {
            uint pix = row + uint(px);
            store(0u, pix, mx[o]);
            store(1u, pix, my[o]);
            store(2u, pix, exx[o]);
            store(3u, pix, eyy[o]);
            store(4u, pix, exy[o]);
        }
    }
}
