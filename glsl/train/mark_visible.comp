#version 460
// Visible Adam's mask (`train --visible-adam`): Gaussian i is seen in this step when a view's
// preprocess gave it a radius > 0 (a culled Gaussian has radius 0: no tile, no pixel, no
// gradient). The step's first view writes the mask, its later views (batched steps) OR into
// it, so a Gaussian seen by any view of the step is updated. Entries past `count` are not
// touched.
layout(local_size_x_id = 0) in;
#include "projected.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Bounds { ProjectedBounds bounds[]; };
layout(std430, set = 0, binding = 1) buffer Visible { uint visible[]; };
layout(push_constant) uniform Push {
    uint count;
    uint first;  // 1: the step's first view (write), 0: a later one (OR)
};

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    if (i >= count) return;
    // NaN radii count as culled (the comparison is false), as every other reader takes them.
    uint seen = bounds[i].radius > 0.0 ? 1u : 0u;
    visible[i] = first != 0u ? seen : (visible[i] | seen);
}
