// Rays from random points of a lightmap chart, for what the bake decides per
// chart from the geometry alone, before its texels exist: which side a
// double-sided chart is baked for (double_sided.h), whether any light can
// reach a chart at all (unlit_charts.h). Traced in one batch by
// Tracer::trace; deterministic for a given scene.
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>

#include <cstdint>
#include <random>
#include <vector>

namespace lf {

struct ChartPoint {
    glm::vec3 position;
    glm::vec3 normal;  // the triangle's geometric normal (its front)
    uint32_t triangle = 0;
};

// The triangles of each chart with area, by chart id (chart[t] for triangle
// t; ids below chart_count), skipping those `keep` rejects.
template <class Keep>
std::vector<std::vector<uint32_t>> triangles_by_chart(const Scene& scene, const std::vector<uint32_t>& chart,
                                                      size_t chart_count, Keep keep) {
    std::vector<std::vector<uint32_t>> out(chart_count);
    for (size_t t = 0; t < scene.triangles.size(); ++t)
        if (scene.triangle_area(t) > 0.0f && keep(t)) out[chart[t]].push_back(uint32_t(t));
    return out;
}

// `count` points on `triangles` (of one chart), area-weighted.
std::vector<ChartPoint> random_chart_points(const Scene& scene, const std::vector<uint32_t>& triangles, int count,
                                            std::mt19937& rng);

// A cosine-distributed direction about unit n from two uniforms in [0, 1).
glm::vec3 cosine_direction(const glm::vec3& n, float u1, float u2);

}  // namespace lf
