#version 460
// Adam on the Gaussians seen this step only (`train --visible-adam`). The kernel is
// documented in adam.glsl.
#define VISIBLE_ONLY 1
#include "adam.glsl"
