#pragma once
// Preparation on every core: a loop whose iterations are independent runs
// on worker threads (the calling thread among them). Each iteration writes
// only what its index owns, so the result is the same whatever the thread
// count and the order (the tests compare against one thread).
//
// Threads are started per call: the loops here take milliseconds to
// seconds, against tens of microseconds to start a thread, and a pool
// shared by the service's jobs would make one job's preparation wait for
// another's.

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <exception>
#include <mutex>
#include <sched.h>
#include <stdexcept>
#include <string>
#include <system_error>
#include <thread>
#include <vector>

namespace lf {

// The threads a parallel loop uses: LIGHTFARM_THREADS where set (1 to
// 1024; 1: the calling thread alone), else the cores this process may run
// on (its CPU affinity: a container's share, not the machine's). Any other
// LIGHTFARM_THREADS is refused (std::invalid_argument), not ignored.
inline size_t preparation_threads() {
    if (const char* env = std::getenv("LIGHTFARM_THREADS")) {
        char* end = nullptr;
        const long n = std::strtol(env, &end, 10);
        if (end == env || *end != '\0' || n < 1 || n > 1024)
            throw std::invalid_argument(std::string("LIGHTFARM_THREADS=") + env +
                                        ": not a thread count (a whole number from 1 to 1024)");
        return size_t(n);
    }
    cpu_set_t cpus;
    if (sched_getaffinity(0, sizeof cpus, &cpus) == 0 && CPU_COUNT(&cpus) > 0) return size_t(CPU_COUNT(&cpus));
    return std::max(1u, std::thread::hardware_concurrency());
}

// Calls body(begin, end) for consecutive ranges that cover [0, count), each
// at least `grain` long (the last may be shorter), on up to
// preparation_threads() threads; returns when every range is done. Ranges
// are handed out in order as threads become free, so uneven iterations
// balance. The first exception a range throws is rethrown here (the
// ranges not yet started are skipped).
template <typename Body>
void parallel_ranges(size_t count, size_t grain, Body&& body) {
    grain = std::max<size_t>(1, grain);
    const size_t ranges = (count + grain - 1) / grain;
    const size_t threads = std::min(preparation_threads(), ranges);
    if (threads <= 1) {
        if (count > 0) body(size_t(0), count);
        return;
    }
    std::atomic<size_t> next{0};
    std::atomic<bool> failed{false};
    std::exception_ptr error;
    std::mutex error_mutex;
    auto work = [&] {
        for (size_t r; !failed && (r = next++) < ranges;) {
            try {
                body(r * grain, std::min(count, (r + 1) * grain));
            } catch (...) {
                const std::lock_guard lock(error_mutex);
                if (!error) error = std::current_exception();
                failed = true;
            }
        }
    };
    std::vector<std::thread> helpers;
    helpers.reserve(threads - 1);
    try {
        for (size_t t = 1; t < threads; ++t) helpers.emplace_back(work);
    } catch (const std::system_error&) {
        // No more threads to be had: the ones started, and this one, do it all.
    }
    work();
    for (std::thread& h : helpers) h.join();
    if (error) std::rethrow_exception(error);
}

// body(i) for every i in [0, count), in ranges of `grain` (parallel_ranges).
template <typename Body>
void parallel_for(size_t count, size_t grain, Body&& body) {
    parallel_ranges(count, grain, [&](size_t begin, size_t end) {
        for (size_t i = begin; i < end; ++i) body(i);
    });
}

}  // namespace lf
