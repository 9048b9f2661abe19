// A bake's events with no silence longer than a second: whenever
// kPeriodSeconds pass without an event, the last "prepare" or "progress"
// event is said again, its seconds moved on by the time since (and a
// prepare event's time left moved down). A stage of preparation can take
// many seconds (the staircase's "methods", compiling and uploading for each
// output: 9 s at 256² on llvmpipe), so can writing the final files (3 s)
// or one pass of a large atlas; a person or a server watching the job
// should never see its last line go stale (issue #54: no line older than
// 2 s). Start, snapshot and done events are said once: they are facts.
#pragma once

#include "bake/bake_job.h"
#include "util/stopwatch.h"

#include <condition_variable>
#include <exception>
#include <mutex>
#include <optional>
#include <thread>

namespace lf {

class EventHeartbeat {
public:
    static constexpr double kPeriodSeconds = 1.0;

    explicit EventHeartbeat(BakeEventSink emit);
    ~EventHeartbeat();  // stop()
    EventHeartbeat(const EventHeartbeat&) = delete;
    EventHeartbeat& operator=(const EventHeartbeat&) = delete;

    // Where the bake says its events: passed on at once, one at a time
    // (the heartbeat's own thread and a snapshot writer's never overlap it).
    // What the sink throws reaches the thread that said the event, or, for a
    // line said again, the bake's next event; nothing is repeated after.
    BakeEventSink sink();
    // Nothing more is repeated (returns once the repeating thread ended).
    void stop();

private:
    void pass_on(const protocol::WorkerEvent& e);
    void repeat();

    BakeEventSink emit_;
    std::mutex mutex_;
    std::condition_variable wake_;
    bool stopped_ = false;
    std::optional<protocol::WorkerEvent> last_;  // the last prepare or progress event said
    Stopwatch since_said_;                       // the last event of any kind
    Stopwatch since_last_;                       // last_
    std::exception_ptr failure_;                 // what the sink threw on the repeating thread
    std::thread thread_;
};

}  // namespace lf
