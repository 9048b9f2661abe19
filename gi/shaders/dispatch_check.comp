#version 450 core
// Checks ComputeProgram::dispatch_1d (tests only): every item below
// item_count is visited exactly once, and every dispatched group writes its
// own slot of a per-group buffer sized by groups_1d.
layout(local_size_x = 64) in;
#include "buffer_bindings.glsl"
#include "check_params.glsl"

layout(std430, binding = LF_BINDING_ITEM_VISITS) buffer ItemVisits { uint item_visits[]; };
layout(std430, binding = LF_BINDING_GROUP_SLOTS) buffer GroupSlots { uint group_slots[]; };

#ifdef LF_CHECK_STRAY_UNIFORM  // a parameter outside the block: ComputeProgram refuses it
uniform uint stray;
#define LF_STRAY stray
#else
#define LF_STRAY 0u
#endif

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i < item_count) atomicAdd(item_visits[i], 1u + LF_STRAY);
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (gl_LocalInvocationIndex == 0u) group_slots[group] = group + 1u;
}
