// Reading the current radiosity map where a ray hit: the hit triangle's
// lightmap UVs interpolated, then a bilinear lookup in the atlas of
// reflected radiance (albedo x lightmap value, thesis eq. 3.6).
#ifndef LF_LIGHTMAP_LOOKUP_GLSL
#define LF_LIGHTMAP_LOOKUP_GLSL

#include "buffer_bindings.glsl"
#include "trace.glsl"
#ifdef LF_EXACT_TEXTURES
#include "surface_textures.glsl"
#endif

// Reflected radiance per atlas texel (rgb; w = 1 where a chart's texel or its
// dilation holds a value, 0 elsewhere), width x height, row 0 at the top.
layout(std430, binding = LF_BINDING_REFLECTED_RADIANCE) buffer ReflectedRadiance { vec4 reflected_radiance[]; };
#ifdef LF_FINAL_GATHER
// The same for the light that has bounced at least once before reaching the
// texel (albedo x its indirect layer): what a final gather reads beyond the
// bounce it computes.
layout(std430, binding = LF_BINDING_REFLECTED_INDIRECT) buffer ReflectedIndirect { vec4 reflected_indirect[]; };
#endif
// Per scene triangle, what a ray that lands on it needs:
//   (uv1 of vertex 0, uv1 of vertex 1),
//   (uv1 of vertex 2, flags bits, area density with which emitter sampling picks its points (0: not an emitter)),
//   (emitted radiance rgb, emitter index bits (if it emits)),
//   (albedo rgb: its mean over the triangle, 0).
layout(std430, binding = LF_BINDING_SURFACE_TRIANGLES) readonly buffer SurfaceTriangles { vec4 surface_triangles[]; };

const uint SURFACE_VEC4S = 4u;

// Per atlas texel: where its light was gathered, and in w what it is
// (LF_ANCHOR_*, buffer_bindings.glsl).
layout(std430, binding = LF_BINDING_TEXEL_ANCHORS) buffer TexelAnchors { vec4 texel_anchors[]; };

// Per atlas texel, dilated: the albedo its samples averaged (rgb), what a
// final gather's hit reflects (radiosity_gather.comp with LF_FINAL_GATHER).
layout(std430, binding = LF_BINDING_TEXEL_ALBEDO) readonly buffer TexelAlbedo { vec4 texel_albedo[]; };

// The atlas's size, from the program's parameter block (LF_ATLAS_PARAMS).
uvec2 lf_atlas_size() { return uvec2(atlas_width, atlas_height); }

vec2 hit_lightmap_uv(Hit hit) {
    vec4 a = surface_triangles[SURFACE_VEC4S * hit.triangle];
    vec4 b = surface_triangles[SURFACE_VEC4S * hit.triangle + 1u];
    return (1.0 - hit.bary.x - hit.bary.y) * a.xy + hit.bary.x * a.zw + hit.bary.y * b.xy;
}

uint hit_triangle_flags(Hit hit) { return floatBitsToUint(surface_triangles[SURFACE_VEC4S * hit.triangle + 1u].z); }
bool hit_is_double_sided(Hit hit) { return (hit_triangle_flags(hit) & LF_TRIANGLE_DOUBLE_SIDED) != 0u; }
// A mesh left out of the lightmap (lightmap scale 0) keeps one texel per
// chart, which holds its samples' mean and is not read: a ray that lands on
// it gathers there.
bool hit_has_lightmap(Hit hit) { return (hit_triangle_flags(hit) & LF_TRIANGLE_WITHOUT_LIGHTMAP) == 0u; }

// Area density of emitter sampling at the hit's triangle (0 if it emits nothing).
float hit_emitter_area_pdf(Hit hit) { return surface_triangles[SURFACE_VEC4S * hit.triangle + 1u].w; }

// The radiance the hit point emits: the emitter's mean over its triangle, or
// under LF_EXACT_TEXTURES its emission texture at the point itself.
vec3 hit_emission(Hit hit) {
#ifdef LF_EXACT_TEXTURES
    return surface_emission(hit.triangle, hit.bary);
#else
    return surface_triangles[SURFACE_VEC4S * hit.triangle + 2u].rgb;
#endif
}

uint hit_emitter_index(Hit hit) { return floatBitsToUint(surface_triangles[SURFACE_VEC4S * hit.triangle + 2u].w); }

