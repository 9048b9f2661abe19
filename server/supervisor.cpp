#include "supervisor.h"

#include "data_dir.h"
#include "disk_space.h"

#include "log.h"
#include "subprocess.h"

#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <variant>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = Supervisor::Clock;

namespace {
// A worker's pid and its node's name ("PID NODE"), kept in its job directory
// (hidden from the artifacts by the leading dot) so that a restarted
// lightfarmd can end a worker its predecessor left behind before running the
// job again. On a shared data directory a pid means something only on the
// node that wrote it.
constexpr const char* kPidFile = ".worker.pid";
// The job's spec as the worker reads it (`--spec`), hidden the same way.
constexpr const char* kSpecFile = ".spec.json";
// Where a job whose owner named the scene otherwise finds it under that name
// (Supervisor::scene_path), hidden the same way.
constexpr const char* kSceneLinkDir = ".scene";

void kill_leftover_worker(const fs::path& dir, const std::string& this_node) {
    std::ifstream in(dir / kPidFile);
    pid_t pid = 0;
    if (!(in >> pid) || pid <= 1) return;
    std::string node;
    if (in >> node && node != this_node) return;  // another machine's process
    // Only if that pid still runs a bake into this very directory.
    std::ifstream cmdline("/proc/" + std::to_string(pid) + "/cmdline");
    std::string args((std::istreambuf_iterator<char>(cmdline)), std::istreambuf_iterator<char>());
    if (args.find(dir.string()) != std::string::npos) {
        ::kill(-pid, SIGKILL);
        log_line("killed worker " + std::to_string(pid) + " left running in " + dir.string());
    }
}

// "lightmap pass 40 (lightmap.pass-0040.exr), …" for the log.
std::string snapshots_text(const std::map<std::string, LatestFile>& latest) {
    std::string what;
    for (const auto& [output, file] : latest)
        what += (what.empty() ? "" : ", ") + output + " pass " + std::to_string(file.pass) + " (" + file.file + ")";
    return what;
}

// "stopped 0.31 s after SIGTERM" for the log.
std::string grace_text(bool ended, double after) {
    char seconds[32];
    std::snprintf(seconds, sizeof seconds, "%.2f", after);
    return std::string(ended ? "stopped" : "was given") + " " + seconds + " s after SIGTERM";
}

// A file name the worker reported must stay inside its output directory.
bool plain_file_name(const std::string& name) {
    return !name.empty() && name.find('/') == std::string::npos && name != "." && name != ".." && name[0] != '.';
}
}  // namespace

Supervisor::Supervisor(JobStore& store, const ServerConfig& config, ChangeSignal& changes, Metrics& metrics)
    : store_(store), config_(config), changes_(changes), metrics_(metrics), engine_(find_engine(config.engine)) {}

Supervisor::~Supervisor() { stop(); }

fs::path Supervisor::job_dir(const std::string& job_id) const { return DataDir(config_.data_dir).job(job_id); }

fs::path Supervisor::scene_path(const SceneRecord& scene, const std::string& job_id) const {
    const fs::path stored = DataDir(config_.data_dir).scene(scene.id) / scene.main_file;
    if (scene.name.empty() || scene.name == scene.main_file) return stored;
    return job_dir(job_id) / kSceneLinkDir / scene.name;
}

void Supervisor::start() {
    std::lock_guard lock(lifecycle_mutex_);
    if (stopping_) return;  // stopped before it started
    compact_events();
    end_abandoned_attempts(store_.take_over_abandoned(/*at_start=*/true));
    // Workers take the GPUs in turn (--device gpu:N): two per GPU, one on a
    // machine without a GPU (worker_count).
    const int gpus = count_gpus();
    const int workers = worker_count(config_, gpus);
    log_line("engine: " + engine_ + ", " + std::to_string(gpus) + " GPU(s), " + std::to_string(workers) + " worker(s)");
    node_info_ = {{"gpus", gpus}, {"workers", workers}, {"lease_seconds", store_.node().lease_seconds}};
    heartbeat();
    for (int i = 0; i < workers; ++i) {
        const std::string device = gpus > 0 ? "gpu:" + std::to_string(i % gpus) : "";
        threads_.emplace_back([this, device] { worker_loop(device); });
    }
    threads_.emplace_back([this] { lease_loop(); });
}

void Supervisor::end_abandoned_attempts(const std::vector<JobRecord>& jobs) {
    const std::string& self = store_.node().name;
    for (const JobRecord& job : jobs) {
        const std::string& id = job.status.id;
        const std::string attempt = std::to_string(job.status.attempts);
        const bool ours = job.node == self || job.node.empty();
        if (ours) kill_leftover_worker(job_dir(id), self);
        const std::string cause = ours ? "lightfarmd stopped during attempt " + attempt
                                       : "node " + job.node + " stopped renewing its lease during attempt " + attempt;
        const bool last = job.status.attempts >= job.status.max_attempts;
        if (last) {
            const std::string error = "bake failed after " + attempt + " attempts";
            store_.finish(id, JobState::Failed, error, cause,
                          protocol::job_event(protocol::JobFailed{error, cause, job.status.attempts}));
        } else {
            store_.requeue(id, protocol::job_event(protocol::JobRetrying{job.status.attempts, cause}), false);
        }
        log_line("job " + id + ": " + cause + ", " + (last ? "no attempt left" : "queued again"));
    }
    if (!jobs.empty()) changes_.notify();
}

