#version 460
// Fills a u32 buffer with a value: used to poison outputs before a run in tests and to clear
// counters inside a command buffer without a host round trip.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) writeonly buffer Data { uint data[]; };
layout(push_constant) uniform Push { uint count; uint value; };
void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i < count) data[i] = value;
}
