#version 460
// One Adam step on one parameter group, every float of the first `n` (= count × stride),
// visible Gaussians or not (a dense update, as torch.optim.Adam does). The order of operations
// is that of torch's multi-tensor Adam, each op rounded to f32 (`precise` forbids the fused
// multiply-adds a compiler could otherwise form, so the host reference can reproduce it):
//   m = m + (1 − β1)·(g − m)             (lerp with a small weight)
//   v = v·β2;  v = v + (1 − β2)·(g·g)
//   d = sqrt(v) / sqrt(1 − β2^t) + eps
//   p = p + (−lr / (1 − β1^t))·(m / d)
// The two bias-correction scalars are computed on the host in f64 and rounded once to f32.
layout(local_size_x_id = 0) in;
// Each invocation updates 4 consecutive floats through vec4 views of the buffers (CPU drivers
// access storage buffers lane by lane, so one 16-byte access beats four 4-byte ones); the
// n % 4 floats of the tail go through the float views. Component-wise vec4 arithmetic rounds
// exactly as the scalar code does.
layout(std430, set = 0, binding = 0) buffer Params { float params[]; };
layout(std430, set = 0, binding = 1) readonly buffer Grads { float grads[]; };
layout(std430, set = 0, binding = 2) buffer M { float m[]; };
layout(std430, set = 0, binding = 3) buffer V { float v[]; };
layout(std430, set = 0, binding = 0) buffer Params4 { vec4 params4[]; };
layout(std430, set = 0, binding = 1) readonly buffer Grads4 { vec4 grads4[]; };
layout(std430, set = 0, binding = 2) buffer M4 { vec4 m4[]; };
layout(std430, set = 0, binding = 3) buffer V4 { vec4 v4[]; };
layout(push_constant) uniform Push {
    uint n;
    float one_minus_beta1;
    float beta2;
    float one_minus_beta2;
    float neg_step_size;
    float bias2_sqrt;
    float eps;
    uint pad;
};

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    uint n4 = n / 4u;
    if (i < n4) {
        precise vec4 g = grads4[i];
        precise vec4 m0 = m4[i];
        precise vec4 m1 = m0 + one_minus_beta1 * (g - m0);
        precise vec4 v1 = v4[i] * beta2;
        precise vec4 v2 = v1 + one_minus_beta2 * (g * g);
        precise vec4 d = sqrt(v2) / bias2_sqrt + eps;
        precise vec4 p = params4[i] + neg_step_size * (m1 / d);
        m4[i] = m1;
        v4[i] = v2;
        params4[i] = p;
    } else if (i < n4 + (n & 3u)) {
        uint j = 4u * n4 + (i - n4);
        precise float g = grads[j];
        precise float m0 = m[j];
        precise float m1 = m0 + one_minus_beta1 * (g - m0);
        precise float v1 = v[j] * beta2;
        precise float v2 = v1 + one_minus_beta2 * (g * g);
        precise float d = sqrt(v2) / bias2_sqrt + eps;
        precise float p = params[j] + neg_step_size * (m1 / d);
        m[j] = m1;
        v[j] = v2;
        params[j] = p;
    }
}
