#version 450 core
// One ray per probe and corner of its M x M cube grid, along the corner's own
// direction: where the polygon-to-point estimator puts that corner
// (gi/probes/probe_eval.h, "Corner distances"), exactly on the surface the
// direction meets, whatever that surface's angle to the cube's faces. The
// texels' mean distances put a corner on a surface only when the surface
// faces the probe across a cube face (a floor seen through a side face was
// off its plane: -29% at 0.36 m from the probe, R 32, M 4).
// Built with LF_TEXEL_CENTRES, the same along each texel's centre direction
// instead (M x M per face, texel order): a texel whose corners and centre lie
// on one plane sees one flat surface (gi/probes/probe_eval.cpp, probe_sees).
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "probes_params.glsl"
#include "trace.glsl"
#include "probe_cube.glsl"

// Probe k: (reference point, 0).
layout(std430, binding = LF_BINDING_PROBE_POSITIONS) readonly buffer ProbePositions { vec4 probe_positions[]; };
// Per probe, corner (face f, column a, row b) at (f (M+1) + b) (M+1) + a: the
// distance to the surface, or miss_distance where the ray leaves the scene.
layout(std430, binding = LF_BINDING_PROBE_CORNERS) writeonly buffer ProbeCorners { float corner_distances[]; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= corner_count) return;
#ifdef LF_TEXEL_CENTRES
    uint side = m;
    const float offset = 0.5;
#else
    uint side = m + 1u;
    const float offset = 0.0;
#endif
    uint per_face = side * side;
    uint probe = i / (6u * per_face), in_probe = i % (6u * per_face);
    int face = int(in_probe / per_face);
    uint b = (in_probe % per_face) / side, a = in_probe % side;
    vec3 dir = lf_cube_direction(face, (vec2(float(a), float(b)) + offset) / float(m));
    // Past see-through surfaces, to what lies behind them: the capture's
    // radiance through a sheet is what is behind it, times the sheet's
    // transmittance, and belongs at that depth (probe_capture.comp too).
    Hit hit = trace_closest_opaque(probe_positions[probe].xyz, dir, miss_distance);
    corner_distances[i] = hit.triangle == LF_NO_HIT ? miss_distance : hit.t;
}
