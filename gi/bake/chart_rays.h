// Rays from random points of a lightmap chart, for what the bake decides per
// chart from the geometry alone, before its texels exist: which side a
// double-sided chart is baked for (double_sided.h), whether any light can
// reach a chart at all (unlit_charts.h), how fast its light changes
// (light_density.h). Traced by Tracer::trace (hits of the geometry) or
// Tracer::transmittance (the light's share that passes), in one batch or a
// RayBatch's; deterministic for a given scene.
#pragma once

#include "scene/scene.h"
#include "trace/tracer.h"

#include <glm/glm.hpp>

#include <cstdint>
#include <functional>
#include <random>
#include <type_traits>
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

// How many random points a decision from the geometry alone (a chart's side,
// whether it can be lit) takes on each chart.
inline constexpr int kPointsPerChart = 4;

// `count` points on `triangles` (of one chart), area-weighted.
std::vector<ChartPoint> random_chart_points(const Scene& scene, const std::vector<uint32_t>& triangles, int count,
                                            std::mt19937& rng);

// A cosine-distributed direction about unit n from two uniforms in [0, 1).
glm::vec3 cosine_direction(const glm::vec3& n, float u1, float u2);

// The punctual lights a point tries, as indices into scene.lights: all of
// them, or kLightsPerPoint drawn at random where the scene has more.
inline constexpr size_t kLightsPerPoint = 8;
std::vector<size_t> punctual_lights_to_try(const Scene& scene, std::mt19937& rng);

// Rays with what each is for (an Item with a member `ray`), traced a batch
// of about a million at a time (the memory of a scene's worth of rays stays
// bounded), each answer folded into the caller's result with its item. The
// answer: a RayHit of the geometry (Tracer::trace), or with Result =
// glm::vec3 the light's share that passes (Tracer::transmittance).
template <class Item, class Result = RayHit>
class RayBatch {
public:
    using Fold = std::function<void(const Item&, const Result&)>;
    RayBatch(const Tracer& tracer, Fold fold) : tracer_(tracer), fold_(std::move(fold)) {}

    std::vector<Item>& items() { return items_; }  // append here
    // Traces what is there once a batch is full (call between charts).
    void trace_if_full() {
        if (items_.size() >= kRaysPerBatch) trace();
    }
    // Traces what is there (call once at the end).
    void trace() {
        std::vector<Ray> rays(items_.size());
        for (size_t i = 0; i < items_.size(); ++i) rays[i] = items_[i].ray;
        std::vector<Result> answers;
        if constexpr (std::is_same_v<Result, RayHit>) answers = tracer_.trace(rays);
        else answers = tracer_.transmittance(rays);
        for (size_t i = 0; i < items_.size(); ++i) fold_(items_[i], answers[i]);
        traced_ += items_.size();
        items_.clear();
    }
    size_t traced() const { return traced_; }

private:
    static constexpr size_t kRaysPerBatch = size_t(1) << 20;
    const Tracer& tracer_;
    Fold fold_;
    std::vector<Item> items_;
    size_t traced_ = 0;
};

}  // namespace lf
