// Bits of the per-Gaussian `decisions` word written by decide.comp and read by expand.comp,
// scatter.comp and split.comp; mirrors `src/train/density/mod.rs`. A later pass (LPM) may OR
// its own bits in between decide and expand.
const uint DECIDE_REMOVE = 1u;   // the original is not carried over (pruned)
const uint DECIDE_CLONE = 2u;    // emit one identical copy
const uint DECIDE_SPLIT = 4u;    // emit two split children; the original is removed
const uint DECIDE_LOWERED = 8u;  // densified only because of the per-Gaussian threshold scale

bool decide_keeps(uint d) { return (d & (DECIDE_REMOVE | DECIDE_SPLIT)) == 0u; }

uint linear_index() {
    return (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
}
