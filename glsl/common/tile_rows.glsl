// Which tiles of a splat's rectangle get a (tile, splat) pair: per tile row, the columns whose
// pixel centres the ellipse q(x − mean) ≤ q_cut reaches (splat_q_cut in splat_reach.glsl: where
// alpha may be ≥ alpha_min). The rasterizers skip the splat at every pixel of the other tiles,
// so leaving them out changes no pixel and no gradient, while an elongated or faint splat's
// rectangle holds many such tiles: fewer pairs to emit, sort and walk. Mirrors
// `reference::project::ellipse_row_span` and `Projected::row_tiles` (the derivation is there),
// margins included; the binning kernels (tile counts and emit) must call it identically.
// Includes projected.glsl and splat_reach.glsl first.

const float TILE_PX = 16.0;

// Tile columns [x0, x1) of tile row `ty` within the rectangle's columns `cols` = [min, max).
// `ellipse` false: the whole rectangle row (surfels, whose footprint is not this ellipse).
uvec2 row_tiles(ProjectedSplat s, uint ty, uvec2 cols, bool ellipse, float alpha_min,
                bool smooth_mode) {
    if (!ellipse || cols.x >= cols.y) return cols;
    float q_cut = splat_q_cut(s.opacity, alpha_min, smooth_mode);
    if (q_cut < 0.0) return uvec2(cols.x);
    float a = s.conic_a, b = s.conic_b, c = s.conic_c;
    float ac = a * c;
    float det = ac - b * b;
    if (!(a > 0.0 && c > 0.0 && det > 1e-4 * ac && q_cut < 1e30)) return cols;
    vec2 mean = vec2(s.mean_x, s.mean_y);
    float hx = sqrt(c * q_cut / det), hy = sqrt(a * q_cut / det);
    // Margin for f32 rounding (coordinates to ~1e-7 relative), beyond q_cut's own 2 %.
    float m = 1e-3 + 1e-6 * (abs(mean.x) + abs(mean.y) + hx + hy);
    float band0 = float(ty) * TILE_PX + 0.5;
    float lo_y = max(band0 - mean.y - m, -hy);
    float hi_y = min(band0 + (TILE_PX - 1.0) - mean.y + m, hy);
    if (lo_y > hi_y) return uvec2(cols.x);
    // dy of the leftmost point (the rightmost: −k), clamped into the band.
    float k = b * sqrt(q_cut / (c * det));
    float dl = clamp(k, lo_y, hi_y), dr = clamp(-k, lo_y, hi_y);
    float lo = mean.x + (-b * dl - sqrt(max(a * q_cut - det * dl * dl, 0.0))) / a - m;
    float hi = mean.x + (-b * dr + sqrt(max(a * q_cut - det * dr * dr, 0.0))) / a + m;
    if (!(abs(lo) < 1e30 && abs(hi) < 1e30)) return cols;
    // Tile tx holds the pixel centres tx·16 + 0.5 ..= tx·16 + 15.5; clamp in float first.
    float first = clamp(ceil((lo - (TILE_PX - 0.5)) / TILE_PX), float(cols.x), float(cols.y));
    float end = clamp(floor((hi - 0.5) / TILE_PX) + 1.0, float(cols.x), float(cols.y));
    return uvec2(uint(first), max(uint(first), uint(end)));
}
