#version 460
#extension GL_EXT_shader_atomic_float : require
// 2DGS rasterizer backward for devices with float32 atomic add on storage buffers and
// subgroup shuffles;
// specialisation constant 2 can still select the compare-and-swap path. The body is in
// rasterize_backward.glsl.
#define HAS_FLOAT_ATOMICS 1
#define HAS_SHUFFLE 1
#include "rasterize_backward.glsl"
