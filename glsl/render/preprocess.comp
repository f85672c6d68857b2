#version 460
// Forward step 1: one invocation per Gaussian. World → camera, near-plane cull, 3D covariance,
// EWA projection, conic, screen radius, tile rectangle and SH colour; also the depth sort key.
// Mirrors src/reference/project.rs step by step (the numbered steps of src/reference/mod.rs).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"
#include "sh_basis.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 2) readonly buffer Rotations { vec4 rotations[]; };
layout(std430, set = 0, binding = 3) readonly buffer Opacities { float opacity_logits[]; };
layout(std430, set = 0, binding = 4) readonly buffer ShDc { float sh_dc[]; };
layout(std430, set = 0, binding = 5) readonly buffer ShRest0 { float sh_rest0[]; };
layout(std430, set = 0, binding = 6) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 7) writeonly buffer OutSplats { ProjectedSplat projected_splats[]; };
// Depth sort input: key = camera-z float bits (positive floats order as uints), culled last;
// value = Gaussian index, so a stable sort breaks depth ties by index like the reference.
layout(std430, set = 0, binding = 8) writeonly buffer DepthKeys { uint depth_keys[]; };
layout(std430, set = 0, binding = 9) writeonly buffer DepthVals { uint depth_vals[]; };
layout(std430, set = 0, binding = 10) buffer Counts { uint counts[]; };
// Mip-Splatting's 3D filter (flag 4): one standard deviation per Gaussian.
layout(std430, set = 0, binding = 11) readonly buffer Filter3d { float filter3d[]; };
layout(std430, set = 0, binding = 12) readonly buffer ShRest1 { float sh_rest1[]; };
layout(std430, set = 0, binding = 13) readonly buffer ShRest2 { float sh_rest2[]; };
layout(std430, set = 0, binding = 14) writeonly buffer OutBounds { ProjectedBounds projected_bounds_out[]; };
layout(std430, set = 0, binding = 15) readonly buffer ShRest3 { float sh_rest3[]; };
layout(std430, set = 0, binding = 16) readonly buffer ShRest4 { float sh_rest4[]; };
#include "sh_rest_planes.glsl"

layout(push_constant) uniform Push {
    uint count;
    uint camera_index;
    uint sh_degree;      // active degree
    uint rest_coeffs;    // stored SH rest coefficients per Gaussian ((D+1)² − 1)
    RenderConstants rc;
};

const float QUAT_NORM2_MIN = 1e-24;

mat3 quat_to_rotation(vec4 q) {  // (w, x, y, z), unit; row-major rows written as columns below
    float w = q.x, x = q.y, y = q.z, z = q.w;
    // GLSL matrices are column-major: mat3(c0, c1, c2).
    return mat3(
        vec3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)));
}

void write_culled(uint i, float depth) {
    Projected p;
    p.mean_x = 0.0; p.mean_y = 0.0; p.depth = depth; p.opacity = 0.0;
    p.conic_a = 0.0; p.conic_b = 0.0; p.conic_c = 0.0; p.radius = 0.0;
    p.r = 0.0; p.g = 0.0; p.b = 0.0; p.flags = 0u;
    p.tile_min_x = 0u; p.tile_min_y = 0u; p.tile_max_x = 0u; p.tile_max_y = 0u;
    projected_splats[i] = projected_splat(p);
    projected_bounds_out[i] = projected_bounds(p);
    depth_keys[i] = CULLED_DEPTH_KEY;
    depth_vals[i] = i;
}