Supervisor::RunningHere::RunningHere(Supervisor& supervisor, std::string job_id)
    : s(supervisor), id(std::move(job_id)) {
    std::lock_guard lock(s.cancel_mutex_);
    s.running_here_.insert(id);
}

Supervisor::RunningHere::~RunningHere() {
    std::lock_guard lock(s.cancel_mutex_);
    s.running_here_.erase(id);
    s.lost_.erase(id);
}

void Supervisor::heartbeat() {
    try {
        store_.heartbeat(node_info_);
    } catch (const StoreError& e) {
        store_trouble(std::string("node heartbeat: ") + e.what());
    }
}

void Supervisor::keep_leases() {
    heartbeat();
    std::vector<std::string> running;
    {
        std::lock_guard lock(cancel_mutex_);
        running.assign(running_here_.begin(), running_here_.end());
    }
    for (const std::string& id : running) {
        try {
            if (!store_.renew_lease(id)) {
                std::lock_guard lock(cancel_mutex_);
                lost_.insert(id);
            }
        } catch (const StoreError& e) {
            // The worker bakes on: the lease is renewed when the store is back,
            // unless it expired meanwhile and another node took the job.
            store_trouble("job " + id + ": cannot renew its lease: " + e.what());
        }
    }
    try {
        end_abandoned_attempts(store_.take_over_abandoned(/*at_start=*/false));
        requeue_unrun_claims();
    } catch (const StoreError& e) {
        store_trouble(std::string("cannot look for jobs of lost nodes: ") + e.what());
    }
}

// A claim whose commit was cut off (the database crashed as it committed:
// a PANIC on a WAL it could not sync) failed here but may be stored all the
// same: the job then runs on this node in the store, no slot runs it, and
// no other node takes it over while this one renews its heartbeat. It goes
// back to the queue with its attempt refunded: no worker ran. Found by the
// PostgreSQL fault harness. Under claim_mutex_ no slot is between its claim
// and its RunningHere, and the slots' jobs are read before the store's: a
// job running here in the store and in none of them is one no slot holds
// (a slot whose attempt ends meanwhile is in the list, and its job is no
// longer running in the store when it leaves it).
void Supervisor::requeue_unrun_claims() {
    const std::lock_guard claims(claim_mutex_);
    std::set<std::string> in_slots;
    {
        std::lock_guard lock(cancel_mutex_);
        in_slots = running_here_;
    }
    for (const JobRecord& job : store_.running_jobs()) {
        const std::string& id = job.status.id;
        if (job.node != store_.node().name || in_slots.count(id)) continue;
        const std::string cause = "lightfarmd lost the answer to its claim; no worker ran";
        if (store_.requeue(id, protocol::job_event(protocol::JobRetrying{job.status.attempts, cause, true}), true)) {
            log_line("job " + id + ": " + cause + ", queued again");
            changes_.notify();
        }
    }
}

void Supervisor::lease_loop() {
    // Three renewals per lease: a lease survives two missed ones.
    const auto period = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(std::max(0.05, store_.node().lease_seconds / 3)));
    for (auto next = Clock::now() + period; !stopping_; next += period) {
        while (!stopping_ && Clock::now() < next) std::this_thread::sleep_for(std::chrono::milliseconds(20));
        if (!stopping_) keep_leases();
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
    // Idempotent, and safe before, during or after start(): every thread
    // started is joined (start() after stop() starts none).
    std::lock_guard lock(lifecycle_mutex_);
    stopping_ = true;
    changes_.notify();
    const bool started = !threads_.empty();
    for (std::thread& t : threads_) t.join();
    threads_.clear();
    // Signed off: a lightfarmd started again under this name takes it at
    // once, rather than watching for a live twin (check_node_name_is_free).
    if (started) {
        node_info_["stopped"] = true;
        heartbeat();
    }
}

void Supervisor::cancel(const std::string& job_id) {
    std::lock_guard lock(cancel_mutex_);
    cancelled_.insert(job_id);
}

void Supervisor::store_trouble(const std::string& message) {
    std::lock_guard lock(trouble_mutex_);
    const auto now = Clock::now();
    if (now - last_trouble_log_ < std::chrono::seconds(10)) {
        ++unlogged_trouble_;
        return;
    }
    log_line(message +
             (unlogged_trouble_ ? " (and " + std::to_string(unlogged_trouble_) + " more store failures)" : ""));
    unlogged_trouble_ = 0;
    last_trouble_log_ = now;
}

