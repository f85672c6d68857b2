// One real spherical-harmonics basis function and its gradient (the 3DGS sign convention),
// for the backward kernels; mirrors src/reference/sh.rs `basis` and `basis_gradient`.
const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float SH_C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                -1.0925484305920792, 0.5462742152960396);
const float SH_C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                                0.3731763325901154, -0.4570457994644658, 1.445305721320277,
                                -0.5900435899266435);

// Basis value k and its gradient (of the polynomial in x, y, z) at the unit direction d.
float sh_basis(uint k, vec3 d, out vec3 grad) {
    float x = d.x, y = d.y, z = d.z;
    float xx = x * x, yy = y * y, zz = z * z;
    switch (k) {
    case 0u: grad = vec3(0.0); return SH_C0;
    case 1u: grad = vec3(0.0, -SH_C1, 0.0); return -SH_C1 * y;
    case 2u: grad = vec3(0.0, 0.0, SH_C1); return SH_C1 * z;
    case 3u: grad = vec3(-SH_C1, 0.0, 0.0); return -SH_C1 * x;
    case 4u: grad = SH_C2[0] * vec3(y, x, 0.0); return SH_C2[0] * x * y;
    case 5u: grad = SH_C2[1] * vec3(0.0, z, y); return SH_C2[1] * y * z;
    case 6u: grad = SH_C2[2] * vec3(-2.0 * x, -2.0 * y, 4.0 * z);
             return SH_C2[2] * (2.0 * zz - xx - yy);
    case 7u: grad = SH_C2[3] * vec3(z, 0.0, x); return SH_C2[3] * x * z;
    case 8u: grad = SH_C2[4] * vec3(2.0 * x, -2.0 * y, 0.0); return SH_C2[4] * (xx - yy);
    case 9u: grad = SH_C3[0] * vec3(6.0 * x * y, 3.0 * (xx - yy), 0.0);
             return SH_C3[0] * y * (3.0 * xx - yy);
    case 10u: grad = SH_C3[1] * vec3(y * z, x * z, x * y); return SH_C3[1] * x * y * z;
    case 11u: grad = SH_C3[2] * vec3(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z);
              return SH_C3[2] * y * (4.0 * zz - xx - yy);
    case 12u: grad = SH_C3[3] * vec3(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy);
              return SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    case 13u: grad = SH_C3[4] * vec3(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z);
              return SH_C3[4] * x * (4.0 * zz - xx - yy);
    case 14u: grad = SH_C3[5] * vec3(2.0 * x * z, -2.0 * y * z, xx - yy);
              return SH_C3[5] * z * (xx - yy);
    default: grad = SH_C3[6] * vec3(3.0 * (xx - yy), -6.0 * x * y, 0.0);
             return SH_C3[6] * x * (xx - 3.0 * yy);
    }
}
