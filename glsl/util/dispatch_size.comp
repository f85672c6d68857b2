#version 460
// The group counts of a dispatch sized by a count the GPU wrote (counts[count_index] items,
// per_group items a workgroup), for vkCmdDispatchIndirect: passes over the frame's pairs then
// run as many workgroups as there are pairs rather than as the buffers' capacity (1.5× to 8×
// more). An idle workgroup is nearly free on a GPU but not on CPU drivers, where a radix sort of
// 1 M keys with room for 2 M took twice as long (`cargo bench --bench sort`, lavapipe).
// Spills into y past max_x like GpuContext::groups_1d; at least one group, since some kernels
// write a count from their first workgroup even when there is nothing to do.
layout(local_size_x = 1) in;
layout(std430, set = 0, binding = 0) readonly buffer Counts { uint counts[]; };
layout(std430, set = 0, binding = 1) writeonly buffer Args { uint args[]; };
layout(push_constant) uniform Push { uint count_index; uint per_group; uint max_x; uint slot; };

void main() {
    uint n = counts[count_index];
    // Without n + per_group − 1, which would wrap for counts near 2^32.
    uint groups = max(n / per_group + (n % per_group != 0u ? 1u : 0u), 1u);
    uint y = groups / max_x + (groups % max_x != 0u ? 1u : 0u);
    uint x = groups / y + (groups % y != 0u ? 1u : 0u);
    args[slot * 3u] = x;
    args[slot * 3u + 1u] = y;
    args[slot * 3u + 2u] = 1u;
}
