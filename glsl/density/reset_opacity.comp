#version 460
// Opacity reset: opacity = min(opacity, 0.01), done on logits (sigmoid is monotone, so
// min(x, logit(0.01)) is the same rule without a sigmoid/logit round trip), and the opacity
// group's Adam moments cleared, as the reference does by replacing the optimizer state.
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) buffer Opacity { float opacity_logits[]; };
layout(std430, set = 0, binding = 1) writeonly buffer M { float m[]; };
layout(std430, set = 0, binding = 2) writeonly buffer V { float v[]; };
layout(push_constant) uniform Push { uint count; float max_logit; };

void main() {
    uint i = linear_index();
    if (i >= count) return;
    opacity_logits[i] = min(opacity_logits[i], max_logit);
    m[i] = 0.0;
    v[i] = 0.0;
}
