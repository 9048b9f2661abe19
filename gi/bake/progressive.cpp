#include "bake/progressive.h"

#include <cstdio>

namespace lf {

nlohmann::json to_json(const PassStats& s) {
    return {{"pass", s.pass}, {"rays", s.rays}, {"seconds", s.seconds}, {"error_estimate", s.error_estimate}};
}

std::string snapshot_file_name(const std::string& stem, int pass, const std::string& extension) {
    char number[16];
    std::snprintf(number, sizeof number, "%04d", pass);
    return stem + ".pass-" + number + "." + extension;
}

PassStats run_progressive(ProgressiveMethod& method, const StopRule& stop,
                          const std::function<void(const PassStats&, bool)>& on_pass) {
    PassStats stats;
    int next_snapshot = 1;
    while (stats.pass < stop.max_passes) {
        stats = method.step();
        const bool snapshot_due = stats.pass == next_snapshot;
        if (snapshot_due) next_snapshot *= 2;
        const bool converged = stop.target_error > 0.0 && stats.pass >= stop.min_passes &&
                               stats.error_estimate <= stop.target_error;
        const bool out_of_time = stop.time_limit > 0.0 && stats.seconds >= stop.time_limit;
        if (on_pass) on_pass(stats, snapshot_due);
        if (converged || out_of_time) break;
    }
    return stats;
}

}  // namespace lf
