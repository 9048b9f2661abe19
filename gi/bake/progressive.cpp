#include "bake/progressive.h"

#include <cstdio>

namespace lf {

StopRule stop_rule_from(const protocol::StopSettings& stop) {
    StopRule rule;
    rule.max_passes = stop.passes;
    rule.target_error = stop.target_error;
    rule.time_limit = stop.time_limit;
    return rule;
}

std::string snapshot_file_name(const std::string& stem, int pass, const std::string& extension) {
    char number[16];
    std::snprintf(number, sizeof number, "%04d", pass);
    return stem + ".pass-" + number + "." + extension;
}

PassStats run_progressive(const std::function<PassStats()>& step, const StopRule& stop,
                          const std::function<void(const PassStats&, bool)>& on_pass) {
    PassStats stats;
    int next_snapshot = 1;
    while (stats.pass < stop.max_passes) {
        stats = step();
        const bool snapshot_due = stats.pass == next_snapshot;
        if (snapshot_due) next_snapshot *= 2;
        const bool converged = stop.target_error > 0.0 && stats.pass >= stop.min_passes &&
                               stats.error_estimate.value_or(1e30) <= stop.target_error;
        const bool out_of_time = stop.time_limit > 0.0 && stats.seconds >= stop.time_limit;
        if (on_pass) on_pass(stats, snapshot_due);
        if (converged || out_of_time) break;
    }
    return stats;
}

}  // namespace lf