bool Supervisor::persist(const std::string& what, const std::function<void()>& write) {
    auto backoff = std::chrono::milliseconds(50);
    const auto first = Clock::now();
    for (int tries = 1;; ++tries) {
        try {
            write();
            if (tries > 1)
                log_line(
                    what + ": stored after " + std::to_string(tries) + " tries (" +
                    std::to_string(std::chrono::duration_cast<std::chrono::seconds>(Clock::now() - first).count()) +
                    " s)");
            return true;
        } catch (const StoreError& e) {
            if (stopping_) {
                log_line(what + ": " + e.what() +
                         "; lightfarmd is stopping: the job stays running in the store "
                         "and its next start queues it again");
                return false;
            }
            store_trouble(what + ": " + e.what() + "; retrying");
        }
        const auto until = Clock::now() + backoff;
        while (!stopping_ && Clock::now() < until) std::this_thread::sleep_for(std::chrono::milliseconds(20));
        backoff = std::min(backoff * 2, std::chrono::milliseconds(2000));
    }
}

void Supervisor::compact_events() {
    const int64_t now = std::chrono::duration_cast<std::chrono::seconds>(Clock::now().time_since_epoch()).count();
    last_compaction_ = now;
    const double before = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count() -
                          config_.event_retention_days * 86400.0;
    try {
        if (const int64_t removed = store_.compact_events(before); removed > 0)
            log_line("event retention: removed " + std::to_string(removed) + " progress events of jobs finished over " +
                     std::to_string(config_.event_retention_days) + " days ago");
    } catch (const StoreError& e) {
        store_trouble(std::string("event retention: ") + e.what());
    }
}

void Supervisor::worker_loop(const std::string& device) {
    std::chrono::milliseconds fault_backoff(0);
    bool claim_failed = false;
    while (!stopping_) {
        const uint64_t seen = changes_.generation();
        const int64_t now = std::chrono::duration_cast<std::chrono::seconds>(Clock::now().time_since_epoch()).count();
        if (int64_t last = last_compaction_; now - last >= 3600 && last_compaction_.compare_exchange_strong(last, now))
            compact_events();
        // A claim that failed may be stored all the same (its answer was
        // lost): once the store answers again, such a job is queued again.
        if (claim_failed) {
            try {
                requeue_unrun_claims();
                claim_failed = false;
            } catch (const StoreError& e) {
                store_trouble(std::string("cannot look for a claim whose answer was lost: ") + e.what());
            }
        }
        std::optional<JobRecord> job;
        std::unique_lock claiming(claim_mutex_);
        try {
            job = store_.claim_next();
        } catch (const StoreError& e) {
            store_trouble(std::string("cannot take a job from the queue: ") + e.what());
            claim_failed = true;
        } catch (const std::exception& e) {
            log_line(std::string("cannot read the queue: ") + e.what());
        }
        if (!job) {
            claiming.unlock();
            changes_.wait(seen, std::chrono::seconds(1));
            continue;
        }
        const RunningHere running_here(*this, job->status.id);
        claiming.unlock();
        changes_.notify();
        bool machine_fault = false;
        try {
            machine_fault = run_attempt(*job, device);
        } catch (const StoreError& e) {
            // The store failed where the attempt does not retry it (reading
            // the job's scene as a database restarts): the machine's fault,
            // never the job's, so no attempt is counted (a PostgreSQL restart
            // right after a claim cost one: ScaleOut.ADatabaseRestarted…).
            server_fault(*job, std::string("the job store failed: ") + e.what());
            machine_fault = true;
        } catch (const std::exception& e) {
            // The server's own trouble (a store error) still ends the
            // attempt cleanly rather than leaving the job running forever.
            log_line("job " + job->status.id + ": " + e.what());
            attempt_failed(*job, std::string("lightfarmd: ") + e.what());
        }
        // After a fault of this machine (a full disk) the slot waits, 0.5 s
        // doubling up to 30 s, before it takes a job again: the job it gave
        // back is not retried in a tight loop while the fault lasts.
        fault_backoff = machine_fault ? std::clamp(fault_backoff * 2, std::chrono::milliseconds(500),
                                                   std::chrono::milliseconds(30000))
                                      : std::chrono::milliseconds(0);
        for (const auto until = Clock::now() + fault_backoff; !stopping_ && Clock::now() < until;)
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
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
        persist("job " + id + ": requeue", [&] {
            store_.requeue(id, protocol::job_event(protocol::JobRetrying{attempts, cause}), false);
        });
    } else {
        const std::string error =
            "bake failed after " + std::to_string(attempts) + " attempt" + (attempts == 1 ? "" : "s");
        log_line("job " + id + ": " + error + ": " + cause);
        persist("job " + id + ": failed state", [&] {
            if (store_.renew_lease(id))  // still ours: not cancelled or taken over meanwhile
                store_.finish(id, JobState::Failed, error, cause,
                              protocol::job_event(protocol::JobFailed{error, cause, attempts}));
        });
    }
}

void Supervisor::server_fault(const JobRecord& job, const std::string& cause) {
    const std::string& id = job.status.id;
    ++metrics_.server_faults;
    log_line("job " + id + ": " + cause +
             "; the machine's fault, not the job's: queued again, the attempt not counted");
    persist("job " + id + ": requeue", [&] {
        store_.requeue(
            id, protocol::job_event(protocol::JobRetrying{job.status.attempts, "lightfarmd: " + cause, true}), true);
    });
}

