#version 460
// Density-control decisions, one word per Gaussian (bits in decisions.glsl), Inria's rules:
//   stat = grad_accum / denom (0 when never seen); densify when stat ≥ threshold (× the
//   optional per-Gaussian scale), or (flag 4) when abs_accum / denom ≥ abs_threshold, the
//   absolute-gradient test (src/train/density/abs_quantile.rs); clone when max scale ≤ percent_dense·extent, split otherwise;
//   prune when opacity < min_opacity, and with `prune_large` when max scale > 0.1·extent;
//   optionally (screen_max ≥ 0) when the largest screen radius exceeds screen_max.
// New Gaussians face the same prune tests with their own parameters (a clone has its parent's;
// split children have scale / 1.6), so a new Gaussian that would be pruned at once is never
// emitted. Scale and opacity tests compare in the log / logit domain against thresholds formed
// on the host (monotone, so equivalent up to the threshold's rounding).
// scores[i]: how far a candidate is over the threshold, all on one scale: statistic /
// grad_threshold (flag 32: over its own scaled threshold, the paper's LPM ranking), the larger
// of that and the absolute gradient's ratio, +∞ over a threshold ≤ 0, times score_weight[i]
// with flag 16 (a strategy's guide), or score_weight[i] itself with flags 16 and 64 (a
// strategy's own ranking, src/taming/); 0 for the others. The Gaussian budget ranks additions by
// it (src/train/density/budget.rs). Flag 8 (the exact budget, src/train/density/growth.rs):
// every Gaussian with a positive statistic is a candidate and the budget chooses among them
// (nothing is then "lowered"). Flag 128 (a growth region, src/train/density/region.rs): a
// Gaussian whose centre lies outside the region's two bands is no candidate by either test
// (it is never cloned nor split, its score is 0); the prune tests are unchanged.
layout(local_size_x_id = 0) in;
#include "decisions.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Accum { float grad_accum[]; };
layout(std430, set = 0, binding = 1) readonly buffer Denom { float denom[]; };
layout(std430, set = 0, binding = 2) readonly buffer MaxRadii { float max_radii[]; };
layout(std430, set = 0, binding = 3) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 4) readonly buffer Opacity { float opacity_logits[]; };
layout(std430, set = 0, binding = 5) readonly buffer ThresholdScale { float threshold_scale[]; };
layout(std430, set = 0, binding = 6) writeonly buffer Decisions { uint decisions[]; };
layout(std430, set = 0, binding = 7) readonly buffer AbsAccum { float abs_accum[]; };
layout(std430, set = 0, binding = 8) writeonly buffer Scores { float scores[]; };
layout(std430, set = 0, binding = 9) readonly buffer ScoreWeight { float score_weight[]; };
layout(std430, set = 0, binding = 10) readonly buffer Positions { float positions[]; };
layout(push_constant) uniform Push {
    uint count;
    uint flags;  // 1: prune large (world size); 2: use threshold_scale; 4: absolute-gradient test;
                 // 8: every seen Gaussian a candidate; 16: use score_weight; 32: rank lowered;
                 // 64: score_weight replaces the score; 128: grow only inside the region
    float grad_threshold;
    float log_clone_max;      // ln(percent_dense · extent)
    float min_opacity_logit;  // logit(min_opacity)
    float log_world_max;      // ln(0.1 · extent)
    float log_split_shrink;   // ln(1.6)
    float screen_max;         // < 0: off
    float abs_threshold;      // with flag 4
    // With flag 128, per band: its axis, lo and hi (the centre's dot product with the axis
    // must lie in [lo, hi)).
    float b0x, b0y, b0z, b0lo, b0hi;
    float b1x, b1y, b1z, b1lo, b1hi;
};

bool grows_at(uint i) {
    if ((flags & 128u) == 0u) return true;
    float px = positions[3u * i], py = positions[3u * i + 1u], pz = positions[3u * i + 2u];
    // `precise`: the same f32 operations in the same order as the host reference.
    precise float c0 = b0x * px + b0y * py + b0z * pz;
    precise float c1 = b1x * px + b1y * py + b1z * pz;
    return c0 >= b0lo && c0 < b0hi && c1 >= b1lo && c1 < b1hi;
}

void main() {
    uint i = linear_index();
    float INF = uintBitsToFloat(0x7F800000u);
    if (i >= count) return;
    float dn = denom[i];
    precise float stat = dn > 0.0 ? grad_accum[i] / dn : 0.0;
    precise float thr = grad_threshold;
    if ((flags & 2u) != 0u) thr = grad_threshold * threshold_scale[i];
    precise float abs_stat = dn > 0.0 ? abs_accum[i] / dn : 0.0;
    bool rank_all = (flags & 8u) != 0u;
    bool grows = grows_at(i);
    bool by_abs = grows && (flags & 4u) != 0u
        && (rank_all ? abs_stat > 0.0 : abs_stat >= abs_threshold);
    bool by_grad = grows && (rank_all ? (stat > 0.0 && grad_threshold < INF) : stat >= thr);
    bool densify = by_grad || by_abs;
    precise float over = (flags & 32u) != 0u ? thr : grad_threshold;
    precise float grad_ratio = by_grad ? (over > 0.0 ? stat / over : INF) : 0.0;
    precise float abs_ratio = by_abs ? (abs_threshold > 0.0 ? abs_stat / abs_threshold : INF) : 0.0;
    precise float score = max(grad_ratio, abs_ratio);
    if ((flags & 16u) != 0u && densify) {
        score = (flags & 64u) != 0u ? score_weight[i] : score * score_weight[i];
    }
    scores[i] = score;
    float ls = max(max(log_scales[3u * i], log_scales[3u * i + 1u]), log_scales[3u * i + 2u]);
    bool clone = densify && ls <= log_clone_max;
    bool split = densify && ls > log_clone_max;
    bool prune_large = (flags & 1u) != 0u;
    bool faint = opacity_logits[i] < min_opacity_logit;
    bool big = prune_large && ls > log_world_max;
    bool big_screen = screen_max >= 0.0 && max_radii[i] > screen_max;
    precise float child_ls = ls - log_split_shrink;
    bool child_big = prune_large && child_ls > log_world_max;

    uint d = 0u;
    if (faint || big || big_screen) d |= DECIDE_REMOVE;
    if (clone && !faint && !big) d |= DECIDE_CLONE;
    if (split) d |= (faint || child_big) ? DECIDE_REMOVE : DECIDE_SPLIT;
    if ((clone || split) && !(stat >= grad_threshold) && !by_abs && !rank_all) d |= DECIDE_LOWERED;
    decisions[i] = d;
}
