#include "server_harness.h"

#include <OpenEXR/ImfArray.h>
#include <OpenEXR/ImfRgbaFile.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>

extern char** environ;

namespace lf::test {

using nlohmann::json;

// A server may answer before it has read a request's body (a 413, a 401): a
// client still writing then gets EPIPE. Like lightfarmd (server/main.cpp),
// every test that links this harness takes that as a failed call it can
// report, not as a SIGPIPE that ends the test binary with no message.
const bool kSigpipeIgnored = [] {
    signal(SIGPIPE, SIG_IGN);
    return true;
}();

TempDir::TempDir() {
    std::random_device rd;
    path = fs::temp_directory_path() / ("lightfarm-test-" + std::to_string(getpid()) + "-" + std::to_string(rd()));
    fs::create_directories(path);
}

TempDir::~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
}

void write_text(const fs::path& path, const std::string& text) {
    fs::create_directories(path.parent_path());
    std::ofstream(path, std::ios::binary) << text;
}

std::string read_text(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void write_exr(const fs::path& path, int w, int h, float r, float g, float b) {
    std::vector<Imf::Rgba> pixels(size_t(w) * size_t(h), Imf::Rgba(r, g, b, 1.0f));
    Imf::RgbaOutputFile file(path.c_str(), w, h, Imf::WRITE_RGBA);
    file.setFrameBuffer(pixels.data(), 1, size_t(w));
    file.writePixels(h);
}

namespace {
// The fake `lightfarm`. Plain POSIX sh; files appear by temp + rename as the
// real engine's do.
constexpr const char* kFakeEngine = R"sh(#!/bin/sh
state="$(dirname "$0")"
cmd="$1"; shift
if [ "$cmd" = inspect ]; then
  echo "$1" >> "$state/inspects"
  if grep -q BROKEN "$1"; then echo "lightfarm inspect: error: $1: not a glTF" >&2; exit 1; fi
  if grep -q SEGV "$1"; then kill -SEGV $$; fi
  if [ -f "$state/summary" ]; then cat "$state/summary"; exit 0; fi
  echo "{\"source\": \"$(basename "$1")\", \"triangles\": $(cat "$state/triangles" 2>/dev/null || echo 12), \"textures\": [],"\
       "\"emissive_triangles\": 2, \"punctual_light_count\": 0, \"max_texture_size\": 0,"\
       "\"has_lightmap_uvs\": true, \"min_atlas_res\": 0}"
  exit 0
fi
if [ "$cmd" = devices ]; then
  echo "{\"gpus\": $(cat "$state/gpus" 2>/dev/null || echo 0)}"
  exit 0
fi
[ "$cmd" = bake ] || { echo "fake lightfarm: unknown command $cmd" >&2; exit 2; }
echo "$@" > "$state/last_args"
echo "$@" >> "$state/all_args"
scene="$1"; shift
out=""; passes=4; spec=""; resume=no
while [ $# -gt 0 ]; do
  case "$1" in
    --out) out="$2"; shift 2;;
    --resume) resume=yes; shift;;
    --passes) passes="$2"; shift 2;;
    --spec) spec="$2"; shift 2;;
    *) shift;;
  esac
done
with_sh=no
if [ -n "$spec" ]; then
  cp "$spec" "$state/last_spec.json"
  # The spec is canonical JSON on one line: outputs.lightmap.passes is the only "passes" key.
  p=$(grep -o '"passes":[0-9]*' "$spec" | head -n 1 | cut -d: -f2)
  [ -n "$p" ] && passes=$p
  grep -q '"sh":{' "$spec" && with_sh=yes