std::string Supervisor::disk_full() const {
    const uint64_t free = free_disk_bytes(config_.data_dir);
    if (free >= config_.limits.free_disk_bytes) return "";
    return "the data directory's disk has " + megabytes(free) + " free, less than --limit free_disk_bytes (" +
           megabytes(config_.limits.free_disk_bytes) + ")";
}

void Supervisor::fail_now(const JobRecord& job, const std::string& error, const std::string& cause) {
    log_line("job " + job.status.id + ": " + error + (cause.empty() ? "" : ": " + cause));
    persist("job " + job.status.id + ": failed state", [&] {
        if (store_.renew_lease(job.status.id))  // still ours: not cancelled or taken over meanwhile
            store_.finish(job.status.id, JobState::Failed, error, cause,
                          protocol::job_event(protocol::JobFailed{error, cause, job.status.attempts}));
    });
}

namespace {

// The output a progress event without a name is about: the only one asked for.
std::string output_or_only(const std::string& output, const protocol::BakeSettings& bake) {
    if (!output.empty() || bake.outputs.size() != 1) return output;
    return bake.outputs.begin()->first;
}

}  // namespace

AttemptUpdate apply_worker_event(const AttemptState& state, const protocol::WorkerEvent& event,
                                 const protocol::BakeSettings& bake, const std::string& job_id, int attempt) {
    AttemptUpdate u;
    u.state = state;
    const std::string base = "/v1/jobs/" + job_id + "/artifacts/";

    if (const auto* prepare = std::get_if<protocol::PrepareEvent>(&event)) {
        // Before the first pass: the job's progress says which stage runs
        // and preparation's time left (the whole job's is not known yet).
        Progress p;
        p.preparing = prepare->stage;
        p.prepare_seconds = prepare->seconds;
        p.prepare_eta_seconds = prepare->eta_seconds;
        u.progress = p;
        json data = protocol::to_json(protocol::WorkerEvent(*prepare));
        data.erase("event");
        // A long stage said again (gi/bake/event_heartbeat.h): the stream
        // gets it, the store keeps only the newest such (kAgain).
        data.erase("again");
        if (prepare->again) data[kAgain] = true;
        u.event = JobEvent{0, "preparing", data};
    } else if (const auto* start = std::get_if<protocol::StartEvent>(&event)) {
        json data = protocol::to_json(protocol::WorkerEvent(*start));
        data.erase("event");
        data["attempt"] = attempt;
        u.state.job = protocol::JobProgress(bake);
        u.state.job->start(*start);
        u.state.job->hold_at_least(state.shown_fraction);
        // A resumed output's rays so far were counted by the attempt that traced them.
        for (const auto& [output, at] : start->resumed) u.state.rays[output] = at.rays;
        u.event = JobEvent{0, "started", data};
    } else if (const auto* progress = std::get_if<protocol::ProgressEvent>(&event)) {
        const std::string output = output_or_only(progress->output, bake);
        if (!u.state.job) {  // a worker that sent no start event
            u.state.job = protocol::JobProgress(bake);
            u.state.job->hold_at_least(state.shown_fraction);
        }
        const Progress p = u.state.job->update(output, progress->progress);
        // Rays are counted per output: each output's totals start again at 0.
        const uint64_t seen = state.rays.count(output) ? state.rays.at(output) : 0;
        u.new_rays = p.rays >= seen ? p.rays - seen : p.rays;
        u.state.rays[output] = p.rays;
        u.state.passes[output] = p.pass;
        if (p.seconds > 0) u.rays_per_second = double(p.rays) / p.seconds;
        u.progress = p;
        json data = protocol::to_json(p);
        if (!output.empty()) data["output"] = output;
        if (progress->again) data[kAgain] = true;  // the last pass said again: kept until the next
        u.event = JobEvent{0, "progress", data};
    } else if (const auto* snapshot = std::get_if<protocol::SnapshotEvent>(&event)) {
        if (!plain_file_name(snapshot->file)) {
            u.ignored = "a snapshot with a bad file name: " + snapshot->file;
            return u;
        }
        const std::string output = output_or_only(snapshot->output, bake);
        if (output.empty()) {
            u.ignored = "a snapshot of no output: " + snapshot->file;
            return u;
        }
        u.latest[output] = LatestFile{snapshot->file, snapshot->pass, false};
        u.event = JobEvent{
            0,
            "snapshot",
            {{"output", output}, {"file", snapshot->file}, {"pass", snapshot->pass}, {"url", base + snapshot->file}}};
    } else {
        const auto& done = std::get<protocol::DoneEvent>(event);
        Progress p = done.progress;
        p.eta_seconds = 0.0;
        if (state.job) p.prepare_seconds = state.job->prepare_seconds();
        u.progress = p;
        protocol::JobDone job_done;
        job_done.progress = p;
        for (const std::string& f : done.files)
            if (plain_file_name(f)) job_done.files.push_back(f);
        for (const auto& [output, file] : done.final_files) {
            if (!plain_file_name(file)) continue;
            job_done.final_files[output] = file;
            // The pass the output's final file holds: its last progress.
            const int pass = state.passes.count(output) ? state.passes.at(output) : p.pass;
            u.latest[output] = LatestFile{file, pass, true};
        }
        u.state.done = protocol::to_json(job_done);
    }
    return u;
}

