#version 460
// SpacetimeGaussians' full model, backward of features_at_time.comp: the feature channels'
// gradients (6 per Gaussian, from the rasterizer backward) to f_spec (as they are) and f_t
// (times Δ = t − c). Δ is detached: the temporal centre gets nothing here. Written, not added.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer TCenter { float t_center[]; };
layout(std430, set = 0, binding = 1) readonly buffer DFeatures { float d_features[]; };
layout(std430, set = 0, binding = 2) writeonly buffer DFSpec { float d_f_spec[]; };
layout(std430, set = 0, binding = 3) writeonly buffer DFT { float d_f_t[]; };
layout(push_constant) uniform Push {
    uint count;
    float t;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    float d = t - t_center[i];
    for (uint c = 0u; c < 3u; c++) {
        d_f_spec[3u * i + c] = d_features[6u * i + c];
        d_f_t[3u * i + c] = d * d_features[6u * i + 3u + c];
    }
}
