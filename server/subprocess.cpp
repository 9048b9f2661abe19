#include "subprocess.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <stdexcept>

extern char** environ;

namespace lf::server {

namespace {
constexpr size_t kStderrKeep = 8192;

void close_fd(int& fd) {
    if (fd >= 0) ::close(fd);
    fd = -1;
}

// argv[0] as execv() takes it: a name without '/' looked up in PATH here, in
// the parent, so that the forked child only makes async-signal-safe calls.
std::string resolve_program(const std::string& name) {
    if (name.find('/') != std::string::npos) return name;
    const char* path = std::getenv("PATH");
    std::string dirs = path ? path : "/usr/local/bin:/usr/bin:/bin";
    size_t start = 0;
    while (start <= dirs.size()) {
        const size_t colon = std::min(dirs.find(':', start), dirs.size());
        const std::string dir = dirs.substr(start, colon - start);
        const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + name;
        if (::access(candidate.c_str(), X_OK) == 0) return candidate;
        start = colon + 1;
    }
    return name;  // execv fails with ENOENT, reported to the caller
}

// fork + exec with resource limits, which posix_spawn cannot set. The child
// only calls async-signal-safe functions (the server has many threads).
pid_t spawn_limited(const std::vector<std::string>& argv, int out_fd, int err_fd, const SpawnLimits& limits) {
    const std::string program = resolve_program(argv[0]);
    std::vector<char*> args;
    for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    int report[2];  // the child writes errno here when exec fails; closed on exec
    if (pipe2(report, O_CLOEXEC) != 0) throw std::runtime_error(std::string("pipe: ") + strerror(errno));
    const pid_t pid = fork();
    if (pid < 0) {
        const int e = errno;
        ::close(report[0]);
        ::close(report[1]);
        throw std::runtime_error(std::string("fork: ") + strerror(e));
    }
    if (pid == 0) {
        setpgid(0, 0);  // its own group: kill() reaches its children too
        struct sigaction dfl {};
        dfl.sa_handler = SIG_DFL;
        for (int sig : {SIGPIPE, SIGTERM, SIGINT}) sigaction(sig, &dfl, nullptr);
        sigset_t none;
        sigemptyset(&none);
        sigprocmask(SIG_SETMASK, &none, nullptr);
        const int in = ::open("/dev/null", O_RDONLY);
        if (in >= 0 && in != 0) {
            dup2(in, 0);
            ::close(in);
        }
        dup2(out_fd, 1);
        dup2(err_fd, 2);
        if (limits.address_space_bytes > 0) {
            const rlimit as{rlim_t(limits.address_space_bytes), rlim_t(limits.address_space_bytes)};
            if (setrlimit(RLIMIT_AS, &as) != 0) {
                const int e = errno;
                (void)!::write(report[1], &e, sizeof e);
                _exit(127);
            }
        }
        execv(program.c_str(), args.data());
        const int e = errno;
        (void)!::write(report[1], &e, sizeof e);
        _exit(127);
    }
    setpgid(pid, pid);  // also here: no window in which kill(-pid) misses it
    ::close(report[1]);
    int child_errno = 0;
    ssize_t got;
    while ((got = ::read(report[0], &child_errno, sizeof child_errno)) < 0 && errno == EINTR) {
    }
    ::close(report[0]);
    if (got == ssize_t(sizeof child_errno)) {
        int st = 0;
        while (waitpid(pid, &st, 0) < 0 && errno == EINTR) {
        }
        throw std::runtime_error("cannot start " + argv[0] + ": " + strerror(child_errno));
    }
    return pid;
}
}  // namespace

std::string ExitStatus::describe() const {
    if (exited) return "exited with status " + std::to_string(code);
    return "killed by signal " + std::to_string(signal) + " (" + strsignal(signal) + ")";
}

Subprocess::Subprocess(const std::vector<std::string>& argv, const SpawnLimits& limits) {
    if (argv.empty()) throw std::runtime_error("no command to run");
    int out[2], err[2];
    // O_CLOEXEC: the pipes of one worker must not leak into another worker.
    if (pipe2(out, O_CLOEXEC) != 0) throw std::runtime_error(std::string("pipe: ") + strerror(errno));
    if (pipe2(err, O_CLOEXEC) != 0) {
        ::close(out[0]);
        ::close(out[1]);
        throw std::runtime_error(std::string("pipe: ") + strerror(errno));
    }
    if (limits.address_space_bytes > 0) {
        try {
            pid_ = spawn_limited(argv, out[1], err[1], limits);
        } catch (...) {
            for (int fd : {out[0], out[1], err[0], err[1]}) ::close(fd);
            throw;
        }
        ::close(out[1]);
        ::close(err[1]);
        out_fd_ = out[0];
        err_fd_ = err[0];
        return;
    }
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_adddup2(&actions, out[1], 1);
    posix_spawn_file_actions_adddup2(&actions, err[1], 2);
    posix_spawnattr_t attr;
    posix_spawnattr_init(&attr);
    posix_spawnattr_setpgroup(&attr, 0);  // its own group: kill() reaches its children too
    // The server ignores SIGPIPE; the child should get the default back.
    sigset_t defaults;
    sigemptyset(&defaults);
    sigaddset(&defaults, SIGPIPE);
    sigaddset(&defaults, SIGTERM);
    sigaddset(&defaults, SIGINT);
    posix_spawnattr_setsigdefault(&attr, &defaults);
    sigset_t none;
    sigemptyset(&none);
    posix_spawnattr_setsigmask(&attr, &none);
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETPGROUP | POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);

