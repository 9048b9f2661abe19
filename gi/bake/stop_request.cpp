#include "bake/stop_request.h"

#include <atomic>

namespace lf {

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

}  // namespace lf
