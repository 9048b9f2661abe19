// The one job driver, as `lightfarm bake` and the service's worker run it:
// load the scene once, prepare what the requested outputs need once (atlas,
// texel samples, one GL context, one tracer), run every output's method
// through the one progressive loop, and own the worker events, the snapshot
// names and manifest.json. A new method plugs in here (make_methods) with no
// change to the events, the CLI or the server.
#pragma once

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

// The job's input cannot be baked as asked (no light, an atlas that cannot
// fit, a mesh that is not there): running it again cannot help. The CLI
// exits with protocol::kExitInputError for it (and for a SceneError).
class BakeInputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
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

// Stopping a bake where it stands (the worker's SIGTERM: its job was
// cancelled). Once asked, the job driver takes one last snapshot of the
// pass the device holds after the batch in flight (the snapshots being
// written first), announces it, and throws BakeStopped. Safe to call from a
// signal handler. Returns whether a bake is passing now and will take that
// snapshot (armed by StopPoint); false: nothing to save, exit at once.
// Defined in bake/progressive.cpp, beside the loop.
bool request_stop() noexcept;
bool stop_requested() noexcept;
void clear_stop_request() noexcept;  // for tests

// While one lives, a stop request is taken at the next batch (the job
// driver holds one from its first pass to its done event).
class StopPoint {
public:
    StopPoint() noexcept;
    ~StopPoint();
    StopPoint(const StopPoint&) = delete;
    StopPoint& operator=(const StopPoint&) = delete;
};

class BakeStopped : public std::runtime_error {
public:
    BakeStopped(std::string output, int pass, std::vector<std::string> files);
    std::string output;              // the output that was passing
    int pass = 0;                    // the pass its last snapshot holds
    std::vector<std::string> files;  // that snapshot's files
};

// Bytes of memory a bake may use now: MemAvailable of `meminfo`, and under a
// container's limit (cgroup v2 memory.max of `cgroup_dir`, less its
// memory.current) no more than what is left of that; 0 when neither says.
// A bake refuses up front an atlas whose estimate exceeds it.
uint64_t available_memory(const std::filesystem::path& meminfo = "/proc/meminfo",
                          const std::filesystem::path& cgroup_dir = "/sys/fs/cgroup");

}  // namespace lf
