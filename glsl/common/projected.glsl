// What preprocess computes per Gaussian (a local record; mirrors `ProjectedGpu` in
// src/render/layout.rs). radius == 0 means culled (and the tile rectangle is empty).
struct Projected {
    float mean_x, mean_y, depth, opacity;
    float conic_a, conic_b, conic_c, radius;
    float r, g, b;
    uint flags;  // bit c: colour channel c was clamped at 0 (passes no gradient)
    uint tile_min_x, tile_min_y, tile_max_x, tile_max_y;
};

// The depth sort's key: the bits of the camera depth, a positive float past the near plane
// (> 0), so the sign bit is always clear and the sort takes 31 bits (7 passes rather than 8:
// `RadixSort::pass_widths`). Culled splats carry the largest key, above +inf's bits, and end
// last. `DEPTH_KEY_BITS` in src/render/forward.rs must match.
const uint CULLED_DEPTH_KEY = 0x7FFFFFFFu;

// It is stored as two buffers, so that no per-Gaussian buffer is wider than 36 bytes and one
// storage binding (128 MiB on lavapipe) holds 3.7 M Gaussians rather than 2.1 M; the split also
// follows the readers: the rasterizers, forward and backward, read only `ProjectedSplat`;
// binning, density statistics and the preprocess backward read only `ProjectedBounds`.
// std430 lays both out as tightly packed scalars (`ProjectedSplatGpu`, `ProjectedBoundsGpu`).
struct ProjectedSplat {
    float mean_x, mean_y, opacity;
    float conic_a, conic_b, conic_c;
    float r, g, b;
};
struct ProjectedBounds {
    float depth, radius;
    uint flags;
    uint tile_min_x, tile_min_y, tile_max_x, tile_max_y;
};

ProjectedSplat projected_splat(Projected p) {
    return ProjectedSplat(p.mean_x, p.mean_y, p.opacity, p.conic_a, p.conic_b, p.conic_c,
                          p.r, p.g, p.b);
}

ProjectedBounds projected_bounds(Projected p) {
    return ProjectedBounds(p.depth, p.radius, p.flags, p.tile_min_x, p.tile_min_y,
                           p.tile_max_x, p.tile_max_y);
}

// Mip-Splatting's 2D filter: the floor of its opacity compensation (reference::MIP_MIN_COMPENSATION).
const float MIP_MIN_COMPENSATION = 0.005;

// The 2D filter's opacity factor sqrt(max(floor², det0 / det1)) from the undilated
// determinant det0 and the dilated det1; `floored` says the floor is active (no gradient).
float mip_compensation(float det0, float det1, out bool floored) {
    float ratio = det0 / det1;
    floored = !(ratio > MIP_MIN_COMPENSATION * MIP_MIN_COMPENSATION);
    return floored ? MIP_MIN_COMPENSATION : sqrt(ratio);
}

// Mip-Splatting's 3D filter of standard deviation f: the scales the renderer uses,
// sqrt(s² + f²), and the opacity factor sqrt(Π s² / Π (s² + f²)) (src/reference/mip.rs).
vec3 filtered_scales(vec3 s, float f, out float rho) {
    float phi = f * f;
    vec3 s2 = s * s;
    vec3 w = s2 / (s2 + phi);
    rho = sqrt(w.x * w.y * w.z);
    return sqrt(s2 + phi);
}

// The rasterizer's constants (push constant block member); mirrors `RenderConstants`.
struct RenderConstants {
    float near, eps2d, fov_clamp, det_min;
    float alpha_min, alpha_max, t_min;
    uint flags;  // 1: smooth test mode; 2: Mip-Splatting's 2D filter compensation
};
