#version 460
// SpacetimeGaussians' full model: every Gaussian's feature channels at time t, the specular
// feature as it is and the time feature scaled by Δ = t − c (detached, as the motion's):
// out[6i..6i+6] = [f_spec, Δ·f_t]. Oracle: src/reference/decoder.rs `time_features`.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer FSpec { float f_spec[]; };
layout(std430, set = 0, binding = 1) readonly buffer FT { float f_t[]; };
layout(std430, set = 0, binding = 2) readonly buffer TCenter { float t_center[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Out { float features[]; };
layout(push_constant) uniform Push {
    uint count;
    float t;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    float d = t - t_center[i];
    for (uint c = 0u; c < 3u; c++) {
        features[6u * i + c] = f_spec[3u * i + c];
        features[6u * i + 3u + c] = d * f_t[3u * i + c];
    }
}
