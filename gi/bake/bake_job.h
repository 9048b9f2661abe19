// The one job driver, as `lightfarm bake` and the service's worker run it:
// load the scene once, prepare what the requested outputs need once (atlas,
// texel samples, one GL context, one tracer), run every output's method
// through the one progressive loop, and own the worker events, the snapshot
// names and manifest.json. A new method plugs in here (make_methods) with no
// change to the events, the CLI or the server.
#pragma once

#include "bake/bake_errors.h"   // what run_bake_job throws
#include "bake/stop_request.h"  // how a running bake is stopped
#include "bake_settings.h"
#include "sh/environment.h"
#include "gpu/context.h"
#include "worker_protocol.h"

#include <filesystem>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf {

struct BakeJob {
    std::filesystem::path scene;  // the .gltf / .glb
    std::filesystem::path out;    // the output directory (created)
    protocol::BakeSettings settings;
    DeviceChoice device = DeviceChoice::Auto;
    // Continue from the method states an interrupted run of the same job
    // left in `out` (bake/method_state.h) instead of from pass 0; an output
    // whose state does not fit starts again, and the start event says why.
    bool resume = false;
};

// The job's environment (--env): its map file (.exr, .hdr), its uniform sky,
// or none. A map that cannot be read is a BakeInputError naming it.
std::optional<Environment> read_environment(const protocol::EnvironmentSetting& env);

// What a bake of `job` would make of its atlas, without baking (`lightfarm
// bake --plan`): {"scene", "atlas": the manifest's atlas section (size,
// texel density, charts, border fraction…), "warnings", "seconds"}. Loads
// the scene and builds the atlas as the bake would (the unlit charts traced
// too); stops before the texels. A BakeInputError where the bake would fail
// on its input, and when no requested output uses the atlas.
nlohmann::json plan_bake_atlas(const BakeJob& job);

// Worker events as they happen: start, progress and snapshot per pass, done.
using BakeEventSink = std::function<void(const protocol::WorkerEvent&)>;

// Runs the job and returns its "done" event (also emitted). Throws on any
// failure; no file is ever left half-written under its final name. Each
// output's state is saved with its snapshots, for a run with `resume`.
protocol::DoneEvent run_bake_job(const BakeJob& job, const BakeEventSink& emit);

// Bytes of memory a bake may use now: MemAvailable of `meminfo`, and under a
// container's limit (cgroup v2 memory.max of `cgroup_dir`, less its
// memory.current) no more than what is left of that; 0 when neither says.
// A bake refuses up front an atlas whose estimate exceeds it.
uint64_t available_memory(const std::filesystem::path& meminfo = "/proc/meminfo",
                          const std::filesystem::path& cgroup_dir = "/sys/fs/cgroup");

}  // namespace lf