bool finite(float v) { return !isnan(v) && !isinf(v); }

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (i == 0u) counts[0] = count;
    if (i >= count) return;
    Camera cam = cameras[camera_index];
    vec3 pos = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    vec3 t = camera_transform(cam, pos);
    // Step 1: near plane (a NaN depth fails the comparison and is culled too).
    if (!(t.z > rc.near)) { write_culled(i, t.z); return; }

    // Step 2: rotation; a (near-)zero or non-finite quaternion reads as the identity.
    vec4 q = rotations[i];
    float n2 = dot(q, q);
    mat3 R = (finite(n2) && n2 >= QUAT_NORM2_MIN) ? quat_to_rotation(q * inversesqrt(n2))
                                                  : mat3(1.0);
    // Step 3: M = R S, Σ = M Mᵀ, rotated into the camera: W M.
    vec3 s = exp(vec3(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]));
    // Mip-Splatting's 3D filter: Σ + f²·I (R is orthonormal) and the opacity that keeps the
    // Gaussian's integral.
    float rho3d = 1.0;
    if ((rc.flags & 4u) != 0u) s = filtered_scales(s, filter3d[i], rho3d);
    mat3 M = mat3(R[0] * s.x, R[1] * s.y, R[2] * s.z);
    mat3 W = transpose(mat3(cam.r0.xyz, cam.r1.xyz, cam.r2.xyz));  // rows r0, r1, r2
    mat3 WM = W * M;

    // Step 4: EWA Jacobian with x/z, y/z clamped to fov_clamp × the half-FoV tangents measured
    // from the principal point (keeps off-screen Gaussians from exploding the footprint).
    float fx = cam.intrinsics.x, fy = cam.intrinsics.y, cx = cam.intrinsics.z, cy = cam.intrinsics.w;
    float wd = float(cam.size.x), ht = float(cam.size.y);
    float tx = min(max(t.x / t.z, -rc.fov_clamp * cx / fx), rc.fov_clamp * (wd - cx) / fx);
    float ty = min(max(t.y / t.z, -rc.fov_clamp * cy / fy), rc.fov_clamp * (ht - cy) / fy);
    // Rows of J: (fx/z, 0, −fx·tx/z) and (0, fy/z, −fy·ty/z).
    vec3 j0 = vec3(fx / t.z, 0.0, -fx * tx / t.z);
    vec3 j1 = vec3(0.0, fy / t.z, -fy * ty / t.z);
    // Rows of J·W·M: u_k = (J W M) row k = (row k of J) · (W M).
    vec3 u0 = j0 * WM;
    vec3 u1 = j1 * WM;
    // Step 5: Σ2D = (JWM)(JWM)ᵀ + eps2d·I (the low-pass dilation).
    float a = dot(u0, u0) + rc.eps2d;
    float b = dot(u0, u1);
    float c = dot(u1, u1) + rc.eps2d;

    // Step 6: cull a non-positive determinant, clamp it away from 0, invert.
    float det_raw = a * c - b * b;
    if (!(det_raw > 0.0)) { write_culled(i, t.z); return; }
    float det = max(det_raw, rc.det_min);
    vec3 conic = vec3(c / det, -b / det, a / det);

    // Step 7: radius from the larger eigenvalue.
    float mid = 0.5 * (a + c);
    float lambda_max = mid + sqrt(max(mid * mid - det, 0.0));
    float radius = ceil(3.0 * sqrt(lambda_max));
    vec2 mean2d = vec2(fx * t.x / t.z + cx, fy * t.y / t.z + cy);

    // Step 9: colour from SH along the view direction, +0.5, clamped at 0.
    vec3 dir = normalize(pos - cam.center.xyz);
    float basis[16];
    sh_basis(sh_degree, dir, basis);
    vec3 raw = basis[0] * vec3(sh_dc[3u * i], sh_dc[3u * i + 1u], sh_dc[3u * i + 2u]);
    uint ncoef = min((sh_degree + 1u) * (sh_degree + 1u), rest_coeffs + 1u);
    uint n_rest = ncoef - 1u;
    FOR_EACH_SH_REST_PLANE(SH_REST_PLANE_COLOUR)
    vec3 shifted = raw + 0.5;
    uint flags = (shifted.r < 0.0 ? 1u : 0u) | (shifted.g < 0.0 ? 2u : 0u) | (shifted.b < 0.0 ? 4u : 0u);
    vec3 rgb = max(shifted, vec3(0.0));
    // Flag 8 (SpacetimeGaussians' full model): the DC coefficients are raw features, blended
    // as they are (no offset, no clamp, no view dependence); the decoder makes them colours.
    if ((rc.flags & 8u) != 0u) {
        rgb = vec3(sh_dc[3u * i], sh_dc[3u * i + 1u], sh_dc[3u * i + 2u]);
        flags = 0u;
    }

    // Step 5 (Mip-Splatting's 2D filter, flag 2): opacity × ρ, ρ² = det0 / det1 with the
    // undilated determinant taken as |u0 × u1|² (no cancellation for thin footprints).
    float compensation = 1.0;
    if ((rc.flags & 2u) != 0u) {
        vec3 cr = cross(u0, u1);
        bool floored;
        compensation = mip_compensation(dot(cr, cr), det_raw, floored);
    }

    // Step 10: nothing non-finite reaches the rasterizer.
    float opacity = rho3d * compensation / (1.0 + exp(-opacity_logits[i]));
    bool ok = finite(mean2d.x) && finite(mean2d.y) && finite(conic.x) && finite(conic.y) &&
              finite(conic.z) && finite(radius) && finite(raw.r) && finite(raw.g) &&
              finite(raw.b) && finite(opacity);
    if (!ok) { write_culled(i, t.z); return; }

    // Step 8: tile rectangle [min, max), clamped to the grid in float before converting so a
    // huge or far off-screen footprint cannot overflow an integer. Its half-size is the 3σ
    // radius or, when smaller, the distance past which opacity·exp(power) < alpha_min in every
    // direction (the splat is skipped there anyway: same image, fewer pairs to sort and blend).
    float ts = 16.0;
    vec2 grid = vec2(cam.size.zw);
    // Off-screen test on the 3σ square: Inria's "visible" (radius > 0) ignores opacity.
    vec2 lo3 = clamp(floor((mean2d - radius) / ts), vec2(0.0), grid);
    vec2 hi3 = clamp(ceil((mean2d + radius) / ts), vec2(0.0), grid);
    bool on_screen = hi3.x > lo3.x && hi3.y > lo3.y;
    float extent = radius;
    if ((rc.flags & 1u) == 0u) {
        float p_max = log(opacity / rc.alpha_min);
        extent = p_max > 0.0 ? min(radius, ceil(sqrt(2.0 * p_max * lambda_max))) : 0.0;
    }
    vec2 lo = clamp(floor((mean2d - extent) / ts), vec2(0.0), grid);
    vec2 hi = clamp(ceil((mean2d + extent) / ts), vec2(0.0), grid);
    if (!(extent > 0.0)) { lo = vec2(0.0); hi = vec2(0.0); }
    Projected p;
    p.mean_x = mean2d.x; p.mean_y = mean2d.y; p.depth = t.z; p.opacity = opacity;
    p.conic_a = conic.x; p.conic_b = conic.y; p.conic_c = conic.z; p.radius = radius;
    p.r = rgb.r; p.g = rgb.g; p.b = rgb.b; p.flags = flags;
    p.tile_min_x = uint(lo.x); p.tile_min_y = uint(lo.y);
    p.tile_max_x = uint(hi.x); p.tile_max_y = uint(hi.y);
    bool touches = p.tile_max_x > p.tile_min_x && p.tile_max_y > p.tile_min_y;
    if (!on_screen) p.radius = 0.0;  // off-screen: treated as culled downstream
    projected_splats[i] = projected_splat(p);
    projected_bounds_out[i] = projected_bounds(p);
    depth_keys[i] = touches ? floatBitsToUint(t.z) : CULLED_DEPTH_KEY;
    depth_vals[i] = i;
}
