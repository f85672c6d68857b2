#version 460
// 2DGS preprocess backward: one invocation per surfel carries the rasterizer backward's
// gradients (grad_rows: M's rows; grad_rest: the box centre, clamped colour, opacity, normal) to the
// stored parameters, following src/reference/surfel/backward.rs `preprocess_backward`: the
// box-centre formula (the low-pass centre is a function of M), M's columns K W s_u r1,
// K W s_v r2, K t, the normal's camera-facing flip, the quaternion normalisation, the sigmoid
// and the SH colour. Every output of surfels 0..count is WRITTEN (not accumulated); culled
// surfels and surfels with all-zero gradients get zeros (the backward is linear in them).
// Also writes the official densification statistic (view_grad_norm): the norm of
// (∂L/∂M13·M33·W/2, ∂L/∂M23·M33·H/2) from the rasterize stage alone.
//
// Clamps: sigmoid' = σ(x)σ(−x); a colour channel clamped at 0 passes nothing; a quaternion
// with |q|² < QUAT_NORM2_MIN (or not finite) is the identity, no gradient; SH coefficients
// above the active degree get 0; the box half-extents (integer radius) pass nothing.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"
#include "surfel.glsl"
#include "sh_basis_grad.glsl"
#include "quat_backward.glsl"

const uint GRAD_STRIDE = 18u;  // slots a surfel, 9 in each buffer
const uint GRAD_HALF = 9u;
const float QUAT_NORM2_MIN = 1e-24;

layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Bounds { ProjectedBounds bounds[]; };
layout(std430, set = 0, binding = 2) readonly buffer GradRows { float grad_rows[]; };
layout(std430, set = 0, binding = 3) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 4) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 5) readonly buffer Rotations { float rotations[]; };
layout(std430, set = 0, binding = 6) readonly buffer OpacityLogits { float opacity_logits[]; };
layout(std430, set = 0, binding = 7) readonly buffer ShDc { float sh_dc[]; };
layout(std430, set = 0, binding = 8) readonly buffer ShRest0 { float sh_rest0[]; };
layout(std430, set = 0, binding = 9) writeonly buffer GPositions { float g_positions[]; };
layout(std430, set = 0, binding = 10) writeonly buffer GLogScales { float g_log_scales[]; };
layout(std430, set = 0, binding = 11) writeonly buffer GRotations { float g_rotations[]; };
layout(std430, set = 0, binding = 12) writeonly buffer GOpacity { float g_opacity_logits[]; };
layout(std430, set = 0, binding = 13) writeonly buffer GShDc { float g_sh_dc[]; };
layout(std430, set = 0, binding = 14) writeonly buffer GShRest0 { float g_sh_rest0[]; };
layout(std430, set = 0, binding = 15) writeonly buffer ViewGradNorm { float view_grad_norm[]; };
layout(std430, set = 0, binding = 16) readonly buffer ShRest1 { float sh_rest1[]; };
layout(std430, set = 0, binding = 17) readonly buffer ShRest2 { float sh_rest2[]; };
layout(std430, set = 0, binding = 18) writeonly buffer GShRest1 { float g_sh_rest1[]; };
layout(std430, set = 0, binding = 19) writeonly buffer GShRest2 { float g_sh_rest2[]; };
layout(std430, set = 0, binding = 20) readonly buffer GradRest { float grad_rest[]; };
layout(std430, set = 0, binding = 21) readonly buffer ShRest3 { float sh_rest3[]; };
layout(std430, set = 0, binding = 22) readonly buffer ShRest4 { float sh_rest4[]; };
layout(std430, set = 0, binding = 23) writeonly buffer GShRest3 { float g_sh_rest3[]; };
layout(std430, set = 0, binding = 24) writeonly buffer GShRest4 { float g_sh_rest4[]; };
#define SH_REST_GRADS
#include "sh_rest_planes.glsl"

layout(push_constant) uniform Push {
    SurfelConstants sc;
    uint camera_index;
    uint count;
    uint sh_degree;      // active degree (0..=stored degree)
    uint rest_coeffs;    // stored (d+1)² − 1: fixes the SH rest planes' strides
    uint scale_stride;   // floats per surfel in log_scales (2, or 3 with the third unused)
} pc;

void write_zeros(uint i) {
    for (uint k = 0u; k < 3u; k++) {
        g_positions[3u * i + k] = 0.0;
        g_sh_dc[3u * i + k] = 0.0;
    }
    for (uint k = 0u; k < pc.scale_stride; k++) g_log_scales[pc.scale_stride * i + k] = 0.0;
    for (uint k = 0u; k < 4u; k++) g_rotations[4u * i + k] = 0.0;
    g_opacity_logits[i] = 0.0;
    FOR_EACH_SH_REST_PLANE(SH_REST_PLANE_ZERO)
    view_grad_norm[i] = 0.0;
}

