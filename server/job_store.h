// Where jobs, their events and scene ownership live. The routes and the
// supervisor only see this interface; SqliteJobStore is the embedded default,
// and a networked store can be added beside it without touching them.
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

#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf::server {

// The store could not read or write (disk full, I/O error, a database file made
// read-only, locked for too long). Nothing of the failed call was stored. The
// message names what failed, never a path.
class StoreError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

using protocol::JobEvent;
using protocol::JobState;
using protocol::JobStatus;
using protocol::LatestFile;
using protocol::Progress;

struct SceneRecord {
    std::string id;          // content hash
    std::string main_file;   // the .glb or .gltf inside the scene's directory
    nlohmann::json summary;  // `lightfarm inspect --json` of it
};

struct JobRecord {
    JobStatus status;
    std::string owner;       // hash of the token that created it
    std::string cache_key;   // equal keys = equal bakes (scene bytes, outputs, seed)
    double max_seconds = 0;  // deadline of one attempt
};

class JobStore {
public:
    virtual ~JobStore() = default;

    // --- scenes: stored once per content, owned by every token that uploaded them
    virtual std::optional<SceneRecord> scene(const std::string& id) = 0;
    virtual void add_scene(const SceneRecord& scene) = 0;  // no-op if it exists
    // Returns false when `owner` already had it.
    virtual bool add_scene_owner(const std::string& id, const std::string& owner) = 0;
    virtual bool scene_owned_by(const std::string& id, const std::string& owner) = 0;

    // --- jobs
    // Inserts a job with its first events (a cache hit is born succeeded,
    // with its "done" event).
    virtual void insert_job(const JobRecord& job, const std::vector<JobEvent>& events = {}) = 0;
    virtual std::optional<JobRecord> job(const std::string& id) = 0;
    virtual std::vector<JobRecord> jobs_of(const std::string& owner) = 0;  // newest first
    virtual int queued_count(const std::string& owner) = 0;
    virtual std::map<JobState, int> count_by_state() = 0;
    // A succeeded job with this cache key, if any.
    virtual std::optional<JobRecord> succeeded_with_key(const std::string& cache_key) = 0;

    // The oldest queued job, now running with one more attempt counted.
    virtual std::optional<JobRecord> claim_next() = 0;
    virtual void set_progress(const std::string& id, const Progress& p) = 0;
    // The newest file of one output (from a snapshot or done event), kept
    // across attempts until a newer event replaces it.
    virtual void set_latest(const std::string& id, const std::string& output, const LatestFile& file) = 0;
    // Running -> queued after a failed attempt (or, with refund, an
    // interruption that is not the job's fault). Appends `event` (a
    // "retrying" event) in the same transaction. False if no longer running.
    virtual bool requeue(const std::string& id, const JobEvent& event, bool refund_attempt) = 0;
    // Queued/running -> a final state, with its final event, atomically: the
    // final event is always the job's last. False if it was already final.
    virtual bool finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                        const JobEvent& event) = 0;
    // Jobs left running by a previous lightfarmd (it stopped or was killed).
    virtual std::vector<JobRecord> running_jobs() = 0;
    // True when the store holds no job and no scene (a new store, or one that
    // lost its records: lightfarmd checks this against the data directory).
    virtual bool empty() = 0;
    virtual bool has_job(const std::string& id) = 0;

    // --- events: ids are assigned here, 1, 2, 3 ... per job, never reused
    // Appends a non-final event while the job is running; returns its id, or
    // 0 when the job is no longer running (the event is dropped).
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
};

}  // namespace lf::server
