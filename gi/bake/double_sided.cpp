#include "bake/double_sided.h"

#include "atlas/atlas.h"
#include "bake/chart_rays.h"
#include "trace/ray_reference.h"

#include <glm/gtc/constants.hpp>

#include <algorithm>
#include <random>

namespace lf {

namespace {

// 16 rays a side: a closed room's wall scores 16 of 16 inside and 0 outside,
// far beyond the margin; the staircase's 9,121 charts cost 0.3 M rays.
constexpr int kRaysPerSide = 4;  // cosine rays from each point, on each side
// A chart turns only when its back hits geometry this much more often than
// its front: a wall of a closed room scores about 1 inside and 0 outside; a
// free-standing panel about the same on both sides, and keeps its front.
constexpr float kClearMargin = 0.25f;

struct ChartRays {
    std::vector<uint32_t> charts;  // the double-sided charts, in first-triangle order
    std::vector<Ray> rays;         // per chart: kPointsPerChart * kRaysPerSide front rays, then as many back
};

ChartRays rays_of_double_sided_charts(const Scene& scene, const std::vector<uint32_t>& chart) {
    const auto triangles_of = triangles_by_chart(scene, chart, scene.positions.size(), [&](size_t t) {
        // A volume's mesh keeps its winding: its faces say where rays enter it.
        const Material& m = scene.materials[scene.triangle_material[t]];
        return m.double_sided && !m.has_volume();
    });
    ChartRays out;
    for (size_t t = 0; t < scene.triangles.size(); ++t)  // charts in first-triangle order
        if (!triangles_of[chart[t]].empty() && triangles_of[chart[t]].front() == t) out.charts.push_back(chart[t]);
    const float far = 2.0f * glm::length(scene.bounds.hi - scene.bounds.lo);
    std::mt19937 rng(20261123u);
    std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
    out.rays.reserve(out.charts.size() * 2 * kPointsPerChart * kRaysPerSide);
    for (uint32_t c : out.charts)
        for (const float side : {1.0f, -1.0f})
            for (const ChartPoint& p : random_chart_points(scene, triangles_of[c], kPointsPerChart, rng)) {
                const glm::vec3 n = side * p.normal;
                const glm::vec3 origin = offset_ray_origin(p.position, n);
                for (int r = 0; r < kRaysPerSide; ++r)
                    out.rays.push_back({origin, far, cosine_direction(n, uniform(rng), uniform(rng)), 1u});
            }
    return out;
}

void turn_chart_triangles(Scene& scene, const std::vector<uint32_t>& chart, const std::vector<bool>& turn,
                          TurnedCharts& report) {
    std::vector<bool> vertex_turned(scene.positions.size(), false);
    scene.triangle_turned.assign(scene.triangles.size(), 0);
    for (size_t t = 0; t < scene.triangles.size(); ++t) {
        if (!turn[chart[t]]) continue;
        glm::uvec3& v = scene.triangles[t];
        std::swap(v.y, v.z);
        scene.triangle_turned[t] = 1;
        ++report.triangles;
        for (uint32_t k : {v.x, v.y, v.z})
            if (!vertex_turned[k]) {
                vertex_turned[k] = true;
                scene.normals[k] = -scene.normals[k];
            }
    }
}

}  // namespace

TurnedCharts face_double_sided_charts_to_the_scene(Scene& scene, const Tracer& tracer) {
    TurnedCharts report;
    const std::vector<uint32_t> chart = uv_island_of_triangle(scene);
    const ChartRays batch = rays_of_double_sided_charts(scene, chart);
    if (batch.charts.empty()) return report;
    const std::vector<RayHit> hits = tracer.trace(batch.rays);
    report.rays = batch.rays.size();

    constexpr int per_side = kPointsPerChart * kRaysPerSide;
    std::vector<bool> turn(scene.positions.size(), false);
    for (size_t c = 0; c < batch.charts.size(); ++c) {
        int front = 0, back = 0;
        for (int r = 0; r < per_side; ++r) {
            front += hits[c * 2 * per_side + size_t(r)].triangle != kNoHit;
            back += hits[c * 2 * per_side + per_side + size_t(r)].triangle != kNoHit;
        }
        if (float(back - front) > kClearMargin * per_side) {
            turn[batch.charts[c]] = true;
            ++report.charts;
        }
    }
    if (report.charts) turn_chart_triangles(scene, chart, turn, report);
    return report;
}

}  // namespace lf
