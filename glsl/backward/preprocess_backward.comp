#version 460
// Preprocess backward: one invocation per Gaussian carries the 2D gradients of the rasterizer
// backward (grad2d: mean2d, conic, clamped colour, opacity) to the stored parameters, following
// src/reference/backward.rs step by step. Every output of Gaussians 0..count is WRITTEN (not
// accumulated); culled Gaussians (radius 0) and Gaussians with all-zero 2D gradients get zeros
// (the backward is linear in the 2D gradients, so the latter is exact and also keeps 0·inf
// out of Gaussians with extreme parameters that touched no pixel).
//
// Clamps and where they act (same as the reference):
// - sigmoid: dL/dlogit = dL/dopacity · σ(x)·σ(−x) (no cancellation at large |x|);
// - colour clamp at 0 (flags of Projected): a clamped channel passes no gradient to the SH
//   coefficients nor to the view direction;
// - determinant clamp max(det, det_min): no gradient through det when active;
// - EWA Jacobian x/z, y/z clamp to fov_clamp half-FoV tangents: no gradient through x/z (y/z)
//   when active (the clamped value is a constant);
// - quaternion with |q|² < QUAT_NORM2_MIN (or not finite): read as identity, no gradient;
// - SH coefficients above the active degree: gradient 0.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 1) const uint SUBGROUP_SIZE = 32;
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"

const uint GRAD2D_STRIDE = 9u;
// Below this squared norm a quaternion is the identity (reference::QUAT_NORM2_MIN).
const float QUAT_NORM2_MIN = 1e-24;

layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Bounds { ProjectedBounds bounds[]; };
layout(std430, set = 0, binding = 2) readonly buffer Grad2d { float grad2d[]; };
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
// Mip-Splatting's 3D filter (flag 4): one standard deviation per Gaussian.
layout(std430, set = 0, binding = 16) readonly buffer Filter3d { float filter3d[]; };
layout(std430, set = 0, binding = 17) readonly buffer ShRest1 { float sh_rest1[]; };
layout(std430, set = 0, binding = 18) readonly buffer ShRest2 { float sh_rest2[]; };
layout(std430, set = 0, binding = 19) writeonly buffer GShRest1 { float g_sh_rest1[]; };
layout(std430, set = 0, binding = 20) writeonly buffer GShRest2 { float g_sh_rest2[]; };
layout(std430, set = 0, binding = 21) readonly buffer ShRest3 { float sh_rest3[]; };
layout(std430, set = 0, binding = 22) readonly buffer ShRest4 { float sh_rest4[]; };
layout(std430, set = 0, binding = 23) writeonly buffer GShRest3 { float g_sh_rest3[]; };
layout(std430, set = 0, binding = 24) writeonly buffer GShRest4 { float g_sh_rest4[]; };
#define SH_REST_GRADS
#include "sh_rest_planes.glsl"

layout(push_constant) uniform Push {
    RenderConstants rc;
    uint camera_index;
    uint count;
    uint sh_degree;      // active degree (0..=stored degree)
    uint rest_coeffs;    // stored (d+1)² − 1: fixes the SH rest planes' strides
} pc;

#include "sh_basis_grad.glsl"
#include "quat_backward.glsl"

