// SpacetimeGaussians' temporal opacity as a logit, shared by the forward and backward kernels.
// The f64 oracle and the derivation are in src/reference/spacetime.rs; this copies its choices.

// Floor of 1 − σ(o)·g (reference ONE_MINUS_MIN): acts only for logits above 69.
const float ONE_MINUS_MIN = 1e-30;

// log(1 + e^x) without overflow.
float softplus(float x) {
    return max(x, 0.0) + log(1.0 + exp(-abs(x)));
}

// 1 − e^{−x} for x ≥ 0: f32 has no expm1, so small x use the series (5 terms: relative error
// below x⁵/720 ≈ 1.4e-8 at x = 0.1, under f32's rounding), larger x the plain form.
float one_minus_exp_neg(float x) {
    if (x < 0.1) {
        return x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0)))));
    }
    return 1.0 - exp(-x);
}

// 1 − σ(o)·g for g = e^{−u²}, as a sum of non-negative terms: σ(−o) + σ(o)·(1 − g).
float one_minus_opacity(float o, float u2) {
    float sig = 1.0 / (1.0 + exp(-o));
    float sig_neg = 1.0 / (1.0 + exp(o));
    return max(sig_neg + sig * one_minus_exp_neg(u2), ONE_MINUS_MIN);
}
