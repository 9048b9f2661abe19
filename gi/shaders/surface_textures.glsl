// Albedo and emission at the exact point a ray lands, textures sampled at
// its TEXCOORD_0 (LF_EXACT_TEXTURES): what the path tracer and the probes'
// capture reflect and see, so that a brute-force estimate models the
// surfaces the file describes, not a per-triangle or per-texel average.
// Mirrors Scene::albedo_at / Scene::emission_at and Texture::sample (bilinear,
// REPEAT, texel centres at half-integers, row 0 at the top); the texels are
// half floats (relative error < 2^-11). The buffers are made by
// gi/bake/surface_textures.cpp.
#ifndef LF_SURFACE_TEXTURES_GLSL
#define LF_SURFACE_TEXTURES_GLSL
#include "buffer_bindings.glsl"
#include "material_layout.glsl"

// Per scene triangle, two vec4: (uv0 of vertex 0, uv0 of vertex 1), (uv0 of vertex 2, material index bits, 0).
layout(std430, binding = LF_BINDING_SURFACE_TEXCOORDS) readonly buffer SurfaceTexCoords { vec4 surface_texcoords[]; };
// material_textures[0] = M materials, [1] = where the texture table starts;
// material m's record at LF_MATERIALS_FIRST + LF_MATERIAL_UINTS m (material_layout.glsl);
// texture k in the table: first texel, width, height, 0;
// a texel: two uints, packHalf2x16(r, g) and packHalf2x16(b, a).
layout(std430, binding = LF_BINDING_MATERIAL_TEXTURES) readonly buffer MaterialTextures { uint material_textures[]; };

vec4 texture_fetch(uint first, uint width, int x, int y) {
    uint t = first + 2u * (uint(y) * width + uint(x));
    return vec4(unpackHalf2x16(material_textures[t]), unpackHalf2x16(material_textures[t + 1u]));
}

// Texture k (an index into the table) at uv: Texture::sample.
vec4 texture_sample(uint k, vec2 uv) {
    uint entry = material_textures[1u] + 4u * k;
    uint first = material_textures[entry];
    int width = int(material_textures[entry + 1u]), height = int(material_textures[entry + 2u]);
    if (any(isnan(uv)) || any(isinf(uv))) return texture_fetch(first, uint(width), 0, 0);
    vec2 p = fract(uv) * vec2(width, height) - 0.5;
    vec2 p0 = floor(p);
    vec2 f = p - p0;
    // p0 is in [-1, size - 1]: -1 wraps to the last texel (GLSL's % of a
    // negative number is undefined, so no modulo).
    ivec2 size = ivec2(width, height);
    ivec2 i0 = ivec2(p0) + ivec2(lessThan(p0, vec2(0.0))) * size;
    ivec2 i1 = ivec2(notEqual(i0 + 1, size)) * (i0 + 1);
    vec4 top = mix(texture_fetch(first, uint(width), i0.x, i0.y), texture_fetch(first, uint(width), i1.x, i0.y), f.x);
    vec4 bottom = mix(texture_fetch(first, uint(width), i0.x, i1.y), texture_fetch(first, uint(width), i1.x, i1.y), f.x);
    return mix(top, bottom, f.y);
}

uint surface_material(uint triangle) { return floatBitsToUint(surface_texcoords[2u * triangle + 1u].z); }

vec2 surface_uv0(uint triangle, vec2 bary) {
    vec4 a = surface_texcoords[2u * triangle], b = surface_texcoords[2u * triangle + 1u];
    return (1.0 - bary.x - bary.y) * a.xy + bary.x * a.zw + bary.y * b.xy;
}

uint material_uint(uint m, uint at) { return material_textures[LF_MATERIALS_FIRST + LF_MATERIAL_UINTS * m + at]; }
float material_float(uint m, uint at) { return uintBitsToFloat(material_uint(m, at)); }
vec3 material_vec3(uint m, uint at) {
    return vec3(material_float(m, at), material_float(m, at + 1u), material_float(m, at + 2u));
}

// Scene::albedo_at: the base colour times its texture at the point.
vec3 surface_albedo(uint triangle, vec2 bary) {
    uint m = surface_material(triangle);
    uint texture = material_uint(m, LF_MAT_BASE_TEXTURE);
    vec3 albedo = material_vec3(m, LF_MAT_BASE_COLOR);
    return texture == 0u ? albedo : albedo * texture_sample(texture - 1u, surface_uv0(triangle, bary)).rgb;
}

// Scene::emission_at: the emitted radiance times its texture at the point.
vec3 surface_emission(uint triangle, vec2 bary) {
    uint m = surface_material(triangle);
    uint texture = material_uint(m, LF_MAT_EMISSIVE_TEXTURE);
    vec3 emission = material_vec3(m, LF_MAT_EMISSION);
    if (texture == 0u || emission == vec3(0.0)) return emission;
    return emission * texture_sample(texture - 1u, surface_uv0(triangle, bary)).rgb;
}

// How a see-through surface (Material::is_see_through) passes light at a
// point: the share of the surface that is there (coverage: alphaMode against
// base colour alpha x its texture's), and the tint of the light that passes
// through what is there (transmission x base colour; the absorption inside
// a volume is the path's, trace.glsl's lf_cross_medium). Scene::transmittance_at
// is 1 - coverage + coverage x that tint.
void surface_see_through(uint triangle, vec2 bary, out float coverage, out vec3 transmitted) {
    uint m = surface_material(triangle);
    uint texture = material_uint(m, LF_MAT_BASE_TEXTURE);
    vec4 base = vec4(material_vec3(m, LF_MAT_BASE_COLOR), material_float(m, LF_MAT_ALPHA));
    if (texture != 0u) base *= texture_sample(texture - 1u, surface_uv0(triangle, bary));
    uint mode = material_uint(m, LF_MAT_ALPHA_MODE);
    coverage = mode == LF_ALPHA_MASK ? (base.a >= material_float(m, LF_MAT_ALPHA_CUTOFF) ? 1.0 : 0.0)
             : mode == LF_ALPHA_BLEND ? base.a : 1.0;
    transmitted = material_float(m, LF_MAT_TRANSMISSION) * base.rgb;
}

#endif
