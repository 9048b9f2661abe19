// Runs queued jobs in worker processes and turns what they print into
// progress, events and a final state.
//
// The worker contract (protocol/worker_protocol.h): the supervisor writes the
// job's spec to DIR/.spec.json and runs
//   ENGINE bake SCENE --out DIR --json --spec DIR/.spec.json [--device gpu:N]
// which prints typed events (start, progress, snapshot, done) one per stdout
// line and exits with a WorkerExit status. An input error (exit 2 or 3) fails
// the job at once: running it again cannot help. A worker that exits
// otherwise, is killed by a signal, prints nothing for --stall-timeout seconds
// or runs past the job's deadline costs the job one attempt; after the last
// one the job fails with that cause. Nothing a worker does can stop the server.
#pragma once

#include "config.h"
#include "events.h"
#include "job_store.h"
#include "metrics.h"

#include <atomic>
#include <chrono>
#include <deque>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

namespace lf::server {

// What one attempt has seen of its worker so far.
struct AttemptState {
    std::map<std::string, uint64_t> rays;      // output -> rays its progress reported last
    std::map<std::string, int> passes;         // output -> pass its progress reported last
    std::optional<nlohmann::json> done;        // the "done" event's data, once the worker reported done
    std::optional<protocol::JobProgress> job;  // from the start event: the whole job's ETA and done fraction
    double shown_fraction = 0.0;               // the job's bar as earlier attempts left it (never goes back)
};

// What applying one worker event asks the supervisor to store. Empty parts
// change nothing.
struct AttemptUpdate {
    AttemptState state;                        // the attempt's state after the event
    std::optional<Progress> progress;          // the job's progress
    std::optional<JobEvent> event;             // a non-final event for the job's stream
    std::map<std::string, LatestFile> latest;  // output -> its newest file
    uint64_t new_rays = 0;                     // rays traced since the previous event
    std::optional<double> rays_per_second;     // this worker's rate
    std::string ignored;                       // why the event was ignored ("" = it was not)
};

// The pure heart of supervision: one decoded worker event of attempt
// `attempt` of job `job_id`, whose validated settings are `bake`, applied to
// `state`. No process, no store, no clock: unit-tested alone.
AttemptUpdate apply_worker_event(const AttemptState& state, const protocol::WorkerEvent& event,
                                 const protocol::BakeSettings& bake, const std::string& job_id, int attempt);

// A worker's stderr line fit for the job's owner: the server's own paths
// replaced by what the user knows. The scene's stored path becomes its
// uploaded name, a file inside the stored upload its name in the upload, and
// the job directory and the data directory are not shown.
std::string user_facing(std::string line, const std::filesystem::path& scene_path, const std::string& scene_name,
                        const std::filesystem::path& scene_dir, const std::filesystem::path& job_dir,
                        const std::filesystem::path& data_dir);

class Subprocess;

// A failure of this server's machine (its disk, a file it wrote for the
// worker), never the job's: the job goes back to the queue without costing
// an attempt, and the worker slot backs off before it takes another.
class ServerFault : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

class Supervisor {
public:
    using Clock = std::chrono::steady_clock;

    Supervisor(JobStore& store, const ServerConfig& config, ChangeSignal& changes, Metrics& metrics);
    ~Supervisor();  // stop()

    // Requeues jobs a previous lightfarmd left running (one attempt counted;
    // failed when none is left), then starts the worker threads and the
    // lease thread (heartbeat, lease renewal, jobs of lost nodes).
    void start();
    // Stops running workers and puts their jobs back in the queue without
    // counting the attempt: a restart is not the job's fault. Each worker
    // gets SIGTERM and up to kStopGraceSeconds to write its last snapshot
    // (with its state: the next start resumes there), then SIGKILL.
    void stop();
    static constexpr double kStopGraceSeconds = 5.0;

    // The job was marked cancelled in the store; stop its worker if it runs
    // here: SIGTERM, then up to kCancelGraceSeconds for its last snapshot
    // (where the bake stood: the job's `latest`), then SIGKILL.
    void cancel(const std::string& job_id);
    static constexpr double kCancelGraceSeconds = 10.0;