std::string user_facing(std::string line, const fs::path& scene_path, const std::string& scene_name,
                        const fs::path& scene_dir, const fs::path& job_dir, const fs::path& data_dir) {
    auto replace_all = [&line](const std::string& from, const std::string& to) {
        if (from.empty()) return;
        for (size_t at = line.find(from); at != std::string::npos; at = line.find(from, at + to.size()))
            line.replace(at, from.size(), to);
    };
    // Each path as given and as the worker may have resolved it, longest first.
    auto forms = [](const fs::path& p) {
        std::vector<std::string> out = {p.string()};
        std::error_code ec;
        const fs::path resolved = fs::weakly_canonical(p, ec);
        if (!ec && resolved.string() != p.string()) out.push_back(resolved.string());
        return out;
    };
    for (const std::string& f : forms(scene_path)) replace_all(f, scene_name);
    for (const std::string& f : forms(scene_dir)) replace_all(f + "/", "");
    for (const std::string& f : forms(job_dir / ".spec.json")) replace_all(f, "the job's settings");
    for (const std::string& f : forms(job_dir)) {
        replace_all(f + "/", "");
        replace_all(f, "the job's output directory");
    }
    for (const std::string& f : forms(data_dir)) replace_all(f, "the server's data directory");
    return line;
}

std::unique_ptr<Subprocess> Supervisor::start_worker(const JobRecord& job, const protocol::JobSpec& spec,
                                                     const SceneRecord& scene, const std::string& device) {
    const fs::path dir = job_dir(job.status.id);
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw ServerFault("cannot make the job's directory: " + ec.message());
    // The worker reads the job's own spec: no translation into flags.
    const fs::path spec_file = dir / kSpecFile;
    {
        // A name of this process's own: on a shared data directory a node
        // that lost the job may still be writing beside the one that has it.
        const fs::path tmp =
            dir / (std::string(kSpecFile) + "." + store_.node().name + "." + std::to_string(::getpid()) + ".tmp");
        std::ofstream out(tmp);
        out << protocol::to_json(spec).dump() << "\n";
        out.close();  // the bytes reach the disk here: a full disk fails now, not before
        if (!out) {
            fs::remove(tmp, ec);
            throw ServerFault("cannot write the job's spec (" + std::string(std::strerror(errno)) + ")");
        }
        fs::rename(tmp, spec_file, ec);
        if (ec) {
            const std::string why = ec.message();
            fs::remove(tmp, ec);
            throw ServerFault("cannot put the job's spec in place (" + why + ")");
        }
    }
    // Bytes another tenant stored first are this job's owner's under the name
    // it uploaded them as (issue #33): the worker bakes a link of that name,
    // so that what it writes and says (manifest.json's `scene`, an error
    // naming the file) names the scene as its owner does.
    const fs::path scene_file = scene_path(scene, job.status.id);
    if (const fs::path stored = DataDir(config_.data_dir).scene(scene.id) / scene.main_file; scene_file != stored) {
        fs::create_directories(scene_file.parent_path(), ec);
        std::error_code gone;
        fs::remove(scene_file, gone);
        if (!ec) fs::create_symlink(stored.lexically_relative(scene_file.parent_path()), scene_file, ec);
        if (ec) throw ServerFault("cannot link the scene into the job's directory (" + ec.message() + ")");
    }
    std::vector<std::string> argv = {engine_,  "bake",   scene_file.string(), "--out", dir.string(),
                                     "--json", "--spec", spec_file.string()};
    if (!device.empty()) {
        argv.push_back("--device");
        argv.push_back(device);
    }
    // A retry (a crashed worker, a node that died or was stopped) continues
    // from the states an earlier attempt saved with its snapshots, on any
    // node: the job's directory is on the shared data dir.
    if (fs::exists(dir / protocol::kResumeDir)) argv.push_back("--resume");
    ++metrics_.worker_starts;
    auto child = std::make_unique<Subprocess>(argv);
    // Without its pid file a worker this lightfarmd leaves behind (kill -9)
    // would bake beside the next attempt: no file, no worker (the
    // Subprocess's destructor ends it).
    std::ofstream pid_file(dir / kPidFile);
    pid_file << child->pid() << " " << store_.node().name << "\n";
    pid_file.close();
    if (!pid_file) throw ServerFault("cannot write the worker's pid file (" + std::string(std::strerror(errno)) + ")");
    log_line("job " + job.status.id + ": attempt " + std::to_string(job.status.attempts) + ", worker " +
             std::to_string(child->pid()));
    return child;
}

void Supervisor::store_update(const std::string& id, const AttemptUpdate& u) {
    // Each write is idempotent but the event, which comes last: a retry after
    // a failure in any of them stores the event once.
    if (u.progress) store_.set_progress(id, *u.progress);
    for (const auto& [output, file] : u.latest) store_.set_latest(id, output, file);
    if (u.event) store_.append_event(id, *u.event);
}

