#version 450 core
// Passes of the radiosity map (thesis §3.2-3.5): in each, every covered
// texel gathers direct light by shadow rays to the emitters and indirect
// light by one cosine-distributed ray that reads the current radiosity map.
// With LF_FINAL_GATHER defined the indirect ray's first bounce is computed
// where it lands (final_gather below) and the map supplies only the light
// beyond. With LF_PATH_TRACE defined it is the brute-force baseline instead:
// the indirect ray continues as a path (next-event estimation at every
// vertex, Russian roulette) and reads no map.
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#include "buffer_bindings.glsl"
#include "radiosity_params.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"
#include "lightmap_lookup.glsl"
#include "direct_light.glsl"
#include "environment.glsl"
#include "radiosity_texels.glsl"
#include "path_trace.glsl"
#include "radiosity_resolve.glsl"


// Per pass of the dispatch, per covered texel: resolve_texel's totals.
layout(std430, binding = LF_BINDING_TEXEL_TOTALS) writeonly buffer TexelTotals { vec4 texel_totals[]; };

#ifdef LF_DIRECTIONAL
// Per covered texel: the running sum of its L1 vector's x, y, z (RGB each;
// the pass count in the first's w). See lf_add_directional.
layout(std430, binding = LF_BINDING_DIRECTIONAL_ACCUMULATORS) buffer DirectionalAccumulators { vec4 directional_accumulators[]; };
#endif

// The sky's irradiance at y over pi, by one cosine ray: the sky's radiance
// where the ray escapes (0 without a sky: no ray). A final gather's hit
// points take no sample of a map (environment.glsl): each would be one more
// inlined traversal in an already large program, compiled at every
// bake's start on llvmpipe; their cosine rays count the sky whole.
vec3 sky_light(vec3 y, vec3 ny, inout Rng rng, inout uint rays) {
    if (!lf_has_background()) return vec3(0.0);
    rays += 1u;
    vec3 dir = sample_cosine_hemisphere(ny, rng_next2(rng));
    return trace_transmittance(y, dir, far) * lf_background(dir);
}

// The radiance the front of a surface reflects towards the texel at the
// point y (geometric normal ny) where a ray landed, its emission aside, as
// the map says: albedo x the map's value there (E/pi units). Under
// LF_FINAL_GATHER its first bounce is computed at y instead: y's direct
// light sampled as the texels' is (one emitter sample, the punctual lights,
// the sky), times the albedo there, plus albedo x the map's indirect layer
// for the light that reaches y after bouncing at least once (publish_texel
// publishes that under LF_FINAL_GATHER). False where the map cannot
// say (reflected_lookup).
bool map_radiance(Hit hit, vec3 y, vec3 ny, inout Rng rng, inout uint rays, out vec3 radiance) {
    vec2 uv = hit_lightmap_uv(hit);
#ifdef LF_FINAL_GATHER
    vec3 beyond;
    if (!reflected_lookup(uv, true, beyond)) return false;
    vec3 e = sample_emitters(y, ny, y, rng_next2(rng), rng_next2(rng), 1.0, false) + punctual_irradiance(y, ny, y, far);
    rays += (emitter_count > 0u ? 1u : 0u) + punctual_count;
    radiance = hit_texel_albedo(hit) * (e * (1.0 / PI) + sky_light(y, ny, rng, rays)) + beyond;
    return true;
#else
    return reflected_lookup(uv, false, radiance);
#endif
}

