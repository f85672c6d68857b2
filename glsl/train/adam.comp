#version 460
// Adam, the dense update of every Gaussian (torch.optim.Adam). The kernel is documented in
// adam.glsl.
#define VISIBLE_ONLY 0
#include "adam.glsl"
