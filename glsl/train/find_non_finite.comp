#version 460
// First non-finite value of one parameter group: every float of the first `n` (= count ×
// stride) is tested, and the Gaussian index (i / stride) of any NaN or ±inf is folded into
// `first[slot]` with atomicMin (the host fills it with 0xFFFFFFFF, meaning "none").
// The test is on the bits (all-ones exponent), so no compiler assumption about NaN can
// remove it.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Values { float values[]; };
layout(std430, set = 0, binding = 1) buffer First { uint first[]; };
layout(push_constant) uniform Push {
    uint n;
    uint stride;
    uint slot;
};

void main() {
    uint i = (gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x) * gl_WorkGroupSize.x
        + gl_LocalInvocationID.x;
    if (i >= n) return;
    if ((floatBitsToUint(values[i]) & 0x7f800000u) == 0x7f800000u) {
        atomicMin(first[slot], i / stride);
    }
}
