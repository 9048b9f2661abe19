#version 450 core
// Runs gi/shaders/unit_vector.glsl on vectors the tests packed
// (tests/test_radiosity.cpp): cases[i] = (packed, 0, 0, 0) ->
// results[i] = (the unit vector, 0).
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "check_params.glsl"
#include "unit_vector.glsl"

layout(std430, binding = LF_BINDING_CHECK_CASES) readonly buffer Cases { vec4 cases[]; };
layout(std430, binding = LF_BINDING_CHECK_RESULTS) writeonly buffer Results { vec4 results[]; };


void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= item_count) return;
    results[i] = vec4(lf_unpack_unit_vector(cases[i].x), 0.0);
}
