#version 450 core
// Runs gi/shaders/surface_textures.glsl on inputs from the tests
// (tests/test_radiosity.cpp), to compare with Scene::albedo_at and
// Scene::emission_at and Scene::transmittance_at: cases[i] = (triangle
// bits, b1, b2, 0) -> results[3i] = albedo, results[3i + 1] = emission,
// results[3i + 2] = transmittance.
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "check_params.glsl"
#include "surface_textures.glsl"

layout(std430, binding = LF_BINDING_CHECK_CASES) readonly buffer Cases { vec4 cases[]; };
layout(std430, binding = LF_BINDING_CHECK_RESULTS) writeonly buffer Results { vec4 results[]; };


void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= item_count) return;
    uint triangle = floatBitsToUint(cases[i].x);
    results[3u * i] = vec4(surface_albedo(triangle, cases[i].yz), 0.0);
    results[3u * i + 1u] = vec4(surface_emission(triangle, cases[i].yz), 0.0);
    float coverage;
    vec3 transmitted;
    surface_see_through(triangle, cases[i].yz, coverage, transmitted);
    results[3u * i + 2u] = vec4(vec3(1.0 - coverage) + coverage * transmitted, 0.0);
}
