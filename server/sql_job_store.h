// JobStore over SQL, each statement written once for both databases:
// SqliteJobStore (one lightfarmd, DATA/jobs.sqlite) and PostgresJobStore
// (many lightfarmd nodes on one database, docs/scale-out.md) differ only in
// their SqlConnection (sql_connection.h): how it connects, migrates its
// schema, runs a statement and a transaction, and the fragments of its
// dialect.
//
// What sharing a database needs holds on both: a job is claimed by one
// statement that skips rows other nodes are claiming (FOR UPDATE SKIP
// LOCKED), so two nodes never get the same one; leases and heartbeats are
// timed by the database's clock (one clock for all nodes); every transaction
// that adds events to a job first locks the job's row (or, on SQLite, the
// database), so event ids are given in commit order and a reader on any node
// sees them without gaps.
//
// One connection behind a mutex: the store is tiny next to a bake, and this
// keeps transactions simple. Every statement's and every COMMIT's result is
// checked: a failure is a StoreError and the transaction is rolled back.
#pragma once

#include "job_store.h"
#include "sql_connection.h"

#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace lf::server {

class SqlJobStore : public JobStore {
public:
    std::optional<SceneRecord> scene(const std::string& id) override;
    void add_scene(const SceneRecord& scene) override;
    std::optional<SceneRecord> scene_for(const std::string& id, const std::string& owner) override;
    bool add_scene_owner(const std::string& id, const std::string& owner, const std::string& name) override;
    bool scene_owned_by(const std::string& id, const std::string& owner) override;

    void insert_job(const JobRecord& job, const std::vector<JobEvent>& events) override;
    std::optional<JobRecord> job(const std::string& id) override;
    std::vector<JobRecord> jobs_of(const std::string& owner) override;
    int queued_count(const std::string& owner) override;
    int queued_ahead(const std::string& id) override;
    std::map<JobState, int> count_by_state() override;
    std::optional<JobRecord> succeeded_with_key(const std::string& cache_key, const std::string& owner) override;

    std::optional<JobRecord> claim_next() override;
    bool renew_lease(const std::string& id) override;
    std::vector<JobRecord> take_over_abandoned(bool at_start) override;
    void set_progress(const std::string& id, const Progress& p) override;
    void set_latest(const std::string& id, const std::string& output, const LatestFile& file) override;
    // In sql_job_store_cancelled.cpp.
    void set_cancelled_result(const std::string& id, const std::optional<Progress>& progress,
                              const std::map<std::string, LatestFile>& latest) override;
    bool requeue(const std::string& id, const JobEvent& event, bool refund_attempt) override;
    bool finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                const JobEvent& event) override;
    std::vector<JobRecord> running_jobs() override;
    std::vector<double> recent_job_seconds(int n) override;
    bool empty() override;
    bool has_job(const std::string& id) override;

    int64_t append_event(const std::string& id, const JobEvent& event) override;
    std::vector<JobEvent> events_after(const std::string& id, int64_t after) override;
    int64_t compact_events(double finished_before) override;

    void heartbeat(const nlohmann::json& info) override;
    std::vector<NodeRecord> nodes() override;

protected:
    // `db`: connected, its schema migrated.
    SqlJobStore(std::unique_ptr<SqlConnection> db, NodeIdentity node);
    const SqlConnection& connection() const { return *db_; }

private:
    // `where`: what follows "SELECT <the job columns> FROM jobs".
    std::vector<JobRecord> select_jobs(const char* what, const std::string& where, const std::vector<SqlValue>& params);
    // Adds an event; the caller holds the job's row lock (or inserted the job).
    int64_t insert_event_locked(const std::string& id, const JobEvent& event);

    std::mutex mutex_;
    std::unique_ptr<SqlConnection> db_;
};

}  // namespace lf::server
