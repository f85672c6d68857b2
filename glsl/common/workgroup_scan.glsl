// Workgroup-wide exclusive scan of one uint per invocation, for any subgroup size the device
// runs with. Needs `WG_SIZE` (specialisation constant 0) declared before inclusion and
// GL_KHR_shader_subgroup_arithmetic enabled.
shared uint wgs_subgroup_sums[WG_SIZE];
shared uint wgs_total;

// Returns the exclusive prefix of `v` over the workgroup; `total` gets the workgroup sum.
// Every invocation of the workgroup must call it (it contains barriers).
uint workgroup_exclusive_scan(uint v, out uint total) {
    uint inclusive = subgroupInclusiveAdd(v);
    if (gl_SubgroupInvocationID == gl_SubgroupSize - 1u) {
        wgs_subgroup_sums[gl_SubgroupID] = inclusive;
    }
    barrier();
    // Few subgroups per workgroup (at most WG_SIZE / subgroup size): a serial scan by one
    // invocation is cheaper than another level of subgroup operations and works for any size.
    if (gl_LocalInvocationIndex == 0u) {
        uint running = 0u;
        for (uint i = 0u; i < gl_NumSubgroups; i++) {
            uint s = wgs_subgroup_sums[i];
            wgs_subgroup_sums[i] = running;
            running += s;
        }
        wgs_total = running;
    }
    barrier();
    uint result = wgs_subgroup_sums[gl_SubgroupID] + inclusive - v;
    total = wgs_total;
    barrier();
    return result;
}
