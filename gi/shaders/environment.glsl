// The light from beyond the scene: the radiance a ray that escapes sees
// (W/(sr m^2)), a uniform sky or an equirectangular map, nearest texel, in
// gi/sh/environment.h's convention (y up; the image's centre looks along +x):
//   u = 0.5 + atan(d.z, d.x) / (2 pi),  v = acos(d.y) / pi  (v = 0: the top row, looking up)
// The program's parameter block holds LF_ENVIRONMENT_PARAMS (params_block.glsl):
// the map's size (0 x 0: the uniform sky background_rgb) and, under a map,
// background_rgb scales it. Bound by EnvironmentLight.
//
// A map is importance-sampled: a direction is drawn in proportion to its
// texel's luminance (the mean of R, G, B) times the texel's solid angle
// (sin θ), and combined with the cosine ray that the point also traces, by
// the balance heuristic (Veach 1997): lf_environment_light
// is the map's sample, lf_escape_weight the weight of a cosine ray that
// escaped. A small bright sun, which a cosine ray finds with the
// probability of its projected solid angle, is then found by every sample.
// The uniform sky keeps cosine rays alone (their density is the
// integrand's). A texel's pass and each path vertex take a map sample; a
// final gather's hit points and the gathers where the map cannot say do
// not (each call inlines a traversal: compile time on llvmpipe,
// BENCHMARKS.md), and count their escaping cosine rays whole. The buffer holds, after the W x H texels (rgb; w: the
// row's CDF up to and including that texel), the H rows' CDF (x).
#ifndef LF_ENVIRONMENT_GLSL
#define LF_ENVIRONMENT_GLSL

#include "random.glsl"
#include "trace.glsl"

// A buffer texture, not a storage block: a compute program may have 16 of
// those (GL_MAX_COMPUTE_SHADER_STORAGE_BLOCKS, llvmpipe's and NVIDIA's), and
// the radiosity gather's variants use them all.
layout(binding = LF_TEXTURE_ENVIRONMENT) uniform samplerBuffer environment_texels;

vec3 lf_background_scale() { return vec3(background_r, background_g, background_b); }

// Whether escaping rays see any light (a sky ray is worth tracing).
bool lf_has_background() { return lf_background_scale() != vec3(0.0); }

// The map's texel (x, y) in direction d (unit length), nearest.
uvec2 lf_environment_texel(vec3 d) {
    float u = 0.5 + atan(d.z, d.x) / (2.0 * PI);
    float v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    return uvec2(min(uint(u * float(env_width)), env_width - 1u), min(uint(v * float(env_height)), env_height - 1u));
}

// The radiance seen along the escaping direction d (unit length).
vec3 lf_background(vec3 d) {
    if (env_width == 0u) return lf_background_scale();
    uvec2 t = lf_environment_texel(d);
    return lf_background_scale() * texelFetch(environment_texels, int(t.y * env_width + t.x)).rgb;
}

// Whether the environment is a map that is importance-sampled (not black).
bool lf_environment_sampled() { return env_pdf_scale > 0.0; }

// The density over solid angle with which lf_sample_environment draws d:
// the texel's probability (luminance × sin θ at the row's centre, over the
// map's total: env_pdf_scale holds W H / (2 π² total)) over the solid angle
// d's point of the texel stands for (sin θ at d: rows are drawn uniformly in θ).
float lf_environment_pdf(vec3 d) {
    uvec2 t = lf_environment_texel(d);
    float luminance = dot(texelFetch(environment_texels, int(t.y * env_width + t.x)).rgb, vec3(1.0 / 3.0));
    float sin_centre = sin((float(t.y) + 0.5) / float(env_height) * PI);
    return luminance * sin_centre * env_pdf_scale / max(sqrt(max(1.0 - d.y * d.y, 0.0)), 1e-6);
}

// The first of `count` CDF values from texel `first` (channel w, or x) that
// is above u (the last if none), and where u falls between it and the one
// before (0..1).
uint lf_cdf_search(int first, uint count, bool row_cdf, float u, out float within) {
    uint lo = 0u, hi = count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        vec4 t = texelFetch(environment_texels, first + int(mid));
        if ((row_cdf ? t.w : t.x) <= u) lo = mid + 1u; else hi = mid;  // the first above u: never a bin of no weight
    }
    vec4 at = texelFetch(environment_texels, first + int(lo));
    float below = 0.0;
    if (lo > 0u) {
        vec4 before = texelFetch(environment_texels, first + int(lo) - 1);
        below = row_cdf ? before.w : before.x;
    }
    float above = row_cdf ? at.w : at.x;
    within = clamp((u - below) / max(above - below, 1e-30), 0.0, 1.0);
    return lo;
}

// A direction drawn in proportion to the map's luminance × solid angle: a
// row by the rows' CDF, a texel by its row's, uniform in (φ, θ) within it.
vec3 lf_sample_environment(vec2 u, out float pdf) {
    float fy, fx;
    uint y = lf_cdf_search(int(env_width * env_height), env_height, false, u.x, fy);
    uint x = lf_cdf_search(int(y * env_width), env_width, true, u.y, fx);
    float theta = (float(y) + fy) / float(env_height) * PI;
    float phi = ((float(x) + fx) / float(env_width) - 0.5) * 2.0 * PI;
    vec3 d = vec3(sin(theta) * cos(phi), cos(theta), sin(theta) * sin(phi));
    pdf = lf_environment_pdf(d);
    return d;
}

// The balance heuristic's weight of a cosine ray (about n) that escaped along d.
float lf_escape_weight(vec3 d, vec3 n) {
    if (!lf_environment_sampled()) return 1.0;
    float p_cosine = max(dot(d, n), 0.0) / PI;
    float sum = p_cosine + lf_environment_pdf(d);
    return sum > 0.0 ? p_cosine / sum : 0.0;  // a tangent ray into a black texel: 0, not 0/0
}

// One sample of the map's irradiance / π at a point of normal n (rays from
// origin, at most t_far long inside the scene), weighted against the
// point's cosine ray (lf_escape_weight): L cos / (π (p_map + p_cosine)).
// Its direction in `dir` (a directional lightmap adds it to its L1).
// u: the sample's two random numbers (a point of a stratified sequence, where the caller keeps one).
vec3 lf_environment_light_at(vec3 origin, vec3 n, vec2 u, float t_far, inout uint rays, out vec3 dir) {
    dir = n;
    if (!lf_environment_sampled()) return vec3(0.0);
    float pdf;
    dir = lf_sample_environment(u, pdf);
    float cos_x = dot(dir, n);
    if (cos_x <= 0.0 || !(pdf > 0.0)) return vec3(0.0);
    rays += 1u;
    vec3 passes = trace_transmittance(origin, dir, t_far);
    if (passes == vec3(0.0)) return vec3(0.0);
    return passes * lf_background(dir) * (cos_x / PI) / (pdf + cos_x / PI);
}

// The same with u from rng, drawn only under a map: a bake without one keeps its samples.
vec3 lf_environment_light(vec3 origin, vec3 n, inout Rng rng, float t_far, inout uint rays, out vec3 dir) {
    dir = n;
    if (!lf_environment_sampled()) return vec3(0.0);
    return lf_environment_light_at(origin, n, rng_next2(rng), t_far, rays, dir);
}

#endif
