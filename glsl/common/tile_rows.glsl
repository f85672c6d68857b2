// Which tiles of a splat's rectangle get a (tile, splat) pair: per tile row, the columns whose
// pixel centres the ellipse q(x − mean) ≤ q_cut reaches (splat_q_cut in splat_reach.glsl: where
// alpha may be ≥ alpha_min). The rasterizers skip the splat at every pixel of the other tiles,
// so leaving them out changes no pixel and no gradient, while an elongated or faint splat's
// rectangle holds many such tiles: fewer pairs to emit, sort and walk. Mirrors
// `reference::project::ellipse_row_span` and `Projected::row_tiles` (the derivation is there),
// margins included; the binning kernels (tile counts and emit) must call it identically.
// Includes projected.glsl and splat_reach.glsl first.

const float TILE_PX = 16.0;

// What every row of one splat shares, computed once per splat (the row loop only clamps).
struct RowSpanner {
    bool bounded;  // false: every row gets the whole rectangle row
    bool empty;    // true: no row gets any tile
    vec2 mean;
    float a, b, det, a_q, hy, k, m;
};

// `ellipse` false: no bound (surfels, whose footprint is not this ellipse).
RowSpanner row_spanner(ProjectedSplat s, bool ellipse, float alpha_min, bool smooth_mode) {
    RowSpanner r;
    r.bounded = false;
    r.empty = false;
    r.mean = vec2(s.mean_x, s.mean_y);
    r.a = s.conic_a; r.b = s.conic_b; r.det = 0.0; r.a_q = 0.0; r.hy = 0.0; r.k = 0.0; r.m = 0.0;
    if (!ellipse) return r;
    float q_cut = splat_q_cut(s.opacity, alpha_min, smooth_mode);
    if (q_cut < 0.0) { r.empty = true; return r; }
    float a = s.conic_a, b = s.conic_b, c = s.conic_c;
    float ac = a * c;
    float det = ac - b * b;
    bool finite_mean = abs(r.mean.x) < 1e30 && abs(r.mean.y) < 1e30;
    if (!(a > 0.0 && c > 0.0 && det > 1e-4 * ac && q_cut < 1e30) || !finite_mean) return r;
    r.det = det;
    r.a_q = a * q_cut;
    float hx = sqrt(c * q_cut / det);
    r.hy = sqrt(a * q_cut / det);
    // dy of the leftmost point (the rightmost: −k).
    r.k = b * sqrt(q_cut / (c * det));
    // Margin for f32 rounding (coordinates to ~1e-7 relative), beyond q_cut's own 2 %.
    r.m = 1e-3 + 1e-6 * (abs(r.mean.x) + abs(r.mean.y) + hx + r.hy);
    r.bounded = hx < 1e30 && r.hy < 1e30 && abs(r.k) < 1e30;
    return r;
}

// Tile columns [x0, x1) of tile row `ty` within the rectangle's columns `cols` = [min, max).
uvec2 row_tiles(RowSpanner r, uint ty, uvec2 cols) {
    if (r.empty || cols.x >= cols.y) return uvec2(cols.x);
    if (!r.bounded) return cols;
    float band0 = float(ty) * TILE_PX + 0.5;
    float lo_y = max(band0 - r.mean.y - r.m, -r.hy);
    float hi_y = min(band0 + (TILE_PX - 1.0) - r.mean.y + r.m, r.hy);
    if (lo_y > hi_y) return uvec2(cols.x);
    float dl = clamp(r.k, lo_y, hi_y), dr = clamp(-r.k, lo_y, hi_y);
    float lo = r.mean.x + (-r.b * dl - sqrt(max(r.a_q - r.det * dl * dl, 0.0))) / r.a - r.m;
    float hi = r.mean.x + (-r.b * dr + sqrt(max(r.a_q - r.det * dr * dr, 0.0))) / r.a + r.m;
    if (!(abs(lo) < 1e30 && abs(hi) < 1e30)) return cols;
    // Tile tx holds the pixel centres tx·16 + 0.5 ..= tx·16 + 15.5; clamp in float first.
    float first = clamp(ceil((lo - (TILE_PX - 0.5)) / TILE_PX), float(cols.x), float(cols.y));
    float end = clamp(floor((hi - 0.5) / TILE_PX) + 1.0, float(cols.x), float(cols.y));
    return uvec2(uint(first), max(uint(first), uint(end)));
}
