#version 460
// Marks for removal every Gaussian whose centre lies outside the axis-aligned box [lo, hi]
// (a coordinate below lo or above hi; infinite bounds leave an axis open), and nothing else:
// a model's own culls in world space (SpacetimeGaussians' Neural 3D Video rules, which remove
// Gaussians with z < 4.5 and, once, those outside the initial points' bounding box). Written
// where decide.comp would write, so expand / scatter apply it like any prune. A NaN coordinate
// compares false both ways and is kept, as the official tensor masks keep it.
// Host reference: `prune_outside_box` in src/reference/density.rs.
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Decisions { uint decisions[]; };
layout(push_constant) uniform Push {
    uint count;
    float lo_x, lo_y, lo_z;
    float hi_x, hi_y, hi_z;
};

void main() {
    uint i = linear_index();
    if (i >= count) return;
    vec3 p = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    bool below = p.x < lo_x || p.y < lo_y || p.z < lo_z;
    bool above = p.x > hi_x || p.y > hi_y || p.z > hi_z;
    decisions[i] = (below || above) ? DECIDE_REMOVE : 0u;
}
