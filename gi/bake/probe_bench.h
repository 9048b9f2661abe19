// Speed against accuracy of the probes method (the questions of issue #11,
// after the paper's §4 timings): capture time per probe against the capture
// resolution R; evaluation throughput of the four estimators (and
// polygon-to-point with each polygon clipped to the point's horizon) against
// M, in C++ and through the GLSL include on the job's GPU; and their error against
// ground truth, over random points around the probe and over points
// approaching a wall with normals facing it (the paper's Figures 4–5).
//
// Ground truth at a point is a probe captured there (truth_resolution, not
// downsampled) integrated against the clamped cosine at its own reference
// point: exact up to its path-tracing noise, with no parallax to correct.
// The error of an estimator over a set of points is Σ|e − t| / Σ t over the
// points and the three channels (a normalised mean absolute error).
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include <optional>
#include <vector>

namespace lf {

struct ProbeBenchOptions {
    std::optional<glm::vec3> at;          // the probe; default the bounds' centre
    glm::vec3 toward{-1.0f, 0.0f, 0.0f};  // the wall sweep's direction (unit)
    std::vector<int> capture_resolutions{32, 64, 128, 256};
    std::vector<int> ms{1, 2, 4, 8};  // each must divide every R
    int passes = 8;                   // per measured capture
    int truth_resolution = 32;
    int truth_passes = 24;
    int random_points = 48;
    double min_seconds = 0.2;  // per throughput measurement
    uint32_t seed = 1;
};

// Returns {"probe": [x,y,z], "device", "capture": [{res, passes, seconds,
// seconds_per_pass, rays}], "error": [{res, m, estimator, random, wall: [..]}],
// "wall": {"gaps": [..], "distance"}, "throughput": [{m, estimator,
// cpu_points_per_second, gpu_points_per_second (polygon_to_point only)}]}.
// Runs on the current GL context (a GpuContext the caller holds). Throws
// std::invalid_argument for options that cannot be measured.
nlohmann::json run_probe_bench(const Scene& scene, const ProbeBenchOptions& options);

}  // namespace lf
