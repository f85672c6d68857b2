// Real spherical-harmonics basis up to degree 3 (the 3DGS sign convention); mirrors
// src/reference/sh.rs `basis`. Unused entries are left at 0.
const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float SH_C2_0 = 1.0925484305920792;
const float SH_C2_1 = -1.0925484305920792;
const float SH_C2_2 = 0.31539156525252005;
const float SH_C2_3 = -1.0925484305920792;
const float SH_C2_4 = 0.5462742152960396;
const float SH_C3_0 = -0.5900435899266435;
const float SH_C3_1 = 2.890611442640554;
const float SH_C3_2 = -0.4570457994644658;
const float SH_C3_3 = 0.3731763325901154;
const float SH_C3_4 = -0.4570457994644658;
const float SH_C3_5 = 1.445305721320277;
const float SH_C3_6 = -0.5900435899266435;

void sh_basis(uint degree, vec3 d, out float b[16]) {
    for (int k = 0; k < 16; k++) b[k] = 0.0;
    float x = d.x, y = d.y, z = d.z;
    b[0] = SH_C0;
    if (degree >= 1u) {
        b[1] = -SH_C1 * y;
        b[2] = SH_C1 * z;
        b[3] = -SH_C1 * x;
    }
    if (degree >= 2u) {
        float xx = x * x, yy = y * y, zz = z * z;
        b[4] = SH_C2_0 * x * y;
        b[5] = SH_C2_1 * y * z;
        b[6] = SH_C2_2 * (2.0 * zz - xx - yy);
        b[7] = SH_C2_3 * x * z;
        b[8] = SH_C2_4 * (xx - yy);
    }
    if (degree >= 3u) {
        float xx = x * x, yy = y * y, zz = z * z;
        b[9] = SH_C3_0 * y * (3.0 * xx - yy);
        b[10] = SH_C3_1 * x * y * z;
        b[11] = SH_C3_2 * y * (4.0 * zz - xx - yy);
        b[12] = SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
        b[13] = SH_C3_4 * x * (4.0 * zz - xx - yy);
        b[14] = SH_C3_5 * z * (xx - yy);
        b[15] = SH_C3_6 * x * (xx - 3.0 * yy);
    }
}
