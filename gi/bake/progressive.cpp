#include "bake/progressive.h"

#include "bake/bake_job.h"
#include "util/stopwatch.h"

#include <atomic>

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

void PassBatcher::record(int passes, double seconds) {
    if (passes == size_ && seconds < seconds_) size_ = std::min(max_, 2 * size_);
    else if (seconds > 2.0 * seconds_) size_ = std::max(1, size_ / 2);
}

PassStats run_progressive(ProgressiveMethod& method, const std::function<void(const std::vector<PassStats>&)>& on_batch,
                          const PassStats& from, const std::function<int()>& wanted_pass) {
    const StopRule stop = method.stop_rule();
    PassBatcher batcher(method.max_batch());
    PassStats stats = from;
    while (!stop_reached(stop, stats)) {
        int limit = stop.max_passes - stats.pass;
        if (wanted_pass) limit = std::min(limit, wanted_pass() - stats.pass);
        const int count = batcher.next(limit);
        const Stopwatch clock;
        const std::vector<PassStats> passes = method.run_passes(count);
        batcher.record(count, clock.seconds());
        stats = passes.back();
        if (on_batch) on_batch(passes);
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
