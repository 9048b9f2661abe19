#include "supervisor.h"

#include "log.h"
#include "subprocess.h"

#include <signal.h>

#include <chrono>
#include <fstream>
#include <sstream>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

namespace {
// A worker's pid, kept in its job directory (hidden from the artifacts by the
// leading dot) so that a restarted lightfarmd can end a worker its
// predecessor left behind before running the job again.
constexpr const char* kPidFile = ".worker.pid";

void kill_leftover_worker(const fs::path& dir) {
    std::ifstream in(dir / kPidFile);
    pid_t pid = 0;
    if (!(in >> pid) || pid <= 1) return;
    // Only if that pid still runs a bake into this very directory.
    std::ifstream cmdline("/proc/" + std::to_string(pid) + "/cmdline");
    std::string args((std::istreambuf_iterator<char>(cmdline)), std::istreambuf_iterator<char>());
    if (args.find(dir.string()) != std::string::npos) {
        ::kill(-pid, SIGKILL);
        log_line("killed worker " + std::to_string(pid) + " left running in " + dir.string());
    }
}

std::optional<double> number_field(const json& j, const char* key) {
    if (j.contains(key) && j[key].is_number()) return j[key].get<double>();
    return std::nullopt;
}

// A file name the worker reported must stay inside its output directory.
bool plain_file_name(const std::string& name) {
    return !name.empty() && name.find('/') == std::string::npos && name != "." && name != ".." && name[0] != '.';
}
}  // namespace

Supervisor::Supervisor(JobStore& store, const ServerConfig& config, ChangeSignal& changes, Metrics& metrics)
    : store_(store), config_(config), changes_(changes), metrics_(metrics), engine_(find_engine(config.engine)) {}

Supervisor::~Supervisor() { stop(); }

fs::path Supervisor::job_dir(const std::string& job_id) const { return fs::path(config_.data_dir) / "jobs" / job_id; }

fs::path Supervisor::scene_path(const SceneRecord& scene) const {
    return fs::path(config_.data_dir) / "scenes" / scene.id / scene.main_file;
}

void Supervisor::start() {
    for (const JobRecord& job : store_.running_jobs()) {
        const std::string& id = job.status.id;
        kill_leftover_worker(job_dir(id));
        const std::string cause = "lightfarmd stopped during attempt " + std::to_string(job.status.attempts);
        if (job.status.attempts >= job.status.max_attempts) {
            store_.finish(id, JobState::Failed, "bake failed after " + std::to_string(job.status.attempts) + " attempts",
                          cause, {0, "failed", {{"error", "bake failed"}, {"cause", cause}, {"attempts", job.status.attempts}}});
        } else {
            store_.requeue(id, {0, "retrying", {{"attempt", job.status.attempts}, {"cause", cause}}}, false);
        }
        log_line("job " + id + ": " + cause + ", " +
                 (job.status.attempts >= job.status.max_attempts ? "no attempt left" : "queued again"));
    }
    // One worker per GPU, each pinned to its own (--device gpu:N); one on a
    // machine without a GPU. --workers N overrides the count.
    const int gpus = count_gpus();
    const int workers = config_.workers > 0 ? config_.workers : std::max(1, gpus);
    log_line("engine: " + engine_ + ", " + std::to_string(gpus) + " GPU(s), " + std::to_string(workers) + " worker(s)");
    for (int i = 0; i < workers; ++i) {
        const std::string device = gpus > 0 ? "gpu:" + std::to_string(i % gpus) : "";
        threads_.emplace_back([this, device] { worker_loop(device); });
    }
}

int Supervisor::count_gpus() const {
    // The server knows nothing of GL: the engine says what devices there are.
    const RunResult r = run_command({engine_, "devices", "--json"}, std::chrono::seconds(30));
    if (!r.status.success()) {
        log_line("engine devices: " + (r.timed_out ? std::string("timed out") : r.status.describe()) +
                 "; assuming no GPU");
        return 0;
    }
    try {
        return json::parse(r.out).value("gpus", 0);
    } catch (const std::exception&) {
        log_line("engine devices: unreadable answer; assuming no GPU");
        return 0;
    }
}