// The radiance a hit point reflects towards the texel where the map cannot
// say, gathered where the ray landed instead: its direct light (emitter
// sampling alone, no MIS: the cosine ray below does not count emission) and
// one cosine ray, which reads the map, or the sky, where it lands; where the
// map cannot say there either, the same is done there, and so on: a path,
// ended by Russian roulette after LF_GATHER_ROULETTE_AFTER points (as
// path_radiance's), never by reading the map where it cannot say. Reading
// it there after four points (as this did) made a box's back 2 mm from a
// wall 37% too bright: the texel read deep in the gap averages its dark
// inside with the open wall beside the box (RadiosityMap.
// ABoxAMillimetreFromAWallIsAsDarkBehindAsThePathTracerSays); and the
// inside of something closed (grey_white_room's panelling boxes with a
// side authored facing in) reads nothing and stays dark.
// The map cannot say
//  * on the back of a double-sided surface: a texel holds one side's light,
//    the side its chart was baked for (gi/bake/double_sided.h), and where a
//    ray lands on the other (a wall's outside lit by the sky, seen through a
//    window) the map holds the wrong side's: grey_white_room was 11% dark
//    for it, and 2.3% dark while a back met one bounce later read the map;
//  * closer than `near` (the gathering texel's size) to where the ray left:
//    light changes there within a texel, in the crease between the two
//    surfaces, or in the gap between a surface and a layer laid over it
//    (the staircase's paint a millimetre behind its wallpaper), and the
//    texel there averages it with its open side (photon mapping's final
//    gather traces its short rays on, in corners, for the same reason:
//    Jensen 1996, "Global Illumination using Photon Maps");
//  * on a mesh left out of the lightmap (lightmap scale 0);
//  * next to geometry that cuts through the texels, or where no texel holds
//    a value (reflected_lookup).
#define LF_GATHER_ROULETTE_AFTER 4u
#define LF_GATHER_MAX_POINTS 64u
bool map_may_say(Hit hit, float near) {  // the rest is reflected_lookup's
    return hit.front && hit.t > near && hit_has_lightmap(hit);
}
vec3 gather_at_hit(Hit hit, vec3 y, vec3 ny, float near, inout Rng rng, inout uint rays) {
    vec3 radiance = vec3(0.0), throughput = vec3(1.0);
    for (uint point = 1u; point <= LF_GATHER_MAX_POINTS; ++point) {
        throughput *= hit_texel_albedo(hit);
        float keep = max(throughput.r, max(throughput.g, throughput.b));
        if (keep <= 0.0) break;
        vec3 e = sample_emitters(y, ny, y, rng_next2(rng), rng_next2(rng), 1.0, false) + punctual_irradiance(y, ny, y, far);
        radiance += throughput * e * (1.0 / PI);
        rays += (emitter_count > 0u ? 1u : 0u) + punctual_count;
        if (point > LF_GATHER_ROULETTE_AFTER) {
            if (rng_next(rng) >= keep) break;
            throughput /= keep;
        }
        vec3 dir = sample_cosine_hemisphere(ny, rng_next2(rng));
        Hit next = trace_closest(y, dir, far);
        throughput *= next.tint;  // through the see-through surfaces it passed
        rays += 1u;
        if (next.triangle == LF_NO_HIT) return radiance + throughput * lf_background(dir);  // no map sample here (sky_light)
        if (!next.front && !hit_is_double_sided(next)) break;  // inside a one-sided surface: dark
        vec3 n_next = normalize(next.front ? next.normal : -next.normal);
        vec3 y_next = offset_ray_origin(y + next.t * dir, n_next);
        vec3 beyond;
        if (map_may_say(next, near) && map_radiance(next, y_next, n_next, rng, rays, beyond)) return radiance + throughput * beyond;
        hit = next;  // the map cannot say here either: gather there too
        y = y_next;
        ny = n_next;
    }
    return radiance;
}

// Direct light at texel i's point x (shading normal n, rays from origin) in
// pass `pass`: eq. 3.12 for the emitters (MIS with the indirect ray),
// punctual lights exactly; irradiance E, not yet over pi. The emitter
// samples (which emitter, where on it) follow an R3 sequence over the whole
// bake, rotated per texel: stratified across passes, they converge faster
// than independent samples wherever a texel sees its lights unoccluded.
vec3 texel_direct_light(uint i, uint pass, vec3 x, vec3 n, vec3 origin) {
    uvec3 light_rotation = uvec3(pcg_hash(i ^ pcg_hash(seed + 1u)), pcg_hash(i * 5u + seed), pcg_hash(i * 11u + seed));
    vec3 direct = vec3(0.0);
#ifdef LF_DIRECTIONAL
    lf_directional = vec3[](vec3(0.0), vec3(0.0), vec3(0.0));  // this pass's alone
    lf_directional_on = true;  // the texel's own light only, not the hit points' of the final gather
#endif
    for (uint k = 0u; k < light_samples; ++k) {
        vec3 u = r3_sample(light_rotation, pass * light_samples + k);
        direct += sample_emitters(x, n, origin, u.xx, u.yz, float(light_samples), true);
    }
    direct += punctual_irradiance(x, n, origin, far);
#ifdef LF_DIRECTIONAL
    lf_directional_on = false;
#endif
    return direct;
}

