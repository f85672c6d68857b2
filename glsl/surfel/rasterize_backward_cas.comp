#version 460
// 2DGS rasterizer backward for devices without float atomics or shuffles: compare-and-swap on
// the bits, sums through shared memory (the SPIR-V declares neither capability). The body is in
// rasterize_backward.glsl.
#define HAS_FLOAT_ATOMICS 0
#define HAS_SHUFFLE 0
#include "rasterize_backward.glsl"
