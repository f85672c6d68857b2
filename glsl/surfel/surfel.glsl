// 2DGS surfels on the GPU: the per-surfel geometry preprocess writes beside `Projected`, the
// rasterizer's constants, and the ray–splat intersection every surfel kernel shares. Mirrors
// src/render/surfel/layout.rs and src/reference/surfel (the numbered steps of its module docs).

// Per surfel, 12 floats (`SurfelGeomGpu`): the rows h1, h2, h3 of the transform M from
// (u, v, 1) to homogeneous pixels, then the camera-facing camera-space normal.
const uint GEOM_STRIDE = 12u;

// Per pixel, 8 floats (`SurfelMapsGpu`): expected-depth numerator Σw·z, median depth, Σw·n
// (3), distortion, M1 = Σw·m(z), M2 = Σw·m(z)².
const uint MAPS_STRIDE = 8u;

// The surfel rasterizer's constants (push constant block member); mirrors `SurfelConstants`.
struct SurfelConstants {
    float near, far, alpha_min, alpha_max;
    float t_min, filter_inv_square, cutoff;
    uint flags;  // 1: smooth test mode
};

bool surfel_finite(float v) { return !isnan(v) && !isinf(v); }

// The distortion's mapped depth m(z) = far/(far − near)·(1 − near/z).
float mapped_depth(SurfelConstants sc, float z) {
    return sc.far / (sc.far - sc.near) * (1.0 - sc.near / z);
}

// One surfel at one pixel centre (steps 1–4 of the rasterizer). Returns false when the pair is
// skipped (ray parallel to the plane, non-finite or near hit, too faint). `alpha_clamped`:
// opacity·G was above alpha_max (no gradient through alpha).
struct SurfelHit {
    vec3 a, c, p;   // planes x·h3 − h1, y·h3 − h2 and their intersection a × c
    vec2 uv;
    float z, gauss, alpha;
    bool lowpass, alpha_clamped;
};

bool surfel_sample(SurfelConstants sc, vec3 h1, vec3 h2, vec3 h3, vec2 m, float opacity,
                   vec2 pix, out SurfelHit s) {
    s.a = pix.x * h3 - h1;
    s.c = pix.y * h3 - h2;
    s.p = cross(s.a, s.c);
    // The official guard: only an exactly parallel ray is skipped before the division.
    if (s.p.z == 0.0) return false;
    s.uv = s.p.xy / s.p.z;
    s.z = s.uv.x * h3.x + s.uv.y * h3.y + h3.z;
    // Ours: a p3 small enough to overflow the quotient would put inf/NaN into the depth maps.
    if (!surfel_finite(s.z)) return false;
    // Also removes hits behind the camera (negative depth).
    if (s.z < sc.near) return false;
    float rho3d = dot(s.uv, s.uv);
    vec2 d = m - pix;
    float rho2d = sc.filter_inv_square * dot(d, d);
    // The object-space term wins ties (the official backward's branch test).
    s.lowpass = rho3d > rho2d;
    s.gauss = exp(-0.5 * (s.lowpass ? rho2d : rho3d));
    float raw = opacity * s.gauss;
    bool smooth_mode = (sc.flags & 1u) != 0u;
    s.alpha_clamped = !smooth_mode && raw > sc.alpha_max;
    s.alpha = s.alpha_clamped ? sc.alpha_max : raw;
    return smooth_mode || s.alpha >= sc.alpha_min;
}
