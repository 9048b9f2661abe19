#version 450 core
// One pass of the probes' capture (Umenhoffer & Szirmay-Kalos, §3): for every
// texel of every probe's cube map, one ray from the probe's reference point
// through a random point of the texel. It records the distance to the surface
// it meets and that surface's outgoing radiance towards the probe: its
// emission plus the light it reflects, traced as a path from the hit point
// (path_trace.glsl, next-event estimation at every vertex). Tracing the
// reflected light, rather than reading albedo x the job's lightmap, makes the
// probes independent of whether a lightmap is baked, of its resolution and of
// its bias; it costs a path per texel per pass.
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "probes_params.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"
#include "lightmap_lookup.glsl"
#include "direct_light.glsl"
#include "environment.glsl"
#include "path_trace.glsl"
#include "probe_cube.glsl"

// Probe k: (reference point, 0).
layout(std430, binding = LF_BINDING_PROBE_POSITIONS) readonly buffer ProbePositions { vec4 probe_positions[]; };
// Per cube texel (probe-major, then face, row, column): two vec4,
//   (radiance sum rgb, rays), (distance sum over hits, hits, back-face hits, sum of radiance mean²).
layout(std430, binding = LF_BINDING_PROBE_TEXELS) buffer ProbeTexels { vec4 probe_texels[]; };
// Rays traced so far (the pass's primary rays and every path's).
layout(std430, binding = LF_BINDING_PROBE_RAYS) buffer ProbeRays { uint probe_rays; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= texel_count) return;
    uint per_face = resolution * resolution;
    uint probe = i / (6u * per_face);
    uint in_probe = i % (6u * per_face);
    int face = int(in_probe / per_face);
    uint row = (in_probe % per_face) / resolution, column = in_probe % resolution;

    Rng rng = rng_start(i, pass, seed);
    vec2 uv = (vec2(float(column), float(row)) + rng_next2(rng)) / float(resolution);
    vec3 dir = lf_cube_direction(face, uv);
    vec3 origin = probe_positions[probe].xyz;

    vec3 radiance = vec3(0.0);
    float distance = 0.0, hit = 0.0, backface = 0.0;
    uint rays = 1u;
    // The distance is that of the closest surface that passes no light: a
    // see-through sheet that stopped this ray (a blend's draw) or passed it
    // does not move the texel's depth, so its polygons lie on what is seen
    // through the sheet, with that radiance times the sheet's transmittance
    // (probe_corners.comp's rays go there too).
    float opaque_t;
    Hit h = trace_closest_and_opaque(origin, dir, far, opaque_t);
    if (opaque_t < far) {
        distance = opaque_t;
        hit = 1.0;
    }
    if (h.triangle == LF_NO_HIT) {
        radiance = h.tint * lf_background(dir);
    } else if (h.front || hit_is_double_sided(h)) {
        radiance = h.tint * (hit_emission(h) + path_radiance(h, origin, dir, rng, rays));
    } else {
        // The back of a one-sided surface: the probe sees the inside of something.
        backface = 1.0;
    }
    vec4 a = probe_texels[2u * i], b = probe_texels[2u * i + 1u];
    float mean = (radiance.r + radiance.g + radiance.b) / 3.0;
    probe_texels[2u * i] = vec4(a.rgb + radiance, a.w + 1.0);
    probe_texels[2u * i + 1u] = vec4(b.x + distance, b.y + hit, b.z + backface, b.w + mean * mean);
    atomicAdd(probe_rays, rays);
}
