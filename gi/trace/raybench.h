// Ray throughput of the tracer on a scene: coherent (pinhole grid) and
// incoherent (cosine-distributed from surface points) closest-hit rays.
#pragma once

#include "gpu/context.h"
#include "scene/scene.h"

#include <nlohmann/json.hpp>

namespace lf {

struct RaybenchOptions {
    size_t rays_per_dispatch = 1u << 22;  // 4M
    double min_seconds = 1.0;             // per ray kind, after one warm-up dispatch
    size_t max_dispatches = 64;
};

// Returns {"scene", "triangles", "device": {vendor, renderer}, "bvh": {...},
//          "coherent": {"rays", "seconds", "rays_per_second", "hit_fraction"}, "incoherent": {...}}.
nlohmann::json run_raybench(const GpuContext& gpu, const Scene& scene, const RaybenchOptions& options = {});

}  // namespace lf
