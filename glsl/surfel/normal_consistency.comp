#version 460
// 2DGS regularisers, step 2 (one invocation per pixel): the surface-depth normal
// n̂ = normalize(a × c), a = P(x, y+1) − P(x, y−1), c = P(x+1, y) − P(x−1, y), P = depth·ray
// (0 on the border and where |a × c| ≤ NORMAL_EPS), the loss term 1 − N·n̂·alpha with the
// weighting alpha detached (official), its gradient with respect to the rendered normal N
// (into dl_dmaps), and dL/da, dL/dc for the gather of step 3. Mirrors
// src/reference/surfel/regularise.rs `normal_consistency`.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;
#include "camera.glsl"
#include "surfel.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Maps { float maps[]; };
layout(std430, set = 0, binding = 2) readonly buffer FinalT { float final_t[]; };
layout(std430, set = 0, binding = 3) readonly buffer SurfDepth { float surf_depth[]; };
// Per pixel 6 floats: dL/da, dL/dc (0 where no normal).
layout(std430, set = 0, binding = 4) writeonly buffer DiffGrads { float diff_grads[]; };
layout(std430, set = 0, binding = 5) writeonly buffer DlDMaps { float dl_dmaps[]; };
// Per pixel: the loss term 1 − N·n̂·alpha (summed by the host for reports).
layout(std430, set = 0, binding = 6) writeonly buffer Terms { float terms[]; };
layout(push_constant) uniform Push {
    uint camera_index;
    float weight;   // λ_normal / pixels
    float distortion_weight;  // λ_dist / pixels
};

// The official torch normalize eps.
const float NORMAL_EPS = 1e-12;
const uint MAP_GRADS_STRIDE = 8u;

vec3 ray(Camera cam, uint x, uint y) {
    return vec3((float(x) + 0.5 - cam.intrinsics.z) / cam.intrinsics.x,
                (float(y) + 0.5 - cam.intrinsics.w) / cam.intrinsics.y, 1.0);
}

vec3 point(Camera cam, uint x, uint y) {
    return surf_depth[y * cam.size.x + x] * ray(cam, x, y);
}

void main() {
    Camera cam = cameras[camera_index];
    uint w = cam.size.x, h = cam.size.y;
    uint pix = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (pix >= w * h) return;
    uint x = pix % w, y = pix / w;
    float alpha = 1.0 - final_t[pix];
    vec3 rendered = vec3(maps[MAPS_STRIDE * pix + 2u], maps[MAPS_STRIDE * pix + 3u],
                         maps[MAPS_STRIDE * pix + 4u]);
    vec3 nh = vec3(0.0);
    vec3 dl_da = vec3(0.0), dl_dc = vec3(0.0);
    if (x >= 1u && y >= 1u && x + 1u < w && y + 1u < h) {
        vec3 a = point(cam, x, y + 1u) - point(cam, x, y - 1u);
        vec3 c = point(cam, x + 1u, y) - point(cam, x - 1u, y);
        vec3 v = cross(a, c);
        float len = length(v);
        if (len > NORMAL_EPS && surfel_finite(len)) {
            nh = v / len;
            // L = −weight·alpha·N·n̂: dL/dv = −weight·alpha·(N − n̂ (n̂·N))/|v|.
            vec3 dl_dv = -weight * alpha * (rendered - nh * dot(nh, rendered)) / len;
            dl_da = cross(c, dl_dv);
            dl_dc = cross(dl_dv, a);
        }
    }
    for (uint k = 0u; k < 3u; k++) {
        diff_grads[6u * pix + k] = dl_da[k];
        diff_grads[6u * pix + 3u + k] = dl_dc[k];
    }
    terms[pix] = 1.0 - alpha * dot(rendered, nh);
    uint o = MAP_GRADS_STRIDE * pix;
    vec3 g_n = -weight * alpha * nh;
    dl_dmaps[o + 3u] = g_n.x;
    dl_dmaps[o + 4u] = g_n.y;
    dl_dmaps[o + 5u] = g_n.z;
    dl_dmaps[o + 6u] = distortion_weight;
    dl_dmaps[o + 7u] = 0.0;
}