fi
runs=$(( $(cat "$state/runs" 2>/dev/null || echo 0) + 1 ))
echo $runs > "$state/runs.tmp" && mv "$state/runs.tmp" "$state/runs"
while [ -f "$state/gate" ]; do sleep 0.02; done
mode=$(cat "$state/mode" 2>/dev/null || echo ok)
delay=$(cat "$state/delay" 2>/dev/null || echo 0)
# As the engine does: a state saved with each snapshot, which --resume continues from.
from=0
[ $resume = yes ] && [ -f "$out/.resume/lightmap.state" ] && from=$(cat "$out/.resume/lightmap.state")
resumed=""
[ "$from" -gt 0 ] && resumed=",\"resumed\":{\"lightmap\":{\"pass\":$from,\"rays\":$((from * 1000))}}"
echo "{\"event\":\"start\",\"renderer\":\"fake\",\"vendor\":\"tests\",\"triangles\":12,\"prepare_seconds\":0,\"outputs\":{}$resumed}"
case "$mode" in
  crash_first) if [ $runs -eq 1 ]; then echo "lightfarm bake: error: lost the GPU context" >&2; exit 1; fi;;
  always_crash) echo "lightfarm bake: error: about to die" >&2
                # Killed mid-write, as the engine names its temporaries (protocol::temporary_file_name).
                echo half > "$out/.lightmap.exr.tmp-$$"; mkdir -p "$out/.resume"; echo half > "$out/.resume/.lightmap.state.tmp-$$"
                kill -KILL $$;;
  hang_first) if [ $runs -eq 1 ]; then sleep 60; fi;;
  hang_always) sleep 60;;
  input_error) echo "lightfarm bake: error: $scene: nothing to bake: no emissive surface (spec $spec)" >&2; exit 3;;
  spec_unreadable_first) if [ $runs -eq 1 ]; then echo "lightfarm: --spec $spec is not whole JSON (empty, or cut short)" >&2; exit 4; fi;;
  write_fails_first) if [ $runs -eq 1 ]; then echo "lightfarm bake: error: $out/lightmap.exr: cannot write (No space left on device)" >&2; exit 5; fi;;
esac
snap() {  # snap OUTPUT FILE PASS
  cp "$state/snapshot.exr" "$out/.$2.tmp" && mv "$out/.$2.tmp" "$out/$2"
  if [ "$1" = lightmap ]; then
    mkdir -p "$out/.resume" && echo "$3" > "$out/.resume/.state.tmp" && mv "$out/.resume/.state.tmp" "$out/.resume/lightmap.state"
  fi
  echo "{\"event\":\"snapshot\",\"output\":\"$1\",\"file\":\"$2\",\"pass\":$3}"
}
progress() {  # progress OUTPUT PASS
  echo "{\"event\":\"progress\",\"output\":\"$1\",\"pass\":$2,\"rays\":$(($2 * 1000)),\"seconds\":$2,\"error_estimate\":$((100 / $2))}"
}
if [ -f "$state/snapshot_passes" ]; then
  # Snapshots at the passes listed, named as the engine names them (%04d: pass-2048, pass-16384).
  for p in $(cat "$state/snapshot_passes"); do
    progress lightmap $p
    snap lightmap "$(printf 'lightmap.pass-%04d.exr' $p)" $p
    passes=$p
  done
else
  p=$((from + 1))
  # As the engine does on SIGTERM (a cancel): one last snapshot of the pass it stands at, then exit 6.
  # (Its progress again: a trap may run between any two commands.)
  [ "$mode" = snapshot_on_term ] &&
    trap 'progress lightmap $last; snap lightmap "$(printf "lightmap.pass-%04d.exr" $last)" $last; exit 6' TERM
  last=$from
  while [ $p -le $passes ]; do
    [ "$delay" = 0 ] || sleep "$delay"
    last=$p
    progress lightmap $p
    case $p in 1|2|4|8|16|32|64) snap lightmap "$(printf 'lightmap.pass-%04d.exr' $p)" $p;; esac
    p=$((p + 1))
  done
fi
if [ $with_sh = yes ]; then
  progress sh 1
  snap sh sh_transfer.pass-0001.bin 1
