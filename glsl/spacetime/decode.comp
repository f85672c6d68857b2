#version 460
// SpacetimeGaussians' full model, forward decoder: one invocation per pixel turns the blended
// base colour (3 channels) and features (6) into RGB = sigmoid(B + W2 ReLU(W1 x)), see
// decoder.glsl. The weights are read from a buffer (90 floats, the same for every pixel).
#include "decoder.glsl"

layout(local_size_x_id = 0) in;
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
    uint pix = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    uint n = cam.size.x * cam.size.y;
    if (pix >= n) return;
    vec3 dir = pixel_ray(cam, pix % cam.size.x, pix / cam.size.x);
    float x[DEC_INPUTS];
    for (uint c = 0u; c < 6u; c++) x[c] = feature_image[6u * pix + c];
    for (uint c = 0u; c < 3u; c++) {
        x[6u + c] = cam.center[c];
        x[9u + c] = dir[c];
    }
    float h[DEC_HIDDEN];
    for (uint r = 0u; r < DEC_HIDDEN; r++) {
        float s = 0.0;
        for (uint c = 0u; c < DEC_INPUTS; c++) s += w[r * DEC_INPUTS + c] * x[c];
        h[r] = max(s, 0.0);
    }
    for (uint o = 0u; o < DEC_OUTPUTS; o++) {
        float y = base_image[3u * pix + o];
        for (uint c = 0u; c < DEC_HIDDEN; c++) y += w[DEC_W2 + o * DEC_HIDDEN + c] * h[c];
        rgb[3u * pix + o] = 1.0 / (1.0 + exp(-y));
    }
}
