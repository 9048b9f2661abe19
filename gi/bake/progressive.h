// The one progressive loop every method runs in, for the CLI and the worker
// alike: step() a pass at a time until a pass count, a target error or a time
// limit is reached, reporting each pass and snapshotting on a geometric
// schedule (passes 1, 2, 4, 8 …).
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <string>

namespace lf {

struct PassStats {
    int pass = 0;               // passes done so far
    uint64_t rays = 0;          // rays traced so far
    double seconds = 0.0;       // bake time so far (this method's passes)
    double error_estimate = 0;  // relative standard error over covered texels (or the method's equivalent)
};

class ProgressiveMethod {
public:
    virtual ~ProgressiveMethod() = default;
    // Runs one pass and returns the totals after it.
    virtual PassStats step() = 0;
};

struct StopRule {
    int max_passes = 256;
    double target_error = 0.0;  // stop once error_estimate <= this (0 = never)
    double time_limit = 0.0;    // seconds (0 = none)
    int min_passes = 4;         // an error estimate from fewer passes is not trusted
};

// {"pass", "rays", "seconds", "error_estimate"}: the fields of the bake events.
nlohmann::json to_json(const PassStats& stats);

// "<stem>.pass-NNNN.<extension>": the name of an intermediate snapshot.
std::string snapshot_file_name(const std::string& stem, int pass, const std::string& extension);

// Runs passes until `stop` says so. on_pass(stats, snapshot_due) is called
// after every pass; snapshot_due is true on passes 1, 2, 4, 8 …
PassStats run_progressive(ProgressiveMethod& method, const StopRule& stop,
                          const std::function<void(const PassStats&, bool snapshot_due)>& on_pass);

}  // namespace lf
