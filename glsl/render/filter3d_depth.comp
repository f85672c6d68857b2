#version 460
// Mip-Splatting's 3D filter, pass 1 of 2 (src/reference/mip.rs): per Gaussian, the smallest
// camera depth of its centre over the training cameras that see it (depth > 0.2, projection
// within 15 % of the image past each edge). Seen: filter = depth · scale, scale =
// √0.2 / (largest training focal length), and the largest such filter goes into seen_max
// (positive floats order as their bits). Unseen: −1, filled by filter3d_fill.comp.
layout(local_size_x_id = 0) in;
#include "camera.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 2) readonly buffer TrainIds { uint train_ids[]; };
layout(std430, set = 0, binding = 3) writeonly buffer Filter { float filter3d[]; };
layout(std430, set = 0, binding = 4) buffer SeenMax { uint seen_max[]; };
layout(push_constant) uniform Push {
    uint count;
    uint n_cameras;
    float scale;
};

const float MIN_DEPTH = 0.2;
const float MARGIN = 0.15;

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    vec3 p = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    float d_min = 1e30;
    for (uint k = 0u; k < n_cameras; k++) {
        Camera cam = cameras[train_ids[k]];
        vec3 t = camera_transform(cam, p);
        if (!(t.z > MIN_DEPTH)) continue;
        vec2 size = vec2(cam.size.xy);
        vec2 uv = vec2(cam.intrinsics.x * t.x / t.z + cam.intrinsics.z,
                       cam.intrinsics.y * t.y / t.z + cam.intrinsics.w);
        if (all(greaterThanEqual(uv, -MARGIN * size)) &&
            all(lessThanEqual(uv, (1.0 + MARGIN) * size))) {
            d_min = min(d_min, t.z);
        }
    }
    if (d_min < 1e30) {
        float f = d_min * scale;
        filter3d[i] = f;
        atomicMax(seen_max[0], floatBitsToUint(f));
    } else {
        filter3d[i] = -1.0;
    }
}
