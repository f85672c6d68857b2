#version 460
// The forward rasterizer without the shuffle capability in the SPIR-V (devices that lack it
// must not even see it). The kernel is documented in rasterize.glsl.
#define HAS_SHUFFLE 0
#include "rasterize.glsl"
