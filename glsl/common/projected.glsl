// What preprocess writes per Gaussian (std430, 64 bytes); mirrors `ProjectedGpu` in
// src/render/layout.rs. radius == 0 means culled (and the tile rectangle is empty).
struct Projected {
    float mean_x, mean_y, depth, opacity;
    float conic_a, conic_b, conic_c, radius;
    float r, g, b;
    uint flags;  // bit c: colour channel c was clamped at 0 (passes no gradient)
    uint tile_min_x, tile_min_y, tile_max_x, tile_max_y;
};

// The rasterizer's constants (push constant block member); mirrors `RenderConstants`.
struct RenderConstants {
    float near, eps2d, fov_clamp, det_min;
    float alpha_min, alpha_max, t_min;
    uint smooth_mode;
};