void write_zeros(uint i) {
    for (uint k = 0u; k < 3u; k++) {
        g_positions[3u * i + k] = 0.0;
        g_log_scales[3u * i + k] = 0.0;
        g_sh_dc[3u * i + k] = 0.0;
    }
    for (uint k = 0u; k < 4u; k++) g_rotations[4u * i + k] = 0.0;
    g_opacity_logits[i] = 0.0;
    FOR_EACH_SH_REST_PLANE(SH_REST_PLANE_ZERO)
    view_grad_norm[i] = 0.0;
}

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * WG_SIZE
             + gl_LocalInvocationIndex;
    if (i >= pc.count) return;
    ProjectedBounds pr = bounds[i];
    uint gb = i * GRAD2D_STRIDE;
    vec2 dl_dmean = vec2(grad2d[gb], grad2d[gb + 1u]);
    vec3 dl_dconic = vec3(grad2d[gb + 2u], grad2d[gb + 3u], grad2d[gb + 4u]);
    vec3 dl_drgb = vec3(grad2d[gb + 5u], grad2d[gb + 6u], grad2d[gb + 7u]);
    float dl_dopacity = grad2d[gb + 8u];
    bool any_grad = any(notEqual(dl_dmean, vec2(0.0))) || any(notEqual(dl_dconic, vec3(0.0)))
                    || any(notEqual(dl_drgb, vec3(0.0))) || dl_dopacity != 0.0;
    if (!(pr.radius > 0.0) || !any_grad) {
        write_zeros(i);
        return;
    }
    Camera cam = cameras[pc.camera_index];
    vec3 W[3] = vec3[3](cam.r0.xyz, cam.r1.xyz, cam.r2.xyz);
    float fx = cam.intrinsics.x, fy = cam.intrinsics.y;
    float cx = cam.intrinsics.z, cy = cam.intrinsics.w;
    float width = float(cam.size.x), height = float(cam.size.y);

    vec3 pos = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    vec3 log_s = vec3(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]);
    vec4 q = vec4(rotations[4u * i], rotations[4u * i + 1u], rotations[4u * i + 2u],
                  rotations[4u * i + 3u]);
    float logit = opacity_logits[i];

    // Opacity: sigmoid' = σ(x)·σ(−x), each factor computed without cancellation.
    float sig_pos = 1.0 / (1.0 + exp(-logit));
    float sig_neg = 1.0 / (1.0 + exp(logit));

    // Colour: SH coefficients and the view direction. Clamp: a channel clamped at 0 in the
    // forward passes no gradient.
    vec3 dl_draw = dl_drgb;
    if ((pr.flags & 1u) != 0u) dl_draw.x = 0.0;
    if ((pr.flags & 2u) != 0u) dl_draw.y = 0.0;
    if ((pr.flags & 4u) != 0u) dl_draw.z = 0.0;
    vec3 view = pos - cam.center.xyz;
    float view_len = length(view);
    vec3 dir = view / view_len;
    // Flag 8: raw DC features (the forward's colour is sh_dc itself, see preprocess.comp).
    bool raw_colour = (pc.rc.flags & 8u) != 0u;
    uint n_active = raw_colour ? 1u : (pc.sh_degree + 1u) * (pc.sh_degree + 1u);
    vec3 dl_ddir = vec3(0.0);
    {
        vec3 bgrad;
        float b = sh_basis(0u, dir, bgrad);
        if (raw_colour) {
            b = 1.0;
            bgrad = vec3(0.0);
        }
        vec3 coeff = vec3(sh_dc[3u * i], sh_dc[3u * i + 1u], sh_dc[3u * i + 2u]);
        g_sh_dc[3u * i] = b * dl_draw.x;
        g_sh_dc[3u * i + 1u] = b * dl_draw.y;
        g_sh_dc[3u * i + 2u] = b * dl_draw.z;
        dl_ddir += bgrad * dot(coeff, dl_draw);
    }
    // The rest coefficients up to the active degree; those above it do not take part
    // (gradient 0).
    uint n_rest = min(n_active - 1u, pc.rest_coeffs);
    FOR_EACH_SH_REST_PLANE(SH_REST_PLANE_BACKWARD)
    // dir = v/|v|: d dir/dv = (I − dir dirᵀ)/|v|.
    vec3 dl_dpos = (dl_ddir - dir * dot(dir, dl_ddir)) / view_len;

    // Camera-space mean.
    vec3 t = camera_transform(cam, pos);
    float z = t.z;

    // 3D covariance factor M = R S (rows), Σ = M Mᵀ. Clamp: degenerate quaternion → identity.
    float qn2 = dot(q, q);
    bool quat_ok = !(isinf(qn2) || isnan(qn2)) && qn2 >= QUAT_NORM2_MIN;
    float qn = sqrt(qn2);
    vec4 unit = quat_ok ? q / qn : vec4(1.0, 0.0, 0.0, 0.0);
    vec3 R[3];
    quat_rows(unit, R);
    vec3 s = exp(log_s);
    // Mip-Splatting's 3D filter: the covariance is built from s' = sqrt(s² + f²), the opacity
    // carries ρ3 = sqrt(Π s² / Π s'²); w = s² / s'² = dl'/dl (l = log-scale).
    float rho3d = 1.0;
    vec3 w = vec3(1.0);
    bool filtered = (pc.rc.flags & 4u) != 0u;
    if (filtered) {
        vec3 s_raw = s;
        s = filtered_scales(s_raw, filter3d[i], rho3d);
        w = (s_raw * s_raw) / (s * s);
    }
    vec3 M[3] = vec3[3](R[0] * s, R[1] * s, R[2] * s);

    // EWA Jacobian. Clamp: x/z and y/z limited to fov_clamp half-FoV tangents measured from the
    // principal point, written min(max(·)) so an inverted interval still gives a number; a
    // clamped ratio is a constant (no gradient through it).
    float lim_x_lo = -pc.rc.fov_clamp * cx / fx, lim_x_hi = pc.rc.fov_clamp * (width - cx) / fx;
    float lim_y_lo = -pc.rc.fov_clamp * cy / fy, lim_y_hi = pc.rc.fov_clamp * (height - cy) / fy;
    float tx_raw = t.x / z, ty_raw = t.y / z;
    float tx = min(max(tx_raw, lim_x_lo), lim_x_hi);
    float ty = min(max(ty_raw, lim_y_lo), lim_y_hi);
    bool clamp_x = tx != tx_raw, clamp_y = ty != ty_raw;
    vec3 J0 = vec3(fx / z, 0.0, -fx * tx / z);
    vec3 J1 = vec3(0.0, fy / z, -fy * ty / z);
    // T = J W (2×3 rows).
    vec3 T0 = J0.x * W[0] + J0.y * W[1] + J0.z * W[2];
    vec3 T1 = J1.x * W[0] + J1.y * W[1] + J1.z * W[2];
    // A = T M: cov2d (before dilation) = A Aᵀ. The determinant is taken as |A0 × A1|² (the
    // Lagrange identity for a·c − b²) plus the dilation terms: the same value as
    // (a + eps)(c + eps) − b² without its cancellation for large, thin footprints.
    vec3 A0 = vec3(dot(T0, vec3(M[0].x, M[1].x, M[2].x)), dot(T0, vec3(M[0].y, M[1].y, M[2].y)),
                   dot(T0, vec3(M[0].z, M[1].z, M[2].z)));
    vec3 A1 = vec3(dot(T1, vec3(M[0].x, M[1].x, M[2].x)), dot(T1, vec3(M[0].y, M[1].y, M[2].y)),
                   dot(T1, vec3(M[0].z, M[1].z, M[2].z)));
    float ra = dot(A0, A0), rb = dot(A0, A1), rc = dot(A1, A1);
    vec3 cr = cross(A0, A1);
    float a = ra + pc.rc.eps2d, b = rb, c = rc + pc.rc.eps2d;
    float det_raw = dot(cr, cr) + pc.rc.eps2d * (ra + rc) + pc.rc.eps2d * pc.rc.eps2d;

    // Conic [c, −b, a]/det → cov2d. Clamp: det = max(det_raw, det_min); no gradient through
    // det when the clamp is active.
    float det = max(det_raw, pc.rc.det_min);
    // Mip-Splatting's 2D filter (flag 2): the opacity is σ·ρ, ρ = sqrt(det0 / det1) unless
    // floored; dρ/dΣ = ρ/2 · (∇det0 / det0 − ∇det1 / det1), ∇det = (c, −2b, a) of the undilated
    // (det0 = |A0 × A1|²) and dilated (det1) covariance.
    float compensation = 1.0;
    bool floored = true;
    if ((pc.rc.flags & 2u) != 0u) {
        compensation = mip_compensation(dot(cr, cr), det_raw, floored);
    }
    g_opacity_logits[i] = dl_dopacity * rho3d * compensation * sig_pos * sig_neg;
    vec3 dl_dcov;
    if (det_raw >= pc.rc.det_min) {
        // Unclamped: the conic is Σ2D⁻¹, so dL/dΣ2D = −C G C with G the symmetric conic
        // gradient. Equal to the reference's [gc, −gb, ga]/det + dL/ddet·[c, −2b, a], whose two
        // terms nearly cancel in f32 for large round footprints; this form does not.
        vec3 C = vec3(c, -b, a) / det;
        mat2 Cm = mat2(C.x, C.y, C.y, C.z);
        mat2 Gm = mat2(dl_dconic.x, 0.5 * dl_dconic.y, 0.5 * dl_dconic.y, dl_dconic.z);
        mat2 H = -(Cm * Gm * Cm);
        dl_dcov = vec3(H[0][0], 2.0 * H[0][1], H[1][1]);
    } else {
        // Clamped: det is a constant, only the adjugate's entries carry gradient.
        dl_dcov = vec3(dl_dconic.z, -dl_dconic.y, dl_dconic.x) / det;
    }

    if (!floored) {
        float det0 = dot(cr, cr);
        float k = dl_dopacity * sig_pos * rho3d * 0.5 * compensation;
        dl_dcov += k * (vec3(rc, -2.0 * b, ra) / det0 - vec3(c, -2.0 * b, a) / det_raw);
    }
    // cov2d = T Σ Tᵀ + eps·I. G is the symmetric gradient (b appears twice: half each).
    float g00 = dl_dcov.x, g01 = 0.5 * dl_dcov.y, g11 = dl_dcov.z;
    // Σ rows.
    vec3 S[3];
    for (int r = 0; r < 3; r++) {
        S[r] = vec3(dot(M[r], M[0]), dot(M[r], M[1]), dot(M[r], M[2]));
    }
    // dL/dΣ = Tᵀ G T: entry (r, col) = Σ_mn T[m][r] G[m][n] T[n][col].
    vec3 GT0 = g00 * T0 + g01 * T1;  // row 0 of G T
    vec3 GT1 = g01 * T0 + g11 * T1;  // row 1 of G T
    vec3 dl_dsigma[3];
    for (int r = 0; r < 3; r++) dl_dsigma[r] = T0[r] * GT0 + T1[r] * GT1;
    // dL/dT = 2 G T Σ = 2 (G T) Σ (Σ symmetric).
    vec3 dl_dT0 = 2.0 * (GT0.x * S[0] + GT0.y * S[1] + GT0.z * S[2]);
    vec3 dl_dT1 = 2.0 * (GT1.x * S[0] + GT1.y * S[1] + GT1.z * S[2]);
    // dL/dJ = dL/dT Wᵀ.
    vec3 dl_dJ0 = vec3(dot(dl_dT0, W[0]), dot(dl_dT0, W[1]), dot(dl_dT0, W[2]));
    vec3 dl_dJ1 = vec3(dot(dl_dT1, W[0]), dot(dl_dT1, W[1]), dot(dl_dT1, W[2]));

    // Jacobian → camera-space mean.
    float z2 = z * z;
    vec3 dl_dt = vec3(0.0);
    dl_dt.z += dl_dJ0.x * (-fx / z2) + dl_dJ1.y * (-fy / z2);
    dl_dt.z += dl_dJ0.z * (fx * tx / z2) + dl_dJ1.z * (fy * ty / z2);
    if (!clamp_x) {
        float dl_dtx = dl_dJ0.z * (-fx / z);
        dl_dt.x += dl_dtx / z;
        dl_dt.z += dl_dtx * (-t.x / z2);
    }
    if (!clamp_y) {
        float dl_dty = dl_dJ1.z * (-fy / z);
        dl_dt.y += dl_dty / z;
        dl_dt.z += dl_dty * (-t.y / z2);
    }
    // Projected mean u = fx·x/z + cx, v = fy·y/z + cy (not clamped).
    dl_dt.x += dl_dmean.x * fx / z;
    dl_dt.y += dl_dmean.y * fy / z;
    dl_dt.z += -dl_dmean.x * fx * t.x / z2 - dl_dmean.y * fy * t.y / z2;

    // Camera → world: t = W p + T, so dL/dp += Wᵀ dL/dt.
    dl_dpos += dl_dt.x * W[0] + dl_dt.y * W[1] + dl_dt.z * W[2];
    g_positions[3u * i] = dl_dpos.x;
    g_positions[3u * i + 1u] = dl_dpos.y;
    g_positions[3u * i + 2u] = dl_dpos.z;

    // Σ = M Mᵀ → dL/dM = 2 dL/dΣ M; M = R diag(s).
    vec3 dl_dls = vec3(0.0);
    vec3 dl_dR[3];
    for (int r = 0; r < 3; r++) {
        vec3 dm = 2.0 * (dl_dsigma[r].x * M[0] + dl_dsigma[r].y * M[1] + dl_dsigma[r].z * M[2]);
        dl_dls += dm * R[r] * s;
        dl_dR[r] = dm * s;
    }
    if (filtered) {
        // dL/dl = dL/dl' · w, plus the opacity factor: ∂ ln ρ3 / ∂l_k = 1 − w_k.
        float opacity_eff = sig_pos * rho3d * compensation;
        dl_dls = dl_dls * w + dl_dopacity * opacity_eff * (vec3(1.0) - w);
    }
    g_log_scales[3u * i] = dl_dls.x;
    g_log_scales[3u * i + 1u] = dl_dls.y;
    g_log_scales[3u * i + 2u] = dl_dls.z;

    vec4 dl_dq = vec4(0.0);
    if (quat_ok) {
        vec4 dl_dunit = rotation_backward(unit, dl_dR);
        // q̂ = q/|q|: dL/dq = (dL/dq̂ − q̂ (q̂·dL/dq̂)) / |q|.
        dl_dq = (dl_dunit - unit * dot(unit, dl_dunit)) / qn;
    }
    g_rotations[4u * i] = dl_dq.x;
    g_rotations[4u * i + 1u] = dl_dq.y;
    g_rotations[4u * i + 2u] = dl_dq.z;
    g_rotations[4u * i + 3u] = dl_dq.w;

    // Density control's statistic: the mean2d gradient in NDC units.
    view_grad_norm[i] = length(vec2(dl_dmean.x * 0.5 * width, dl_dmean.y * 0.5 * height));
}
