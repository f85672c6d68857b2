#version 460
// The 2DGS forward rasterizer for devices without subgroup shuffles (one pixel per invocation).
// The kernel is documented in rasterize.glsl.
#define HAS_SHUFFLE 0
#include "rasterize.glsl"
