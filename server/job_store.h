// Where jobs, their events and scene ownership live. The routes and the
// supervisor only see this interface; SqliteJobStore is the embedded default
// (one lightfarmd), PostgresJobStore the shared one (many lightfarmd nodes on
// one database, docs/scale-out.md). Both are SqlJobStore (sql_job_store.h):
// the same statements over two SQL dialects.
//
// Each store speaks for one node (NodeIdentity): a job it claims is leased to
// that node, which renews the lease while the job runs; a job whose lease
// expired (its node was killed or cut off) is taken over by another node. The
// writes of a running attempt (events, progress, requeue) only land while the
// job still runs on the store's node, so a node that lost its job cannot
// write into the attempt that replaced it.
//
// Every method is safe to call from several threads at once.
//
// A store never lies: every method either did what it says (a write is
// committed, durable against a crash of lightfarmd) or throws StoreError and
// changed nothing. Routes answer a StoreError with 503 and Retry-After (never
// a 201 for something not stored); the supervisor retries its writes.
#pragma once

#include "job_status.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf::server {

// The store could not read or write (disk full, I/O error, a database file made
// read-only, locked for too long). Nothing of the failed call was stored. The
// message names what failed, never a path.
// What the store could not do. what(): the whole story, for the server's
// log (the database's own words: a file's path, an address, a HINT);
// cause(): what a tenant may be told (issue #55: PostgreSQL's file path,
// HINT and address reached tenants' error messages).
class StoreError : public std::runtime_error {
public:
    static constexpr const char* kFailed = "it failed; the server's log says how";
    explicit StoreError(const std::string& what, std::string cause = kFailed)
        : std::runtime_error(what), cause_(std::move(cause)) {}
    const std::string& cause() const { return cause_; }

private:
    std::string cause_;
};

using protocol::JobEvent;
using protocol::JobState;
using protocol::JobStatus;
using protocol::LatestFile;
using protocol::Progress;

struct SceneRecord {
    std::string id;          // content hash
    std::string main_file;   // the .glb or .gltf inside the scene's directory (its first uploader's name)
    nlohmann::json summary;  // `lightfarm inspect --json` of it
    // The main file's name as the owner it was read for uploaded it
    // (scene_for): tenants who upload the same bytes each see their own.
    // "" when read without an owner (scene()).
    std::string name = {};
};

// Who a store speaks for, and how long its leases last.
struct NodeIdentity {
    std::string name;           // unique among the nodes sharing a store (default: the host name)
    double lease_seconds = 30;  // a claimed job is this node's for this long after each renewal
};
std::string default_node_name();  // the host name, else "lightfarmd"

// A node's last heartbeat (GET /v1/nodes).
struct NodeRecord {
    std::string name;
    double started_at = 0;     // seconds since the epoch
    double heartbeat_at = 0;   // the newest heartbeat
    double heartbeat_age = 0;  // seconds since it, by the store's clock (the database's: one for all nodes)
    nlohmann::json info;       // what the node said of itself: {"gpus", "workers", "url", "lease_seconds", "stopped"}

    // Its lease, as it said (30 s, the default, if it did not).
    double lease_seconds() const { return info.is_object() ? info.value("lease_seconds", 30.0) : 30.0; }
    // Signed off at a clean stop (Supervisor::stop): its name is free at once.
    bool stopped() const { return info.is_object() && info.value("stopped", false); }
    // Renewing its heartbeat: not stopped, its last heartbeat within its lease.
    bool alive() const { return !stopped() && heartbeat_age < lease_seconds(); }
};

struct JobRecord {
    JobStatus status;
    std::string node;        // the node that runs it, or ran it last ("" never claimed)
    std::string owner;       // hash of the token that created it
    std::string cache_key;   // equal keys = equal bakes (scene bytes, outputs, seed)
    double max_seconds = 0;  // deadline of one attempt
};

class JobStore {
public:
    virtual ~JobStore() = default;

    // --- scenes: stored once per content, owned by every token that uploaded
    // them, each owner under the file name it uploaded them as
    virtual std::optional<SceneRecord> scene(const std::string& id) = 0;
    // The scene as `owner` uploaded it (its `name` that owner's), or nullopt
    // when `owner` has not uploaded it.
    virtual std::optional<SceneRecord> scene_for(const std::string& id, const std::string& owner) = 0;
    virtual void add_scene(const SceneRecord& scene) = 0;  // no-op if it exists
    // `owner` uploaded the scene as `name`. Returns false (and keeps the
    // name it had) when `owner` already had it.
    virtual bool add_scene_owner(const std::string& id, const std::string& owner, const std::string& name) = 0;
    virtual bool scene_owned_by(const std::string& id, const std::string& owner) = 0;

