#include "bake/event_heartbeat.h"

#include <algorithm>
#include <chrono>
#include <exception>
#include <utility>

namespace lf {

EventHeartbeat::EventHeartbeat(BakeEventSink emit) : emit_(std::move(emit)) {
    thread_ = std::thread([this] { repeat(); });
}

EventHeartbeat::~EventHeartbeat() { stop(); }

void EventHeartbeat::stop() {
    {
        const std::lock_guard<std::mutex> lock(mutex_);
        stopped_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) thread_.join();
}

BakeEventSink EventHeartbeat::sink() {
    return [this](const protocol::WorkerEvent& e) { pass_on(e); };
}

void EventHeartbeat::pass_on(const protocol::WorkerEvent& e) {
    const std::lock_guard<std::mutex> lock(mutex_);
    // The sink may throw (a closed pipe; a test that stops a bake at a
    // pass): on the caller's thread, as if there were no heartbeat.
    if (failure_) std::rethrow_exception(std::exchange(failure_, nullptr));
    try {
        emit_(e);
    } catch (...) {
        stopped_ = true;  // the bake is ending: nothing more is repeated
        wake_.notify_all();
        throw;
    }
    since_said_ = Stopwatch();
    if (std::holds_alternative<protocol::PrepareEvent>(e) || std::holds_alternative<protocol::ProgressEvent>(e)) {
        last_ = e;
        since_last_ = Stopwatch();
    } else if (!std::holds_alternative<protocol::SnapshotEvent>(e)) {
        last_.reset();  // after start or done, the last progress is another phase's
    }
}

void EventHeartbeat::repeat() {
    std::unique_lock<std::mutex> lock(mutex_);
    while (!stopped_) {
        const double wait = std::max(0.01, kPeriodSeconds - since_said_.seconds());
        if (wake_.wait_for(lock, std::chrono::duration<double>(wait), [this] { return stopped_; })) break;
        if (!last_ || since_said_.seconds() < kPeriodSeconds) continue;
        const double moved = since_last_.seconds();
        protocol::WorkerEvent again = *last_;
        if (auto* prepare = std::get_if<protocol::PrepareEvent>(&again)) {
            prepare->again = true;
            prepare->seconds += moved;
            if (prepare->eta_seconds) prepare->eta_seconds = std::max(0.0, *prepare->eta_seconds - moved);
        } else if (auto* progress = std::get_if<protocol::ProgressEvent>(&again)) {
            progress->again = true;
            progress->progress.seconds += moved;
        }
        try {
            emit_(again);
        } catch (...) {
            failure_ = std::current_exception();  // for the bake's own thread, at its next event
            break;
        }
        since_said_ = Stopwatch();
    }
}

}  // namespace lf
