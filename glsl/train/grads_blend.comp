#version 460
// Several views in one optimizer step (SpacetimeGaussians' two-camera batch): the gradient of
// the next view is added to the running sum, and at the last view the sum is scaled to the mean:
// dst = (dst + src) · scale, over the first `n` floats of one parameter group. Each op rounds to
// f32 (`precise`: no fused multiply-add), so the host check is exact.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) buffer Dst { float dst[]; };
layout(std430, set = 0, binding = 1) readonly buffer Src { float src[]; };
layout(push_constant) uniform Push {
    uint n;
    float scale;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= n) return;
    precise float s = dst[i] + src[i];
    precise float m = s * scale;
    dst[i] = m;
}
