// A child process with its stdout and stderr piped to us: the engine CLI run as
// a worker (`lightfarm bake`) or as a validator (`lightfarm inspect`).
//
// The child runs in its own process group so that kill() also ends anything it
// started; stdin is /dev/null. Nothing here throws on what the child does
// (crash, garbage, silence): the caller decides what that costs.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

namespace lf::server {

struct ExitStatus {
    bool exited = false;  // normal exit: code is valid; else killed by `signal`
    int code = 0;
    int signal = 0;
    bool success() const { return exited && code == 0; }
    std::string describe() const;  // "exited with status 3", "killed by signal 9 (Killed)"
};

struct SpawnLimits {
    // RLIMIT_AS of the child (0: none): an allocation beyond it fails in the
    // child (std::bad_alloc, a crash), never in the server or the machine.
    uint64_t address_space_bytes = 0;
};

class Subprocess {
public:
    // Starts argv[0] (searched in PATH when it has no '/'). Throws
    // std::runtime_error when it cannot be started.
    explicit Subprocess(const std::vector<std::string>& argv, const SpawnLimits& limits = {});
    ~Subprocess();  // kills and reaps a child that is still running
    Subprocess(const Subprocess&) = delete;
    Subprocess& operator=(const Subprocess&) = delete;

    enum class Read { Line, Timeout, End };
    // Next line of stdout (without '\n'), waiting at most `timeout`. Meanwhile
    // drains stderr into stderr_tail(). End: stdout closed.
    Read read_line(std::string& line, std::chrono::milliseconds timeout);

    // SIGKILL to the whole process group. Like every member, for the one
    // thread that owns this object.
    void kill();
    // SIGTERM to the whole process group: a worker takes one last snapshot
    // and exits (see Supervisor's cancel grace); kill() if it does not.
    void terminate();
    // Waits for the child to end (call after End or kill()).
    ExitStatus wait();

    pid_t pid() const { return pid_; }
    // The last few KiB of stderr, and its last non-empty line.
    const std::string& stderr_tail() const { return stderr_; }
    std::string stderr_last_line() const;

private:
    void drain_stderr();
    pid_t pid_ = -1;
    int out_fd_ = -1, err_fd_ = -1;
    bool reaped_ = false;
    ExitStatus status_;
    std::string out_buffer_;
    std::string stderr_;
};

// Runs a command to completion with a deadline (then kills it); stdout whole.
struct RunResult {
    ExitStatus status;
    bool timed_out = false;
    std::string out;
    std::string err_last_line;
};
RunResult run_command(const std::vector<std::string>& argv, std::chrono::milliseconds timeout,
                      size_t max_output = 16 << 20, const SpawnLimits& limits = {});

}  // namespace lf::server
