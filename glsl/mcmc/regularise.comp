#version 460
// MCMC's regularisers' gradients, added to the step's before the optimizer:
// λ_o · mean σ(logit) gives λ_o/N · σ(1 − σ) to each logit; λ_s · mean exp(log-scale), over the
// first `axes` scales of every Gaussian, gives λ_s/(N·axes) · exp(log-scale) to each of them
// (src/reference/mcmc.rs). The push constants hold the coefficients with N folded in.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Opacity { float opacity_logits[]; };
layout(std430, set = 0, binding = 1) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 2) buffer GradOpacity { float grad_opacity[]; };
layout(std430, set = 0, binding = 3) buffer GradLogScales { float grad_log_scales[]; };
layout(push_constant) uniform Push { uint count; uint axes; float opacity_coeff; float scale_coeff; };

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    if (i >= count) return;
    float o = 1.0 / (1.0 + exp(-opacity_logits[i]));
    grad_opacity[i] += opacity_coeff * o * (1.0 - o);
    for (uint a = 0u; a < axes; a++) {
        grad_log_scales[3u * i + a] += scale_coeff * exp(log_scales[3u * i + a]);
    }
}
