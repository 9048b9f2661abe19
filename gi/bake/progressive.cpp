#include "bake/progressive.h"

namespace lf {

StopRule stop_rule_from(const protocol::StopSettings& stop) {
    StopRule rule;
    rule.max_passes = stop.passes;
    rule.target_error = stop.target_error;
    rule.time_limit = stop.time_limit;
    return rule;
}

bool stop_reached(const StopRule& stop, const PassStats& stats) {
    const bool converged = stop.target_error > 0.0 && stats.pass >= stop.min_passes &&
                           stats.error_estimate.value_or(1e30) <= stop.target_error;
    const bool out_of_time = stop.time_limit > 0.0 && stats.seconds >= stop.time_limit;
    return stats.pass >= stop.max_passes || converged || out_of_time;
}

PassStats run_progressive(const std::function<PassStats()>& step, const StopRule& stop,
                          const std::function<void(const PassStats&)>& on_pass, const PassStats& from) {
    PassStats stats = from;
    while (!stop_reached(stop, stats)) {
        stats = step();
        if (on_pass) on_pass(stats);
    }
    return stats;
}

bool SnapshotSchedule::due(int pass, double now, bool writer_idle) {
    const bool wanted = pass >= next_pass_ || (last_at_ >= 0.0 && now - last_at_ >= interval_);
    if (!wanted || !writer_idle) return false;
    if (last_at_ >= 0.0 && now - last_at_ < last_cost_ * (1.0 - budget_) / budget_) return false;
    last_at_ = now;
    while (next_pass_ <= pass) next_pass_ *= 2;
    return true;
}

}  // namespace lf
