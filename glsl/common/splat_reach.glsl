// Half extents (x, y) of the box around a splat's mean outside which its alpha is below
// alpha_min, with margins for f32 rounding (1 % and half a pixel): a pixel outside the box
// neither contributes in the forward nor gets a gradient in the backward, so the rasterizers'
// subgroups skip splats whose box misses all their pixels. Negative: the splat touches no pixel
// at all; 1e30: no usable bound (smooth mode, a badly conditioned conic, non-finite input).
vec2 splat_reach(float opacity, vec3 conic, float alpha_min, bool smooth_mode) {
    if (smooth_mode) return vec2(1e30);
    // alpha = opacity·exp(power) >= alpha_min needs −power <= ln(opacity / alpha_min).
    float p = log(opacity / alpha_min) + 1e-3;
    if (p < 0.0) return vec2(-1.0);
    float ac = conic.x * conic.z;
    float det = ac - conic.y * conic.y;
    // det is exact enough (relative error ~1e-7 · ac / det) only while ac / det stays small.
    if (!(det > 1e-4 * ac && ac > 0.0)) return vec2(1e30);
    // The box of {d : dᵀ C d <= 2p} has half extents sqrt(2p · (C⁻¹)ₓₓ), sqrt(2p · (C⁻¹)ᵧᵧ).
    vec2 h = sqrt(2.0 * p * vec2(conic.z, conic.x) / det) * 1.01 + 0.5;
    return all(lessThan(h, vec2(1e30))) ? h : vec2(1e30);
}

// Whether a splat at `mean` with half extents `reach` may touch a pixel centre in [lo, hi].
bool reach_meets(vec2 mean, vec2 reach, vec2 lo, vec2 hi) {
    return all(greaterThanEqual(mean + reach, lo)) && all(lessThanEqual(mean - reach, hi));
}

// The 2p of splat_reach (with the same margins): a pixel can only get alpha >= alpha_min where
// q(d) = a·dx² + 2b·dx·dy + c·dy² (= −2·power) is at most this. −1: never; 1e30: no bound.
float splat_q_cut(float opacity, float alpha_min, bool smooth_mode) {
    if (smooth_mode) return 1e30;
    float p = log(opacity / alpha_min) + 1e-3;
    return p < 0.0 ? -1.0 : 2.0 * p * 1.02 + 1e-3;
}

// Whether the ellipse q(x − mean) <= q_cut meets the box [lo, hi] (conservative: true when the
// conic is too badly conditioned for f32). A convex quadratic whose minimum (the mean) lies
// outside the box is smallest on the box's boundary, so the four edges are enough.
bool ellipse_meets(vec2 mean, vec3 conic, float q_cut, vec2 lo, vec2 hi) {
    float a = conic.x, b = conic.y, c = conic.z;
    float ac = a * c;
    if (!(a > 0.0 && c > 0.0 && ac - b * b > 1e-4 * ac) || q_cut >= 1e30) return q_cut >= 0.0;
    vec2 dlo = lo - mean, dhi = hi - mean;
    if (all(lessThanEqual(dlo, vec2(0.0))) && all(greaterThanEqual(dhi, vec2(0.0)))) {
        return q_cut >= 0.0;
    }
    // Edges x = const: the best dy is −b·dx / c (clamped); edges y = const likewise.
    vec2 dx = vec2(dlo.x, dhi.x);
    vec2 dy_x = clamp(-b * dx / c, vec2(dlo.y), vec2(dhi.y));
    vec2 dy = vec2(dlo.y, dhi.y);
    vec2 dx_y = clamp(-b * dy / a, vec2(dlo.x), vec2(dhi.x));
    vec2 q1 = a * dx * dx + 2.0 * b * dx * dy_x + c * dy_x * dy_x;
    vec2 q2 = a * dx_y * dx_y + 2.0 * b * dx_y * dy + c * dy * dy;
    return min(min(q1.x, q1.y), min(q2.x, q2.y)) <= q_cut;
}
