// The CLI's commands against a lightfarmd server: submit, watch, fetch,
// cancel, jobs. The bake options of `submit` are those of `lightfarm bake`,
// read through protocol/'s one catalog.
#pragma once

#include "job_status.h"
#include "worker_protocol.h"

#include <string>

namespace lf::cli {

// True for the commands run_remote_command handles.
bool is_remote_command(const std::string& command);

// Runs `lightfarm COMMAND ...` (argv[1] is the command). Prints a server or
// connection error as one line on stderr; returns the exit status (0 ok, 1
// failed, 2 usage).
int run_remote_command(const std::string& command, int argc, char** argv);

extern const char* const kRemoteUsage;

// What `watch` and `submit --wait` show on a terminal for a progress event:
// "3cfd1af2a543 lightmap  [##########--------------]  42%  pass 108  error 0.0312  ETA 14s".
std::string progress_line(const std::string& job, const std::string& output, const protocol::Progress& p);
// "JOB  preparing: atlas  3.1 s  ETA 12 s": the line before the first pass.
std::string preparing_line(const std::string& job, const protocol::PrepareEvent& e);
// "JOB  queued: N jobs ahead of it, R running": while a job waits its turn.
std::string queued_line(const std::string& job, const protocol::QueuePlace& q);

}  // namespace lf::cli
