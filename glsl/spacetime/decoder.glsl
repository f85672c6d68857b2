// SpacetimeGaussians' full-model decoder, shared by decode.comp and decode_backward.comp
// (oracle: src/reference/decoder.rs). Input x = [S, Tf, camera centre, unit world direction
// through the pixel centre] (12), h = ReLU(W1 x) (6), y = W2 h (3), RGB = sigmoid(B + y);
// weights flat: W1 row-major (6×12) then W2 (3×6), no biases.
#include "camera.glsl"

const uint DEC_INPUTS = 12u;
const uint DEC_HIDDEN = 6u;
const uint DEC_OUTPUTS = 3u;
const uint DEC_WEIGHTS = DEC_HIDDEN * DEC_INPUTS + DEC_OUTPUTS * DEC_HIDDEN;
const uint DEC_W2 = DEC_HIDDEN * DEC_INPUTS;

// The unit world-space direction through the centre of pixel (px, py): Rᵀ (x, y, 1).
vec3 pixel_ray(Camera cam, uint px, uint py) {
    float x = (float(px) + 0.5 - cam.intrinsics.z) / cam.intrinsics.x;
    float y = (float(py) + 0.5 - cam.intrinsics.w) / cam.intrinsics.y;
    vec3 d = cam.r0.xyz * x + cam.r1.xyz * y + cam.r2.xyz;
    return normalize(d);
}
