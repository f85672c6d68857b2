// Reading the rendered image (f32 RGB interleaved) and the ground truth (packed RGBA8, r in the
// low byte, composited over the background). Needs the `Image` and `Gt` blocks declared as
// `image[]` and `gt[]`, and loss_common.glsl.

vec3 load_render(uint pix) {
    return vec3(image[pix * 3u], image[pix * 3u + 1u], image[pix * 3u + 2u]);
}

vec3 load_gt(uint pix) {
    vec4 v = unpackUnorm4x8(gt[gt_offset + pix]);
    return v.rgb * v.a + vec3(bg_r, bg_g, bg_b) * (1.0 - v.a);
}
