// A bake stopped where it stands, from a signal handler (the worker's
// SIGTERM, the CLI's Ctrl-C): the request, and where the job driver takes it.
#pragma once

#include "bake/bake_errors.h"

namespace lf {

// Stopping a bake where it stands (the worker's SIGTERM: its job was
// cancelled). Once asked, the job driver takes one last snapshot of the
// pass the device holds after the batch in flight (the snapshots being
// written first), announces it, and throws BakeStopped. Safe to call from a
// signal handler. Returns whether a bake is passing now and will take that
// snapshot (armed by StopPoint); false: nothing to save, exit at once.
bool request_stop() noexcept;
bool stop_requested() noexcept;
void clear_stop_request() noexcept;  // for tests

// While one lives, a stop request is taken at the next batch (the job
// driver holds one from its first pass to its done event).
class StopPoint {
public:
    StopPoint() noexcept;
    ~StopPoint();
    StopPoint(const StopPoint&) = delete;
    StopPoint& operator=(const StopPoint&) = delete;
};

}  // namespace lf