// The albedo a path reflects with at the hit: its texture at the point under
// LF_EXACT_TEXTURES, else the triangle's mean (Scene::mean_albedo).
vec3 hit_albedo(Hit hit) {
#ifdef LF_EXACT_TEXTURES
    return surface_albedo(hit.triangle, hit.bary);
#else
    return surface_triangles[SURFACE_VEC4S * hit.triangle + 3u].rgb;
#endif
}

uint atlas_index(int x, int y) {
    return uint(clamp(y, 0, int(lf_atlas_size().y) - 1)) * lf_atlas_size().x + uint(clamp(x, 0, int(lf_atlas_size().x) - 1));
}

// The four atlas texels a bilinear lookup at uv reads, and their weights.
void bilinear_taps(vec2 uv, out uint a[4], out float w[4]) {
    vec2 p = uv * vec2(lf_atlas_size()) - 0.5;
    vec2 f = fract(p);
    ivec2 i = ivec2(floor(p));
    for (int k = 0; k < 4; ++k) {
        a[k] = atlas_index(i.x + (k & 1), i.y + (k >> 1));
        w[k] = ((k & 1) == 1 ? f.x : 1.0 - f.x) * ((k >> 1) == 1 ? f.y : 1.0 - f.y);
    }
}

// Bilinear lookup of the reflected radiance where a ray landed, into
// `radiance`: of reflected_radiance, or (indirect_only, under a final gather)
// of reflected_indirect. uv (0,0) is the atlas's top-left corner and texel
// centres sit at half-integers (DESIGN.md). Charts are dilated, so the four
// texels read near a chart's border hold that chart's values; where a chart
// is smaller than the lookup's footprint, taps that hold no value (w = 0) are
// left out rather than read as black.
//
// False where the map cannot say what the landing point reflects, and the
// caller gathers there instead (radiosity_gather.comp's gather_at_hit):
//  * where a tap was cut by geometry or is next to one that was
//    (LF_ANCHOR_CUT, LF_ANCHOR_NEXT_TO_CUT). Such a texel gathered on one
//    side of the surface through it, at points kept out of it, in the
//    crease: its value is not the open part's that a ray lands on (the
//    staircase's lit walls read 3% dark through its cut texels), nor the
//    sealed side's (its cavities read light no path brings them: a fifth of
//    its squared error; BENCHMARKS.md). Reading such texels only where their
//    anchor was in sight of the landing point left both; reading black
//    there made small-charted scenes 8% dark (monkey.glb at 64²).
//  * where no tap holds a value (a chart smaller than a texel).
bool reflected_lookup(vec2 uv, bool indirect_only, out vec3 radiance) {
    uint a[4];
    float w[4];
    bilinear_taps(uv, a, w);
    vec3 sum = vec3(0.0);
    float weight_sum = 0.0;
    bool near_cut = false;
    for (int k = 0; k < 4; ++k) {
        if (w[k] == 0.0) continue;
        near_cut = near_cut || texel_anchors[a[k]].w >= LF_ANCHOR_CUT;
#ifdef LF_FINAL_GATHER
        vec4 r = indirect_only ? reflected_indirect[a[k]] : reflected_radiance[a[k]];
#else
        vec4 r = reflected_radiance[a[k]];
#endif
        sum += w[k] * r.w * r.rgb;
        weight_sum += w[k] * r.w;
    }
    radiance = weight_sum > 0.0 ? sum / weight_sum : vec3(0.0);
    return !near_cut && weight_sum > 0.0;
}

// Bilinear lookup of the texels' albedo at the hit (the weights of
// reflected_lookup, taps without a value left out); the triangle's own
// albedo where no tap has one (a chart smaller than a texel) and on a mesh
// without a lightmap (whose one texel per chart holds its samples' mean).
vec3 hit_texel_albedo(Hit hit) {
    if (!hit_has_lightmap(hit)) return hit_albedo(hit);
    uint a[4];
    float w[4];
    bilinear_taps(hit_lightmap_uv(hit), a, w);
    vec3 sum = vec3(0.0);
    float weight_sum = 0.0;
    for (int k = 0; k < 4; ++k) {
        vec4 albedo = texel_albedo[a[k]];
        sum += w[k] * albedo.w * albedo.rgb;
        weight_sum += w[k] * albedo.w;
    }
    return weight_sum > 0.0 ? sum / weight_sum : hit_albedo(hit);
}

#endif
