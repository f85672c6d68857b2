#version 460
// SpacetimeGaussians' full model, decoder backward: each invocation recomputes the forward
// (decode.comp) of PIXELS consecutive pixels and writes dL/dB (3 per pixel, the rasterizer
// backward's dL/d(image)) and dL/d[S, Tf] (6 per pixel, its feature gradients). The 90 weight
// gradients are summed over the invocation's pixels in order, then over the workgroup
// (subgroupAdd, then the subgroups in order in shared memory) into one partial row per
// workgroup; decode_reduce.comp adds the rows in a fixed order, so the result does not depend
// on scheduling (no float atomics). PIXELS is 1 on GPUs and 8 on CPU drivers, where every
// weight load and every subgroup sum is a loop over the lanes (decode.comp), so they are
// shared by 8 pixels there.
// The loops over hidden and output units stay loops ([[dont_unroll]]): fully unrolled around
// the per-pixel arrays, lavapipe's LLVM took about 30 s to compile this kernel at 8 pixels
// (over 100 s at 16) against 1 s, for a pass that is a small part of a training step. The
// forward (decode.comp), which decides the frame rate, is unrolled: it compiles in about 1 s.
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_EXT_control_flow_attributes : require
#include "camera.glsl"
#include "decoder.glsl"

layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;  // must divide WG_SIZE
layout(constant_id = 2) const uint PIXELS = 1;
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Base { float base_image[]; };
layout(std430, set = 0, binding = 2) readonly buffer Features { float feature_image[]; };
layout(std430, set = 0, binding = 3) readonly buffer Weights { float w[]; };
layout(std430, set = 0, binding = 4) readonly buffer DlDRgb { float dl_drgb[]; };
layout(std430, set = 0, binding = 5) writeonly buffer DlDBase { float dl_dbase[]; };
layout(std430, set = 0, binding = 6) writeonly buffer DlDFeatures { float dl_dfeatures[]; };
layout(std430, set = 0, binding = 7) writeonly buffer Partial { float partial[]; };
layout(push_constant) uniform Push {
    uint camera_index;
};

// [subgroup · DEC_WEIGHTS + k]: each subgroup's sums.
shared float s_part[WG_SIZE / SUBGROUP_SIZE * DEC_WEIGHTS];

void main() {
    Camera cam = cameras[camera_index];
    uint wg = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint first = (wg * gl_WorkGroupSize.x + gl_LocalInvocationIndex) * PIXELS;
    uint n = cam.size.x * cam.size.y;
    float gw[DEC_WEIGHTS];
    for (uint k = 0u; k < DEC_WEIGHTS; k++) gw[k] = 0.0;
    // Pixels past the image (whole invocations in the last workgroup, or the end of the last
    // invocation) repeat the last pixel with zero gradients, so they take part in the sums
    // with zeros and write nothing.
    if (first < n) {
        float x[PIXELS][DEC_INPUTS];
        for (uint p = 0u; p < PIXELS; p++) {
            uint pix = min(first + p, n - 1u);
            for (uint c = 0u; c < DEC_FEATURES; c++) x[p][c] = feature_image[DEC_FEATURES * pix + c];
            decoder_view_inputs(x[p], cam, pix % cam.size.x, pix / cam.size.x);
        }
        float pre[PIXELS][DEC_HIDDEN];
        float h[PIXELS][DEC_HIDDEN];
        [[dont_unroll]] for (uint r = 0u; r < DEC_HIDDEN; r++) {
            for (uint p = 0u; p < PIXELS; p++) pre[p][r] = 0.0;
            for (uint c = 0u; c < DEC_INPUTS; c++) {
                float wv = w[r * DEC_INPUTS + c];
                for (uint p = 0u; p < PIXELS; p++) pre[p][r] += wv * x[p][c];
            }
            for (uint p = 0u; p < PIXELS; p++) h[p][r] = max(pre[p][r], 0.0);
        }
        float delta[PIXELS][DEC_OUTPUTS];
        [[dont_unroll]] for (uint o = 0u; o < DEC_OUTPUTS; o++) {
            float y[PIXELS];
            for (uint p = 0u; p < PIXELS; p++) y[p] = base_image[3u * min(first + p, n - 1u) + o];
            for (uint c = 0u; c < DEC_HIDDEN; c++) {
                float wv = w[DEC_W2 + o * DEC_HIDDEN + c];
                for (uint p = 0u; p < PIXELS; p++) y[p] += wv * h[p][c];
            }
            for (uint p = 0u; p < PIXELS; p++) {
                bool inside = first + p < n;
                float v = 1.0 / (1.0 + exp(-y[p]));
                float d = inside ? dl_drgb[3u * (first + p) + o] * v * (1.0 - v) : 0.0;
                delta[p][o] = d;
                if (inside) dl_dbase[3u * (first + p) + o] = d;
            }
            for (uint c = 0u; c < DEC_HIDDEN; c++) {
                for (uint p = 0u; p < PIXELS; p++) gw[DEC_W2 + o * DEC_HIDDEN + c] += delta[p][o] * h[p][c];
            }
        }
        float delta_h[PIXELS][DEC_HIDDEN];
        [[dont_unroll]] for (uint r = 0u; r < DEC_HIDDEN; r++) {
            float s[PIXELS];
            for (uint p = 0u; p < PIXELS; p++) s[p] = 0.0;
            [[dont_unroll]] for (uint o = 0u; o < DEC_OUTPUTS; o++) {
                float wv = w[DEC_W2 + o * DEC_HIDDEN + r];
                for (uint p = 0u; p < PIXELS; p++) s[p] += wv * delta[p][o];
            }
            // ReLU: no gradient where the pre-activation is not positive.
            for (uint p = 0u; p < PIXELS; p++) delta_h[p][r] = pre[p][r] > 0.0 ? s[p] : 0.0;
            for (uint c = 0u; c < DEC_INPUTS; c++) {
                for (uint p = 0u; p < PIXELS; p++) gw[r * DEC_INPUTS + c] += delta_h[p][r] * x[p][c];
            }
        }
        [[dont_unroll]] for (uint c = 0u; c < 6u; c++) {
            float s[PIXELS];
            for (uint p = 0u; p < PIXELS; p++) s[p] = 0.0;
            [[dont_unroll]] for (uint r = 0u; r < DEC_HIDDEN; r++) {
                float wv = w[r * DEC_INPUTS + c];
                for (uint p = 0u; p < PIXELS; p++) s[p] += wv * delta_h[p][r];
            }
            for (uint p = 0u; p < PIXELS; p++) {
                if (first + p < n) dl_dfeatures[6u * (first + p) + c] = s[p];
            }
        }
    }
    uint num_sg = gl_WorkGroupSize.x / SUBGROUP_SIZE;
    for (uint k = 0u; k < DEC_WEIGHTS; k++) {
        float s = subgroupAdd(gw[k]);
        if (subgroupElect()) s_part[gl_SubgroupID * DEC_WEIGHTS + k] = s;
    }
    barrier();
    for (uint k = gl_LocalInvocationIndex; k < DEC_WEIGHTS; k += gl_WorkGroupSize.x) {
        float s = 0.0;
        for (uint sg = 0u; sg < num_sg; sg++) s += s_part[sg * DEC_WEIGHTS + k];
        partial[wg * DEC_WEIGHTS + k] = s;
    }
}
