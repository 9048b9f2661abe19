#version 450 core
// Runs the spherical-triangle functions of gi/shaders/sampling.glsl on
// triangles the tests packed (tests/test_radiosity.cpp), seen from the
// origin: cases[3i .. 3i+2] = (A, n.x), (B, n.y), (C, n.z) -> results[i] =
// (the solid angle, the integral of max(0, n . w) over it estimated from
// `grid`² stratified directions of sample_spherical_triangle, atan2 of A's
// x and y by accurate_atan2, GLSL's own atan of the same).
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "check_params.glsl"
#include "sampling.glsl"

layout(std430, binding = LF_BINDING_CHECK_CASES) readonly buffer Cases { vec4 cases[]; };
layout(std430, binding = LF_BINDING_CHECK_RESULTS) writeonly buffer Results { vec4 results[]; };


void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= item_count) return;
    vec4 a = cases[3u * i], b = cases[3u * i + 1u], c = cases[3u * i + 2u];
    vec3 n = vec3(a.w, b.w, c.w);
    SphericalTriangle t = spherical_triangle(vec3(0.0), a.xyz, b.xyz, c.xyz);
    float omega = t.area;
    float sum = 0.0;
    if (omega > 0.0) {
        for (uint row = 0u; row < grid; ++row) {  // by rows: one float sum of grid² terms would round off
            float row_sum = 0.0;
            for (uint k = 0u; k < grid; ++k) {
                vec2 u = (vec2(k, row) + 0.5) / float(grid);
                row_sum += max(0.0, dot(n, sample_spherical_triangle(t, u)));
            }
            sum += row_sum;
        }
    }
    results[i] = vec4(omega, sum * omega / float(grid * grid), accurate_atan2(a.y, a.x), atan(a.y, a.x));
}
