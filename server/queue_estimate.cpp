#include "queue_estimate.h"

#include <algorithm>
#include <functional>
#include <queue>

namespace lf::server {

std::optional<double> queued_start_estimate(int ahead, int slots,
                                            const std::vector<std::optional<double>>& running_left,
                                            std::optional<double> typical_seconds) {
    // Each slot's time until free, soonest first.
    std::priority_queue<double, std::vector<double>, std::greater<double>> free_in;
    for (const std::optional<double>& left : running_left) {
        if (!left && !typical_seconds) return std::nullopt;
        free_in.push(std::max(0.0, left ? *left : *typical_seconds));
    }
    for (int s = int(running_left.size()); s < slots; ++s) free_in.push(0.0);
    if (free_in.empty()) free_in.push(0.0);  // no worker known: the next one to come
    for (int k = 0; k < ahead; ++k) {
        if (!typical_seconds) return std::nullopt;
        const double start = free_in.top();
        free_in.pop();
        free_in.push(start + *typical_seconds);
    }
    return free_in.top();
}

std::optional<double> typical_job_seconds(std::vector<double> seconds) {
    if (seconds.empty()) return std::nullopt;
    const auto middle = seconds.begin() + std::ptrdiff_t(seconds.size() / 2);
    std::nth_element(seconds.begin(), middle, seconds.end());
    return *middle;
}

}  // namespace lf::server
