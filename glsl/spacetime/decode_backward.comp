#version 460
// SpacetimeGaussians' full model, decoder backward: one invocation per pixel recomputes the
// forward (decode.comp) and writes dL/dB (3 per pixel, the rasterizer backward's dL/d(image))
// and dL/d[S, Tf] (6 per pixel, its feature gradients). The 90 weight gradients are summed
// over the workgroup (subgroupAdd, then the subgroups in order in shared memory) into one
// partial row per workgroup; decode_reduce.comp adds the rows in a fixed order, so the result
// does not depend on scheduling (no float atomics).
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#include "decoder.glsl"

layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;  // must divide WG_SIZE
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
    uint pix = wg * gl_WorkGroupSize.x + gl_LocalInvocationIndex;
    uint n = cam.size.x * cam.size.y;
    // Pixels past the image take part in the reductions with zero gradients.
    bool inside = pix < n;
    float gw[DEC_WEIGHTS];
    for (uint k = 0u; k < DEC_WEIGHTS; k++) gw[k] = 0.0;
    if (inside) {
        vec3 dir = pixel_ray(cam, pix % cam.size.x, pix / cam.size.x);
        float x[DEC_INPUTS];
        for (uint c = 0u; c < 6u; c++) x[c] = feature_image[6u * pix + c];
        for (uint c = 0u; c < 3u; c++) {
            x[6u + c] = cam.center[c];
            x[9u + c] = dir[c];
        }
        float pre[DEC_HIDDEN];
        float h[DEC_HIDDEN];
        for (uint r = 0u; r < DEC_HIDDEN; r++) {
            float s = 0.0;
            for (uint c = 0u; c < DEC_INPUTS; c++) s += w[r * DEC_INPUTS + c] * x[c];
            pre[r] = s;
            h[r] = max(s, 0.0);
        }
        float delta[DEC_OUTPUTS];
        for (uint o = 0u; o < DEC_OUTPUTS; o++) {
            float y = base_image[3u * pix + o];
            for (uint c = 0u; c < DEC_HIDDEN; c++) y += w[DEC_W2 + o * DEC_HIDDEN + c] * h[c];
            float v = 1.0 / (1.0 + exp(-y));
            delta[o] = dl_drgb[3u * pix + o] * v * (1.0 - v);
            dl_dbase[3u * pix + o] = delta[o];
            for (uint c = 0u; c < DEC_HIDDEN; c++) gw[DEC_W2 + o * DEC_HIDDEN + c] = delta[o] * h[c];
        }
        float delta_h[DEC_HIDDEN];
        for (uint r = 0u; r < DEC_HIDDEN; r++) {
            float s = 0.0;
            for (uint o = 0u; o < DEC_OUTPUTS; o++) s += w[DEC_W2 + o * DEC_HIDDEN + r] * delta[o];
            // ReLU: no gradient where the pre-activation is not positive.
            delta_h[r] = pre[r] > 0.0 ? s : 0.0;
            for (uint c = 0u; c < DEC_INPUTS; c++) gw[r * DEC_INPUTS + c] = delta_h[r] * x[c];
        }
        for (uint c = 0u; c < 6u; c++) {
            float s = 0.0;
            for (uint r = 0u; r < DEC_HIDDEN; r++) s += w[r * DEC_INPUTS + c] * delta_h[r];
            dl_dfeatures[6u * pix + c] = s;
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
