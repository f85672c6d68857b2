#version 460
// 2DGS forward step 1: one invocation per surfel. World → camera, near cull, the transform M
// (homography from the surfel's (u, v, 1) to pixels), the camera-facing normal, the screen box
// of the cutoff circle (whose centre is also the low-pass filter's), tile rectangle, SH colour
// and the depth sort key. Mirrors src/reference/surfel/project.rs step by step. Writes the
// shared `Projected` (mean = box centre, conic unused) so binning and sorting are 3DGS's, and
// the surfel geometry (M, normal) beside it.
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(local_size_x_id = 0) in;

#include "camera.glsl"
#include "projected.glsl"
#include "sh_basis.glsl"
#include "surfel.glsl"

layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 2) readonly buffer Rotations { vec4 rotations[]; };
layout(std430, set = 0, binding = 3) readonly buffer Opacities { float opacity_logits[]; };
layout(std430, set = 0, binding = 4) readonly buffer ShDc { float sh_dc[]; };
layout(std430, set = 0, binding = 5) readonly buffer ShRest0 { float sh_rest0[]; };
layout(std430, set = 0, binding = 6) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 7) writeonly buffer OutSplats { ProjectedSplat projected_splats[]; };
layout(std430, set = 0, binding = 8) writeonly buffer DepthKeys { uint depth_keys[]; };
layout(std430, set = 0, binding = 9) writeonly buffer DepthVals { uint depth_vals[]; };
layout(std430, set = 0, binding = 10) buffer Counts { uint counts[]; };
layout(std430, set = 0, binding = 11) writeonly buffer Geom { float geom[]; };
layout(std430, set = 0, binding = 12) readonly buffer ShRest1 { float sh_rest1[]; };
layout(std430, set = 0, binding = 13) readonly buffer ShRest2 { float sh_rest2[]; };
layout(std430, set = 0, binding = 14) writeonly buffer OutBounds { ProjectedBounds projected_bounds_out[]; };
layout(std430, set = 0, binding = 15) writeonly buffer Normals { float normals[]; };
layout(std430, set = 0, binding = 16) readonly buffer ShRest3 { float sh_rest3[]; };
layout(std430, set = 0, binding = 17) readonly buffer ShRest4 { float sh_rest4[]; };
#include "sh_rest_planes.glsl"

layout(push_constant) uniform Push {
    uint count;
    uint camera_index;
    uint sh_degree;      // active degree
    uint rest_coeffs;    // stored SH rest coefficients per surfel ((D+1)² − 1)
    uint scale_stride;   // floats per surfel in log_scales (2, or 3 in a 3DGS-shaped buffer)
    uint pad0, pad1, pad2;
    SurfelConstants sc;
};

const float QUAT_NORM2_MIN = 1e-24;
// The smallest radicand of the box half-extents (official compute_aabb).
const float EXTENT_RADICAND_MIN = 1e-4;

mat3 quat_to_rotation(vec4 q) {  // (w, x, y, z), unit; GLSL matrices are column-major
    float w = q.x, x = q.y, y = q.z, z = q.w;
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
    for (uint k = 0u; k < GEOM_STRIDE; k++) geom[GEOM_STRIDE * i + k] = 0.0;
    for (uint k = 0u; k < 3u; k++) normals[3u * i + k] = 0.0;
    depth_keys[i] = CULLED_DEPTH_KEY;
    depth_vals[i] = i;
}

