#version 450 core
// Batched tracing: rays in, hits out. For tools, tests and any caller that
// has its rays on the CPU; the bake methods trace from their own shaders.
// mode 0 (Tracer::trace): geometry alone, every triangle stops a ray,
// see-through or not. mode 1 (Tracer::transmittance): the share of light
// that passes along the ray, per channel (trace.glsl's trace_transmittance).
#include "buffer_bindings.glsl"
#include "tracer_params.glsl"
#include "trace.glsl"

layout(local_size_x = 64) in;

// Ray: (origin, t_max), (direction, any-hit flag as uint bits: nonzero = occlusion query).
layout(std430, binding = LF_BINDING_RAYS) readonly buffer Rays { vec4 rays[]; };
// Hit: (t, triangle bits, b1, b2); triangle = LF_NO_HIT on a miss. mode 1: (rgb, 0).
layout(std430, binding = LF_BINDING_HITS) writeonly buffer Hits { vec4 hits[]; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= ray_count) return;
    vec4 o = rays[2u * i], d = rays[2u * i + 1u];
    if (mode == 1u) {
        hits[i] = vec4(trace_transmittance(o.xyz, d.xyz, o.w), 0.0);
        return;
    }
    Hit h = floatBitsToUint(d.w) != 0u ? Hit(0.0, trace_occluded_geometry(o.xyz, d.xyz, o.w) ? 0u : LF_NO_HIT, vec2(0.0), false, vec3(0.0), vec3(1.0))
                                       : trace_closest_geometry(o.xyz, d.xyz, o.w);
    hits[i] = vec4(h.t, uintBitsToFloat(h.triangle), h.bary);
}
