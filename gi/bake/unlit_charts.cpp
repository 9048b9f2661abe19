#include "bake/unlit_charts.h"

#include "bake/chart_rays.h"
#include "trace/ray_reference.h"

#include <algorithm>
#include <random>

namespace lf {

namespace {

constexpr int kRaysPerPoint = 4;  // cosine rays from each point, on each side it is seen from

// One ray and what it says about its chart when traced.
struct ChartRay {
    Ray ray;
    uint32_t chart;
    bool shadow;  // to a punctual light: lit when nothing is hit
};

std::vector<ChartRay> rays_from_point(const Scene& scene, const ChartPoint& p, uint32_t chart, std::mt19937& rng) {
    std::vector<ChartRay> rays;
    std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
    const float far = 2.0f * glm::length(scene.bounds.hi - scene.bounds.lo) + 1.0f;
    const bool double_sided = scene.materials[scene.triangle_material[p.triangle]].double_sided;
    for (const float side : {1.0f, -1.0f}) {
        if (side < 0.0f && !double_sided) break;
        const glm::vec3 n = side * p.normal, origin = offset_ray_origin(p.position, n);
        for (int r = 0; r < kRaysPerPoint; ++r)
            rays.push_back({{origin, far, cosine_direction(n, uniform(rng), uniform(rng)), 0u}, chart, false});
        for (const size_t l : punctual_lights_to_try(scene, rng)) {
            const PunctualLight& light = scene.lights[l];
            const bool directional = light.type == PunctualLight::Type::Directional;
            const glm::vec3 to = directional ? -glm::normalize(light.direction) : light.position - origin;
            const float distance = directional ? far : glm::length(to);
            if (distance <= 0.0f || glm::dot(to, n) <= 0.0f) continue;  // behind this side
            rays.push_back({{origin, 0.999f * distance, to / glm::length(to), 1u}, chart, true});
        }
    }
    return rays;
}

// What a traced ray says: light can come this way.
bool brings_light(const Scene& scene, const ChartRay& r, const RayHit& hit) {
    if (r.shadow) return hit.triangle == kNoHit;
    if (hit.triangle == kNoHit) return false;  // escaped, and there is no sky
    const bool front = glm::dot(r.ray.direction, scene.geometric_normal(hit.triangle)) < 0.0f;
    return front || scene.materials[scene.triangle_material[hit.triangle]].double_sided;
}

}  // namespace

std::vector<uint8_t> find_glass_charts(const Scene& scene, const std::vector<uint32_t>& chart, size_t chart_count) {
    std::vector<uint8_t> glass(chart_count, 1), seen(chart_count, 0);
    for (size_t t = 0; t < chart.size(); ++t) {
        seen[chart[t]] = 1;
        if (!(scene.materials[scene.triangle_material.at(t)].transmission > 0.0f)) glass[chart[t]] = 0;
    }
    for (size_t c = 0; c < chart_count; ++c) glass[c] &= seen[c];
    return glass;
}

UnlitCharts find_unlit_charts(const Scene& scene, const Tracer& tracer, const std::vector<uint32_t>& chart,
                              size_t chart_count, bool sky) {
    UnlitCharts out;
    out.unlit.assign(chart_count, 0);
    if (sky) return out;
    const auto triangles_of = triangles_by_chart(scene, chart, chart_count, [](size_t) { return true; });
    std::vector<uint8_t> lit(chart_count, 0);
    std::mt19937 rng(20261124u);
    RayBatch<ChartRay> batch(tracer, [&](const ChartRay& r, const RayHit& hit) {
        if (brings_light(scene, r, hit)) lit[r.chart] = 1;
    });
    for (uint32_t c = 0; c < chart_count; ++c) {
        for (const ChartPoint& p : random_chart_points(scene, triangles_of[c], kPointsPerChart, rng)) {
            const std::vector<ChartRay> rays = rays_from_point(scene, p, c, rng);
            batch.items().insert(batch.items().end(), rays.begin(), rays.end());
        }
        batch.trace_if_full();
    }
    batch.trace();
    out.rays = batch.traced();
    // A chart without area has no points: it counts as lit (it gets its one texel anyway).
    for (uint32_t c = 0; c < chart_count; ++c) out.unlit[c] = !lit[c] && !triangles_of[c].empty();
    return out;
}

}  // namespace lf
