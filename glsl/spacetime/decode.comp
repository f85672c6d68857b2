#version 460
// SpacetimeGaussians' full model, forward decoder: turns the blended base colour (3 channels)
// and features (6) of each pixel into RGB = sigmoid(B + W2 ReLU(W1 x)), see decoder.glsl.
// Each invocation decodes PIXELS consecutive pixels (1 on GPUs; 8 on CPU drivers, where a
// load of the 90 weights, the same for every pixel, costs a loop over the subgroup's lanes:
// per pixel it was three quarters of the decoder's time on lavapipe), so every weight is
// read once per PIXELS pixels.
#include "decoder.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 2) const uint PIXELS = 1;
layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Base { float base_image[]; };
layout(std430, set = 0, binding = 2) readonly buffer Features { float feature_image[]; };
layout(std430, set = 0, binding = 3) readonly buffer Weights { float w[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Rgb { float rgb[]; };
layout(push_constant) uniform Push {
    uint camera_index;
};

void main() {
    Camera cam = cameras[camera_index];
    uint inv = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    uint first = inv * PIXELS;
    uint n = cam.size.x * cam.size.y;
    if (first >= n) return;
    // Pixels past the image repeat the last one (computed, not written).
    float x[PIXELS][DEC_INPUTS];
    for (uint p = 0u; p < PIXELS; p++) {
        uint pix = min(first + p, n - 1u);
        vec3 dir = pixel_ray(cam, pix % cam.size.x, pix / cam.size.x);
        for (uint c = 0u; c < 6u; c++) x[p][c] = feature_image[6u * pix + c];
        for (uint c = 0u; c < 3u; c++) {
            x[p][6u + c] = cam.center[c];
            x[p][9u + c] = dir[c];
        }
    }
    float h[PIXELS][DEC_HIDDEN];
    for (uint r = 0u; r < DEC_HIDDEN; r++) {
        float s[PIXELS];
        for (uint p = 0u; p < PIXELS; p++) s[p] = 0.0;
        for (uint c = 0u; c < DEC_INPUTS; c++) {
            float wv = w[r * DEC_INPUTS + c];
            for (uint p = 0u; p < PIXELS; p++) s[p] += wv * x[p][c];
        }
        for (uint p = 0u; p < PIXELS; p++) h[p][r] = max(s[p], 0.0);
    }
    for (uint o = 0u; o < DEC_OUTPUTS; o++) {
        float y[PIXELS];
        for (uint p = 0u; p < PIXELS; p++) y[p] = base_image[3u * min(first + p, n - 1u) + o];
        for (uint c = 0u; c < DEC_HIDDEN; c++) {
            float wv = w[DEC_W2 + o * DEC_HIDDEN + c];
            for (uint p = 0u; p < PIXELS; p++) y[p] += wv * h[p][c];
        }
        for (uint p = 0u; p < PIXELS; p++) {
            if (first + p < n) rgb[3u * (first + p) + o] = 1.0 / (1.0 + exp(-y[p]));
        }
    }
}