// Kᵀ g: the gradient of a camera-space vector v from that of K v.
vec3 apply_k_transpose(vec4 intr, vec3 g) {
    return vec3(intr.x * g.x, intr.y * g.y, intr.z * g.x + intr.w * g.y + g.z);
}

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * WG_SIZE
             + gl_LocalInvocationIndex;
    if (i >= pc.count) return;
    ProjectedBounds pr = bounds[i];
    float gr[GRAD_STRIDE];
    bool any_grad = false;
    for (uint k = 0u; k < GRAD_HALF; k++) {
        gr[k] = grad_rows[GRAD_HALF * i + k];
        gr[GRAD_HALF + k] = grad_rest[GRAD_HALF * i + k];
    }
    for (uint k = 0u; k < GRAD_STRIDE; k++) any_grad = any_grad || gr[k] != 0.0;
    if (!(pr.radius > 0.0) || !any_grad) {
        write_zeros(i);
        return;
    }
    vec3 g_h1 = vec3(gr[0], gr[1], gr[2]);
    vec3 g_h2 = vec3(gr[3], gr[4], gr[5]);
    vec3 g_h3 = vec3(gr[6], gr[7], gr[8]);
    vec2 g_m = vec2(gr[9], gr[10]);
    vec3 dl_drgb = vec3(gr[11], gr[12], gr[13]);
    float dl_dopacity = gr[14];
    vec3 g_n = vec3(gr[15], gr[16], gr[17]);

    Camera cam = cameras[pc.camera_index];
    vec3 Wr[3] = vec3[3](cam.r0.xyz, cam.r1.xyz, cam.r2.xyz);  // rows of W
    mat3 W = transpose(mat3(Wr[0], Wr[1], Wr[2]));
    mat3 Wt = mat3(Wr[0], Wr[1], Wr[2]);  // columns r0, r1, r2: Wᵀ
    vec4 intr = cam.intrinsics;

    vec3 pos = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    uint ss = pc.scale_stride;
    vec2 s = exp(vec2(log_scales[ss * i], log_scales[ss * i + 1u]));
    vec4 q = vec4(rotations[4u * i], rotations[4u * i + 1u], rotations[4u * i + 2u],
                  rotations[4u * i + 3u]);
    float logit = opacity_logits[i];

    // The official densification statistic, from the rasterize stage's ∂L/∂M alone.
    vec3 t = camera_transform(cam, pos);
    {
        vec3 col2 = vec3(intr.x * t.x + intr.z * t.z, intr.y * t.y + intr.w * t.z, t.z);
        float hw = 0.5 * float(cam.size.x), hh = 0.5 * float(cam.size.y);
        view_grad_norm[i] = length(vec2(g_h1.z * col2.z * hw, g_h2.z * col2.z * hh));
    }

    // Opacity: sigmoid' = σ(x)·σ(−x), each factor without cancellation.
    g_opacity_logits[i] = dl_dopacity * (1.0 / (1.0 + exp(-logit))) * (1.0 / (1.0 + exp(logit)));

    // Colour: SH coefficients and the view direction (a clamped channel passes nothing).
    vec3 dl_draw = dl_drgb;
    if ((pr.flags & 1u) != 0u) dl_draw.x = 0.0;
    if ((pr.flags & 2u) != 0u) dl_draw.y = 0.0;
    if ((pr.flags & 4u) != 0u) dl_draw.z = 0.0;
    vec3 view = pos - cam.center.xyz;
    float view_len = length(view);
    vec3 dir = view / view_len;
    uint n_active = (pc.sh_degree + 1u) * (pc.sh_degree + 1u);
    vec3 dl_ddir = vec3(0.0);
    {
        vec3 bgrad;
        float b = sh_basis(0u, dir, bgrad);
        vec3 coeff = vec3(sh_dc[3u * i], sh_dc[3u * i + 1u], sh_dc[3u * i + 2u]);
        g_sh_dc[3u * i] = b * dl_draw.x;
        g_sh_dc[3u * i + 1u] = b * dl_draw.y;
        g_sh_dc[3u * i + 2u] = b * dl_draw.z;
        dl_ddir += bgrad * dot(coeff, dl_draw);
    }
    uint n_rest = min(n_active - 1u, pc.rest_coeffs);
    FOR_EACH_SH_REST_PLANE(SH_REST_PLANE_BACKWARD)
    vec3 dl_dpos = (dl_ddir - dir * dot(dir, dl_ddir)) / view_len;

    // Rebuild M (as the preprocess) for the box-centre backward.
    float qn2 = dot(q, q);
    bool quat_ok = surfel_finite(qn2) && qn2 >= QUAT_NORM2_MIN;
    float qn = sqrt(qn2);
    vec4 unit = quat_ok ? q / qn : vec4(1.0, 0.0, 0.0, 0.0);
    vec3 R[3];  // rows
    quat_rows(unit, R);
    vec3 r1 = vec3(R[0].x, R[1].x, R[2].x);
    vec3 r2 = vec3(R[0].y, R[1].y, R[2].y);
    vec3 r3 = vec3(R[0].z, R[1].z, R[2].z);
    vec3 col0 = W * (r1 * s.x), col1 = W * (r2 * s.y);
    col0 = vec3(intr.x * col0.x + intr.z * col0.z, intr.y * col0.y + intr.w * col0.z, col0.z);
    col1 = vec3(intr.x * col1.x + intr.z * col1.z, intr.y * col1.y + intr.w * col1.z, col1.z);
    vec3 col2 = vec3(intr.x * t.x + intr.z * t.z, intr.y * t.y + intr.w * t.z, t.z);
    vec3 h1 = vec3(col0.x, col1.x, col2.x);
    vec3 h2 = vec3(col0.y, col1.y, col2.y);
    vec3 h3 = vec3(col0.z, col1.z, col2.z);

    // Box centre m = (Σ τ h1 h3, Σ τ h2 h3)/d, d = Σ τ h3², τ = (k², k², −1).
    float k2 = pc.sc.cutoff * pc.sc.cutoff;
    vec3 tau = vec3(k2, k2, -1.0);
    float d = dot(tau, h3 * h3);
    vec2 m = vec2(dot(tau, h1 * h3), dot(tau, h2 * h3)) / d;
    float along = dot(g_m, m);
    g_h1 += g_m.x * tau * h3 / d;
    g_h2 += g_m.y * tau * h3 / d;
    g_h3 += (g_m.x * tau * h1 + g_m.y * tau * h2) / d - 2.0 * tau * h3 * along / d;

    // Columns of ∂L/∂M: ∂L/∂(K W s_u r1), ∂L/∂(K W s_v r2), ∂L/∂(K t).
    vec3 g_col0 = vec3(g_h1.x, g_h2.x, g_h3.x);
    vec3 g_col1 = vec3(g_h1.y, g_h2.y, g_h3.y);
    vec3 g_col2 = vec3(g_h1.z, g_h2.z, g_h3.z);
    dl_dpos += Wt * apply_k_transpose(intr, g_col2);
    for (uint k = 0u; k < 3u; k++) g_positions[3u * i + k] = dl_dpos[k];

    vec3 g_sr1 = Wt * apply_k_transpose(intr, g_col0);  // ∂L/∂(s_u r1), world
    vec3 g_sr2 = Wt * apply_k_transpose(intr, g_col1);
    g_log_scales[ss * i] = dot(r1, g_sr1) * s.x;
    g_log_scales[ss * i + 1u] = dot(r2, g_sr2) * s.y;
    for (uint k = 2u; k < ss; k++) g_log_scales[ss * i + k] = 0.0;

    // n = sign·W r3, the sign of the forward's camera-facing flip.
    vec3 n_raw = W * r3;
    float sign_n = -dot(t, n_raw) < 0.0 ? -1.0 : 1.0;
    vec3 g_r3 = sign_n * (Wt * g_n);
    vec3 g_r1 = g_sr1 * s.x, g_r2 = g_sr2 * s.y;
    // ∂L/∂R rows: row j = (∂L/∂r1[j], ∂L/∂r2[j], ∂L/∂r3[j]).
    vec3 dl_dR[3] = vec3[3](vec3(g_r1.x, g_r2.x, g_r3.x), vec3(g_r1.y, g_r2.y, g_r3.y),
                            vec3(g_r1.z, g_r2.z, g_r3.z));
    vec4 dl_dq = vec4(0.0);
    if (quat_ok) {
        vec4 dl_dunit = rotation_backward(unit, dl_dR);
        dl_dq = (dl_dunit - unit * dot(unit, dl_dunit)) / qn;
    }
    for (uint k = 0u; k < 4u; k++) g_rotations[4u * i + k] = dl_dq[k];
}
