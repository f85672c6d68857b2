#version 460
// SpacetimeGaussians' full model, forward decoder for training: turns the blended base colour
// (3 channels) and features (6) of each pixel into RGB = sigmoid(B + W2 ReLU(W1 x)), see
// decoder.glsl. (Frames that are only displayed decode in the rasterizer's epilogue instead,
// render/rasterize.glsl; training keeps the two images for the backward.)
// Each invocation decodes PIXELS consecutive pixels (1 on GPUs; 8 on CPU drivers, where a
// load of the 90 weights, the same for every pixel, costs a loop over the subgroup's lanes:
// per pixel it was three quarters of the decoder's time on lavapipe), so every weight is
// read once per PIXELS pixels.
#include "camera.glsl"
#include "decoder.glsl"

layout(local_size_x_id = 0) in;
layout(constant_id = 2) const uint PIXELS = 1;
layout(std430, set = 0, binding = 0) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 1) readonly buffer Base { float base_image[]; };
layout(std430, set = 0, binding = 2) readonly buffer Features { float feature_image[]; };
layout(std430, set = 0, binding = 3) readonly buffer Weights { float dec_w[]; };
layout(std430, set = 0, binding = 4) writeonly buffer Rgb { float rgb[]; };
layout(push_constant) uniform Push {
    uint camera_index;
};
#include "decoder_forward.glsl"

void main() {
    Camera cam = cameras[camera_index];
    uint inv = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    uint first = inv * PIXELS;
    uint n = cam.size.x * cam.size.y;
    if (first >= n) return;
    // Pixels past the image repeat the last one (computed, not written).
    float x[PIXELS][DEC_INPUTS];
    vec3 base[PIXELS];
    for (uint p = 0u; p < PIXELS; p++) {
        uint pix = min(first + p, n - 1u);
        for (uint c = 0u; c < DEC_FEATURES; c++) x[p][c] = feature_image[DEC_FEATURES * pix + c];
        decoder_view_inputs(x[p], cam, pix % cam.size.x, pix / cam.size.x);
        for (uint c = 0u; c < 3u; c++) base[p][c] = base_image[3u * pix + c];
    }
    vec3 out_rgb[PIXELS];
    decode_pixels(x, base, out_rgb);
    for (uint p = 0u; p < PIXELS; p++) {
        if (first + p < n) {
            for (uint c = 0u; c < 3u; c++) rgb[3u * (first + p) + c] = out_rgb[p][c];
        }
    }
}
