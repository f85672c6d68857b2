#version 460
#extension GL_EXT_control_flow_attributes : require
// SSIM backward and the loss gradient in one pass, the GPUs' layout (src/train/loss.rs,
// LossLayout::Tiles; ssim_fwd_tile says why): per channel a workgroup stages its TILE×TILE block
// and 5-pixel apron of the three derivative maps, blurs them horizontally in shared memory and
// each invocation vertically at its pixel, then
//   N·dSSIM/dx = G*dS/dμx + 2x·G*dS/dE[x²] + y·G*dS/dE[xy]
//   dL/dx      = ((1 − w)·sign(x − y) − w·N·dSSIM/dx) / N
// with sign 0 inside the tie band |x − y| ≤ L1_TIE (loss_common.glsl). The maps are zero outside
// the image: the zero-padded blur is its own adjoint.
// One workgroup of TILE² = 256 invocations a block (loss.rs: TILE_WG).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) readonly buffer In0 { float in0[]; };
layout(std430, set = 0, binding = 3) readonly buffer In1 { float in1[]; };
layout(std430, set = 0, binding = 4) readonly buffer In2 { float in2[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Grad { float grad[]; };
#include "image_io.glsl"

const int TILE = 16;
const int SPAN = TILE + 2 * R;
const uint GROUP = uint(TILE * TILE);
// 13.1 KB in all, under Vulkan's guaranteed 16 KB of shared memory.
shared float sd[3 * SPAN * SPAN];
shared float hb[3 * SPAN * TILE];

float load(uint c, uint i) {
    if (c == 0u) return in0[i];
    if (c == 1u) return in1[i];
    return in2[i];
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    int lx = int(lid % uint(TILE)), ly = int(lid / uint(TILE));
    int x0 = int(gl_WorkGroupID.x) * TILE, y0 = int(gl_WorkGroupID.y) * TILE;
    int px = x0 + lx, py = y0 + ly;
    bool inside = px < int(width) && py < int(height);
    uint pix = inside ? uint(py) * width + uint(px) : 0u;
    uint n = width * height;
    vec3 x = inside ? load_render(pix) : vec3(0.0);
    vec3 y = inside ? load_gt(pix) : vec3(0.0);
    vec3 d = l1_sign(x - y);
    [[unroll]] for (uint c = 0u; c < 3u; c++) {
        barrier();
        for (uint i = lid; i < uint(SPAN * SPAN); i += GROUP) {
            int gx = x0 + int(i % uint(SPAN)) - R, gy = y0 + int(i / uint(SPAN)) - R;
            bool in_image = gx >= 0 && gy >= 0 && gx < int(width) && gy < int(height);
            uint p = in_image ? uint(gy) * width + uint(gx) : 0u;
            [[unroll]] for (uint k = 0u; k < 3u; k++)
                sd[k * uint(SPAN * SPAN) + i] = in_image ? load(c, k * n + p) : 0.0;
        }
        barrier();
        for (uint i = lid; i < uint(SPAN * TILE); i += GROUP) {
            uint row = i / uint(TILE), col = i % uint(TILE);
            float m[3] = float[3](0.0, 0.0, 0.0);
            [[unroll]] for (int t = 0; t <= 2 * R; t++) {
                uint s = row * uint(SPAN) + col + uint(t);
                float g = GAUSS[t];
                [[unroll]] for (uint k = 0u; k < 3u; k++) m[k] += g * sd[k * uint(SPAN * SPAN) + s];
            }
            [[unroll]] for (uint k = 0u; k < 3u; k++) hb[(k * uint(SPAN) + row) * uint(TILE) + col] = m[k];
        }
        barrier();
        float m[3] = float[3](0.0, 0.0, 0.0);
        [[unroll]] for (int t = 0; t <= 2 * R; t++) {
            float g = GAUSS[t];
            [[unroll]] for (uint k = 0u; k < 3u; k++)
                m[k] += g * hb[(k * uint(SPAN) + uint(ly + t)) * uint(TILE) + uint(lx)];
        }
        if (inside) {
            float d_ssim = m[0] + 2.0 * x[c] * m[1] + y[c] * m[2];
            grad[pix * 3u + c] = ((1.0 - ssim_weight) * d[c] - ssim_weight * d_ssim) * inv_n;
        }
    }
}