bool Supervisor::flush_updates(const std::string& id, std::deque<AttemptUpdate>& unsaved) {
    while (!unsaved.empty()) {
        try {
            store_update(id, unsaved.front());
        } catch (const StoreError& e) {
            store_trouble("job " + id + ": " + e.what() + "; " + std::to_string(unsaved.size()) +
                          " update(s) kept until the store takes them");
            return false;
        }
        unsaved.pop_front();
    }
    return true;
}

std::string Supervisor::limit_exceeded(const JobRecord& job, Clock::time_point now, Clock::time_point deadline,
                                       Clock::time_point last_output) const {
    std::ostringstream s;
    if (now > deadline) {
        s << "worker ran past the job's deadline of " << job.max_seconds << " s and was killed";
    } else if (now - last_output > std::chrono::duration<double>(config_.stall_seconds)) {
        s << "worker printed nothing for " << config_.stall_seconds << " s (hung) and was killed";
    }
    return s.str();
}

bool Supervisor::cancel_requested(const std::string& job_id) {
    std::lock_guard lock(cancel_mutex_);
    return cancelled_.count(job_id) > 0;
}

bool Supervisor::lease_lost(const std::string& job_id) {
    std::lock_guard lock(cancel_mutex_);
    return lost_.count(job_id) > 0;
}

// How a worker's run ended, as supervise_worker saw it.
struct Supervisor::WorkerEnd {
    AttemptState state;          // what the worker reported
    ExitStatus status;           // its exit
    std::string cause;           // why we ended it ourselves (its deadline, a stall); "" = we did not
    bool past_deadline = false;  // ended at the job's own deadline
    bool saved = false;          // it announced a snapshot: a retry resumes from further on
    bool cancelled = false;      // the job was cancelled
    bool lost = false;           // the job no longer runs on this node
    bool stopped = false;        // lightfarmd stops: the job went back to the queue, and nothing else is to be done
};

namespace {

// The files a worker that has ended was writing when it ended (killed, or
// crashed mid-write): its own temporaries in the job's directory and its
// saved state's (protocol::temporary_file_name). Nothing else of the
// directory is touched; a file that cannot be removed is left.
void remove_temporaries(const fs::path& dir, long pid) {
    for (const fs::path& folder : {dir, dir / protocol::kResumeDir}) {
        std::error_code ec;
        for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
            std::error_code ignored;
            if (protocol::is_temporary_file_of(it->path().filename().string(), pid) && it->is_regular_file(ignored))
                fs::remove(it->path(), ignored);
        }
    }
}

}  // namespace

bool Supervisor::run_attempt(const JobRecord& job, const std::string& device) {
    // Validated once, at submit, against the limits of that day: a lower
    // --limit since then applies to new jobs, not to this one.
    protocol::JobSpec spec;
    try {
        protocol::SpecLimits stored;
        stored.caps.clear();
        stored.allow_local_files = false;
        spec = protocol::parse_job_spec(job.status.spec, stored);
    } catch (const protocol::SpecError& e) {
        fail_now(job, "the job's stored spec is not valid any more", e.what());
        return false;
    }
    // As the job's owner uploaded it (its name), else as stored.
    std::optional<SceneRecord> scene = store_.scene_for(spec.scene, job.owner);
    if (!scene) scene = store_.scene(spec.scene);
    if (!scene) {
        fail_now(job, "scene " + spec.scene + " is missing", "");
        return false;
    }
    // On record but not on this node's disk (a dropped mount, a node with a
    // data directory of its own): the machine's fault, not the job's (issue
    // #55: it failed for good as "these settings"). Queued again; a new
    // upload of the same bytes puts the files back (SceneStore::upload).
    if (const fs::path stored = DataDir(config_.data_dir).scene(scene->id) / scene->main_file;
        !fs::is_regular_file(stored)) {
        server_fault(job,
                     "the scene's files are not on this node's disk (a dropped mount? uploading the scene "
                     "again puts them back)");
        return true;
    }

    if (const std::string full = disk_full(); !full.empty()) {
        server_fault(job, full);
        return true;
    }
    std::unique_ptr<Subprocess> child;
    try {
        child = start_worker(job, spec, *scene, device);
    } catch (const ServerFault& e) {
        server_fault(job, e.what());
        return true;
    } catch (const std::exception& e) {
        attempt_failed(job, e.what());
        return false;
    }

    const WorkerEnd end = supervise_worker(job, spec.bake, *child);
    remove_temporaries(job_dir(job.status.id), child->pid());
    return !end.stopped && end_attempt(job, *scene, *child, end);
}

