#version 460
// Opacity reset: opacity = min(opacity, 0.01), done on logits (sigmoid is monotone, so
// min(x, logit(0.01)) is the same rule without a sigmoid/logit round trip), and the opacity
// group's Adam moments cleared, as the reference does by replacing the optimizer state.
// With Mip-Splatting's 3D filter (`filtered`), the rule acts on the opacity the renderer uses,
// σ(x)·ρ with ρ = sqrt(Π s² / Π (s² + f²)) (docs/algorithms/base-models.md §2.5): where σ(x)·ρ exceeds the
// ceiling r, σ(x') = r / ρ.
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) buffer Opacity { float opacity_logits[]; };
layout(std430, set = 0, binding = 1) writeonly buffer M { float m[]; };
layout(std430, set = 0, binding = 2) writeonly buffer V { float v[]; };
layout(std430, set = 0, binding = 3) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 4) readonly buffer Filter3d { float filter3d[]; };
layout(push_constant) uniform Push { uint count; float max_logit; uint filtered; };

void main() {
    uint i = linear_index();
    if (i >= count) return;
    float x = opacity_logits[i];
    if (filtered != 0u) {
        vec3 s = exp(vec3(log_scales[3u * i], log_scales[3u * i + 1u], log_scales[3u * i + 2u]));
        vec3 s2 = s * s;
        float phi = filter3d[i] * filter3d[i];
        vec3 w = s2 / (s2 + phi);
        float rho = sqrt(w.x * w.y * w.z);
        float ceiling = 1.0 / (1.0 + exp(-max_logit));
        float effective = rho / (1.0 + exp(-x));
        if (effective > ceiling) {
            float p = ceiling / rho;
            opacity_logits[i] = log(p / (1.0 - p));
        }
    } else {
        opacity_logits[i] = min(x, max_logit);
    }
    m[i] = 0.0;
    v[i] = 0.0;
}
