// SpacetimeGaussians' full-model decoder, shared by spacetime/decode.comp,
// spacetime/decode_backward.comp and the rasterizer's fused epilogue (render/rasterize.glsl)
// (oracle: src/reference/decoder.rs). Input x = [S, Tf, camera centre, unit world direction
// through the pixel centre] (12), h = ReLU(W1 x) (6), y = W2 h (3), RGB = sigmoid(B + y);
// weights flat: W1 row-major (6×12) then W2 (3×6), no biases. Include camera.glsl first.

const uint DEC_INPUTS = 12u;
const uint DEC_HIDDEN = 6u;
const uint DEC_OUTPUTS = 3u;
const uint DEC_FEATURES = 6u;
const uint DEC_WEIGHTS = DEC_HIDDEN * DEC_INPUTS + DEC_OUTPUTS * DEC_HIDDEN;
const uint DEC_W2 = DEC_HIDDEN * DEC_INPUTS;

// The unit world-space direction through the centre of pixel (px, py): Rᵀ (x, y, 1).
vec3 pixel_ray(Camera cam, uint px, uint py) {
    float x = (float(px) + 0.5 - cam.intrinsics.z) / cam.intrinsics.x;
    float y = (float(py) + 0.5 - cam.intrinsics.w) / cam.intrinsics.y;
    vec3 d = cam.r0.xyz * x + cam.r1.xyz * y + cam.r2.xyz;
    return normalize(d);
}

// The view part of a pixel's input (entries 6 to 11: camera centre, ray direction); the
// caller sets the features (0 to 5).
void decoder_view_inputs(inout float x[DEC_INPUTS], Camera cam, uint px, uint py) {
    vec3 dir = pixel_ray(cam, px, py);
    for (uint c = 0u; c < 3u; c++) {
        x[6u + c] = cam.center[c];
        x[9u + c] = dir[c];
    }
}