// Adds a pass's direct and indirect samples (E/pi) to texel i's running
// sums, and its L1 vector's under LF_DIRECTIONAL.
void accumulate_pass(uint i, vec3 direct, vec3 indirect) {
#ifdef LF_DIRECTIONAL
    directional_accumulators[3u * i] += vec4(lf_directional[0], 1.0);
    directional_accumulators[3u * i + 1u] += vec4(lf_directional[1], 0.0);
    directional_accumulators[3u * i + 2u] += vec4(lf_directional[2], 0.0);
#endif
    vec4 acc_direct = accumulators[lf_accumulator(i, LF_ACC_DIRECT)];
    vec4 moments = accumulators[lf_accumulator(i, LF_ACC_MOMENTS)];
    vec4 acc_indirect = accumulators[lf_accumulator(i, LF_ACC_INDIRECT)];
    float d = channel_mean(direct), g = channel_mean(indirect);
    // How often the texel finds light at all: what tells a 0 it is sure of
    // from one its few paths missed (LightmapDenoiser::sure_darks).
    if (d + g > 0.0) accumulators[lf_accumulator(i, LF_ACC_ALBEDO)].w += 1.0;
    accumulators[lf_accumulator(i, LF_ACC_DIRECT)] = vec4(acc_direct.rgb + direct, acc_direct.w + 1.0);
    accumulators[lf_accumulator(i, LF_ACC_MOMENTS)] = vec4(moments.x + d * d, moments.y + g * g, moments.zw);
    accumulators[lf_accumulator(i, LF_ACC_INDIRECT)] = vec4(acc_indirect.rgb + indirect, acc_indirect.w + 1.0);
}