    std::vector<char*> args;
    for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const int rc = posix_spawnp(&pid_, args[0], &actions, &attr, args.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    posix_spawnattr_destroy(&attr);
    ::close(out[1]);
    ::close(err[1]);
    if (rc != 0) {
        ::close(out[0]);
        ::close(err[0]);
        throw std::runtime_error("cannot start " + argv[0] + ": " + strerror(rc));
    }
    out_fd_ = out[0];
    err_fd_ = err[0];
}

Subprocess::~Subprocess() {
    if (!reaped_) {
        kill();
        wait();
    }
    close_fd(out_fd_);
    close_fd(err_fd_);
}

void Subprocess::drain_stderr() {
    char buf[4096];
    const ssize_t n = ::read(err_fd_, buf, sizeof buf);
    if (n <= 0) {
        close_fd(err_fd_);
        return;
    }
    stderr_.append(buf, size_t(n));
    if (stderr_.size() > 2 * kStderrKeep) stderr_.erase(0, stderr_.size() - kStderrKeep);
}

Subprocess::Read Subprocess::read_line(std::string& line, std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    for (;;) {
        const size_t nl = out_buffer_.find('\n');
        if (nl != std::string::npos) {
            line = out_buffer_.substr(0, nl);
            out_buffer_.erase(0, nl + 1);
            return Read::Line;
        }
        if (out_fd_ < 0) {
            if (out_buffer_.empty()) return Read::End;
            line.swap(out_buffer_);  // a last line without '\n'
            out_buffer_.clear();
            return Read::Line;
        }
        const auto left =
            std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
        if (left.count() <= 0) return Read::Timeout;
        pollfd fds[2] = {{out_fd_, POLLIN, 0}, {err_fd_, POLLIN, 0}};
        const int n = ::poll(fds, err_fd_ >= 0 ? 2 : 1, int(left.count()));
        if (n < 0 && errno != EINTR) return Read::End;
        if (n <= 0) continue;
        if (err_fd_ >= 0 && (fds[1].revents & (POLLIN | POLLHUP | POLLERR))) drain_stderr();
        if (fds[0].revents & (POLLIN | POLLHUP | POLLERR)) {
            char buf[8192];
            const ssize_t got = ::read(out_fd_, buf, sizeof buf);
            if (got <= 0) close_fd(out_fd_);
            else out_buffer_.append(buf, size_t(got));
        }
    }
}

void Subprocess::kill() {
    if (pid_ > 0 && !reaped_) ::kill(-pid_, SIGKILL);
}

void Subprocess::terminate() {
    if (pid_ > 0 && !reaped_) ::kill(-pid_, SIGTERM);
}

ExitStatus Subprocess::wait() {
    if (reaped_) return status_;
    // Drain stderr so a child blocked on a full pipe can finish.
    while (err_fd_ >= 0) {
        pollfd fd{err_fd_, POLLIN, 0};
        if (::poll(&fd, 1, 100) == 0) {
            int st = 0;
            if (waitpid(pid_, &st, WNOHANG) == pid_) {
                reaped_ = true;
                status_.exited = WIFEXITED(st);
                status_.code = WIFEXITED(st) ? WEXITSTATUS(st) : 0;
                status_.signal = WIFSIGNALED(st) ? WTERMSIG(st) : 0;
                // A grandchild may still hold stderr open; stop reading it.
                close_fd(err_fd_);
                return status_;
            }
            continue;
        }
        drain_stderr();
    }
    int st = 0;
    while (waitpid(pid_, &st, 0) < 0 && errno == EINTR) {
    }
    reaped_ = true;
    status_.exited = WIFEXITED(st);
    status_.code = WIFEXITED(st) ? WEXITSTATUS(st) : 0;
    status_.signal = WIFSIGNALED(st) ? WTERMSIG(st) : 0;
    return status_;
}

std::string Subprocess::stderr_last_line() const {
    size_t end = stderr_.size();
    while (end > 0) {
        while (end > 0 && (stderr_[end - 1] == '\n' || stderr_[end - 1] == '\r' || stderr_[end - 1] == ' ')) --end;
        if (end == 0) break;
        const size_t start = stderr_.rfind('\n', end - 1);
        const size_t from = start == std::string::npos ? 0 : start + 1;
        return stderr_.substr(from, end - from);
    }
    return "";
}

RunResult run_command(const std::vector<std::string>& argv, std::chrono::milliseconds timeout, size_t max_output,
                      const SpawnLimits& limits) {
    RunResult result;
    Subprocess child(argv, limits);
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    std::string line;
    for (;;) {
        const auto left =
            std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now());
        if (left.count() <= 0) {
            result.timed_out = true;
            child.kill();
            break;
        }
        const Subprocess::Read r = child.read_line(line, left);
        if (r == Subprocess::Read::End) break;
        if (r == Subprocess::Read::Line) {
            result.out += line + "\n";
            if (result.out.size() > max_output) {
                child.kill();
                break;
            }
        }
    }
    result.status = child.wait();
    result.err_last_line = child.stderr_last_line();
    return result;
}

}  // namespace lf::server