// K v for a camera-space vector.
vec3 apply_k(vec4 intr, vec3 v) {
    return vec3(intr.x * v.x + intr.z * v.z, intr.y * v.y + intr.w * v.z, v.z);
}

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * WG_SIZE;
    if (i == 0u) counts[0] = count;
    if (i >= count) return;
    Camera cam = cameras[camera_index];
    vec3 pos = vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
    vec3 t = camera_transform(cam, pos);
    // Step 1: near cull on the centre (a NaN depth fails the comparison and is culled too).
    if (!(t.z > sc.near)) { write_culled(i, t.z); return; }

    // Steps 2–3: rotation (a (near-)zero or non-finite quaternion reads as the identity),
    // scales, M = [K W (s_u r1) | K W (s_v r2) | K t].
    vec4 q = rotations[i];
    float n2 = dot(q, q);
    mat3 R = (surfel_finite(n2) && n2 >= QUAT_NORM2_MIN) ? quat_to_rotation(q * inversesqrt(n2))
                                                         : mat3(1.0);
    vec2 s = exp(vec2(log_scales[scale_stride * i], log_scales[scale_stride * i + 1u]));
    mat3 W = transpose(mat3(cam.r0.xyz, cam.r1.xyz, cam.r2.xyz));  // rows r0, r1, r2
    vec3 col0 = apply_k(cam.intrinsics, W * (R[0] * s.x));
    vec3 col1 = apply_k(cam.intrinsics, W * (R[1] * s.y));
    vec3 col2 = apply_k(cam.intrinsics, t);
    vec3 h1 = vec3(col0.x, col1.x, col2.x);
    vec3 h2 = vec3(col0.y, col1.y, col2.y);
    vec3 h3 = vec3(col0.z, col1.z, col2.z);

    // Step 4: the normal, flipped to face the camera; exactly edge-on (the plane holds the
    // camera centre) is culled, a NaN fails the finiteness test below.
    vec3 n = W * R[2];
    float cos_view = -dot(t, n);
    if (cos_view == 0.0) { write_culled(i, t.z); return; }
    if (cos_view < 0.0) n = -n;

    // Step 5: the box of the image of the circle u² + v² = cutoff² through the dual conic
    // M diag(τ) Mᵀ, τ = (k², k², −1).
    float k2 = sc.cutoff * sc.cutoff;
    vec3 tau = vec3(k2, k2, -1.0);
    float d = dot(tau, h3 * h3);
    if (d == 0.0) { write_culled(i, t.z); return; }
    vec3 f = tau / d;
    vec2 m = vec2(dot(f, h1 * h3), dot(f, h2 * h3));
    vec2 quad = vec2(dot(f, h1 * h1), dot(f, h2 * h2));
    // The clamp keeps the square root real for a line-like image or rounding; a NaN radicand
    // comes with a non-finite centre, culled below.
    vec2 radicand = m * m - quad;
    vec2 extent = sqrt(vec2(radicand.x > EXTENT_RADICAND_MIN ? radicand.x : EXTENT_RADICAND_MIN,
                            radicand.y > EXTENT_RADICAND_MIN ? radicand.y : EXTENT_RADICAND_MIN));
    float radius = ceil(max(max(extent.x, extent.y), sc.cutoff * inversesqrt(sc.filter_inv_square)));

    // Step 6: colour from SH along the view direction, +0.5, clamped at 0.
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
    float opacity = 1.0 / (1.0 + exp(-opacity_logits[i]));

    // Step 7: nothing non-finite reaches the rasterizer (d overflows to inf for astronomical
    // scales, where the box would still be finite but meaningless).
    bool ok = surfel_finite(d) && surfel_finite(m.x) && surfel_finite(m.y) &&
              surfel_finite(extent.x) && surfel_finite(extent.y) && surfel_finite(radius) &&
              surfel_finite(raw.r) && surfel_finite(raw.g) && surfel_finite(raw.b) &&
              surfel_finite(opacity) && surfel_finite(n.x) && surfel_finite(n.y) &&
              surfel_finite(n.z);
    for (uint r = 0u; r < 3u; r++) {
        ok = ok && surfel_finite(h1[r]) && surfel_finite(h2[r]) && surfel_finite(h3[r]);
    }
    if (!ok) { write_culled(i, t.z); return; }

    // Step 8: the conservative tile rectangle [floor((m − r)/16), ceil((m + r)/16)), clamped to
    // the grid in float before converting (no opacity-aware shrinking, like the reference).
    vec2 grid = vec2(cam.size.zw);
    vec2 lo = clamp(floor((m - radius) / 16.0), vec2(0.0), grid);
    vec2 hi = clamp(ceil((m + radius) / 16.0), vec2(0.0), grid);
    Projected p;
    p.mean_x = m.x; p.mean_y = m.y; p.depth = t.z; p.opacity = opacity;
    p.conic_a = 0.0; p.conic_b = 0.0; p.conic_c = 0.0; p.radius = radius;
    p.r = rgb.r; p.g = rgb.g; p.b = rgb.b; p.flags = flags;
    p.tile_min_x = uint(lo.x); p.tile_min_y = uint(lo.y);
    p.tile_max_x = uint(hi.x); p.tile_max_y = uint(hi.y);
    bool touches = p.tile_max_x > p.tile_min_x && p.tile_max_y > p.tile_min_y;
    if (!touches) p.radius = 0.0;  // off-screen: culled downstream
    projected_splats[i] = projected_splat(p);
    projected_bounds_out[i] = projected_bounds(p);
    uint g = GEOM_STRIDE * i;
    for (uint r = 0u; r < 3u; r++) {
        geom[g + r] = h1[r];
        geom[g + 3u + r] = h2[r];
        geom[g + 6u + r] = h3[r];
        normals[3u * i + r] = n[r];
    }
    // Step 9: sort by the centre's camera depth.
    depth_keys[i] = touches ? floatBitsToUint(t.z) : CULLED_DEPTH_KEY;
    depth_vals[i] = i;
}