Supervisor::WorkerEnd Supervisor::supervise_worker(const JobRecord& job, const protocol::BakeSettings& bake,
                                                   Subprocess& worker) {
    const std::string& id = job.status.id;
    const auto started = Clock::now();
    const auto deadline =
        started + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(job.max_seconds));
    auto last_output = started;
    WorkerEnd end;
    end.state.shown_fraction = job.status.progress.shown_fraction;  // a retry's bar starts where the last stood
    // What the store could not take yet (a full disk): kept, in order, and
    // stored when it can again; the worker bakes on meanwhile. A progress
    // update replaces an unsaved one of the same output, so this stays small.
    std::deque<AttemptUpdate> unsaved;
    // The newest progress and files the worker reported: what the store
    // drops once the job is cancelled (a cancel between a line and its
    // store), stored again after the cancel (keep_last_snapshot).
    AttemptUpdate seen;
    auto progress_only = [](const AttemptUpdate& u) {
        return u.latest.empty() && u.event && u.event->type == "progress";
    };

    for (std::string line;;) {
        if (stopping_) {
            // Its last snapshot, state and all, is where the next start
            // resumes: a bake killed at once resumed from its last periodic one.
            const TerminateGrace grace = terminate_with_grace(job, bake, end.state, worker, kStopGraceSeconds, false);
            std::map<std::string, LatestFile> latest;
            for (const AttemptUpdate& update : grace.updates) {
                unsaved.push_back(update);
                for (const auto& [output, file] : update.latest) latest[output] = file;
            }
            const std::string what = snapshots_text(latest);
            log_line("job " + id + ": lightfarmd stopping; its worker " + grace_text(grace.ended, grace.seconds) +
                     (what.empty() ? "" : ", its last snapshot: " + what) + (grace.ended ? "" : "; killed"));
            worker.kill();
            end.status = worker.wait();
            try {
                flush_updates(id, unsaved);
                store_.requeue(
                    id, protocol::job_event(protocol::JobRetrying{job.status.attempts, "lightfarmd stopped"}), true);
            } catch (const StoreError& e) {
                log_line("job " + id + ": " + e.what() +
                         "; it stays running in the store and the next start queues it again");
            }
            end.stopped = true;
            return end;
        }
        if (!unsaved.empty()) flush_updates(id, unsaved);
        if ((end.cancelled = cancel_requested(id)) || (end.lost = lease_lost(id))) {
            if (end.cancelled) keep_last_snapshot(job, bake, end.state, seen, worker);
            worker.kill();
            break;
        }
        // The limits hold on every turn, however much the worker prints.
        const auto now = Clock::now();
        if (end.cause = limit_exceeded(job, now, deadline, last_output); !end.cause.empty()) {
            end.past_deadline = now > deadline;
            worker.kill();
            break;
        }
        const auto wait = std::clamp(
            std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now) + std::chrono::milliseconds(1),
            std::chrono::milliseconds(1), std::chrono::milliseconds(200));
        const Subprocess::Read r = worker.read_line(line, wait);
        if (r == Subprocess::Read::End) break;
        if (r == Subprocess::Read::Timeout) continue;
        last_output = Clock::now();

        std::optional<protocol::WorkerEvent> event;
        try {
            event = protocol::parse_worker_event(json::parse(line));
        } catch (const std::exception& e) {
            log_line("job " + id + ": ignoring worker output (" + e.what() + "): " + line.substr(0, 200));
            continue;
        }
        const AttemptUpdate update = apply_worker_event(end.state, *event, bake, id, job.status.attempts);
        if (!update.ignored.empty()) {
            log_line("job " + id + ": ignoring " + update.ignored);
            continue;
        }
        end.state = update.state;
        if (update.progress) seen.progress = update.progress;
        for (const auto& [output, file] : update.latest) seen.latest[output] = file;
        end.saved = end.saved || !update.latest.empty();
        metrics_.rays_total += update.new_rays;
        if (update.rays_per_second) metrics_.set_job_rate(id, *update.rays_per_second);
        if (!unsaved.empty() && progress_only(update) && progress_only(unsaved.back()) &&
            unsaved.back().event->data.value("output", "") == update.event->data.value("output", ""))
            unsaved.back() = update;
        else unsaved.push_back(update);
        flush_updates(id, unsaved);
        changes_.notify();
    }

    end.status = worker.wait();
    std::error_code ec;
    fs::remove(job_dir(id) / kPidFile, ec);
    // The attempt's events before its end, so that the final event stays last.
    if (!unsaved.empty())
        persist("job " + id + ": events", [&] {
            if (!flush_updates(id, unsaved)) throw StoreError("job store: the events are not stored yet");
        });
    return end;
}

Supervisor::TerminateGrace Supervisor::terminate_with_grace(const JobRecord& job, const protocol::BakeSettings& bake,
                                                            AttemptState& state, Subprocess& worker, double grace,
                                                            bool until_stop) {
    const auto start = Clock::now();
    const auto deadline = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(grace));
    worker.terminate();
    TerminateGrace out;
    for (std::string line; !(until_stop && stopping_) && Clock::now() < deadline;) {
        const auto wait = std::clamp(std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()),
                                     std::chrono::milliseconds(1), std::chrono::milliseconds(200));
        const Subprocess::Read r = worker.read_line(line, wait);
        if (r == Subprocess::Read::End) {
            out.ended = true;
            break;
        }
        if (r == Subprocess::Read::Timeout) continue;
        AttemptUpdate update;
        try {
            update = apply_worker_event(state, protocol::parse_worker_event(json::parse(line)), bake, job.status.id,
                                        job.status.attempts);
        } catch (const std::exception&) {
            continue;  // not an event: the log has had enough of this worker
        }
        if (!update.ignored.empty()) continue;
        state = update.state;
        out.updates.push_back(std::move(update));
    }
    out.seconds = std::chrono::duration<double>(Clock::now() - start).count();
    return out;
}

