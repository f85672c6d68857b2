#version 460
// SpacetimeGaussians' density rule for new Gaussians: the clones and split children that
// density control just wrote (rows first..end, after the survivors; they copied the parent's
// temporal centre) get a temporal centre uniform in (0, 1), as the official densify_and_clone
// and densify_and_splitv2 draw them. Counter-based, so the result depends only on (seed, step,
// row); src/train/density/rng.rs gives the same numbers on the host.
layout(local_size_x_id = 0) in;
#include "../density/rng.glsl"
layout(std430, set = 0, binding = 0) buffer TCenter { float t_center[]; };
layout(push_constant) uniform Push {
    uint first;
    uint end;
    uint seed;
    uint step;
};

void main() {
    uint i = first + gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= end) return;
    t_center[i] = rng_uniform(seed, step, i, 0u);
}
