// Quaternion (w, x, y, z) → rotation matrix and its gradient, for the backward kernels;
// mirrors src/reference/project.rs `rotation_of` and src/reference/backward.rs.
// Rotation matrix (rows) of a unit quaternion (w, x, y, z).
void quat_rows(vec4 q, out vec3 r[3]) {
    float w = q.x, x = q.y, y = q.z, z = q.w;
    r[0] = vec3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y));
    r[1] = vec3(2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x));
    r[2] = vec3(2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y));
}

// Gradient of the rotation matrix with respect to the (unit) quaternion; g holds dL/dR rows.
vec4 rotation_backward(vec4 q, vec3 g[3]) {
    float w = q.x, x = q.y, y = q.z, z = q.w;
    return 2.0 * vec4(
        -z * g[0].y + y * g[0].z + z * g[1].x - x * g[1].z - y * g[2].x + x * g[2].y,
        y * g[0].y + z * g[0].z + y * g[1].x - 2.0 * x * g[1].y - w * g[1].z + z * g[2].x
            + w * g[2].y - 2.0 * x * g[2].z,
        -2.0 * y * g[0].x + x * g[0].y + w * g[0].z + x * g[1].x + z * g[1].z - w * g[2].x
            + z * g[2].y - 2.0 * y * g[2].z,
        -2.0 * z * g[0].x - w * g[0].y + x * g[0].z + w * g[1].x - 2.0 * z * g[1].y
            + y * g[1].z + x * g[2].x + y * g[2].y);
}
