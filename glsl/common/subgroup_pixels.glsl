// How the tile rasterizers (3DGS and 2DGS, forward and backward) give pixels to invocations.
// Needs the constants SUBGROUP_SIZE and PIXELS and the subgroup arithmetic extension.

// Pixel k of invocation li, as an index into the 16×16 tile (row-major): invocation li is lane
// li % SUBGROUP_SIZE of group li / SUBGROUP_SIZE, and each such group owns SUBGROUP_SIZE·PIXELS
// consecutive pixels (whole rows), so a subgroup's pixels are close together (a small box for
// its splat lists) and tend to stop at similar depths. A bijection onto 0..255 for any
// WG_SIZE = 256 / PIXELS.
uint tile_pixel(uint li, uint k) {
    uint lane = li % SUBGROUP_SIZE;
    return (li - lane) * PIXELS + k * SUBGROUP_SIZE + lane;
}

// The box [lo, hi] of the pixel centres of the whole subgroup (from the pixels themselves,
// whatever the subgroup's layout): the rasterizers visit only splats whose reach meets it.
// Needs the subgroup arithmetic extension and PIXELS.
void subgroup_pixel_box(vec2 centres[PIXELS], out vec2 lo, out vec2 hi) {
    lo = centres[0];
    hi = centres[0];
    [[unroll]] for (uint k = 1u; k < PIXELS; k++) {
        lo = min(lo, centres[k]);
        hi = max(hi, centres[k]);
    }
    lo = subgroupMin(lo);
    hi = subgroupMax(hi);
}
