// 2DGS surfels on the GPU: the per-surfel geometry preprocess writes beside `Projected`, the
// rasterizer's constants, and the ray–splat intersection every surfel kernel shares. Mirrors
// src/render/surfel/layout.rs and src/reference/surfel (the numbered steps of its module docs).

// Per surfel, 9 floats (`SurfelGeomGpu`): the rows h1, h2, h3 of the transform M from
// (u, v, 1) to homogeneous pixels; the camera-facing camera-space normal is a second buffer of
// 3 floats (one of 12 floats, 48 bytes, would fill a 128 MiB storage binding at 2.8 M surfels;
// no per-surfel buffer is wider than 36 bytes).
const uint GEOM_STRIDE = 9u;

// Per pixel, 8 floats (`SurfelMapsGpu`): expected-depth numerator Σw·z, median depth, Σw·n
// (3), distortion, M1 = Σw·m(z), M2 = Σw·m(z)².
const uint MAPS_STRIDE = 8u;

// The surfel rasterizer's constants (push constant block member); mirrors `SurfelConstants`.
struct SurfelConstants {
    float near, far, alpha_min, alpha_max;
    float t_min, filter_inv_square, cutoff;
    uint flags;  // 1: smooth test mode; 2: no reach bound (every subgroup visits every surfel)
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

// Half extents (x, y), around the box centre m, of the pixels where the surfel can reach
// alpha_min (surfel_sample's test), with margins for f32 rounding (2 % on the squared
// radius, 1 % and a pixel on the extents): a pixel outside the box gets no alpha in the forward
// and no gradient in the backward, so the rasterizers' subgroups skip surfels whose box misses
// all their pixels. Such a pixel has min(rho3d, rho2d) > 2p, p = ln(opacity / alpha_min):
// outside the low-pass disk around m and outside the image of the disk u² + v² <= 2p, which is
// bounded (an ellipse) when the whole disk lies in front of the camera; its box comes from the
// dual conic as in preprocess.comp step 5, here in pixels relative to m so that f32 does not
// lose the small extents against coordinates of hundreds of pixels. Negative: the surfel
// reaches no pixel; 1e30: no usable bound (smooth mode, a disk crossing the camera plane or
// nearly so, non-finite values).
vec2 surfel_reach(SurfelConstants sc, vec3 h1, vec3 h2, vec3 h3, vec2 m, float opacity) {
    if ((sc.flags & 3u) != 0u) return vec2(1e30);
    float p = log(opacity / sc.alpha_min) + 1e-3;
    if (p < 0.0) return vec2(-1.0);
    float q_cut = 2.0 * p * 1.02 + 1e-3;
    float lowpass = sqrt(q_cut / sc.filter_inv_square);
    // Rows of the homography for pixel coordinates relative to m.
    vec3 g1 = h1 - m.x * h3, g2 = h2 - m.y * h3;
    vec3 tau = vec3(q_cut, q_cut, -1.0);
    float d = dot(tau, h3 * h3);
    // d < 0: the nearest point of the disk is in front of the camera. Close to the horizon
    // the image is so elongated that c² − quad loses the extents in f32: with the bound at
    // −1e-3·h3z² the culled lists dropped real hits of oblique surfels (Truck -r 4, 20
    // iterations on one thread: a different model), from −1e-2 on they matched the full
    // lists bit for bit; −5e-2 keeps a margin (the disk's depth varies by < 97 % of its
    // centre's).
    if (!(d < -5e-2 * h3.z * h3.z)) return vec2(1e30);
    vec3 f = tau / d;
    vec2 c = vec2(dot(f, g1 * h3), dot(f, g2 * h3));
    vec2 quad = vec2(dot(f, g1 * g1), dot(f, g2 * g2));
    vec2 ext = sqrt(max(c * c - quad, vec2(0.0)));
    vec2 reach = max(vec2(lowpass), abs(c) + ext) * 1.01 + 1.0;
    return all(lessThan(reach, vec2(1e30))) ? reach : vec2(1e30);
}
