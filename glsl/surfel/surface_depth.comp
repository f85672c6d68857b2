#version 460
// 2DGS regularisers, step 1 (one invocation per pixel): the surface depth
// (1 − depth_ratio)·D/alpha + depth_ratio·median, with D/alpha taken as 0 where it is not
// finite (the official nan_to_num; no gradient there). Mirrors
// src/reference/surfel/regularise.rs `surface_depth`.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "surfel.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 1) readonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 2) writeonly buffer SurfDepth { float surf_depth[]; };
layout(push_constant) uniform Push {
    uint pixels;
    float depth_ratio;
};

void main() {
    uint pix = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (pix >= pixels) return;
    float alpha = 1.0 - final_t[pix];
    float expected = maps[MAPS_STRIDE * pix] / alpha;
    if (!surfel_finite(expected)) expected = 0.0;
    surf_depth[pix] = (1.0 - depth_ratio) * expected + depth_ratio * maps[MAPS_STRIDE * pix + 1u];
}
