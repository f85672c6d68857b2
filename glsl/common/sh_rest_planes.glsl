// The SH rest coefficients live in five column planes (src/splats/sh_planes.rs): plane p holds
// rest coefficients [3p, 3p + 3) of every Gaussian, so no buffer is wider than 36 bytes a
// Gaussian and the storage binding limit does not cap the model. The including kernel declares
// the planes sh_rest0..4 (and, with SH_REST_GRADS, their gradients g_sh_rest0..4) first.
// `rest_coeffs` is the stored (d+1)² − 1.
//
// Kernels walk the planes with FOR_EACH_SH_REST_PLANE(BODY), which expands BODY(p, plane,
// grad_plane) once per plane, each naming its own buffers: no load or store depends on a branch
// on the plane index. CPU drivers (lavapipe) execute both sides of an `if`, so choosing the
// plane per coefficient with branches loaded every plane for every coefficient (preprocess
// took 1.6× as long with five planes); only loops stop early, so a plane's loop over its
// coefficients costs nothing past the active degree.

const uint SH_REST_COEFS_PER_PLANE = 3u;

// Rest coefficients plane p stores for `rest_coeffs` a Gaussian (its stride is three times that).
uint sh_rest_plane_coefs(uint p, uint rest_coeffs) {
    uint first = p * SH_REST_COEFS_PER_PLANE;
    return min(SH_REST_COEFS_PER_PLANE, rest_coeffs - min(rest_coeffs, first));
}

#ifdef SH_REST_GRADS
#define FOR_EACH_SH_REST_PLANE(BODY) \
    BODY(0u, sh_rest0, g_sh_rest0) BODY(1u, sh_rest1, g_sh_rest1) \
    BODY(2u, sh_rest2, g_sh_rest2) BODY(3u, sh_rest3, g_sh_rest3) \
    BODY(4u, sh_rest4, g_sh_rest4)
#else
#define FOR_EACH_SH_REST_PLANE(BODY) \
    BODY(0u, sh_rest0, sh_rest0) BODY(1u, sh_rest1, sh_rest1) BODY(2u, sh_rest2, sh_rest2) \
    BODY(3u, sh_rest3, sh_rest3) BODY(4u, sh_rest4, sh_rest4)
#endif

// Forward colour (preprocess): raw += Σ basis[k + 1] · rest_k over the first n_rest rest
// coefficients of Gaussian i. Reads i, rest_coeffs, n_rest, basis; adds to raw.
#define SH_REST_PLANE_COLOUR(P, PLANE, GRAD_PLANE)                                        \
    {                                                                                     \
        uint first = (P) * SH_REST_COEFS_PER_PLANE;                                       \
        uint stride = 3u * sh_rest_plane_coefs(P, rest_coeffs);                           \
        uint m = min(SH_REST_COEFS_PER_PLANE, n_rest - min(n_rest, first));               \
        for (uint j = 0u; j < m; j++) {                                                   \
            uint o = i * stride + 3u * j;                                                 \
            raw += basis[first + j + 1u] * vec3(PLANE[o], PLANE[o + 1u], PLANE[o + 2u]);  \
        }                                                                                 \
    }

#ifdef SH_REST_GRADS
// Backward (preprocess backward): for the first n_rest rest coefficients of Gaussian i, the
// gradient basis_k · dl_draw and the view direction's share bgrad_k · (rest_k · dl_draw) (into
// dl_ddir); the stored coefficients past them get gradient 0. Reads i, pc.rest_coeffs, n_rest,
// dir, dl_draw.
#define SH_REST_PLANE_BACKWARD(P, PLANE, GRAD_PLANE)                                      \
    {                                                                                     \
        uint first = (P) * SH_REST_COEFS_PER_PLANE;                                       \
        uint stored = sh_rest_plane_coefs(P, pc.rest_coeffs);                             \
        uint m = min(stored, n_rest - min(n_rest, first));                                \
        for (uint j = 0u; j < m; j++) {                                                   \
            uint o = i * 3u * stored + 3u * j;                                            \
            vec3 bgrad;                                                                   \
            float b = sh_basis(first + j + 1u, dir, bgrad);                               \
            vec3 coeff = vec3(PLANE[o], PLANE[o + 1u], PLANE[o + 2u]);                    \
            GRAD_PLANE[o] = b * dl_draw.x;                                                \
            GRAD_PLANE[o + 1u] = b * dl_draw.y;                                           \
            GRAD_PLANE[o + 2u] = b * dl_draw.z;                                           \
            dl_ddir += bgrad * dot(coeff, dl_draw);                                       \
        }                                                                                 \
        for (uint j = m; j < stored; j++) {                                               \
            uint o = i * 3u * stored + 3u * j;                                            \
            GRAD_PLANE[o] = 0.0;                                                          \
            GRAD_PLANE[o + 1u] = 0.0;                                                     \
            GRAD_PLANE[o + 2u] = 0.0;                                                     \
        }                                                                                 \
    }

// Zero gradients for every stored rest coefficient of Gaussian i (culled or gradient-free).
#define SH_REST_PLANE_ZERO(P, PLANE, GRAD_PLANE)                                          \
    {                                                                                     \
        uint n = 3u * sh_rest_plane_coefs(P, pc.rest_coeffs);                             \
        for (uint j = 0u; j < n; j++) GRAD_PLANE[i * n + j] = 0.0;                        \
    }
#endif
