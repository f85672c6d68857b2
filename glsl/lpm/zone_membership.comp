#version 460
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_vote : require
#extension GL_KHR_shader_subgroup_arithmetic : require
// LPM step 7: for every Gaussian centre x, whether it lies inside any zone of the step and
// whether it lies "in front of" any zone; per zone, how many centres lie inside it.
//
// flags[i]: bit 0 (FLAG_INSIDE) inside at least one zone, bit 1 (FLAG_IN_FRONT) in front of at
// least one zone, bit 2 (FLAG_IN_BALL) within the cone radius of a zone's centre; the other
// bits are 0. A zone marked ZONE_NO_RESET sets no FLAG_IN_FRONT or FLAG_IN_BALL.
//
// Inside: sphere |x − c|² ≤ r², box |x_k − c_k| ≤ h_k on each axis, slab: inside the in-front
// cone below and |a| − f ≤ |v| ≤ |a| + f (boundary included everywhere).
// In front (docs/algorithms/lpm.md step 7), with apex o = camera_center, v = x − o, a = c − o, the cone's
// radius r = the zone's cone_radius at the centre (its bounding radius, the authors' smallest
// box half-extent, or the view's cone through its error region) and f = its front_radius (where
// "in front" ends: the bounding radius, or the authors' r): angle(v, a) ≤ atan(r / |a|) and
// |v| ≤ |a| − f (|v| ≤ |a| when |a| ≤ f). Written without sqrt, atan or division, with
// V = v·v, A = a·a, D = v·a, R = r², F = f²:
//   angle:    D ≥ 0 and D²(A + R) ≥ A² V       (cos² of the angle ≥ cos² of atan(r/h) = A/(A+R))
//   distance: A > F:  W = A − V − F ≥ 0 and 4 F V ≤ W²   (|v| + f ≤ h squared twice)
//             A ≤ F:  V ≤ A
//   slab, far face  |v| ≤ |a| + f:  U = V − A − F ≤ 0 or U² ≤ 4AF
//   slab, near face |v| ≥ |a| − f:  A ≤ F, or W ≤ 0, or 4FV ≥ W²
// The angle is undefined at the apex (V = 0) and for a zone centred on its camera (A = 0): such
// points are not in front. Every operation is an IEEE add, sub or mul marked `precise` (no fused
// multiply-add, no reordering), so src/reference/lpm_membership.rs reproduces each flag bit for bit. Terms
// grow as |coordinate|⁶: coordinates must stay below ~1e6 (f32 overflow).
//
// One workgroup handles WG_SIZE · ITEMS Gaussians; zones are staged in shared memory in batches
// of ZONE_BATCH, so any number of zones works and each zone is read once per workgroup. Per-zone
// counts are summed in the subgroup, then in shared memory, then added to zone_inside once per
// workgroup and zone (zone_inside must be zeroed before).
layout(constant_id = 0) const uint WG_SIZE = 256;
layout(constant_id = 2) const uint ITEMS = 4;
layout(constant_id = 3) const uint ZONE_BATCH = 128;
layout(local_size_x_id = 0) in;
#include "zone.glsl"
layout(std430, set = 0, binding = 0) readonly buffer Positions { float positions[]; };
layout(std430, set = 0, binding = 1) readonly buffer Zones { Zone zones[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Flags { uint flags[]; };
layout(std430, set = 0, binding = 3) buffer ZoneInside { uint zone_inside[]; };
layout(push_constant) uniform Push { uint count; uint zone_count; };

shared vec4 s_sphere[ZONE_BATCH];  // centre, r²
shared vec4 s_half[ZONE_BATCH];    // box half extents, w: front radius²
shared vec4 s_apex[ZONE_BATCH];    // camera centre o, A = |c − o|²
shared vec4 s_axis[ZONE_BATCH];    // a = c − o, w: cone radius²
shared uint s_shape[ZONE_BATCH];
shared uint s_inside[ZONE_BATCH];

// Whether x is inside zone j's in-front cone (angle test above); V = |x − o|² when it is.
bool in_cone(vec3 x, uint j, out float V) {
    vec4 o = s_apex[j];
    vec3 a = s_axis[j].xyz;
    float A = o.w;
    float R = s_axis[j].w;
    precise float vx = x.x - o.x;
    precise float vy = x.y - o.y;
    precise float vz = x.z - o.z;
    precise float v2 = vx * vx + vy * vy + vz * vz;
    V = v2;
    precise float D = vx * a.x + vy * a.y + vz * a.z;
    if (!(v2 > 0.0 && A > 0.0 && D >= 0.0)) return false;
    precise float cone_l = (D * D) * (A + R);
    precise float cone_r = (A * A) * v2;
    return cone_l >= cone_r;
}

// The in-front cone cut to a band of distances from its apex (a slab's inside).
bool inside_slab(vec3 x, uint j) {
    float V;
    if (!in_cone(x, j, V)) return false;
    float A = s_apex[j].w;
    float F = s_half[j].w;
    precise float U = (V - A) - F;
    precise float far_l = U * U;
    precise float far_r = (4.0 * A) * F;
    if (!(U <= 0.0 || far_l <= far_r)) return false;
    if (A <= F) return true;
    precise float W = (A - V) - F;
    precise float near_l = (4.0 * F) * V;
    precise float near_r = W * W;
    return W <= 0.0 || near_l >= near_r;
}

bool inside_zone(vec3 x, uint j) {
    vec4 s = s_sphere[j];
    uint shape = s_shape[j] & ZONE_SHAPE_MASK;
    if (shape == ZONE_SLAB) return inside_slab(x, j);
    if (shape == ZONE_BOX) {
        vec3 h = s_half[j].xyz;
        precise vec3 d = abs(x - s.xyz);
        return d.x <= h.x && d.y <= h.y && d.z <= h.z;
    }
    precise float dx = x.x - s.x;
    precise float dy = x.y - s.y;
    precise float dz = x.z - s.z;
    precise float d2 = dx * dx + dy * dy + dz * dz;
    return d2 <= s.w;
}

bool in_ball(vec3 x, uint j) {
    vec4 s = s_sphere[j];
    precise float dx = x.x - s.x;
    precise float dy = x.y - s.y;
    precise float dz = x.z - s.z;
    precise float d2 = dx * dx + dy * dy + dz * dz;
    return d2 <= s_axis[j].w;
}

bool in_front(vec3 x, uint j) {
    float V;
    if (!in_cone(x, j, V)) return false;
    float A = s_apex[j].w;
    float F = s_half[j].w;
    if (A > F) {
        precise float W = (A - V) - F;
        precise float dist_l = (4.0 * F) * V;
        precise float dist_r = W * W;
        return W >= 0.0 && dist_l <= dist_r;
    }
    return V <= A;
}

void main() {
    uint tid = gl_LocalInvocationIndex;
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    uint first = group * WG_SIZE * ITEMS + tid;
    vec3 x[ITEMS];
    uint f[ITEMS];
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k * WG_SIZE;
        x[k] = i < count ? vec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u])
                         : vec3(0.0);
        f[k] = 0u;
    }
    // Every invocation runs the zone loops (no early exit): they hold barriers and subgroup ops.
    for (uint zb = 0u; zb < zone_count; zb += ZONE_BATCH) {
        uint nb = min(ZONE_BATCH, zone_count - zb);
        barrier();  // the previous batch is no longer read
        for (uint j = tid; j < nb; j += WG_SIZE) {
            Zone z = zones[zb + j];
            precise float R = z.radius * z.radius;
            precise float ax = z.center.x - z.camera_center.x;
            precise float ay = z.center.y - z.camera_center.y;
            precise float az = z.center.z - z.camera_center.z;
            precise float A = ax * ax + ay * ay + az * az;
            s_sphere[j] = vec4(z.center, R);
            precise float F = z.front_radius * z.front_radius;
            s_half[j] = vec4(z.half_extents, F);
            s_apex[j] = vec4(z.camera_center, A);
            precise float C = z.cone_radius * z.cone_radius;
            s_axis[j] = vec4(ax, ay, az, C);
            s_shape[j] = z.shape;
            s_inside[j] = 0u;
        }
        barrier();
        for (uint j = 0u; j < nb; j++) {
            uint c = 0u;
            bool resets = (s_shape[j] & ZONE_NO_RESET) == 0u;
            for (uint k = 0u; k < ITEMS; k++) {
                if (first + k * WG_SIZE >= count) continue;
                if (inside_zone(x[k], j)) {
                    f[k] |= FLAG_INSIDE;
                    c++;
                }
                if (resets && (f[k] & FLAG_IN_FRONT) == 0u && in_front(x[k], j)) f[k] |= FLAG_IN_FRONT;
                if (resets && (f[k] & FLAG_IN_BALL) == 0u && in_ball(x[k], j)) f[k] |= FLAG_IN_BALL;
            }
            if (subgroupAny(c != 0u)) {
                uint s = subgroupAdd(c);
                if (subgroupElect()) atomicAdd(s_inside[j], s);
            }
        }
        barrier();
        for (uint j = tid; j < nb; j += WG_SIZE) {
            uint s = s_inside[j];
            if (s != 0u) atomicAdd(zone_inside[zb + j], s);
        }
    }
    for (uint k = 0u; k < ITEMS; k++) {
        uint i = first + k * WG_SIZE;
        if (i < count) flags[i] = f[k];
    }
}
