// The SH rest coefficients live in five column planes (src/splats/sh_planes.rs): plane p holds
// rest coefficients [3p, 3p + 3) of every Gaussian, so no buffer is wider than 36 bytes a
// Gaussian and the storage binding limit does not cap the model. The including kernel declares
// the planes sh_rest0..4 (and, with SH_REST_GRADS, their gradients g_sh_rest0..4) first.
// `rest_coeffs` is the stored (d+1)² − 1; the plane index is the same for every invocation
// of a loop over coefficients, so the branches below do not diverge.

const uint SH_REST_COEFS_PER_PLANE = 3u;

// Float offset of rest coefficient k (channel 0) of Gaussian i inside its plane k / 3.
uint sh_rest_offset(uint i, uint k, uint rest_coeffs) {
    uint p = k / SH_REST_COEFS_PER_PLANE;
    uint first = p * SH_REST_COEFS_PER_PLANE;
    uint coefs = min(SH_REST_COEFS_PER_PLANE, rest_coeffs - min(rest_coeffs, first));
    return i * 3u * coefs + 3u * (k - first);
}

vec3 sh_rest_read(uint i, uint k, uint rest_coeffs) {
    uint o = sh_rest_offset(i, k, rest_coeffs);
    uint p = k / SH_REST_COEFS_PER_PLANE;
    if (p == 0u) return vec3(sh_rest0[o], sh_rest0[o + 1u], sh_rest0[o + 2u]);
    if (p == 1u) return vec3(sh_rest1[o], sh_rest1[o + 1u], sh_rest1[o + 2u]);
    if (p == 2u) return vec3(sh_rest2[o], sh_rest2[o + 1u], sh_rest2[o + 2u]);
    if (p == 3u) return vec3(sh_rest3[o], sh_rest3[o + 1u], sh_rest3[o + 2u]);
    return vec3(sh_rest4[o], sh_rest4[o + 1u], sh_rest4[o + 2u]);
}

#ifdef SH_REST_GRADS
void sh_rest_write_grad(uint i, uint k, uint rest_coeffs, vec3 g) {
    uint o = sh_rest_offset(i, k, rest_coeffs);
    uint p = k / SH_REST_COEFS_PER_PLANE;
    if (p == 0u) {
        g_sh_rest0[o] = g.x; g_sh_rest0[o + 1u] = g.y; g_sh_rest0[o + 2u] = g.z;
    } else if (p == 1u) {
        g_sh_rest1[o] = g.x; g_sh_rest1[o + 1u] = g.y; g_sh_rest1[o + 2u] = g.z;
    } else if (p == 2u) {
        g_sh_rest2[o] = g.x; g_sh_rest2[o + 1u] = g.y; g_sh_rest2[o + 2u] = g.z;
    } else if (p == 3u) {
        g_sh_rest3[o] = g.x; g_sh_rest3[o + 1u] = g.y; g_sh_rest3[o + 2u] = g.z;
    } else {
        g_sh_rest4[o] = g.x; g_sh_rest4[o + 1u] = g.y; g_sh_rest4[o + 2u] = g.z;
    }
}
#endif
