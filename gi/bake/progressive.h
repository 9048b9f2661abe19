// The one progressive loop every method runs in, for the CLI and the worker
// alike: step() a pass at a time until a pass count, a target error or a time
// limit is reached, reporting each pass and snapshotting on a geometric
// schedule (passes 1, 2, 4, 8 …).
#pragma once

#include "bake_settings.h"
#include "worker_protocol.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace lf {

// Totals after a pass (pass, rays, seconds, error estimate): the worker
// protocol's Progress, so the engine and the server count the same thing.
using PassStats = protocol::Progress;

struct StopRule {
    int max_passes = 256;
    double target_error = 0.0;  // stop once error_estimate <= this (0 = never)
    double time_limit = 0.0;    // seconds (0 = none)
    int min_passes = 4;         // an error estimate from fewer passes is not trusted
};
StopRule stop_rule_from(const protocol::StopSettings& stop);

// What a method hands the driver when it is done: its files (the main one
// first) and its section of manifest.json.
struct MethodResult {
    std::vector<std::string> files;
    nlohmann::json manifest = nlohmann::json::object();
};

// One output of a bake job (DESIGN.md "Data flow"): a progressive solution
// and its writers. The job driver (bake/bake_job.h) prepares the scene once,
// makes the methods, and runs each through run_progressive; a method never
// emits events or names the job's files beyond its own.
class ProgressiveMethod {
public:
    virtual ~ProgressiveMethod() = default;
    // The output's name in the job spec: "lightmap", "sh".
    virtual std::string output() const = 0;
    virtual StopRule stop_rule() const = 0;
    // What it bakes (texels, vertices, settings): the start event and the manifest.
    virtual nlohmann::json description() const = 0;
    // Runs one pass and returns the totals after it.
    virtual PassStats step() = 0;
    // Writes the current result as intermediate files of pass `stats.pass`
    // (names from snapshot_file_name) and returns their names.
    virtual std::vector<std::string> snapshot(const std::filesystem::path& dir, const PassStats& stats) = 0;
    // Writes the final files.
    virtual MethodResult finish(const std::filesystem::path& dir, const PassStats& stats) = 0;
};

// "<stem>.pass-NNNN.<extension>": the name of an intermediate snapshot.
std::string snapshot_file_name(const std::string& stem, int pass, const std::string& extension);

// Runs passes until `stop` says so. on_pass(stats, snapshot_due) is called
// after every pass; snapshot_due is true on passes 1, 2, 4, 8 …
PassStats run_progressive(const std::function<PassStats()>& step, const StopRule& stop,
                          const std::function<void(const PassStats&, bool snapshot_due)>& on_pass);

}  // namespace lf
