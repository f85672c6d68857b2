#version 460
// The 2DGS forward rasterizer for devices with subgroup shuffles (CPU drivers use them to hand
// each surfel to every lane). The kernel is documented in rasterize.glsl.
#define HAS_SHUFFLE 1
#include "rasterize.glsl"
