// The job spec: what a client asks lightfarmd to bake.
//
//   {"scene": "<scene id>",
//    "outputs": {"lightmap": {"passes": 64}}, "atlas": {"res": 256},
//    "seed": 1,
//    "limits": {"max_seconds": 600, "max_attempts": 3}}
//
// Everything but "scene" and "limits" is the bake's settings
// (protocol/bake_settings.h, the one catalog): the server validates a spec
// once, at submit, and the worker reads the same JSON (`lightfarm bake --spec`).
#pragma once

#include "bake_settings.h"
#include "worker_protocol.h"

#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <optional>
#include <string>

namespace lf::protocol {

// What the job may use; absent = the server's default.
struct JobLimits {
    std::optional<double> max_seconds;  // wall-clock deadline of one attempt
    std::optional<int> max_attempts;    // worker runs before the job fails
};

struct JobSpec {
    std::string scene;
    BakeSettings bake;
    JobLimits limits;
};

// Parses and validates; throws SpecError naming the first bad field. Unknown
// fields are errors.
JobSpec parse_job_spec(const nlohmann::json& j, const SpecLimits& limits = {});
// Canonical: every setting of the chosen outputs with its value.
nlohmann::json to_json(const JobSpec& spec);

// The part of a spec that determines the bake's result (scene, settings; not
// limits), as canonical JSON text: equal text = equal bake.
std::string bake_identity(const JobSpec& spec);

// Probes: the most a job may place, and the capture texels (probes x 6 x
// R², 32 bytes each on the GPU) it may ask for.
inline constexpr uint64_t kMaxProbes = 4096;
inline constexpr uint64_t kMaxCaptureTexels = uint64_t(1) << 25;

// Probes per axis of a grid of cells `spacing` metres wide over a box of
// `extent` (each at least 1; saturating, never overflowing). The engine
// places its grid by it and the server checks a spec by it.
std::array<uint64_t, 3> probe_grid_counts(const std::array<double, 3>& extent, double spacing);

// What can be known before a worker runs, from the scene's summary: a bake
// that the scene makes impossible or too large (a lightmap with no light and
// no environment; a generated atlas smaller than the scene's charts need,
// by res or by max_res; a mesh index the scene does not draw (SH lists,
// atlas.mesh_scale); a probe grid
// or capture over the limits). Throws SpecError naming the field and the fix.
void check_spec_against_scene(const BakeSettings& bake, const SceneSummary& scene);

}  // namespace lf::protocol
