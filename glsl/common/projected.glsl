// What preprocess writes per Gaussian (std430, 64 bytes); mirrors `ProjectedGpu` in
// src/render/layout.rs. radius == 0 means culled (and the tile rectangle is empty).
struct Projected {
    float mean_x, mean_y, depth, opacity;
    float conic_a, conic_b, conic_c, radius;
    float r, g, b;
    uint flags;  // bit c: colour channel c was clamped at 0 (passes no gradient)
    uint tile_min_x, tile_min_y, tile_max_x, tile_max_y;
};

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