// Pass `pass` of covered texel i: its rays, added to its accumulators;
// returns the rays it traced beyond the pass's fixed ones.
uint gather_texel(uint i, uint pass) {
    uvec4 texel = covered_texels[i];
    Rng rng = rng_start(i, pass, seed);
    // Cycle through the texel's sample points so the estimate averages its footprint.
    uint s = texel.x + (pass + pcg_hash(i)) % texel.y;
    vec3 x = sample_position(s);
    vec3 n = sample_normal(s);
    vec3 ng = sample_geometric_normal(s);
    vec3 origin = offset_ray_origin(x, ng);
    vec3 direct = texel_direct_light(i, pass, x, n, origin);

    // Indirect: eq. 3.7, one cosine-distributed ray. The hit point's emission
    // is left out (the direct term already counts it); what it reflects is
    // albedo x its current lightmap value. Where the ray escapes to the sky,
    // that is direct light (the sky is a light source) and goes to the direct
    // sum, which is never restarted: the sky's estimate averages every pass,
    // and a final gather can tell the sky from the light beyond one bounce.
    // Directions follow an R2 sequence (Roberts 2018) rotated per texel, over
    // the whole bake: any run of consecutive passes, such as an epoch's, is
    // itself a rotated R2 set, so each epoch stays stratified.
    uvec2 rotation = uvec2(pcg_hash(i ^ seed), pcg_hash(i * 7u + seed));
    vec3 dir = sample_cosine_hemisphere(n, r2_sample(rotation, pass));
    vec3 indirect;
    vec3 sky = vec3(0.0);  // E/pi of the sky by this cosine ray
    uint path_rays = 0u;  // rays beyond the pass's fixed ones (paths, final gathers, gathers where the map cannot say, map samples)
    // Under a map, one sample of it, weighted against the cosine ray
    // (environment.glsl); stratified over the bake as the cosine ray is.
    vec3 map_dir = n, map_light = vec3(0.0);
    if (lf_environment_sampled()) {  // no hashing per texel and pass without a map
        uvec2 map_rotation = uvec2(pcg_hash(i * 13u + seed), pcg_hash(i ^ pcg_hash(seed + 2u)));
        map_light = lf_environment_light_at(origin, n, r2_sample(map_rotation, pass), far, path_rays, map_dir);
        if (dot(map_dir, ng) <= 0.0) map_light = vec3(0.0);  // below the surface, as the cosine ray is below
    }
    if (dot(dir, ng) <= 0.0) {
        indirect = vec3(0.0);  // below the surface (shading normal differs from geometry)
    } else {
        Hit hit = trace_closest(origin, dir, far);
        if (hit.triangle == LF_NO_HIT) {
            indirect = vec3(0.0);
            sky = hit.tint * lf_background(dir) * lf_escape_weight(dir, n);  // through any window on the way
        } else if (hit.front || hit_is_double_sided(hit)) {
            // The hit point, lifted off its surface on the ray's side.
            vec3 n_hit = normalize(hit.front ? hit.normal : -hit.normal);
            vec3 y = offset_ray_origin(origin + hit.t * dir, n_hit);
#if defined(LF_PATH_TRACE)
            indirect = path_radiance(hit, origin, dir, rng, path_rays);
#else
            float near = sample_texel_size(s);
            bool answered = map_may_say(hit, near) && map_radiance(hit, y, n_hit, rng, path_rays, indirect);
            if (!answered) indirect = gather_at_hit(hit, y, n_hit, near, rng, path_rays);
#endif
            indirect *= hit.tint;  // through the see-through surfaces the ray passed
            // Landing on an emitter: its light, MIS-weighted against emitter
            // sampling (which alone counts emitters when LF_LIGHT_SAMPLING != 0).
            float area_pdf = LF_LIGHT_SAMPLING == 0 ? hit_emitter_area_pdf(hit) : 0.0;
            if (area_pdf > 0.0) {
                float cos_x = dot(n, dir);
                float cos_y = abs(dot(normalize(hit.normal), dir));
                float pdf_light = emitter_pdf(hit_emitter_index(hit), x, hit.t * hit.t, cos_y);
                vec3 e = hit.tint * hit_emission(hit) * cos_x * mis_weight(pdf_light, cos_x / PI, float(light_samples));
                direct += e;
#ifdef LF_DIRECTIONAL
                lf_directional_on = true;
                lf_add_directional(e, dir, n);
                lf_directional_on = false;
#endif
            }
        } else {
            indirect = vec3(0.0);  // the back of a one-sided surface is the inside of something
        }
    }
    direct = direct * (1.0 / PI) + sky + map_light;
#ifdef LF_DIRECTIONAL
    // The cosine ray's sample: E/pi = L for a cosine ray, so its irradiance is pi L.
    lf_directional_on = true;
    lf_add_directional(PI * (indirect + sky), dir, n);
    lf_add_directional(PI * map_light, map_dir, n);
    lf_directional_on = false;
#endif
    accumulate_pass(i, direct, indirect);
    return path_rays;
}

// Pass first_pass + k of covered texel i, resolved (radiosity_resolve.glsl).
void gather_and_resolve(uint i, uint k) {
    uint extra_rays = 0u;
    // A converged texel costs no more rays.
    if (accumulators[lf_accumulator(i, LF_ACC_MOMENTS)].w == 0.0) extra_rays = gather_texel(i, first_pass + k);
    texel_totals[k * covered_count + i] = resolve_texel(i, end_epoch != 0u && k + 1u == pass_count, float(extra_rays));
}

// `pass_count` passes from `first_pass`, each resolved texel by texel as it ends
// (radiosity_resolve.glsl) with its error totals in a slot of its own. All
// of them read the map as it was last published: the map is published at
// the ends of RadiosityMapBaker's cells of passes, never within a dispatch.
// Several passes in one dispatch fill a device that one small pass cannot.
void main() {
    uint i = covered_index();
    if (i >= covered_count) return;
#ifdef LF_ONE_PASS_PER_DISPATCH
    gather_and_resolve(i, 0u);  // no loop: llvmpipe runs the gather a quarter slower in one
#else
    for (uint k = 0u; k < pass_count; ++k) gather_and_resolve(i, k);
#endif
}
