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

namespace {

// Lock-free atomics: read and written from a signal handler.
std::atomic<bool> g_stop_requested{false};
std::atomic<int> g_stop_points{0};
static_assert(std::atomic<bool>::is_always_lock_free && std::atomic<int>::is_always_lock_free);

std::string stopped_message(const std::string& output, int pass, const std::vector<std::string>& files) {
    std::string what = "stopped on request at pass " + std::to_string(pass) + " of " + output;
    if (!files.empty()) what += "; its newest snapshot: " + files.front();
    return what;
}

}  // namespace

bool request_stop() noexcept {
    g_stop_requested.store(true);
    return g_stop_points.load() > 0;
}

bool stop_requested() noexcept { return g_stop_requested.load(); }

void clear_stop_request() noexcept { g_stop_requested.store(false); }

StopPoint::StopPoint() noexcept { g_stop_points.fetch_add(1); }

StopPoint::~StopPoint() { g_stop_points.fetch_sub(1); }

BakeStopped::BakeStopped(std::string output_, int pass_, std::vector<std::string> files_)
    : std::runtime_error(stopped_message(output_, pass_, files_)),
      output(std::move(output_)),
      pass(pass_),
      files(std::move(files_)) {}

bool SnapshotSchedule::due(int pass, double now, bool writer_idle) {
    const bool wanted = pass >= next_pass_ || (last_at_ >= 0.0 && now - last_at_ >= interval_);
    if (!wanted || !writer_idle) return false;
    if (last_at_ >= 0.0 && now - last_at_ < last_cost_ * (1.0 - budget_) / budget_) return false;
    last_at_ = now;
    while (next_pass_ <= pass) next_pass_ *= 2;
    return true;
}

}  // namespace lf
