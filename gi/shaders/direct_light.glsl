// Direct light at a surface point (thesis §3.3): shadow rays to points
// sampled on the emissive triangles, and exact punctual lights.
// Returns irradiance E (W/m²); callers divide by pi for a lightmap value.
#ifndef LF_DIRECT_LIGHT_GLSL
#define LF_DIRECT_LIGHT_GLSL

#include "buffer_bindings.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"
#ifdef LF_EXACT_TEXTURES
#include "surface_textures.glsl"
#endif

// Emissive triangle e: (v0, cdf), (v1, pdf of choosing it), (v2, area),
// (mean radiance, bits: scene triangle index << 1 | double-sided).
layout(std430, binding = LF_BINDING_EMITTERS) readonly buffer Emitters { vec4 emitters[]; };
// Punctual light l: (position, type), (direction of travel, range), (intensity rgb, cos inner), (cos outer, 0, 0, 0).
layout(std430, binding = LF_BINDING_PUNCTUAL_LIGHTS) readonly buffer PunctualLights { vec4 punctual_lights[]; };

// emitter_count, punctual_count: the program's parameter block (LF_SHADING_PARAMS).

// How emitters are sampled (compile-time, LF_LIGHT_SAMPLING):
//   0 (default): MIS of solid-angle sampling and the indirect pass's cosine ray
//   1: area sampling alone (thesis eq. 3.12)
//   2: solid-angle sampling alone (Arvo 1995; the thesis's future work, §6.3)
// Solid-angle sampling falls back to area sampling for triangles too small
// (or too far) to subtend a stable solid angle.
#ifndef LF_LIGHT_SAMPLING
#define LF_LIGHT_SAMPLING 0
#endif

// Directional lightmaps (LF_DIRECTIONAL): while lf_directional_on, every
// irradiance contribution c arriving from direction w at a point of normal n
// also adds to the texel's L1 vector, so that E(n')/pi ~ E(n)/pi + L1 . (n' - n)
// for normals n' near n. With c = L cos / pdf, the radiance's L1 SH
// coefficients are E[L Y_1m / pdf] = E[c Y_1m / cos], and the clamped
// cosine's band-1 factor 2pi/3 (Ramamoorthi & Hanrahan 2001) turns them into
// irradiance: L1 = (2pi/3) (0.488603)^2 E[c w / cos] / pi = E[c w / cos] / (2 pi).
// The cosine is held at 0.05 or more: its inverse has an unbounded (log-
// divergent) variance at grazing angles, and the light within 3 degrees of
// the horizon adds almost nothing to a nearby normal's irradiance.
#ifdef LF_DIRECTIONAL
bool lf_directional_on = false;
vec3 lf_directional[3] = vec3[](vec3(0.0), vec3(0.0), vec3(0.0));  // the L1 vector's x, y, z, each RGB
void lf_add_directional(vec3 irradiance, vec3 w, vec3 n) {
    if (!lf_directional_on) return;
    vec3 s = irradiance / (2.0 * PI * max(dot(w, n), 0.05));
    lf_directional[0] += s * w.x;
    lf_directional[1] += s * w.y;
    lf_directional[2] += s * w.z;
}
#else
void lf_add_directional(vec3 irradiance, vec3 w, vec3 n) {}
#endif

const uint LIGHT_POINT = 0u;
const uint LIGHT_SPOT = 1u;
const uint LIGHT_DIRECTIONAL = 2u;

// Picks emitter e with probability pdf_e by inverting the power CDF.
uint choose_emitter(float u) {
    uint lo = 0u, hi = emitter_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (emitters[4u * mid].w < u) lo = mid + 1u; else hi = mid;
    }
    return lo;
}

// Multiple importance sampling (Veach 1997, balance heuristic) of the
// emitters' light: `light_samples` points chosen on the emitters (eq. 3.12,
// area sampling of a power-chosen triangle) and the indirect pass's one
// cosine-distributed ray, which may land on an emitter too. Each strategy's
// sample of E = ∫ Le cos dω is weighted by 1 / (n_l p_l + p_b), both
// densities over solid angle; neither alone is robust (area sampling fails
// next to large emitters, cosine rays on small ones).
float mis_weight(float pdf_light_solid_angle, float pdf_cosine, float light_samples) {
    return 1.0 / (light_samples * pdf_light_solid_angle + pdf_cosine);
}

// Solid-angle density of emitter sampling for a direction that meets an
// emitter at distance² dist2 with cosine cos_y there.
float light_pdf_solid_angle(float area_pdf, float dist2, float cos_y) {
    return cos_y > 0.0 ? area_pdf * dist2 / cos_y : 0.0;
}

// Density over solid angle with which emitter sampling reaches emitter e
// (chosen with probability pdf_choose) from x, at distance² dist2 and
// cosine cos_y on the emitter: by solid angle where the triangle's solid
// angle is usable, by area (eq. 3.12) elsewhere and in LF_LIGHT_SAMPLING 1.
float emitter_pdf(uint e, vec3 x, float dist2, float cos_y) {
    vec4 a = emitters[4u * e], b = emitters[4u * e + 1u], c = emitters[4u * e + 2u];
#if LF_LIGHT_SAMPLING != 1
    float omega = spherical_triangle(x, a.xyz, b.xyz, c.xyz).area;
    if (omega > 0.0) return b.w / omega;
#endif
    return light_pdf_solid_angle(b.w / c.w, dist2, cos_y);
}

