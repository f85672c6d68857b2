#version 460
// The forward rasterizer for devices with subgroup shuffles (CPU drivers use them to hand
// each splat to every lane). The kernel is documented in rasterize.glsl.
#define HAS_SHUFFLE 1
#include "rasterize.glsl"
