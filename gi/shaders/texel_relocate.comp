#version 450 core
// Before the first pass: a sample point that lies inside or behind nearby
// geometry (floor texels under a wall) would gather the wall's inside and
// leak light or go black. Short rays along the surface find the back faces
// that enclose such a point; the point moves just past the nearest one, to
// where the surface is visible again.
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#define LF_SAMPLE_POINTS_ACCESS
#define LF_MOVED_SAMPLES
#include "radiosity_params.glsl"
#include "trace.glsl"
#include "sampling.glsl"
#include "radiosity_texels.glsl"


void main() {
    uint s = covered_index();
    if (s >= sample_count) return;
    vec3 x = sample_position(s);
    float texel_size = sample_texel_size(s);
    vec3 ng = sample_geometric_normal(s);
    vec3 t, b;
    orthonormal_basis(ng, t, b);
    vec3 origin = offset_ray_origin(x, ng);
    float best_t = 2.0;
    vec3 best_dir = vec3(0.0);
    // Eight directions in the tangent plane, tilted slightly off the surface.
    for (int k = 0; k < 8; ++k) {
        float phi = float(k) * (PI / 4.0);
        vec3 dir = normalize(cos(phi) * t + sin(phi) * b + 0.05 * ng) * texel_size;
        Hit hit = trace_closest_geometry(origin, dir, 1.0);
        if (hit.triangle != LF_NO_HIT && !hit.front && hit.t < best_t) {
            best_t = hit.t;
            best_dir = dir;
        }
    }
    if (best_t < 2.0) {
        // Just past the back face, back on the plane of the surface.
        vec3 moved = x + best_dir * (best_t + 0.05);
        moved -= ng * dot(moved - x, ng);
        sample_points[2u * s].xyz = moved;
        atomicOr(moved_samples[s / 32u], 1u << (s % 32u));  // for the texel's anchor (texel_anchor.comp)
    }
}
