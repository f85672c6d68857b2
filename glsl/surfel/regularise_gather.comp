#version 460
// 2DGS regularisers, step 3 (one invocation per pixel): the surface depth's gradient, gathered
// from the four neighbours whose differences use this pixel (a = P(x, y+1) − P(x, y−1),
// c = P(x+1, y) − P(x−1, y), P = depth·ray), carried to the depth numerator, the alpha map
// (through D/alpha, only where it was finite) and the median depth. Writes dl_dmaps slots
// 0..2 (normal consistency's; step 2 wrote the others).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "camera.glsl"
#include "surfel.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 2) readonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 3) readonly buffer DiffGrads { float diff_grads[]; };
layout(std430, set = 0, binding = 4) buffer DlDMaps { float dl_dmaps[]; };
layout(push_constant) uniform Push {
    uint camera_index;
    float depth_ratio;
};

const uint MAP_GRADS_STRIDE = 8u;

vec3 diff(uint q, uint k) {
    return vec3(diff_grads[6u * q + 3u * k], diff_grads[6u * q + 3u * k + 1u],
                diff_grads[6u * q + 3u * k + 2u]);
}

void main() {
    Camera cam = cameras[camera_index];
    uint w = cam.size.x, h = cam.size.y;
    uint pix = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (pix >= w * h) return;
    uint x = pix % w, y = pix / w;
    // dL/dP(x, y): +dL/da of the pixel above (its a ends here), −dL/da of the pixel below,
    // +dL/dc of the pixel to the left, −dL/dc of the pixel to the right (border pixels hold 0).
    vec3 g = vec3(0.0);
    if (y >= 1u) g += diff((y - 1u) * w + x, 0u);
    if (y + 1u < h) g -= diff((y + 1u) * w + x, 0u);
    if (x >= 1u) g += diff(y * w + x - 1u, 1u);
    if (x + 1u < w) g -= diff(y * w + x + 1u, 1u);
    vec3 r = vec3((float(x) + 0.5 - cam.intrinsics.z) / cam.intrinsics.x,
                  (float(y) + 0.5 - cam.intrinsics.w) / cam.intrinsics.y, 1.0);
    float dl_dsurf = dot(g, r);
    float alpha = 1.0 - final_t[pix];
    float d = maps[MAPS_STRIDE * pix];
    float expected = d / alpha;
    uint o = MAP_GRADS_STRIDE * pix;
    float ge = (1.0 - depth_ratio) * dl_dsurf;
    bool finite = surfel_finite(expected);
    dl_dmaps[o] = finite ? -ge * d / (alpha * alpha) : 0.0;
    dl_dmaps[o + 1u] = finite ? ge / alpha : 0.0;
    dl_dmaps[o + 2u] = depth_ratio * dl_dsurf;
}
