// What `lightfarm bake` prints while it bakes: with --json, the worker
// protocol's events as JSON lines on stdout (what lightfarmd reads from its
// workers); else a summary of the start on stderr, a progress bar there when
// stderr is a terminal, and the final counts on stdout.
#pragma once

#include "job_spec.h"
#include "job_status.h"
#include "worker_protocol.h"

#include <map>
#include <string>

namespace lf::cli {

class BakeReporter {
public:
    BakeReporter(bool json, const protocol::BakeSettings& settings);

    void operator()(const protocol::WorkerEvent& e);

private:
    void print_start(const protocol::StartEvent& start);
    void draw_progress(const protocol::ProgressEvent& progress);

    bool json_, terminal_;
    // The whole job's share done and ETA, as the server reckons them.
    protocol::JobProgress job_;
    std::string drawing_;           // the output whose bar is on the current line
    bool preparing_drawn_ = false;  // a preparation line is on the current line
};

}  // namespace lf::cli
