#version 460
// Error map, step 3 of 3 (regions.rs `error_map`): per pixel, Σ_c |render_c·s_r − gt_c·s_g| with
// the factors of error_mean.comp. The map stays on the GPU for the quantile and the block counts.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "ground_truth.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Render { float render[]; };
layout(std430, set = 0, binding = 1) readonly buffer Gt { uint gt[]; };
layout(std430, set = 0, binding = 2) readonly buffer Scales { float scales[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Error { float error[]; };
layout(push_constant) uniform Push { uint pixels; uint gt_offset; float bg_r; float bg_g; float bg_b; };

void main() {
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint i = group * WG_SIZE + gl_LocalInvocationIndex;
    if (i >= pixels) return;
    vec3 g = ground_truth(gt[gt_offset + i], vec3(bg_r, bg_g, bg_b)) * scales[1];
    vec3 r = vec3(render[3u * i], render[3u * i + 1u], render[3u * i + 2u]) * scales[0];
    vec3 d = abs(r - g);
    error[i] = d.r + d.g + d.b;
}
