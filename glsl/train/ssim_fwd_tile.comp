#version 460
#extension GL_EXT_control_flow_attributes : require
// SSIM forward in one pass, the GPUs' layout (src/train/loss.rs, LossLayout::Tiles): a
// workgroup owns a TILE×TILE block of pixels, one pixel an invocation. Per channel it stages the
// block and its 5-pixel apron of render x and ground truth y in shared memory, blurs x, y, x²,
// y², xy horizontally into shared memory (the apron's rows too), then each invocation blurs its
// column vertically and writes its pixel's SSIM derivatives with respect to μx, E[x²] and E[xy]
// (the three maps ssim_bwd_tile blurs again). The segment layout (ssim_fwd_h + ssim_fwd_v) keeps
// every input in registers, which suits a CPU driver; on a GPU its horizontal pass puts adjacent
// lanes on different rows (uncoalesced) and writes 15 maps that the vertical pass reads back.
// Per-workgroup sums of |x − y| and S are reduced in a fixed order (deterministic), as loss_reduce
// expects.
// One workgroup of TILE² = 256 invocations a block (loss.rs: TILE_WG).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "loss_common.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Image { float image[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Out0 { float out0[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out1 { float out1[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Out2 { float out2[]; };
layout(std430, set = 0, binding = 5) writeonly buffer Partials { float partials[]; };
#include "image_io.glsl"

const int TILE = 16;
const int SPAN = TILE + 2 * R;  // staged rows and columns
const uint GROUP = uint(TILE * TILE);
// 13.7 KB in all, under Vulkan's guaranteed 16 KB of shared memory.
shared float sx[SPAN * SPAN];
shared float sy[SPAN * SPAN];
// Horizontally blurred moments of the staged rows: [moment][row][column]; reused for the final
// reduction.
shared float hm[5 * SPAN * TILE];

void store(uint c, uint i, float v) {
    if (c == 0u) out0[i] = v;
    else if (c == 1u) out1[i] = v;
    else out2[i] = v;
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    int lx = int(lid % uint(TILE)), ly = int(lid / uint(TILE));
    int x0 = int(gl_WorkGroupID.x) * TILE, y0 = int(gl_WorkGroupID.y) * TILE;
    int px = x0 + lx, py = y0 + ly;
    bool inside = px < int(width) && py < int(height);
    uint pix = inside ? uint(py) * width + uint(px) : 0u;
    uint n = width * height;
    float l1_sum = 0.0, ssim_sum = 0.0;
    [[unroll]] for (uint c = 0u; c < 3u; c++) {
        // The previous channel's readers of sx, sy and hm are done.
        barrier();
        for (uint i = lid; i < uint(SPAN * SPAN); i += GROUP) {
            int gx = x0 + int(i % uint(SPAN)) - R, gy = y0 + int(i / uint(SPAN)) - R;
            float a = 0.0, b = 0.0;
            if (gx >= 0 && gy >= 0 && gx < int(width) && gy < int(height)) {
                uint p = uint(gy) * width + uint(gx);
                a = image[p * 3u + c];
                b = load_gt(p)[c];
            }
            sx[i] = a;
            sy[i] = b;
        }
        barrier();
        for (uint i = lid; i < uint(SPAN * TILE); i += GROUP) {
            uint row = i / uint(TILE), col = i % uint(TILE);
            float m[5] = float[5](0.0, 0.0, 0.0, 0.0, 0.0);
            [[unroll]] for (int t = 0; t <= 2 * R; t++) {
                uint s = row * uint(SPAN) + col + uint(t);
                float a = sx[s], b = sy[s], g = GAUSS[t];
                m[0] += g * a;
                m[1] += g * b;
                m[2] += g * (a * a);
                m[3] += g * (b * b);
                m[4] += g * (a * b);
            }
            [[unroll]] for (uint k = 0u; k < 5u; k++) hm[(k * uint(SPAN) + row) * uint(TILE) + col] = m[k];
        }
        barrier();
        float m[5] = float[5](0.0, 0.0, 0.0, 0.0, 0.0);
        [[unroll]] for (int t = 0; t <= 2 * R; t++) {
            float g = GAUSS[t];
            [[unroll]] for (uint k = 0u; k < 5u; k++)
                m[k] += g * hm[(k * uint(SPAN) + uint(ly + t)) * uint(TILE) + uint(lx)];
        }
        if (inside) {
            float ux = m[0], uy = m[1];
            float sxx = m[2] - ux * ux;
            float syy = m[3] - uy * uy;
            float sxy = m[4] - ux * uy;
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
            uint centre = uint(ly + R) * uint(SPAN) + uint(lx + R);
            l1_sum += abs(sx[centre] - sy[centre]);
        }
    }
    // Fixed-order tree over the workgroup in hm's first 2·GROUP floats.
    barrier();
    hm[lid] = l1_sum;
    hm[GROUP + lid] = ssim_sum;
    barrier();
    for (uint s = GROUP / 2u; s > 0u; s >>= 1u) {
        if (lid < s) {
            hm[lid] += hm[lid + s];
            hm[GROUP + lid] += hm[GROUP + lid + s];
        }
        barrier();
    }
    if (lid == 0u) {
        uint g = tile_group_index();
        partials[2u * g] = hm[0];
        partials[2u * g + 1u] = hm[GROUP];
    }
}
