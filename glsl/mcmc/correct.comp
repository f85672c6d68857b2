#version 460
// MCMC's opacity and scale correction (src/mcmc/plan.rs): every row of a plan gets the opacity
// logit of an n-way split and its first `axes` log-scales the plan's change (3 for Gaussians, 2
// for surfels, whose third scale is not a scale). Each row is listed once.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Rows { uint rows[]; };
layout(std430, set = 0, binding = 1) readonly buffer Values { float values[]; };  // logit, Δ
layout(std430, set = 0, binding = 2) buffer Opacity { float opacity_logits[]; };
layout(std430, set = 0, binding = 3) buffer LogScales { float log_scales[]; };
layout(push_constant) uniform Push { uint count; uint axes; };

void main() {
    uint k = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    if (k >= count) return;
    uint r = rows[k];
    opacity_logits[r] = values[2u * k];
    precise float delta = values[2u * k + 1u];
    for (uint a = 0u; a < axes; a++) log_scales[3u * r + a] = log_scales[3u * r + a] + delta;
}
