// Paths through the scene for the brute-force estimates (the radiosity
// map's path-tracing baseline, the probes' capture): next-event estimation
// at every vertex (direct_light.glsl; a map's sample, environment.glsl),
// Russian roulette after three bounces.
// Needs trace.glsl, sampling.glsl, random.glsl, lightmap_lookup.glsl (the hit
// surfaces), direct_light.glsl and environment.glsl included first.

// Radiance reflected towards the previous vertex by the path continuing from
// `hit` (emission excluded: the first vertex counts it by MIS), E/pi units.
vec3 path_radiance(Hit hit, vec3 origin, vec3 dir, inout Rng rng, inout uint rays) {
    vec3 result = vec3(0.0);
    vec3 throughput = vec3(1.0);
    for (int bounce = 0; bounce < 64; ++bounce) {
        vec3 ny = normalize(hit.front ? hit.normal : -hit.normal);  // the side the path arrived on
        vec3 y = offset_ray_origin(origin + hit.t * dir, ny);
        // Under LF_EXACT_TEXTURES (the lightmap's path-tracing reference, the
        // probes) the albedo texture at the hit point itself.
        throughput *= hit_albedo(hit);
        float keep = max(throughput.r, max(throughput.g, throughput.b));
        if (keep <= 0.0) break;
        vec3 e = sample_emitters(y, ny, y, rng_next2(rng), rng_next2(rng), 1.0, false) + punctual_irradiance(y, ny, y, far);
        rays += (emitter_count > 0u ? 1u : 0u) + punctual_count;
        vec3 unused;
        result += throughput * (e * (1.0 / PI) + lf_environment_light(y, ny, rng, far, rays, unused));
        if (bounce >= 3) {
            if (rng_next(rng) >= keep) break;
            throughput /= keep;
        }
        origin = y;
        dir = sample_cosine_hemisphere(ny, rng_next2(rng));
        hit = trace_closest(origin, dir, far);
        throughput *= hit.tint;  // through the see-through surfaces it passed
        rays += 1u;
        if (hit.triangle == LF_NO_HIT) {
            result += throughput * lf_background(dir) * lf_escape_weight(dir, ny);  // the map's sample above is its other half
            break;
        }
        if (!(hit.front || hit_is_double_sided(hit))) break;
    }
    return result;
}
