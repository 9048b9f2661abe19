// The one progressive loop every method runs in, for the CLI and the worker
// alike: passes in batches (one read-back each) until a pass count, a target
// error or a time limit is reached, reporting each pass; and when to
// snapshot (passes 1, 2, 4, 8 … and on a time schedule, within a budget of
// the wall time).
#pragma once

#include "bake_settings.h"
#include "worker_protocol.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace lf {

struct MethodState;  // bake/method_state.h

// Totals after a pass (pass, rays, seconds, error estimate): the worker
// protocol's Progress, so the engine and the server count the same thing.
using PassStats = protocol::Progress;

struct StopRule {
    int max_passes = 0;         // the settings say (stop_rule_from): no default of its own
    double target_error = 0.0;  // stop once error_estimate <= this (0 = never)
    double time_limit = 0.0;    // seconds (0 = none)
    int min_passes = 4;         // an error estimate from fewer passes is not trusted
};
StopRule stop_rule_from(const protocol::StopSettings& stop);

// What a method hands the driver when it is done: its files (the main one
// first) and its section of manifest.json.
struct FloatImage;

struct MethodResult {
    std::vector<std::string> files;
    nlohmann::json manifest = nlohmann::json::object();
    // The image written to files.front(), where the method still holds it:
    // the driver makes scene.lit.glb from it rather than read the file back
    // (6.4 s of a 4096² bake). Null for an output an earlier run finished.
    std::shared_ptr<const FloatImage> image;
};

// The second half of a snapshot: builds and writes its files off the GL
// thread; returns their names.
using SnapshotWrite = std::function<std::vector<std::string>()>;

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
    // The rays one pass traces, about: the job's ETA prices an output's
    // passes with it before the output starts (protocol::JobProgress).
    virtual uint64_t rays_per_pass() const = 0;
    // Runs one pass and returns the totals after it.
    virtual PassStats step() = 0;
    // Runs `count` passes back to back (1 <= count <= max_batch()) and
    // returns the totals after each. A method whose passes need nothing read
    // back between them waits for the device once, after the last: on a GPU
    // a pass can be shorter than the round trip.
    virtual std::vector<PassStats> run_passes(int count) {
        std::vector<PassStats> stats;
        for (int p = 0; p < count; ++p) stats.push_back(step());
        return stats;
    }
    virtual int max_batch() const { return 1; }
    // Reads the current result back (on the GL thread, between passes) and
    // returns the work that writes it as intermediate files of pass
    // `stats.pass` (names from snapshot_file_name). The driver runs that work
    // on its writer thread while the passes go on, so it must only use what
    // it captured and what the method never changes after construction.
    virtual SnapshotWrite snapshot(const std::filesystem::path& dir, const PassStats& stats) = 0;
    // Writes the final files.
    virtual MethodResult finish(const std::filesystem::path& dir, const PassStats& stats) = 0;
    // Resuming an interrupted bake (bake/method_state.h): what the passes
    // carry from one pass to the next (read on the GL thread, between
    // passes; the driver fills in the key and the files), and continuing
    // from it. restore() throws MethodStateMismatch, changing nothing, for a
    // state this method cannot take.
    virtual MethodState state() const = 0;
    virtual void restore(const MethodState& state) = 0;
};

// "<stem>.pass-NNNN.<extension>": the name of an intermediate snapshot.
using protocol::snapshot_file_name;

// Whether a bake with these totals is done.
bool stop_reached(const StopRule& stop, const PassStats& stats);

// How many passes a method runs between read-backs
// (ProgressiveMethod::run_passes). Each read-back waits for the device;
// while batches take less than `seconds` the next one doubles, so that the
// wait is a small part of the time, and it halves when one takes more than
// twice that. A batch never goes past `limit` (the pass count, a snapshot
// due at a pass), so every stop and snapshot by pass lands where it would
// one pass at a time; a target error or a time limit is checked after each
// batch, which may run a few passes past it.
class PassBatcher {
public:
    explicit PassBatcher(int max_batch, double seconds = 0.02) : max_(std::max(1, max_batch)), seconds_(seconds) {}
    int next(int limit) const { return std::max(1, std::min(size_, limit)); }
    void record(int passes, double seconds);

private:
    int max_;
    double seconds_;
    int size_ = 1;
};

// Runs `method`'s passes from `from` (a resumed bake's totals; none: pass 0)
// until its stop rule says so, in batches (PassBatcher) that end at
// `wanted_pass()` when given (the next pass someone wants to see, such as
// SnapshotSchedule::next_pass); on_batch(stats) after each batch, one
// PassStats per pass.
PassStats run_progressive(ProgressiveMethod& method, const std::function<void(const std::vector<PassStats>&)>& on_batch,
                          const PassStats& from = {}, const std::function<int()>& wanted_pass = {});

// When a snapshot is taken: at passes 1, 2, 4, 8 … and whenever `interval`
// seconds have passed since the last one; but never while the last one is
// still being written, and never so often that snapshots cost more than
// `budget` of the wall time (a snapshot that cost c seconds is followed by
// at least c · (1 − budget) / budget seconds without one). A snapshot held
// back is taken at the first pass after that.
class SnapshotSchedule {
public:
    explicit SnapshotSchedule(double budget = 0.1, double interval = 10.0) : budget_(budget), interval_(interval) {}
    // Whether to take a snapshot after pass `pass` at wall time `now`
    // (seconds); true records it as taken.
    bool due(int pass, double now, bool writer_idle);
    // What the last snapshot cost (reading back plus writing), in seconds.
    void record_cost(double seconds) { last_cost_ = seconds; }
    // The next pass due by the doublings (a batch of passes ends there).
    int next_pass() const { return next_pass_; }

private:
    double budget_, interval_;
    int next_pass_ = 1;
    double last_at_ = -1.0;  // wall time of the last snapshot (-1: none yet)
    double last_cost_ = 0.0;
};

}  // namespace lf