fi
[ "$mode" = no_done ] && exit 0
rm -rf "$out/.resume"
cp "$state/snapshot.exr" "$out/.lightmap.exr.tmp" && mv "$out/.lightmap.exr.tmp" "$out/lightmap.exr"
# As the engine's: the scene named by the file it baked.
echo "{\"scene\": \"$(basename "$scene")\", \"passes\": $passes}" > "$out/.manifest.json.tmp" && mv "$out/.manifest.json.tmp" "$out/manifest.json"
final="\"lightmap\":\"lightmap.exr\""
files="\"lightmap.exr\",\"manifest.json\""
if [ $with_sh = yes ]; then
  cp "$state/snapshot.exr" "$out/.scene.sh.glb.tmp" && mv "$out/.scene.sh.glb.tmp" "$out/scene.sh.glb"
  final="$final,\"sh\":\"scene.sh.glb\""
  files="\"lightmap.exr\",\"manifest.json\",\"scene.sh.glb\""
fi
echo "{\"event\":\"done\",\"files\":[$files],\"final\":{$final},\"pass\":$passes,\"rays\":$((passes * 1000)),\"seconds\":$passes,\"error_estimate\":1}"
)sh";
}  // namespace

FakeEngine::FakeEngine(const fs::path& d) : dir(d), script(d / "lightfarm") {
    write_text(script, kFakeEngine);
    fs::permissions(script, fs::perms::owner_all);
    write_exr(dir / "snapshot.exr", 8, 4, 0.5f, 0.25f, 0.125f);
}

int FakeEngine::runs() const {
    const std::string text = read_text(dir / "runs");
    return text.empty() ? 0 : std::stoi(text);
}

Lightfarmd::Lightfarmd(fs::path data, fs::path tokens, fs::path engine, std::vector<std::string> extra,
                       std::vector<std::string> environment)
    : data_(std::move(data)),
      tokens_(std::move(tokens)),
      engine_(std::move(engine)),
      extra_(std::move(extra)),
      environment_(std::move(environment)) {}

Lightfarmd::~Lightfarmd() { stop(); }

pid_t spawn_lightfarmd(std::vector<std::string> args, const fs::path& log,
                       const std::vector<std::string>& environment) {
    args.insert(args.begin(), LIGHTFARMD);
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    // environ, less each name `environment` sets, then `environment`.
    std::vector<std::string> settings;
    for (char** e = environ; *e; ++e) {
        const std::string setting = *e, name = setting.substr(0, setting.find('=') + 1);
        bool overridden = false;
        for (const std::string& s : environment) overridden |= s.rfind(name, 0) == 0;
        if (!overridden) settings.push_back(setting);
    }
    settings.insert(settings.end(), environment.begin(), environment.end());
    std::vector<char*> envp;
    for (std::string& s : settings) envp.push_back(s.data());
    envp.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&actions, 1, 2);
    pid_t pid = -1;
    const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), envp.data());
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) throw std::runtime_error(std::string("cannot start ") + LIGHTFARMD + ": " + std::strerror(rc));
    return pid;
}

void wait_until_ready(pid_t& pid, const fs::path& log, const std::function<bool()>& ready) {
    for (const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(15);
         std::chrono::steady_clock::now() < deadline; std::this_thread::sleep_for(std::chrono::milliseconds(20))) {
        if (ready()) return;
        int status = 0;
        if (waitpid(pid, &status, WNOHANG) == pid) {
            pid = -1;
            const std::string how = WIFSIGNALED(status) ? std::string("killed by ") + strsignal(WTERMSIG(status))
                                                        : "exit " + std::to_string(WEXITSTATUS(status));
            throw std::runtime_error("lightfarmd exited at start (" + how + "):\n" + read_text(log));
        }
    }
    throw std::runtime_error("lightfarmd did not come up in 15 s:\n" + read_text(log));
}