void Supervisor::stop() {
    if (stopping_.exchange(true)) return;
    changes_.notify();
    for (std::thread& t : threads_) t.join();
    threads_.clear();
}

void Supervisor::cancel(const std::string& job_id) {
    std::lock_guard lock(cancel_mutex_);
    cancelled_.insert(job_id);
}

void Supervisor::worker_loop(const std::string& device) {
    while (!stopping_) {
        const uint64_t seen = changes_.generation();
        std::optional<JobRecord> job;
        try {
            job = store_.claim_next();
        } catch (const std::exception& e) {
            log_line(std::string("cannot read the queue: ") + e.what());
        }
        if (!job) {
            changes_.wait(seen, std::chrono::seconds(1));
            continue;
        }
        changes_.notify();
        try {
            run_attempt(*job, device);
        } catch (const std::exception& e) {
            // The server's own trouble (disk full, store error) still ends the
            // attempt cleanly rather than leaving the job running forever.
            log_line("job " + job->status.id + ": " + e.what());
            attempt_failed(*job, std::string("lightfarmd: ") + e.what());
        }
        {
            std::lock_guard lock(cancel_mutex_);
            cancelled_.erase(job->status.id);
        }
        metrics_.clear_job(job->status.id);
        changes_.notify();
    }
}

void Supervisor::attempt_failed(const JobRecord& job, const std::string& cause) {
    const std::string& id = job.status.id;
    ++metrics_.worker_failures;
    const int attempts = job.status.attempts;
    if (attempts < job.status.max_attempts) {
        log_line("job " + id + ": attempt " + std::to_string(attempts) + " failed (" + cause + "), retrying");
        store_.requeue(id, {0, "retrying", {{"attempt", attempts}, {"cause", cause}}}, false);
    } else {
        const std::string error = "bake failed after " + std::to_string(attempts) + " attempt" + (attempts == 1 ? "" : "s");
        log_line("job " + id + ": " + error + ": " + cause);
        store_.finish(id, JobState::Failed, error, cause,
                      {0, "failed", {{"error", error}, {"cause", cause}, {"attempts", attempts}}});
    }
}

