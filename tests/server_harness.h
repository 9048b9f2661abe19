// Test helpers for the service: a temporary directory, a fake engine (a shell
// script standing in for `lightfarm` so crashes and hangs can be staged), and
// a real lightfarmd process on a loopback port with a real HTTP client.
#pragma once

#include "job_status.h"

#include <httplib.h>
#include <nlohmann/json.hpp>
#include <sys/types.h>

#include <chrono>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace lf::test {

namespace fs = std::filesystem;

struct TempDir {
    TempDir();
    ~TempDir();
    fs::path path;
};

void write_text(const fs::path& path, const std::string& text);
std::string read_text(const fs::path& path);

// A tiny EXR (w x h, constant colour) for the fake engine to hand out.
void write_exr(const fs::path& path, int w, int h, float r, float g, float b);

// A shell script that speaks the worker contract (protocol/worker_protocol.h):
// `bake SCENE --out DIR --json --spec SPEC [--device D]`, typed events with
// their output, done with "final". Its behaviour is read from files in its
// state directory at every run, so a test can change it:
//   mode     ok | crash_first (exit 1 once) | always_crash | hang_first | hang_always
//            | no_done | input_error (one stderr line naming the scene, exit 3)
//            | spec_unreadable_first (exit 4 once, as a worker whose spec was cut short)
//            | write_fails_first (exit 5 once, as a worker that could not write a file)
//   delay    seconds between passes (default 0)
//   snapshot_passes  e.g. "2048 16384": lightmap snapshots at exactly these passes
//   runs     incremented at every `bake` (how many workers were started)
//   gate     while this file exists, a worker waits after counting its run,
//            before its first event
//   last_spec.json, last_args, all_args: what the last worker was given
// Passes come from the spec's lightmap "passes" (default 4); a spec with an
// "sh" output also gets an SH snapshot (sh_transfer.pass-0001.bin) and final
// file (scene.sh.glb).
// `inspect` prints the file `summary` verbatim when there is one, else a
// summary with a light and lightmap UVs: {"source", "triangles": N (N from the
// file `triangles`, default 12), "emissive_triangles": 2, ...}; it fails with
// "not a glTF" for files containing the word BROKEN.
struct FakeEngine {
    explicit FakeEngine(const fs::path& dir);
    void set(const std::string& name, const std::string& value) const { write_text(dir / name, value); }
    int runs() const;
    fs::path dir;
    fs::path script;
};

// A lightfarmd process, for any harness that runs one: started with `args`
// (after the binary) and its output in `log`; ready once `ready()` holds
// (polled for up to 15 s; throws with the log when the process exits first
// or never gets there); stopped with SIGTERM, then SIGKILL after 5 s; or
// killed at once, as a crash. The pid is -1 once it is gone.
// `environment`: "NAME=VALUE" settings over this process's own.
pid_t spawn_lightfarmd(std::vector<std::string> args, const fs::path& log,
                       const std::vector<std::string>& environment = {});
void wait_until_ready(pid_t& pid, const fs::path& log, const std::function<bool()>& ready);
void stop_process(pid_t& pid);
void kill_process(pid_t& pid);
// GET /healthz on 127.0.0.1:port answers 200.
bool answers_health(int port);

// lightfarmd on 127.0.0.1 with a free port, its log in DATA/../lightfarmd-N.log.
class Lightfarmd {
public:
    // `extra`: more arguments; `environment`: "NAME=VALUE" settings over this process's own.
    Lightfarmd(fs::path data, fs::path tokens, fs::path engine, std::vector<std::string> extra = {},
               std::vector<std::string> environment = {});
    ~Lightfarmd();  // stop()
    void start();   // waits (bounded) until it answers /healthz
    void stop();    // SIGTERM, then SIGKILL after a few seconds
    void kill9();   // SIGKILL, as a crash
    // Sends `sig` (SIGTERM: a stop asked again) and waits up to `seconds`
    // for lightfarmd to exit by itself: true once it has (then it is gone).
    bool signal_and_wait(int sig, double seconds);
    bool running() const { return pid_ > 0; }
    pid_t pid() const { return pid_; }
    std::string log() const;

    std::string url;
    std::string host = "127.0.0.1";
    int port = 0;
    httplib::Client client(const std::string& token) const;

private:
    fs::path data_, tokens_, engine_;
    std::vector<std::string> extra_, environment_;
    pid_t pid_ = -1;
    int starts_ = 0;
};

using Headers = httplib::Headers;
Headers bearer(const std::string& token);

// Polls GET /v1/jobs/{id} until `pred` holds or `timeout` passes; returns the last status.
nlohmann::json wait_for_job(httplib::Client& c, const std::string& id,
                            const std::function<bool(const nlohmann::json&)>& pred,
                            std::chrono::milliseconds timeout = std::chrono::seconds(20));
inline bool is_finished(const nlohmann::json& s) {
    const std::string st = s.value("state", "");
    return st == "succeeded" || st == "failed" || st == "cancelled";
}

// Reads the event stream of a job (optionally from Last-Event-ID) until its
// final event or `timeout`; `stop_after` > 0 stops after that many events.
std::vector<protocol::JobEvent> read_events(const std::string& host, int port, const std::string& token,
                                            const std::string& id, int64_t last_event_id = -1, size_t stop_after = 0,
                                            std::chrono::milliseconds timeout = std::chrono::seconds(20));

}  // namespace lf::test