void stop_process(pid_t& pid) {
    if (pid <= 0) return;
    ::kill(pid, SIGTERM);
    for (int i = 0; i < 500; ++i) {
        int status = 0;
        if (waitpid(pid, &status, WNOHANG) == pid) {
            pid = -1;
            return;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    kill_process(pid);
}

void kill_process(pid_t& pid) {
    if (pid <= 0) return;
    ::kill(pid, SIGKILL);
    int status = 0;
    waitpid(pid, &status, 0);
    pid = -1;
}

bool answers_health(int port) {
    httplib::Client c("127.0.0.1", port);
    c.set_connection_timeout(1);
    auto r = c.Get("/healthz");
    return r && r->status == 200;
}

void Lightfarmd::start() {
    if (pid_ > 0) throw std::runtime_error("lightfarmd already running");
    fs::create_directories(data_);
    std::error_code ec;
    fs::remove(data_ / "lightfarmd.url", ec);
    std::vector<std::string> args = {"--listen", "127.0.0.1:0",    "--data",   data_.string(),
                                     "--tokens", tokens_.string(), "--engine", engine_.string()};
    args.insert(args.end(), extra_.begin(), extra_.end());
    const fs::path log = data_.parent_path() / ("lightfarmd-" + std::to_string(++starts_) + ".log");
    pid_ = spawn_lightfarmd(args, log, environment_);
    // The URL file, then /healthz.
    wait_until_ready(pid_, log, [&] {
        const std::string text = read_text(data_ / "lightfarmd.url");
        if (text.empty()) return false;
        url = text.substr(0, text.find('\n'));
        port = std::stoi(url.substr(url.rfind(':') + 1));
        return answers_health(port);
    });
}

void Lightfarmd::stop() { stop_process(pid_); }

void Lightfarmd::kill9() { kill_process(pid_); }

bool Lightfarmd::signal_and_wait(int sig, double seconds) {
    if (pid_ <= 0) return true;
    ::kill(pid_, sig);
    for (const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);;) {
        int status = 0;
        if (waitpid(pid_, &status, WNOHANG) == pid_) {
            pid_ = -1;
            return true;
        }
        if (std::chrono::steady_clock::now() >= end) return false;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
}

std::string Lightfarmd::log() const {
    std::string all;
    for (int i = 1; i <= starts_; ++i)
        all += read_text(data_.parent_path() / ("lightfarmd-" + std::to_string(i) + ".log"));
    return all;
}

httplib::Client Lightfarmd::client(const std::string& token) const {
    httplib::Client c(host, port);
    c.set_connection_timeout(2);
    c.set_read_timeout(10);
    if (!token.empty()) c.set_default_headers(bearer(token));
    return c;
}

Headers bearer(const std::string& token) { return {{"Authorization", "Bearer " + token}}; }

json wait_for_job(httplib::Client& c, const std::string& id, const std::function<bool(const json&)>& pred,
                  std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    json last;
    while (std::chrono::steady_clock::now() < deadline) {
        auto r = c.Get("/v1/jobs/" + id);
        if (r && r->status == 200) {
            last = json::parse(r->body);
            if (pred(last)) return last;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(25));
    }
    return last;
}

std::vector<protocol::JobEvent> read_events(const std::string& host, int port, const std::string& token,
                                            const std::string& id, int64_t last_event_id, size_t stop_after,
                                            std::chrono::milliseconds timeout) {
    httplib::Client c(host, port);
    c.set_connection_timeout(2);
    c.set_read_timeout(std::chrono::duration_cast<std::chrono::seconds>(timeout).count() + 1);
    Headers headers = bearer(token);
    if (last_event_id >= 0) headers.emplace("Last-Event-ID", std::to_string(last_event_id));
    protocol::SseParser parser;
    std::vector<protocol::JobEvent> events;
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    c.Get("/v1/jobs/" + id + "/events", headers, [&](const char* data, size_t n) {
        for (protocol::JobEvent& e : parser.feed(std::string(data, n))) {
            events.push_back(e);
            if (protocol::is_final_event(e.type)) return false;
            if (stop_after > 0 && events.size() >= stop_after) return false;
        }
        return std::chrono::steady_clock::now() < deadline;
    });
    return events;
}

}  // namespace lf::test
