#version 460
// Per-iteration densification statistics: for each Gaussian visible in this view (radius > 0),
// add its NDC mean-gradient norm to `grad_accum`, count the view in `denom`, and keep the largest
// screen radius in `max_radii`. Culled Gaussians are left untouched.
layout(local_size_x_id = 0) in;
#include "projected.glsl"
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Norms { float view_grad_norm[]; };
layout(std430, set = 0, binding = 1) readonly buffer Proj { Projected projected[]; };
layout(std430, set = 0, binding = 2) buffer Accum { float grad_accum[]; };
layout(std430, set = 0, binding = 3) buffer Denom { float denom[]; };
layout(std430, set = 0, binding = 4) buffer MaxRadii { float max_radii[]; };
layout(push_constant) uniform Push { uint count; };

void main() {
    uint i = linear_index();
    if (i >= count) return;
    float r = projected[i].radius;
    if (!(r > 0.0)) return;
    grad_accum[i] += view_grad_norm[i];
    denom[i] += 1.0;
    max_radii[i] = max(max_radii[i], r);
}
