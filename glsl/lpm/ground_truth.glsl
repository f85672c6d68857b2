// A ground-truth pixel: RGBA8 packed in a u32 (r in the low byte, as unpackUnorm4x8 reads it),
// straight alpha, composited on the background: rgb·a + bg·(1 − a).
vec3 ground_truth(uint packed, vec3 background) {
    vec4 c = unpackUnorm4x8(packed);
    return c.rgb * c.a + background * (1.0 - c.a);
}
