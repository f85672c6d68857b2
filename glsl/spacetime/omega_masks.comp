#version 460
// SpacetimeGaussians' angular-velocity split, every step after the selection (official
// helper_train.py `freezweightsbymasknounsqueeze`): a Gaussian whose angular velocity is 0
// (unmarked by omega_select.comp, or added later with ω = 0) learns no angular velocity, a
// Gaussian with one learns no rotation: the other group's gradient is zeroed before Adam.
layout(local_size_x_id = 0) in;
layout(std430, set = 0, binding = 0) readonly buffer Omega { vec4 omega[]; };
layout(std430, set = 0, binding = 1) buffer GOmega { vec4 g_omega[]; };
layout(std430, set = 0, binding = 2) buffer GRotations { vec4 g_rotations[]; };
layout(push_constant) uniform Push {
    uint count;
};

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= count) return;
    if (all(equal(omega[i], vec4(0.0)))) {
        g_omega[i] = vec4(0.0);
    } else {
        g_rotations[i] = vec4(0.0);
    }
}