// One emitter sample's MIS-weighted contribution to E at x. Without the
// cosine strategy (a path vertex whose next ray does not count emission),
// it is plain area sampling, eq. 3.12.
vec3 sample_emitters(vec3 x, vec3 n, vec3 origin, vec2 u_choose, vec2 u_point, float light_samples,
                     bool cosine_strategy) {
    if (emitter_count == 0u) return vec3(0.0);
    uint e = choose_emitter(u_choose.x);
    vec4 a = emitters[4u * e], b = emitters[4u * e + 1u], c = emitters[4u * e + 2u], le = emitters[4u * e + 3u];
    vec3 ny = normalize(cross(b.xyz - a.xyz, c.xyz - a.xyz));
    uint emitter_bits = floatBitsToUint(le.w);
    vec3 y;
#if LF_LIGHT_SAMPLING != 1
    SphericalTriangle seen = spherical_triangle(x, a.xyz, b.xyz, c.xyz);
#else
    SphericalTriangle seen = SphericalTriangle(vec3(0.0), vec3(0.0), vec3(0.0), 0.0);  // area sampling alone
#endif
    float omega = seen.area;
    if (omega > 0.0) {
        vec3 dir = sample_spherical_triangle(seen, u_point);
        float along = dot(dir, ny);
        if (abs(along) < 1e-12) return vec3(0.0);  // grazing: no light, and a measure-zero event
        y = x + dir * (dot(a.xyz - x, ny) / along);  // where the direction meets the emitter's plane
    } else {
        vec2 bary = sample_triangle(u_point);
        y = (1.0 - bary.x - bary.y) * a.xyz + bary.x * b.xyz + bary.y * c.xyz;
    }
    vec3 d = y - x;
    float dist2 = dot(d, d);
    if (dist2 <= 0.0) return vec3(0.0);
    vec3 w = d * inversesqrt(dist2);
    float cos_x = dot(n, w);
    float cos_y = -dot(ny, w);
    if ((emitter_bits & 1u) == 0u && cos_y <= 0.0) return vec3(0.0);  // one-sided emitters light their front only
    cos_y = abs(cos_y);
    if (cos_x <= 0.0 || cos_y <= 0.0) return vec3(0.0);
    float pdf_light = omega > 0.0 ? b.w / omega : light_pdf_solid_angle(b.w / c.w, dist2, cos_y);
#if LF_LIGHT_SAMPLING != 0
    cosine_strategy = false;  // light sampling alone
#endif
    // Stop just short of the light's surface so the light does not occlude
    // itself; what passes through cut-outs and glass on the way arrives.
    vec3 passes = trace_transmittance(origin, y - origin, 0.9999);
    if (passes == vec3(0.0)) return vec3(0.0);
#ifdef LF_EXACT_TEXTURES
    // The emission texture where the sample landed (the choice of emitter
    // follows the mean: any choice density is unbiased).
    le.rgb = surface_emission(emitter_bits >> 1u, triangle_barycentrics(y, a.xyz, b.xyz, c.xyz));
#endif
    vec3 irradiance = passes * le.rgb * cos_x * mis_weight(pdf_light, cosine_strategy ? cos_x / PI : 0.0, light_samples);
    lf_add_directional(irradiance, w, n);
    return irradiance;
}

// glTF's recommended spot falloff (KHR_lights_punctual): smooth between the cones.
float spot_attenuation(vec3 light_dir, vec3 to_point, float cos_inner, float cos_outer) {
    float scale = 1.0 / max(0.001, cos_inner - cos_outer);
    float t = clamp((dot(light_dir, to_point) - cos_outer) * scale, 0.0, 1.0);
    return t * t;
}

// Irradiance from every punctual light, with a shadow ray each (the share
// that passes see-through surfaces on the way).
vec3 punctual_irradiance(vec3 x, vec3 n, vec3 origin, float far) {
    vec3 e = vec3(0.0);
    for (uint l = 0u; l < punctual_count; ++l) {
        vec4 p0 = punctual_lights[4u * l], p1 = punctual_lights[4u * l + 1u];
        vec4 p2 = punctual_lights[4u * l + 2u], p3 = punctual_lights[4u * l + 3u];
        uint type = uint(p0.w);
        if (type == LIGHT_DIRECTIONAL) {
            float cos_x = -dot(n, p1.xyz);
            if (cos_x <= 0.0) continue;
            vec3 passes = trace_transmittance(origin, -p1.xyz, far);
            e += passes * p2.rgb * cos_x;  // intensity is irradiance (W/m²) for directional lights
            lf_add_directional(passes * p2.rgb * cos_x, -p1.xyz, n);
            continue;
        }
        vec3 d = p0.xyz - x;
        float dist2 = dot(d, d);
        vec3 w = d * inversesqrt(dist2);
        float cos_x = dot(n, w);
        if (cos_x <= 0.0) continue;
        float falloff = 1.0 / dist2;  // intensity is W/sr
        if (p1.w > 0.0) {  // glTF's range window
            float r = sqrt(dist2) / p1.w;
            falloff *= pow(clamp(1.0 - r * r * r * r, 0.0, 1.0), 2.0);
        }
        if (type == LIGHT_SPOT) falloff *= spot_attenuation(p1.xyz, -w, p2.w, p3.x);
        if (falloff <= 0.0) continue;
        vec3 passes = trace_transmittance(origin, p0.xyz - origin, 1.0);
        e += passes * p2.rgb * cos_x * falloff;
        lf_add_directional(passes * p2.rgb * cos_x * falloff, w, n);
    }
    return e;
}

#endif
