#version 460
// 2DGS rasterizer backward for devices without float atomics: compare-and-swap on the bits
// (the SPIR-V does not declare the float atomic capability). The body is in
// rasterize_backward.glsl.
#define HAS_FLOAT_ATOMICS 0
#include "rasterize_backward.glsl"
