#version 460
// Rasterizer backward without the float atomic-add and shuffle capabilities in the SPIR-V
// (devices that lack either must not even see them): gradients are added with a
// compare-and-swap loop, and summed through shared memory (SUBGROUP_ATOMICS must be 0).
// The body and every clamp are documented in rasterize_backward.glsl.
#define HAS_FLOAT_ATOMICS 0
#define HAS_SHUFFLE 0
#include "rasterize_backward.glsl"
