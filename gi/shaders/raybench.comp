#version 450 core
// Ray throughput: rays generated, traced and counted in one dispatch, as the
// bake methods do (their rays never leave the GPU).
#include "buffer_bindings.glsl"
#include "tracer_params.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"

layout(local_size_x = 64) in;

// Surface points for incoherent rays: (position, 0), (geometric normal, 0).
layout(std430, binding = LF_BINDING_SURFACE_POINTS) readonly buffer SurfacePoints { vec4 surface_points[]; };
// One counter per workgroup-ish slot; summed on the CPU.
layout(std430, binding = LF_BINDING_HIT_COUNTS) buffer HitCounts { uint hit_counts[]; };


shared uint group_hits;

// Traces ray i; true on a hit.
bool trace_benchmark_ray(uint i) {
    vec3 org, dir;
    if (mode == 0u) {
        // 8x8 pixel tiles, one per workgroup, so neighbouring rays run together.
        uint tile = i / 64u, in_tile = i % 64u;
        uint tiles_x = image_width / 8u;
        uint px = (tile % tiles_x) * 8u + in_tile % 8u;
        uint py = (tile / tiles_x) * 8u + in_tile / 8u;
        vec2 ndc = (vec2(px, py) + 0.5) / float(image_width) * 2.0 - 1.0;
        org = vec3(eye_x, eye_y, eye_z);
        dir = normalize(vec3(ndc.x, -ndc.y, -1.0));  // 90 degree field of view towards -z
    } else {
        Rng rng = rng_start(i, pass, 17u);
        uint p = uint(rng_next(rng) * float(point_count)) % point_count;
        vec3 n = surface_points[2u * p + 1u].xyz;
        org = offset_ray_origin(surface_points[2u * p].xyz, n);
        dir = sample_cosine_hemisphere(n, rng_next2(rng));
    }
    return trace_closest(org, dir, t_far).triangle != LF_NO_HIT;
}

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (gl_LocalInvocationIndex == 0u) group_hits = 0u;
    barrier();
    if (i < ray_count && trace_benchmark_ray(i)) atomicAdd(group_hits, 1u);
    barrier();
    // One global atomic per workgroup, spread over 1024 counters, so counting never limits throughput.
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (gl_LocalInvocationIndex == 0u) atomicAdd(hit_counts[group % 1024u], group_hits);
}
