#version 460
// Rasterizer backward without the float atomic-add capability in the SPIR-V (devices that lack
// it must not even see the capability): gradients are added with a compare-and-swap loop.
// The body and every clamp are documented in rasterize_backward.glsl.
#define HAS_FLOAT_ATOMICS 0
#include "rasterize_backward.glsl"
