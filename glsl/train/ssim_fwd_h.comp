#version 460
// SSIM forward, pass 1: horizontal 11-tap blur of x, y, x², y², xy for each channel, where x is
// the render and y the ground truth composited over the background. Zero padding: pixels
// outside the image contribute 0. One workgroup per TILE_W × TILE_H tile; the tile's rows with
// their 5-pixel halo are staged in shared memory once and read 11 times.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint TILE_W = 64;
layout(constant_id = 3) const uint TILE_H = 4;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Out0 { float out0[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out1 { float out1[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Out2 { float out2[]; };
#include "image_io.glsl"

const uint SW = TILE_W + 2u * uint(R);
shared vec3 sx[SW * TILE_H];
shared vec3 sy[SW * TILE_H];

void store(uint c, uint i, float v) {
    if (c == 0u) out0[i] = v;
    else if (c == 1u) out1[i] = v;
    else out2[i] = v;
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    int x0 = int(gl_WorkGroupID.x * TILE_W) - R;
    uint y0 = gl_WorkGroupID.y * TILE_H;
    for (uint i = lid; i < SW * TILE_H; i += WG_SIZE) {
        int px = x0 + int(i % SW);
        uint py = y0 + i / SW;
        vec3 x = vec3(0.0);
        vec3 y = vec3(0.0);
        if (px >= 0 && px < int(width) && py < height) {
            uint pix = py * width + uint(px);
            x = load_render(pix);
            y = load_gt(pix);
        }
        sx[i] = x;
        sy[i] = y;
    }
    barrier();
    uint lx = lid % TILE_W;
    uint ly = lid / TILE_W;
    uint px = gl_WorkGroupID.x * TILE_W + lx;
    uint py = y0 + ly;
    if (px >= width || py >= height) return;
    vec3 mx = vec3(0.0), my = vec3(0.0), exx = vec3(0.0), eyy = vec3(0.0), exy = vec3(0.0);
    uint base = ly * SW + lx;
    for (int k = 0; k < 11; k++) {
        vec3 a = sx[base + uint(k)];
        vec3 b = sy[base + uint(k)];
        float g = GAUSS[k];
        vec3 ga = g * a;
        vec3 gb = g * b;
        mx += ga;
        my += gb;
        exx += ga * a;
        eyy += gb * b;
        exy += ga * b;
    }
    uint n = width * height;
    uint pix = py * width + px;
    for (uint c = 0u; c < 3u; c++) {
        store(c, pix, mx[c]);
        store(c, n + pix, my[c]);
        store(c, 2u * n + pix, exx[c]);
        store(c, 3u * n + pix, eyy[c]);
        store(c, 4u * n + pix, exy[c]);
    }
}
