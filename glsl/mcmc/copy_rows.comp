#version 460
// MCMC's row moves (src/mcmc/gpu.rs), one buffer of `width` floats a Gaussian per dispatch:
// mode 0 copies row src into row dst for every pair (a plan's destinations are never its
// sources, so reads and writes never meet); mode 1 zeroes both rows of every pair (the Adam
// moments of a moved Gaussian and of its source: both start afresh). One invocation per float.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Pairs { uint pairs[]; };  // dst, src
layout(std430, set = 0, binding = 1) buffer Rows { float rows[]; };
layout(push_constant) uniform Push { uint count; uint width; uint mode; };

void main() {
    uint t = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    if (t >= count * width) return;
    uint p = t / width, j = t - p * width;
    uint dst = pairs[2u * p], src = pairs[2u * p + 1u];
    if (mode == 0u) {
        rows[dst * width + j] = rows[src * width + j];
    } else {
        rows[dst * width + j] = 0.0;
        rows[src * width + j] = 0.0;
    }
}
