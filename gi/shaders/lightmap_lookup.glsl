// Reading the current radiosity map where a ray hit: the hit triangle's
// lightmap UVs interpolated, then a bilinear lookup in the atlas of
// reflected radiance (albedo x lightmap value, thesis eq. 3.6).
#ifndef LF_LIGHTMAP_LOOKUP_GLSL
#define LF_LIGHTMAP_LOOKUP_GLSL

#include "trace.glsl"

// Reflected radiance per atlas texel (rgb), width x height, row 0 at the top.
layout(std430, binding = 5) buffer ReflectedRadiance { vec4 reflected_radiance[]; };
// Per scene triangle, what a ray that lands on it needs:
//   (uv1 of vertex 0, uv1 of vertex 1),
//   (uv1 of vertex 2, flags bits, area density with which emitter sampling picks its points (0: not an emitter)),
//   (emitted radiance rgb, 0).
layout(std430, binding = 6) readonly buffer SurfaceTriangles { vec4 surface_triangles[]; };

uniform uvec2 atlas_size;

const uint TRIANGLE_DOUBLE_SIDED = 1u;

vec2 hit_lightmap_uv(Hit hit) {
    vec4 a = surface_triangles[3u * hit.triangle];
    vec4 b = surface_triangles[3u * hit.triangle + 1u];
    return (1.0 - hit.bary.x - hit.bary.y) * a.xy + hit.bary.x * a.zw + hit.bary.y * b.xy;
}

bool hit_is_double_sided(Hit hit) {
    return (floatBitsToUint(surface_triangles[3u * hit.triangle + 1u].z) & TRIANGLE_DOUBLE_SIDED) != 0u;
}

// Area density of emitter sampling at the hit's triangle (0 if it emits nothing).
float hit_emitter_area_pdf(Hit hit) { return surface_triangles[3u * hit.triangle + 1u].w; }

vec3 hit_emission(Hit hit) { return surface_triangles[3u * hit.triangle + 2u].rgb; }

vec3 reflected_texel(int x, int y) {
    x = clamp(x, 0, int(atlas_size.x) - 1);
    y = clamp(y, 0, int(atlas_size.y) - 1);
    return reflected_radiance[uint(y) * atlas_size.x + uint(x)].rgb;
}

// Bilinear lookup; uv (0,0) is the atlas's top-left corner and texel centres
// sit at half-integers (DESIGN.md). Charts are dilated, so the four texels
// read near a chart's border hold that chart's values.
vec3 reflected_radiance_at(vec2 uv) {
    vec2 p = uv * vec2(atlas_size) - 0.5;
    vec2 f = fract(p);
    ivec2 i = ivec2(floor(p));
    return mix(mix(reflected_texel(i.x, i.y), reflected_texel(i.x + 1, i.y), f.x),
               mix(reflected_texel(i.x, i.y + 1), reflected_texel(i.x + 1, i.y + 1), f.x), f.y);
}

#endif
