#version 460
#extension GL_EXT_shader_atomic_float : require
// Per Gaussian, what it gave a frame already drawn by the forward rasterizer, summed over the
// pixels it was blended into: the pixels' weights (an importance map the caller uploads, one
// float a pixel), the number of those pixels, its blending weights T·alpha, and its centre's
// distance to each pixel centre. The exact-budget ADC's blended score (src/taming/) ranks
// candidates by these sums over a few sampled views. Mirrors `contributions` in
// src/reference/raster.rs.
//
// It walks the tile's sorted list exactly as rasterize.glsl blends it (the same alpha, the same
// cut-off and alpha_min tests, the same stop before the transmittance would fall under t_min),
// so a Gaussian is counted at a pixel exactly where the forward pass blended it. One workgroup
// per 16×16 tile, one pixel per invocation, one dispatch per band of tile rows (tile_offset);
// the sums are float atomics (their order, and so their last bits, vary from run to run). The
// outputs are zeroed by the renderer before the frame.
layout(local_size_x = 256) in;
#include "camera.glsl"
#include "projected.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Splats { ProjectedSplat splats[]; };
layout(std430, set = 0, binding = 1) readonly buffer Ids { uint sorted_ids[]; };
layout(std430, set = 0, binding = 2) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 3) readonly buffer Cameras { Camera cameras[]; };
layout(std430, set = 0, binding = 4) readonly buffer PixelWeights { float pixel_weights[]; };
layout(std430, set = 0, binding = 5) buffer WeightSum { float weight_sum[]; };
layout(std430, set = 0, binding = 6) buffer PixelCount { float pixel_count[]; };
layout(std430, set = 0, binding = 7) buffer BlendSum { float blend_sum[]; };
layout(std430, set = 0, binding = 8) buffer DistanceSum { float distance_sum[]; };
layout(push_constant) uniform Push {
    RenderConstants rc;
    uint camera_index;
    uint tile_offset;
};

const uint BATCH = 256u;
shared vec4 s_mean_opacity[BATCH];  // mean x, mean y, opacity, power below which alpha < alpha_min
shared vec4 s_conic[BATCH];         // a, b, c, (unused)
shared uint s_id[BATCH];
shared uint s_done;

void main() {
    Camera cam = cameras[camera_index];
    uint tiles_x = cam.size.z;
    uint tile = tile_offset + gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (tile >= tiles_x * cam.size.w) return;  // uniform over the workgroup
    uint li = gl_LocalInvocationIndex;
    uint px = (tile % tiles_x) * 16u + li % 16u, py = (tile / tiles_x) * 16u + li / 16u;
    bool inside = px < cam.size.x && py < cam.size.y;
    vec2 centre = vec2(float(px) + 0.5, float(py) + 0.5);
    bool smooth_mode = (rc.flags & 1u) != 0u;
    float weight = inside ? pixel_weights[py * cam.size.x + px] : 0.0;
    float T = 1.0;
    // Past the image or stopped: nothing more to blend.
    bool done = !inside;

    uvec2 range = ranges[tile];
    for (uint base = range.x; base < range.y; base += BATCH) {
        if (li == 0u) s_done = 0u;
        barrier();
        if (done) atomicAdd(s_done, 1u);
        uint k = base + li;
        if (k < range.y) {
            uint g = sorted_ids[k];
            ProjectedSplat p = splats[g];
            float cutoff = !smooth_mode ? log(rc.alpha_min / p.opacity) - 1e-3 : -1e30;
            s_mean_opacity[li] = vec4(p.mean_x, p.mean_y, p.opacity, cutoff);
            s_conic[li] = vec4(p.conic_a, p.conic_b, p.conic_c, 0.0);
            s_id[li] = g;
        }
        barrier();
        // Every pixel of the tile done: the rest of the list changes nothing (uniform).
        if (s_done == gl_WorkGroupSize.x) break;
        uint batch = min(BATCH, range.y - base);
        for (uint j = 0u; !done && j < batch; j++) {
            vec4 mo = s_mean_opacity[j];
            vec4 cn = s_conic[j];
            vec2 d = mo.xy - centre;
            float power = -0.5 * (cn.x * d.x * d.x + cn.z * d.y * d.y) - cn.y * d.x * d.y;
            float alpha = mo.z * exp(power);
            if (!smooth_mode) alpha = min(alpha, rc.alpha_max);
            bool hit = power <= 0.0 && power >= mo.w && (smooth_mode || alpha >= rc.alpha_min);
            if (!hit) continue;
            float next_t = T * (1.0 - alpha);
            if (!smooth_mode && next_t < rc.t_min) {
                done = true;
                break;
            }
            uint g = s_id[j];
            atomicAdd(weight_sum[g], weight);
            atomicAdd(pixel_count[g], 1.0);
            atomicAdd(blend_sum[g], T * alpha);
            atomicAdd(distance_sum[g], length(d));
            T = next_t;
        }
        barrier();
    }
}
