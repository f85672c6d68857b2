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