void Supervisor::keep_last_snapshot(const JobRecord& job, const protocol::BakeSettings& bake, AttemptState state,
                                    const AttemptUpdate& seen, Subprocess& worker) {
    const std::string& id = job.status.id;
    const TerminateGrace grace = terminate_with_grace(job, bake, state, worker, kCancelGraceSeconds, true);
    std::optional<Progress> progress = seen.progress;
    std::map<std::string, LatestFile> latest = seen.latest;
    for (const AttemptUpdate& update : grace.updates) {
        if (update.progress) progress = update.progress;
        for (const auto& [output, file] : update.latest) latest[output] = file;
    }
    if (progress || !latest.empty()) {
        try {
            store_.set_cancelled_result(id, progress, latest);
            changes_.notify();
        } catch (const StoreError& e) {
            log_line("job " + id + ": cannot store what its worker wrote after the cancel: " + e.what());
        }
    }
    const std::string what = snapshots_text(latest);
    log_line("job " + id + ": cancelled; its worker " + grace_text(grace.ended, grace.seconds) +
             (what.empty() ? "" : ", its last snapshot: " + what) + (grace.ended ? "" : "; killed"));
}

bool Supervisor::end_attempt(const JobRecord& job, const SceneRecord& scene, const Subprocess& worker,
                             const WorkerEnd& end) {
    const std::string& id = job.status.id;
    if (end.cancelled) {
        log_line("job " + id + ": cancelled, worker ended");
        return false;  // the cancel route already recorded the final state
    }
    if (end.lost) {
        // Cancelled on another node, or taken over after this node could not
        // renew its lease: the job's state is the store's, not this attempt's.
        log_line("job " + id +
                 ": no longer runs on this node (cancelled elsewhere, or taken over after its lease "
                 "expired); worker killed");
        return false;
    }
    // Past the job's own deadline before its first snapshot of this attempt:
    // a retry would start from the same place and end the same way (issue
    // #55: max_seconds 1 cost three worker runs), so the job fails now.
    if (end.past_deadline && !end.saved) {
        ++metrics_.worker_failures;
        fail_now(job,
                 "the job's deadline (limits.max_seconds " + json(job.max_seconds).dump() +
                     ") passed before its first snapshot; raise it (not retried)",
                 end.cause);
        return false;
    }
    if (!end.cause.empty()) {
        attempt_failed(job, end.cause);
        return false;
    }
    if (end.status.success() && end.state.done) {
        const json& done = *end.state.done;
        bool still_ours = true;
        persist("job " + id + ": succeeded state", [&] {
            // Not if the job was cancelled or taken over meanwhile: the store's state stands.
            still_ours = store_.renew_lease(id);
            if (still_ours) store_.finish(id, JobState::Succeeded, "", "", {0, "done", done});  // JobDone's JSON
        });
        log_line("job " + id +
                 (still_ours ? ": succeeded" : ": finished, but no longer runs on this node; not stored"));
        return false;
    }
    const std::string scene_name = !scene.name.empty()        ? scene.name
                                   : !scene.main_file.empty() ? scene.main_file
                                                              : scene.summary.value("source", "the scene");
    const std::string last = user_facing(worker.stderr_last_line(), scene_path(scene, id), scene_name,
                                         DataDir(config_.data_dir).scene(scene.id), job_dir(id), config_.data_dir);
    if (end.status.exited && end.status.code == protocol::kExitSpecUnreadable) {
        server_fault(job, "the worker could not read the spec lightfarmd wrote" + (last.empty() ? "" : ": " + last));
        return true;
    }
    if (end.status.exited && end.status.code == protocol::kExitMachineFault) {
        server_fault(job, "the worker could not write its files" + (last.empty() ? "" : ": " + last));
        return true;
    }
    // A worker that failed while the disk is full failed for the machine.
    if (const std::string full = disk_full(); !full.empty() && !end.status.success()) {
        server_fault(job, "worker " + end.status.describe() + " while " + full);
        return true;
    }
    if (end.status.exited && protocol::is_input_error_exit(end.status.code)) {
        // The scene or the settings cannot be baked: another run cannot help.
        ++metrics_.worker_failures;
        fail_now(job, "the bake cannot run on this scene with these settings (not retried)",
                 last.empty() ? "worker " + end.status.describe() : last);
        return false;
    }
    std::string failure =
        end.status.success() ? "worker exited without reporting done" : "worker " + end.status.describe();
    if (!last.empty()) failure += ": " + last;
    attempt_failed(job, failure);
    return false;
}

}  // namespace lf::server
