#version 460
// Positions and log-scales of split children: child j of Gaussian i sits at
// mean + R(q) · (exp(log_scale) ⊙ n), n ~ N(0, I) from the counter-based RNG keyed by
// (seed, step, i, 3j + axis), i.e. a sample of the parent Gaussian; its log-scale is the
// parent's minus ln(1.6). A quaternion with |q|² < 1e-24 reads as the identity (as in render).
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
#include "rng.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 2) readonly buffer Pos { float positions[]; };
layout(std430, set = 0, binding = 3) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 4) readonly buffer Rot { float rotations[]; };
layout(std430, set = 0, binding = 5) writeonly buffer DstPos { float dst_positions[]; };
layout(std430, set = 0, binding = 6) writeonly buffer DstLogScales { float dst_log_scales[]; };
layout(push_constant) uniform Push { uint count; uint seed; uint step; float log_split_shrink; };

mat3 rotation_of(vec4 q) {
    float n2 = dot(q, q);
    if (!(n2 >= 1e-24)) return mat3(1.0);
    q /= sqrt(n2);
    float w = q.x, x = q.y, y = q.z, z = q.w;
    // Column-major: mat3(col0, col1, col2).
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
        2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
        2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
}

void main() {
    uint i = linear_index();
    if (i >= count) return;
    if ((decisions[i] & DECIDE_SPLIT) == 0u) return;
    vec3 mean = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    vec3 ls = vec3(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]);
    vec4 q = vec4(rotations[4u * i], rotations[4u * i + 1u], rotations[4u * i + 2u],
                  rotations[4u * i + 3u]);
    mat3 r = rotation_of(q);
    vec3 s = exp(ls);
    uint first = offsets[2u * count + i];
    for (uint j = 0u; j < 2u; j++) {
        vec3 n = vec3(rng_normal(seed, step, i, 3u * j), rng_normal(seed, step, i, 3u * j + 1u),
                      rng_normal(seed, step, i, 3u * j + 2u));
        vec3 p = mean + r * (s * n);
        uint o = first + j;
        for (uint k = 0u; k < 3u; k++) {
            dst_positions[3u * o + k] = p[k];
            precise float c = ls[k] - log_split_shrink;
            dst_log_scales[3u * o + k] = c;
        }
    }
}