    // --- jobs
    // Inserts a job with its first events (a cache hit is born succeeded,
    // with its "done" event).
    virtual void insert_job(const JobRecord& job, const std::vector<JobEvent>& events = {}) = 0;
    virtual std::optional<JobRecord> job(const std::string& id) = 0;
    virtual std::vector<JobRecord> jobs_of(const std::string& owner) = 0;  // newest first
    virtual int queued_count(const std::string& owner) = 0;
    // Jobs queued before job `id` (any owner's): the ones to start first.
    virtual int queued_ahead(const std::string& id) = 0;
    virtual std::map<JobState, int> count_by_state() = 0;
    // A succeeded job of `owner` with this cache key, if any. Only the
    // owner's own: a hit on another tenant's bake (answered in 4 ms where a
    // bake takes seconds) told a tenant that someone had baked those bytes
    // with those settings (issue #55).
    virtual std::optional<JobRecord> succeeded_with_key(const std::string& cache_key, const std::string& owner) = 0;

    // The oldest queued job, now running on this node with one more attempt
    // counted and a lease of lease_seconds. Several nodes claiming at once
    // each get a different job.
    virtual std::optional<JobRecord> claim_next() = 0;
    // Extends the lease of a job running on this node. False when the job no
    // longer runs here (cancelled, or taken over after the lease expired):
    // its worker must stop, and its attempt writes nothing more.
    virtual bool renew_lease(const std::string& id) = 0;
    // Running jobs whose node is gone, now leased to this node as they were
    // (their `node` the one that lost them), for the caller to requeue or
    // fail: those whose lease expired and, with `at_start`, those this
    // node's name held before (a previous lightfarmd of this node). Each
    // such job goes to exactly one node.
    virtual std::vector<JobRecord> take_over_abandoned(bool at_start) = 0;
    virtual void set_progress(const std::string& id, const Progress& p) = 0;
    // The newest file of one output (from a snapshot or done event), kept
    // across attempts until a newer event replaces it.
    virtual void set_latest(const std::string& id, const std::string& output, const LatestFile& file) = 0;
    // What a cancelled job's worker wrote in its grace after the cancel
    // (its last snapshot: Supervisor::kCancelGraceSeconds): its progress and
    // newest files, where the job is cancelled and ran on this node. No
    // event: the job's final event stays its last.
    virtual void set_cancelled_result(const std::string& id, const std::optional<Progress>& progress,
                                      const std::map<std::string, LatestFile>& latest) = 0;
    // Running -> queued after a failed attempt (or, with refund, an
    // interruption that is not the job's fault). Appends `event` (a
    // "retrying" event) in the same transaction. False if no longer running
    // on this node.
    virtual bool requeue(const std::string& id, const JobEvent& event, bool refund_attempt) = 0;
    // Queued/running -> a final state, with its final event, atomically: the
    // final event is always the job's last. False if it was already final.
    virtual bool finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                        const JobEvent& event) = 0;
    // Every running job, on any node.
    virtual std::vector<JobRecord> running_jobs() = 0;
    // Wall seconds (its last attempt's start to its end) of the `n` jobs
    // that succeeded last after running (not answered from the cache), any
    // owner's: what prices a queued job's wait (queue_estimate.h).
    virtual std::vector<double> recent_job_seconds(int n) = 0;
    // True when the store holds no job and no scene (a new store, or one that
    // lost its records: lightfarmd checks this against the data directory).
    virtual bool empty() = 0;
    virtual bool has_job(const std::string& id) = 0;

    // --- events: ids are assigned here, 1, 2, 3 ... per job, never reused
    // Appends a non-final event while the job is running on this node;
    // returns its id, or 0 when it is not (the event is dropped).
    // set_progress and set_latest likewise change nothing then.
    //
    // Progress events are coalesced so that the store grows with jobs, not
    // passes: of one output's progress events, those of passes 1..32 and of
    // every power of two are kept, and of the others only the newest (a new
    // one replaces it). Every other event is kept. So a client resuming after
    // event N (Last-Event-ID) gets every later event that is not a replaced
    // progress event, in order, each once; ids may skip the replaced ones.
    virtual int64_t append_event(const std::string& id, const JobEvent& event) = 0;
    virtual std::vector<JobEvent> events_after(const std::string& id, int64_t after) = 0;
    // Retention: of jobs that finished before `finished_before` (seconds since
    // the epoch), keeps every event but progress, and of progress only the
    // newest per output. Returns the number of events removed.
    virtual int64_t compact_events(double finished_before) = 0;

    // --- nodes
    const NodeIdentity& node() const { return node_; }
    // Records that this node is alive, with what it says of itself.
    virtual void heartbeat(const nlohmann::json& info) = 0;
    virtual std::vector<NodeRecord> nodes() = 0;  // by name

protected:
    // An empty name is the default one (default_node_name()).
    explicit JobStore(NodeIdentity node);

private:
    NodeIdentity node_;
};

// ---- rules the store keeps

// An event's data field marking it as the worker's last line said again
// (a long stage or pass: gi/bake/event_heartbeat.h): "again": true.
inline constexpr const char* kAgain = "again";

// Progress events of passes 1..32 and of every power of two are kept; of the
// others only the newest per output (append_event); a progress or preparing
// event said again is kept only until the next of its kind.
bool permanent_progress(const nlohmann::json& data);
// What a progress event replaces an older one of: its output; for a
// preparing event said again, "preparing". Empty for other events.
std::string progress_key(const JobEvent& event);
// Whether the store coalesces `event` (progress, and preparing said again).
bool coalesced_event(const JobEvent& event);
double now_seconds();  // since the epoch

}  // namespace lf::server
