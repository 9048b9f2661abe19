#include "bake/light_density.h"

#include "bake/chart_rays.h"
#include "trace/ray_reference.h"
#include "util/math.h"

#include <glm/gtc/constants.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

namespace lf {

namespace {

// Pairs per chart: one per kTexelsPerPair texels it would get, at least
// kMinPairs and at most kMaxPairs. An edge of the light across a chart is
// found by the pairs that straddle it, about 2/pi x its length x a texel /
// the chart's area of them: a few, on a chart with one shadow edge.
constexpr double kTexelsPerPair = 8.0;
constexpr int kMinPairs = 8, kMaxPairs = 4096;
constexpr int kEmitterSamples = 2;  // emitter points per triplet, shared by its three points
constexpr int kSkySamples = 4;      // sky directions per triplet, shared by its three points
// The indirect light's share of the first look: how open each point is,
// from kAmbientSamples cosine directions per triplet (shared by its three
// points), a surface met within kAmbientReach texels closing a direction
// by 1 - t / reach (no jump where a surface comes into reach).
constexpr int kAmbientSamples = 4;
constexpr float kAmbientReach = 16.0f;

// The emissive triangles, chosen in proportion to their power (as the GPU's
// direct light chooses them: gi/bake/scene_shading.cpp).
struct Emitters {
    std::vector<uint32_t> triangle;
    std::vector<double> cdf;
    double total = 0.0;

