#version 450 core
// Brute-force irradiance under an environment, for checking SH shading:
// E(x) = ∫ V(x,ω) L(ω) max(0, n·ω) dω ≈ (pi/N) Σ V L over cosine-distributed
// rays (shadowed only, like the T^0 transfer). L from an equirectangular map
// or a constant colour (environment.glsl).
layout(local_size_x = 64) in;

#include "buffer_bindings.glsl"
#include "sh_reference_params.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"
#include "environment.glsl"

layout(std430, binding = LF_BINDING_SH_VERTICES) readonly buffer ShVertices { vec4 sh_vertices[]; };
layout(std430, binding = LF_BINDING_IRRADIANCE) buffer Irradiance { vec4 irradiance[]; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= vertex_count) return;
    vec3 p = sh_vertices[2u * i].xyz;
    vec3 n = sh_vertices[2u * i + 1u].xyz;
    vec3 origin = offset_ray_origin(p, n);
    Rng rng = rng_start(i, chunk, seed);
    vec3 sum = vec3(0.0);
    for (uint s = 0u; s < samples; ++s) {
        vec3 dir = sample_cosine_hemisphere(n, rng_next2(rng));
        sum += trace_transmittance(origin, dir, 1e30) * lf_background(dir);
    }
    irradiance[i] += vec4(sum * weight, 0.0);
}
