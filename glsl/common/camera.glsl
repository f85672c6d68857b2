// One camera (std430, 96 bytes); mirrors `CameraGpu` in src/render/layout.rs.
struct Camera {
    vec4 r0;          // world-to-camera rotation rows, translation in w
    vec4 r1;
    vec4 r2;
    vec4 center;      // camera centre in world space
    vec4 intrinsics;  // fx, fy, cx, cy
    uvec4 size;       // width, height, tiles_x, tiles_y
};

vec3 camera_transform(Camera cam, vec3 p) {
    return vec3(dot(cam.r0.xyz, p) + cam.r0.w, dot(cam.r1.xyz, p) + cam.r1.w,
                dot(cam.r2.xyz, p) + cam.r2.w);
}
