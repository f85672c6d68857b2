#version 460
#extension GL_EXT_shader_atomic_float : require
// Rasterizer backward for devices with float32 atomic add on storage buffers and subgroup
// shuffles; specialisation constant 2 can still select the compare-and-swap path (tests force
// it). The body and every clamp are documented in rasterize_backward.glsl.
#define HAS_FLOAT_ATOMICS 1
#define HAS_SHUFFLE 1
#include "rasterize_backward.glsl"