    explicit Emitters(const Scene& scene) {
        for (size_t t = 0; t < scene.triangles.size(); ++t) {
            const Material& m = scene.materials[scene.triangle_material[t]];
            if (!m.is_emissive() || scene.triangle_area(t) <= 0.0f) continue;
            const double p = double(scene.triangle_area(t)) * channel_mean(scene.mean_emission(t));
            if (!(p > 0.0)) continue;
            total += p;
            triangle.push_back(uint32_t(t));
            cdf.push_back(total);
        }
    }
};

// One light sample that the three points of a triplet use: a punctual light, a point
// on an emitter (with its normal, radiance and area density), or a sky or
// ambient direction in the point's own cosine frame (u1, u2).
struct LightSample {
    enum Kind { Punctual, Emitter, Sky, Ambient } kind;
    size_t light = 0;
    glm::vec3 position{0.0f}, normal{0.0f}, radiance{0.0f};
    float pdf = 0.0f;
    float u1 = 0.0f, u2 = 0.0f;
};

// The irradiance at a triplet's points: [0, 6) direct, per side x 3 + (0: p,
// 1: p + offset, 2: p - offset); [6, 12) the same points' openness.
using TripletLight = std::array<float, 12>;
constexpr int kOpenness = 6;

// A shadow ray and the irradiance it brings times the share that passes (a
// direct light's: cut-outs and glass let it through), or an ambient ray and
// the openness it brings, in part where it meets a surface within its reach.
struct LitRay {
    Ray ray;
    size_t pair;
    int point;  // into TripletLight
    float irradiance;
};

// Where q = p + offset leaves the triangle, the nearest point of it (its
// barycentrics clamped and renormalized): the pair stays on the chart.
glm::vec3 onto_triangle(const Scene& scene, uint32_t t, glm::vec3 q) {
    const glm::uvec3 v = scene.triangles[t];
    const glm::vec3 a = scene.positions[v.x], e1 = scene.positions[v.y] - a, e2 = scene.positions[v.z] - a;
    const float d11 = glm::dot(e1, e1), d12 = glm::dot(e1, e2), d22 = glm::dot(e2, e2);
    const float det = d11 * d22 - d12 * d12;
    if (!(det > 0.0f)) return a;
    const glm::vec3 w = q - a;
    const float w1 = glm::dot(w, e1), w2 = glm::dot(w, e2);
    float b1 = std::max(0.0f, (d22 * w1 - d12 * w2) / det), b2 = std::max(0.0f, (d11 * w2 - d12 * w1) / det);
    if (b1 + b2 > 1.0f) {
        const float s = b1 + b2;
        b1 /= s, b2 /= s;
    }
    return a + b1 * e1 + b2 * e2;
}

// The rays from point x (normal n, one side of its surface) that the
// samples ask for, each with the irradiance it brings if nothing blocks it:
// shadow rays to `shadow`, ambient rays to `ambient`.
void rays_for(const Scene& scene, const std::vector<LightSample>& samples, const Environment* sky, glm::vec3 x,
              glm::vec3 n, size_t pair, int point, float far, float reach, std::vector<LitRay>& shadow,
              std::vector<LitRay>& ambient) {
    const glm::vec3 origin = offset_ray_origin(x, n);
    for (const LightSample& s : samples) {
        glm::vec3 to;
        float distance = far, irradiance = 0.0f;
        if (s.kind == LightSample::Sky) {
            to = cosine_direction(n, s.u1, s.u2);
            irradiance = glm::pi<float>() * channel_mean(sky->radiance(to)) / float(kSkySamples);
        } else if (s.kind == LightSample::Ambient) {
            ambient.push_back({{origin, reach, cosine_direction(n, s.u1, s.u2), 0u},
                               pair,
                               kOpenness + point,
                               1.0f / float(kAmbientSamples)});
            continue;
        } else if (s.kind == LightSample::Emitter) {
            to = s.position - origin;
            distance = glm::length(to);
            if (!(distance > 0.0f)) continue;
            to /= distance;
            const float cos_x = glm::dot(n, to), cos_y = std::abs(glm::dot(s.normal, to));
            if (cos_x <= 0.0f) continue;
            irradiance = channel_mean(s.radiance) * cos_x * cos_y / (distance * distance * s.pdf * kEmitterSamples);
            distance *= 0.999f;
        } else {
            const PunctualLight& light = scene.lights[s.light];
            const bool directional = light.type == PunctualLight::Type::Directional;
            to = directional ? -glm::normalize(light.direction) : light.position - origin;
            distance = directional ? far : glm::length(to);
            if (!(distance > 0.0f)) continue;
            to = glm::normalize(to);
            const float cos_x = glm::dot(n, to);
            if (cos_x <= 0.0f) continue;
            float cone = 1.0f;  // a spot's falloff, linear between its cones (a first look)
            if (light.type == PunctualLight::Type::Spot) {
                const float c = glm::dot(-to, glm::normalize(light.direction)), inner = std::cos(light.inner_cone),
                            outer = std::cos(light.outer_cone);
                cone = std::clamp((c - outer) / std::max(inner - outer, 1e-4f), 0.0f, 1.0f);
            }
            irradiance = channel_mean(light.intensity) * cone * cos_x / (directional ? 1.0f : distance * distance);
            distance = directional ? far : 0.999f * distance;
        }
        if (irradiance > 0.0f) shadow.push_back({{origin, distance, to, 1u}, pair, point, irradiance});
    }
}

// The samples one triplet shares.
std::vector<LightSample> pair_samples(const Scene& scene, const Emitters& emitters, const Environment* sky,
                                      std::mt19937& rng) {
    std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
    std::vector<LightSample> samples;
    for (const size_t light : punctual_lights_to_try(scene, rng)) {
        LightSample s{LightSample::Punctual};
        s.light = light;
        samples.push_back(s);
    }
    for (int e = 0; e < kEmitterSamples && emitters.total > 0.0; ++e) {
        const double at = (1.0 - double(uniform(rng))) * emitters.total;
        const size_t k = size_t(std::lower_bound(emitters.cdf.begin(), emitters.cdf.end(), at) - emitters.cdf.begin());
        const uint32_t t = emitters.triangle[std::min(k, emitters.triangle.size() - 1)];
        const glm::uvec3 v = scene.triangles[t];
        float b1 = uniform(rng), b2 = uniform(rng);
        if (b1 + b2 > 1.0f) b1 = 1.0f - b1, b2 = 1.0f - b2;
        LightSample s{LightSample::Emitter};
        s.position = (1.0f - b1 - b2) * scene.positions[v.x] + b1 * scene.positions[v.y] + b2 * scene.positions[v.z];
        s.normal = scene.geometric_normal(t);
        s.radiance = scene.mean_emission(t);
        const double power = double(scene.triangle_area(t)) * channel_mean(s.radiance);
        s.pdf = float(power / emitters.total / double(scene.triangle_area(t)));
        samples.push_back(s);
    }
    for (int d = 0; d < kSkySamples && sky; ++d) {
        LightSample s{LightSample::Sky};
        s.u1 = uniform(rng), s.u2 = uniform(rng);
        samples.push_back(s);
    }
    for (int d = 0; d < kAmbientSamples; ++d) {
        LightSample s{LightSample::Ambient};
        s.u1 = uniform(rng), s.u2 = uniform(rng);
        samples.push_back(s);
    }
    return samples;
}

// The scene's mean albedo (channel mean), by area.
double mean_albedo(const Scene& scene) {
    double sum = 0.0, area = 0.0;
    for (size_t t = 0; t < scene.triangles.size(); ++t) {
        sum += double(scene.triangle_area(t)) * channel_mean(scene.mean_albedo(t));
        area += scene.triangle_area(t);
    }
    return area > 0.0 ? sum / area : 0.0;
}

// k per chart id (the larger of its two sides'; 0 where no triplet): the
// mean squared second difference of the light at its triplets, direct plus
// indirect. The indirect light is not known before the bake; its first
// look is each point's openness A times the light an open point would get
// over a closed one. With the scene's mean direct irradiance E and mean
// albedo rho, the indirect irradiance in a closed room is about
// E rho / (1 - rho) where open, and a direction closed by a nearby surface
// brings back rho of that: the difference is E rho per unit of openness.
// `mean`: E.
std::vector<double> chart_k(const Scene& scene, const std::vector<uint32_t>& pair_chart,
                            const std::vector<TripletLight>& light, double mean, size_t chart_count) {
    const double open_to_closed = mean * std::min(mean_albedo(scene), 0.95);
    std::vector<glm::dvec2> sums(chart_count, glm::dvec2(0.0));  // (front, back) squared second differences
    std::vector<int> pairs(chart_count, 0);
    for (size_t i = 0; i < pair_chart.size(); ++i) {
        const TripletLight& e = light[i];
        auto second_difference = [&](int side) {
            auto at = [&](int point) {
                return double(e[3 * side + point]) + open_to_closed * e[kOpenness + 3 * side + point];
            };
            const double d = 0.5 * (at(1) + at(2)) - at(0);
            return d * d;
        };
        sums[pair_chart[i]] += glm::dvec2(second_difference(0), second_difference(1));
        ++pairs[pair_chart[i]];
    }
    std::vector<double> k(chart_count, 0.0);
    for (size_t c = 0; c < chart_count; ++c)
        if (pairs[c] > 0) k[c] = std::max(sums[c].x, sums[c].y) / pairs[c];
    return k;
}

// The factor f for which the sum of area x clamp(f x r)^2 is the area's sum (bisection in log f).
std::vector<double> normalized_scales(const std::vector<double>& r, const std::vector<double>& area) {
    auto texels_at = [&](double f) {
        double sum = 0.0;
        for (size_t c = 0; c < r.size(); ++c) {
            const double s = std::clamp(f * r[c], kMinLightScale, kMaxLightScale);
            sum += area[c] * s * s;
        }
        return sum;
    };
    if (r.empty() || *std::max_element(r.begin(), r.end()) <= 0.0) return std::vector<double>(r.size(), 1.0);
    double total = 0.0;
    for (double a : area) total += a;
    double lo = -60.0, hi = 60.0;
    for (int i = 0; i < 200; ++i) {
        const double mid = 0.5 * (lo + hi);
        (texels_at(std::exp(mid)) < total ? lo : hi) = mid;
    }
    const double f = std::exp(0.5 * (lo + hi));
    std::vector<double> s(r.size());
    for (size_t c = 0; c < r.size(); ++c) s[c] = std::clamp(f * r[c], kMinLightScale, kMaxLightScale);
    return s;
}

}  // namespace

LightScales light_driven_chart_scales(const Scene& scene, const Tracer& tracer, const std::vector<uint32_t>& chart,
                                      size_t chart_count, const std::vector<uint8_t>& leave, double texel,
                                      const Environment* sky) {
    LightScales out;
    out.scale.assign(chart_count, 1.0);
    out.k.assign(chart_count, 0.0);
    const auto triangles_of = triangles_by_chart(scene, chart, chart_count, [](size_t) { return true; });
    const Emitters emitters(scene);
    const float far = 2.0f * glm::length(scene.bounds.hi - scene.bounds.lo) + 1.0f;
    const float reach = kAmbientReach * float(texel);
    std::mt19937 rng(20261129u);
    std::uniform_real_distribution<float> uniform(0.0f, 1.0f);

    // Per triplet: its chart, and its points' light.
    std::vector<uint32_t> pair_chart;
    std::vector<TripletLight> irradiance;
    RayBatch<LitRay, glm::vec3> shadows(tracer, [&](const LitRay& r, const glm::vec3& passes) {
        irradiance[r.pair][r.point] += r.irradiance * channel_mean(passes);
    });
    RayBatch<LitRay> ambient(tracer, [&](const LitRay& r, const RayHit& hit) {
        irradiance[r.pair][r.point] += r.irradiance * (hit.triangle == kNoHit ? 1.0f : hit.t / reach);
    });
    for (uint32_t c = 0; c < chart_count; ++c) {
        if ((!leave.empty() && leave[c]) || triangles_of[c].empty()) continue;
        double chart_area = 0.0;
        for (uint32_t t : triangles_of[c]) chart_area += scene.triangle_area(t);
        const int pair_count =
            int(std::clamp(chart_area / (texel * texel) / kTexelsPerPair, double(kMinPairs), double(kMaxPairs)));
        for (const ChartPoint& p : random_chart_points(scene, triangles_of[c], pair_count, rng)) {
            const glm::uvec3 v = scene.triangles[p.triangle];
            const glm::vec3 t = glm::normalize(scene.positions[v.y] - scene.positions[v.x]),
                            b = glm::cross(p.normal, t);
            const float phi = 2.0f * glm::pi<float>() * uniform(rng);
            const glm::vec3 offset = float(texel) * (std::cos(phi) * t + std::sin(phi) * b);
            const glm::vec3 points[3] = {p.position, onto_triangle(scene, p.triangle, p.position + offset),
                                         onto_triangle(scene, p.triangle, p.position - offset)};
            const std::vector<LightSample> samples = pair_samples(scene, emitters, sky, rng);
            const size_t pair = pair_chart.size();
            pair_chart.push_back(c);
            irradiance.push_back({});
            const bool double_sided = scene.materials[scene.triangle_material[p.triangle]].double_sided;
            for (int side = 0; side < (double_sided ? 2 : 1); ++side)
                for (int k = 0; k < 3; ++k)
                    rays_for(scene, samples, sky, points[k], side ? -p.normal : p.normal, pair, 3 * side + k, far,
                             reach, shadows.items(), ambient.items());
        }
        shadows.trace_if_full();
        ambient.trace_if_full();
    }
    shadows.trace();
    ambient.trace();
    out.rays = shadows.traced() + ambient.traced();

    if (pair_chart.empty()) return out;
    double mean = 0.0;  // direct irradiance, over the triplets
    for (const TripletLight& e : irradiance) mean += std::max(e[0], e[3]);
    mean /= double(irradiance.size());
    out.k = chart_k(scene, pair_chart, irradiance, mean, chart_count);
    // The floor: light changing by 1% of the scene's mean a texel apart.
    const double floor = 1e-4 * mean * mean;
    std::vector<uint8_t> has_pairs(chart_count, 0);
    for (uint32_t c : pair_chart) has_pairs[c] = 1;
    std::vector<uint32_t> measured;
    std::vector<double> r, area;
    for (uint32_t c = 0; c < chart_count; ++c) {
        if (!has_pairs[c]) continue;
        double a = 0.0;
        for (uint32_t t : triangles_of[c]) a += scene.triangle_area(t);
        measured.push_back(c);
        r.push_back(std::cbrt(out.k[c] + floor));
        area.push_back(a);
    }
    const std::vector<double> s = normalized_scales(r, area);
    for (size_t i = 0; i < measured.size(); ++i) out.scale[measured[i]] = s[i];
    return out;
}

}  // namespace lf
