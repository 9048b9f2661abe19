#include "bake/preparation_estimate.h"

#include <algorithm>
#include <cmath>

namespace lf {

namespace {

// The stages in the order prepare() runs them (bake_job.cpp: the BVH is
// built when something first traces, inside the atlas stage where unlit
// charts are looked for, else just after it); a stage a job does not run is
// predicted to take nothing.
const std::vector<std::string>& stage_order() {
    static const std::vector<std::string> order = {"load",         "gpu",           "atlas",      "bvh",
                                                   "double_sided", "texel_samples", "bvh_turned", "methods"};
    return order;
}

// Per-unit costs on llvmpipe, 2 cores (2026-11-27: the staircase, the
// spheres, the monkey and the Cornell box; docs/BENCHMARKS.md "Preparation").
constexpr double kLoadPerByte = 2.3e-8;
constexpr double kGpuContext = 0.1;
constexpr double kAtlasFixed = 0.05, kAtlasPerTriangle = 8.5e-6;
constexpr double kTurnPerDoubleSidedTriangle = 8e-6;
constexpr double kSamplesPerPoint = 3.5e-7;
constexpr double kBvhPerTriangle = 1.2e-7;
// Programs and buffers, per output. llvmpipe compiles a program at its
// first use unless Mesa's shader cache holds it: monkey.glb's lightmap + SH
// took 0.11-0.19 s warm and 0.96 s with the cache off (2026-11-28); 0.15
// per output lies between (0.3 was more than 5 times the warm case).
constexpr double kMethodFixed = 0.15;
// Moving sample points out of geometry: 8 short rays each, whose traversal
// deepens with the BVH (13.7 µs a point on the monkey's 6k triangles, 31 on
// the spheres' 246k).
constexpr double kRelocatePerPointPerLevel = 1.3e-6;
constexpr double kSeeThroughTracing = 1.8;  // docs/BENCHMARKS.md, the see-through tracer on llvmpipe
// Before loading, the triangles from the bytes (the staircase: 27 bytes a
// triangle); before the atlas, its sample points from a typical automatic
// atlas (the shared scenes': 158k-584k).
constexpr double kBytesPerTriangle = 27;
constexpr double kTypicalSamplePoints = 400'000;

}  // namespace

double PreparationEstimate::predicted(const std::string& stage) const {
    const double triangles =
        size_.triangles > 0 ? double(size_.triangles) : double(size_.scene_bytes) / kBytesPerTriangle;
    const double points = size_.sample_points > 0 ? double(size_.sample_points) : kTypicalSamplePoints;
    if (stage == "load") return kLoadPerByte * double(size_.scene_bytes);
    if (stage == "gpu") return kGpuContext;
    if (stage == "bvh") return kBvhPerTriangle * triangles;
    if (stage == "methods") {
        const double relocate = size_.atlas ? points * kRelocatePerPointPerLevel * std::log2(triangles + 2.0) *
                                                  (size_.see_through ? kSeeThroughTracing : 1.0)
                                            : 0.0;
        return kMethodFixed * size_.outputs + relocate;
    }
    if (!size_.atlas) return 0.0;
    if (stage == "atlas") return kAtlasFixed + kAtlasPerTriangle * triangles;
    if (stage == "double_sided") return kTurnPerDoubleSidedTriangle * double(size_.double_sided_triangles);
    if (stage == "texel_samples") return kSamplesPerPoint * points;
    return 0.0;
}

std::vector<std::pair<std::string, double>> PreparationEstimate::stages_from(const std::string& stage) const {
    std::vector<std::pair<std::string, double>> left;
    const auto& order = stage_order();
    for (auto it = std::find(order.begin(), order.end(), stage); it != order.end(); ++it)
        left.emplace_back(*it, predicted(*it));
    return left;
}

std::optional<double> PreparationEstimate::seconds_left(const std::string& stage, double elapsed) const {
    const auto& order = stage_order();
    const auto at = std::find(order.begin(), order.end(), stage);
    if (at == order.end()) return std::nullopt;
    double done = 0.0, left = 0.0;
    for (auto it = order.begin(); it != at; ++it) done += predicted(*it);
    for (const auto& [name, seconds] : stages_from(stage)) left += seconds;
    // This machine against the one the costs were measured on, once there
    // is enough behind to tell (a fraction of a second is mostly noise).
    const double scale = elapsed >= 1.0 && done > 0.0 ? std::clamp(elapsed / done, 0.05, 20.0) : 1.0;
    return scale * left;
}

}  // namespace lf
