// Error zones as the LPM kernels read them: the mirror of `ZoneRecord` in src/lpm/record.rs
// (64 bytes, std430: each vec3 is followed by a scalar that fills its fourth slot).
struct Zone {
    vec3 center;
    float radius;         // sphere radius; for a box, its circumscribed radius
    vec3 camera_center;   // apex of the "in front" cone
    uint shape;           // ZONE_SPHERE, ZONE_BOX or ZONE_SLAB, | ZONE_NO_RESET
    vec3 color;
    float front_radius;   // "in front" ends at the near side of the ball of this radius;
                          // a slab spans |x − camera_center| within this of |center − camera_center|
    vec3 half_extents;    // box only
    float cone_radius;    // base radius of the in-front cone, radius of the FLAG_IN_BALL ball
};
const uint ZONE_SPHERE = 0u;
const uint ZONE_BOX = 1u;
const uint ZONE_SLAB = 2u;  // the in-front cone cut to a band of distances from its apex
const uint ZONE_SHAPE_MASK = 0xFFu;
// OR-ed into shape: nothing is in front of the zone or in its ball, so the opacity reset
// ignores it (a zone wider than --lpm-reset-max-zone-radius); it still holds Gaussians inside.
const uint ZONE_NO_RESET = 0x100u;

// Bits of the per-Gaussian membership flags (src/lpm/reset_settings.rs has the same constants).
const uint FLAG_INSIDE = 1u;
const uint FLAG_IN_FRONT = 2u;
const uint FLAG_IN_BALL = 4u;  // within cone_radius of a zone's centre (the authors' reset set)
