// Wakes event-stream readers and idle workers when something happened.
// A generation counter, not a queue: readers go back to the store for what
// changed, so a missed wake-up costs at most one wait timeout, never an event.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <mutex>

namespace lf::server {

class ChangeSignal {
public:
    void notify() {
        {
            std::lock_guard lock(mutex_);
            ++generation_;
        }
        cv_.notify_all();
    }
    uint64_t generation() {
        std::lock_guard lock(mutex_);
        return generation_;
    }
    // Returns when the generation differs from `seen`, on shutdown, or at the timeout.
    void wait(uint64_t seen, std::chrono::milliseconds timeout) {
        std::unique_lock lock(mutex_);
        cv_.wait_for(lock, timeout, [&] { return generation_ != seen || stopping_; });
    }
    void shutdown() {
        {
            std::lock_guard lock(mutex_);
            stopping_ = true;
        }
        cv_.notify_all();
    }
    bool stopping() {
        std::lock_guard lock(mutex_);
        return stopping_;
    }

private:
    std::mutex mutex_;
    std::condition_variable cv_;
    uint64_t generation_ = 0;
    bool stopping_ = false;
};

}  // namespace lf::server
