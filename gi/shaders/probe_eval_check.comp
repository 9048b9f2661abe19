#version 450 core
// Runs gi/shaders/probe_eval.glsl and probe_cube.glsl on inputs from the
// tests (tests/test_probes.cpp), to compare with the C++ (probe_eval.h).
//   mode 0: form factor; cases[6i..6i+5] = x, n, c0, c1, c2, c3 -> results[i].x
//   mode 1: probe `probe` at (x, n) = cases[2i], cases[2i+1] -> results[i].rgb
//   mode 2: cube direction; cases[i] = (face, u, v) -> results[i].xyz
//   mode 4: probe `probe`'s SH9 irradiance at normal cases[i] -> results[i].rgb
//   mode 5: whether probe `probe` sees cases[i].xyz -> results[i].x (1 or 0)
//   mode 3: the grid (grid_counts, grid_origin, grid_spacing) at (x, n) = cases[2i], cases[2i+1] -> results[i].rgb
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "check_params.glsl"
#include "probe_eval.glsl"

layout(std430, binding = LF_BINDING_CHECK_CASES) readonly buffer Cases { vec4 cases[]; };
layout(std430, binding = LF_BINDING_CHECK_RESULTS) writeonly buffer Results { vec4 results[]; };

vec3 probe_position() { return vec3(probe_position_x, probe_position_y, probe_position_z); }
ivec3 grid_counts() { return ivec3(grid_counts_x, grid_counts_y, grid_counts_z); }
vec3 grid_origin() { return vec3(grid_origin_x, grid_origin_y, grid_origin_z); }
vec3 grid_spacing() { return vec3(grid_spacing_x, grid_spacing_y, grid_spacing_z); }

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= item_count) return;
    if (mode == 0u) {
        uint b = 6u * i;
        float f = lf_polygon_to_point_form_factor(cases[b].xyz, cases[b + 1u].xyz, cases[b + 2u].xyz,
                                                  cases[b + 3u].xyz, cases[b + 4u].xyz, cases[b + 5u].xyz);
        results[i] = vec4(f, 0.0, 0.0, 0.0);
    } else if (mode == 1u) {
        results[i] = vec4(lf_probe_polygon_to_point(probe, m, probe_position(), cases[2u * i].xyz, cases[2u * i + 1u].xyz), 0.0);
    } else if (mode == 5u) {
        bool sees = lf_probe_sees(probe * lf_probe_stride(m), m, probe_position(), cases[i].xyz);
        results[i] = vec4(sees ? 1.0 : 0.0, 0.0, 0.0, 0.0);
    } else if (mode == 4u) {
        results[i] = vec4(lf_probe_sh9(probe, m, cases[i].xyz), 0.0);
    } else if (mode == 3u) {
        results[i] = vec4(lf_probe_grid_polygon_to_point(grid_counts(), grid_origin(), grid_spacing(), m, cases[2u * i].xyz,
                                                         cases[2u * i + 1u].xyz), 0.0);
    } else {
        vec4 c = cases[i];
        results[i] = vec4(lf_cube_direction(int(c.x), c.yz), 0.0);
    }
}
