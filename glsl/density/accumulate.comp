#version 460
// Per-iteration densification statistics: for each Gaussian visible in this view (radius > 0),
// add this view's share to `grad_accum` and `denom`, and keep the largest screen radius in
// `max_radii`. Culled Gaussians are left untouched.
//   mode 0 (3DGS): grad_accum += |dL/d mean2d| (NDC), denom += 1;
//   mode 1 (Pixel-GS): with n = the pixels the Gaussian contributed to in this view and
//     phi = min(1, (depth · depth_scale)²), depth_scale = 1 / (0.37 · extent):
//     grad_accum += n · phi · |dL/d mean2d|, denom += n. So the views where a Gaussian covers
//     many pixels weigh more, and near-camera Gaussians (floaters) get a smaller statistic;
//     the optimisation's own gradients are untouched.
// With `abs_grad`: abs_accum += the backward's absolute-gradient statistic (Gaussian Opacity
// Fields' test, mode 0 only), over the same views.
// `precise`: the host reference (src/reference/density.rs) repeats these f32 operations
// in this order, without fused multiply-adds, and must match bit for bit.
layout(local_size_x_id = 0) in;
#include "projected.glsl"
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Norms { float view_grad_norm[]; };
layout(std430, set = 0, binding = 1) readonly buffer Bounds { ProjectedBounds bounds[]; };
layout(std430, set = 0, binding = 2) buffer Accum { float grad_accum[]; };
layout(std430, set = 0, binding = 3) buffer Denom { float denom[]; };
layout(std430, set = 0, binding = 4) buffer MaxRadii { float max_radii[]; };
layout(std430, set = 0, binding = 5) readonly buffer PixelCount { uint pixel_count[]; };
layout(std430, set = 0, binding = 6) readonly buffer AbsGrad { float abs_grad[]; };
layout(std430, set = 0, binding = 7) buffer AbsAccum { float abs_accum[]; };
layout(push_constant) uniform Push {
    uint count;
    uint mode;
    float depth_scale;
    uint use_abs;
};

void main() {
    uint i = linear_index();
    if (i >= count) return;
    float r = bounds[i].radius;
    if (!(r > 0.0)) return;
    if (mode == 1u) {
        precise float n = float(pixel_count[i]);
        precise float z = bounds[i].depth * depth_scale;
        precise float phi = min(1.0, z * z);
        precise float add = n * phi * view_grad_norm[i];
        grad_accum[i] = grad_accum[i] + add;
        denom[i] = denom[i] + n;
    } else {
        grad_accum[i] += view_grad_norm[i];
        denom[i] += 1.0;
        if (use_abs != 0u) abs_accum[i] += abs_grad[i];
    }
    max_radii[i] = max(max_radii[i], r);
}
