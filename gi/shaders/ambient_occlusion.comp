#version 450 core
// Passes of ambient occlusion (DESIGN.md "Conventions"): the cosine-weighted
// fraction of the hemisphere with no surface within the AO distance,
//   A(x) = (1/pi) ∫ V_D(x, ω) max(0, n·ω) dω  ≈  (1/N) Σ V_D(x, ω_k),  ω_k ~ cos/pi,
// where V_D is 1 when the ray meets nothing closer than D (the cosine pdf
// cancels the cosine and the 1/pi). One ray per sample point per pass; each
// point's running count of unoccluded rays is its accumulator.
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#include "buffer_bindings.glsl"
#include "ambient_occlusion_params.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"

// Per sample point: (position, 0), (unit normal, 0), (unit geometric normal, 0).
layout(std430, binding = LF_BINDING_AO_POINTS) readonly buffer AoPoints { vec4 ao_points[]; };
// Per sample point: unoccluded rays so far.
layout(std430, binding = LF_BINDING_AO_UNOCCLUDED) buffer AoUnoccluded { float ao_unoccluded[]; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= point_count) return;
    vec3 p = ao_points[3u * i].xyz;
    vec3 n = ao_points[3u * i + 1u].xyz;
    vec3 g = ao_points[3u * i + 2u].xyz;
    // Off the surface along its geometric normal, on the side the shading
    // normal faces (a double-sided chart turned to face the scene).
    vec3 origin = offset_ray_origin(p, dot(g, n) < 0.0 ? -g : g);
    // The R2 sequence rotated per point, continued across passes (as
    // sh_transfer.comp): a resumed bake traces the same rays.
    uvec2 rotation = uvec2(pcg_hash(i ^ pcg_hash(seed)), pcg_hash(i * 7u + 1u + pcg_hash(seed + 1u)));
    float unoccluded = 0.0;
    for (uint k = 0u; k < pass_count; ++k) {
        vec3 dir = sample_cosine_hemisphere(n, r2_sample(rotation, first_pass + k));
        if (!trace_occluded(origin, dir, distance)) unoccluded += 1.0;
    }
    ao_unoccluded[i] += unoccluded;
}