    std::filesystem::path job_dir(const std::string& job_id) const;
    // The scene file a job's worker bakes: the stored one, or where the
    // job's owner uploaded the bytes under another name (scene.name), a link
    // of that name to it in the job's directory (.scene/NAME).
    std::filesystem::path scene_path(const SceneRecord& scene, const std::string& job_id) const;

private:
    // `device`: the engine's --device for this worker ("" = its default).
    void worker_loop(const std::string& device);
    int count_gpus() const;
    // One worker run of a claimed job, start to end state. True when it
    // ended on a fault of this machine (server_fault): the slot backs off.
    bool run_attempt(const JobRecord& job, const std::string& device);
    // Requeues the job without counting the attempt: `cause` is this
    // machine's, not the job's (ServerFault).
    void server_fault(const JobRecord& job, const std::string& cause);
    // Why this machine cannot run a worker now ("" = it can): the data
    // directory's disk below --limit free_disk_bytes.
    std::string disk_full() const;
    struct WorkerEnd;
    // Reads the worker's events until it ends or must be ended (cancelled,
    // lost, past a limit, lightfarmd stopping), storing what each asks for.
    WorkerEnd supervise_worker(const JobRecord& job, const protocol::BakeSettings& bake, Subprocess& worker);
    // The job's state after its worker ended: succeeded, failed, retried, or
    // left to whoever cancelled or took it.
    // True when it ended on a fault of this machine.
    bool end_attempt(const JobRecord& job, const SceneRecord& scene, const Subprocess& worker, const WorkerEnd& end);
    // Writes the spec into the job directory and starts the engine on it.
    // Throws ServerFault when the spec cannot be written whole.
    std::unique_ptr<Subprocess> start_worker(const JobRecord& job, const protocol::JobSpec& spec,
                                             const SceneRecord& scene, const std::string& device);
    // Stores what apply_worker_event asked for; throws StoreError.
    void store_update(const std::string& job_id, const AttemptUpdate& update);
    // Stores the updates the store could not take yet, oldest first; false
    // (and the rest kept) at the first StoreError.
    bool flush_updates(const std::string& job_id, std::deque<AttemptUpdate>& unsaved);
    // Runs `write` until it stops throwing StoreError (backing off up to 2 s
    // between tries) or lightfarmd stops. A job's end (its final state, a
    // requeue) is never dropped: while the store cannot take it, the job
    // stays `running` in the store with this thread still trying; if
    // lightfarmd stops first, its next start requeues the job (or fails it
    // when no attempt is left). Returns false when it gave up on stop.
    bool persist(const std::string& what, const std::function<void()>& write);
    // Logs a store failure, at most every 10 s (with how many were not logged).
    void store_trouble(const std::string& message);
    // Event retention (JobStore::compact_events), at start and hourly.
    void compact_events();
    // Why the worker must be ended now ("" = it may go on): the job's
    // deadline or a stall. Checked on every turn of the read loop.
    std::string limit_exceeded(const JobRecord& job, Clock::time_point now, Clock::time_point deadline,
                               Clock::time_point last_output) const;
    // A cancelled job's worker: SIGTERM, and what it writes within the
    // grace (its last snapshot, announced before it exits) stored as the
    // job's progress and newest files (JobStore::set_cancelled_result),
    // over `seen` (the newest the attempt reported before). The caller
    // kills it after.
    void keep_last_snapshot(const JobRecord& job, const protocol::BakeSettings& bake, AttemptState state,
                            const AttemptUpdate& seen, Subprocess& worker);
    // SIGTERM to the worker, then its events until it ends or `grace`
    // seconds pass (its last snapshot among them); with `until_stop`, a
    // stop of lightfarmd cuts it short too. The caller kills it after.
    struct TerminateGrace {
        std::vector<AttemptUpdate> updates;
        bool ended = false;  // the worker exited within the grace
        double seconds = 0;  // how long it took
    };
    TerminateGrace terminate_with_grace(const JobRecord& job, const protocol::BakeSettings& bake, AttemptState& state,
                                        Subprocess& worker, double grace, bool until_stop);
    bool cancel_requested(const std::string& job_id);
    bool lease_lost(const std::string& job_id);
    // Jobs taken over from a node that is gone (a previous lightfarmd of
    // this node, or another whose lease expired): queued again with their
    // attempt counted, or failed when none is left.
    void end_abandoned_attempts(const std::vector<JobRecord>& jobs);
    // Every lease_seconds / 3: heartbeat, renew the leases of the jobs
    // running here (a job no longer ours is killed: lost_), take over the
    // jobs of lost nodes.
    void lease_loop();
    void keep_leases();
    // Jobs running on this node in the store that no slot runs (a claim
    // whose answer was lost): queued again, their attempt refunded. Called
    // at every renewal and by a slot whose claim failed.
    void requeue_unrun_claims();
    // A job this node claimed, known to the lease loop (running_here_) from
    // its claim until its attempt's end is stored.
    struct RunningHere {
        Supervisor& s;
        std::string id;
        RunningHere(Supervisor& supervisor, std::string job_id);
        ~RunningHere();
        RunningHere(const RunningHere&) = delete;
        RunningHere& operator=(const RunningHere&) = delete;
    };
    void heartbeat();
    void attempt_failed(const JobRecord& job, const std::string& cause);
    // Ends the job now, without another attempt (input errors, a stored spec gone bad, a missing scene).
    void fail_now(const JobRecord& job, const std::string& error, const std::string& cause);

    JobStore& store_;
    const ServerConfig& config_;
    ChangeSignal& changes_;
    Metrics& metrics_;
    std::string engine_;
    std::atomic<bool> stopping_{false};
    std::mutex lifecycle_mutex_;  // start() and stop()
    std::vector<std::thread> threads_;
    std::mutex claim_mutex_;  // a slot's claim and its RunningHere, as one step (requeue_unrun_claims)
    std::mutex cancel_mutex_;
    std::set<std::string> cancelled_;     // running here, to be killed
    std::set<std::string> running_here_;  // jobs whose lease this node renews
    std::set<std::string> lost_;          // running here but no longer ours in the store: to be killed
    nlohmann::json node_info_;            // what the heartbeat says of this node
    std::mutex trouble_mutex_;
    Clock::time_point last_trouble_log_{};
    int unlogged_trouble_ = 0;
    std::atomic<int64_t> last_compaction_{0};  // steady-clock seconds
};

}  // namespace lf::server