void Supervisor::run_attempt(const JobRecord& job, const std::string& device) {
    const std::string& id = job.status.id;
    const protocol::JobSpec spec = protocol::parse_job_spec(job.status.spec, config_.limits.spec);
    const std::optional<SceneRecord> scene = store_.scene(spec.scene);
    if (!scene) {
        store_.finish(id, JobState::Failed, "scene " + spec.scene + " is missing", "",
                      {0, "failed", {{"error", "scene " + spec.scene + " is missing"}, {"cause", ""}, {"attempts", job.status.attempts}}});
        return;
    }
    const fs::path dir = job_dir(id);
    fs::create_directories(dir);

    std::vector<std::string> argv = {engine_, "bake", scene_path(*scene).string(), "--out", dir.string(), "--json"};
    for (std::string& a : protocol::bake_arguments(spec)) argv.push_back(std::move(a));
    if (!device.empty()) {
        argv.push_back("--device");
        argv.push_back(device);
    }
    // ETA follows the stopping rules of the first output asked for.
    const json settings = spec.outputs.begin()->second;

    ++metrics_.worker_starts;
    std::unique_ptr<Subprocess> child;
    try {
        child = std::make_unique<Subprocess>(argv);
    } catch (const std::exception& e) {
        attempt_failed(job, e.what());
        return;
    }
    std::ofstream(dir / kPidFile) << child->pid() << "\n";
    log_line("job " + id + ": attempt " + std::to_string(job.status.attempts) + ", worker " + std::to_string(child->pid()));

    const auto started = Clock::now();
    const auto deadline = started + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(job.max_seconds));
    const auto stall = std::chrono::duration<double>(config_.stall_seconds);
    auto last_output = started;
    uint64_t rays_seen = 0;
    std::optional<json> done;
    std::string cause;  // set when we end the worker ourselves
    bool cancelled = false;

    for (std::string line;;) {
        if (stopping_) {
            child->kill();
            child->wait();
            store_.requeue(id, {0, "retrying", {{"attempt", job.status.attempts}, {"cause", "lightfarmd stopped"}}}, true);
            return;
        }
        {
            std::lock_guard lock(cancel_mutex_);
            cancelled = cancelled_.count(id) > 0;
        }
        if (cancelled) {
            child->kill();
            break;
        }
        const Subprocess::Read r = child->read_line(line, std::chrono::milliseconds(200));
        const auto now = Clock::now();
        if (r == Subprocess::Read::End) break;
        if (r == Subprocess::Read::Timeout) {
            if (now > deadline) {
                std::ostringstream s;
                s << "worker ran past the job's deadline of " << job.max_seconds << " s and was killed";
                cause = s.str();
            } else if (now - last_output > stall) {
                std::ostringstream s;
                s << "worker printed nothing for " << config_.stall_seconds << " s (hung) and was killed";
                cause = s.str();
            }
            if (!cause.empty()) {
                child->kill();
                break;
            }
            continue;
        }
        last_output = now;

        const json msg = json::parse(line, nullptr, false);
        if (!msg.is_object() || !msg.contains("event") || !msg["event"].is_string()) {
            log_line("job " + id + ": ignoring worker output: " + line.substr(0, 200));
            continue;
        }
        const std::string event = msg["event"];
        if (event == "start") {
            json data = msg;
            data.erase("event");
            data["attempt"] = job.status.attempts;
            store_.append_event(id, {0, "started", data});
        } else if (event == "progress" || event == "done") {
            Progress p;
            p.pass = int(number_field(msg, "pass").value_or(0));
            p.rays = uint64_t(number_field(msg, "rays").value_or(0));
            p.seconds = number_field(msg, "seconds").value_or(0);
            p.error_estimate = number_field(msg, "error_estimate");
            if (event == "progress") p.eta_seconds = protocol::estimate_eta(settings, p);
            else p.eta_seconds = 0.0;
            metrics_.rays_total += p.rays >= rays_seen ? p.rays - rays_seen : p.rays;
            rays_seen = p.rays;
            if (p.seconds > 0) metrics_.set_job_rate(id, double(p.rays) / p.seconds);
            store_.set_progress(id, p);
            if (event == "progress") {
                store_.append_event(id, {0, "progress", protocol::to_json(p)});
            } else {
                json data = protocol::to_json(p);
                data["files"] = msg.contains("files") ? msg["files"] : json::array();
                done = data;
            }
        } else if (event == "snapshot") {
            const std::string file = msg.value("file", "");
            if (!plain_file_name(file)) {
                log_line("job " + id + ": ignoring snapshot with a bad file name: " + line.substr(0, 200));
                continue;
            }
            store_.append_event(id, {0, "snapshot", {{"file", file}, {"pass", msg.value("pass", 0)},
                                                     {"url", "/v1/jobs/" + id + "/artifacts/" + file}}});
        }
        changes_.notify();
    }

    const ExitStatus status = child->wait();
    std::error_code ec;
    fs::remove(dir / kPidFile, ec);
    if (cancelled) {
        log_line("job " + id + ": cancelled, worker killed");
        return;  // the cancel route already recorded the final state
    }
    if (cause.empty()) {
        if (status.success() && done) {
            (*done)["cached"] = false;
            store_.finish(id, JobState::Succeeded, "", "", {0, "done", *done});
            log_line("job " + id + ": succeeded");
            return;
        }
        cause = status.success() ? "worker exited without reporting done" : "worker " + status.describe();
        const std::string last = child->stderr_last_line();
        if (!last.empty()) cause += ": " + last;
    }
    attempt_failed(job, cause);
}

}  // namespace lf::server
