// JobStore in a PostgreSQL database that many lightfarmd nodes share
// (`lightfarmd --store postgresql://USER@HOST:PORT/DB`, docs/scale-out.md).
//
// The same semantics as SqliteJobStore, with what sharing needs: a job is
// claimed with SELECT ... FOR UPDATE SKIP LOCKED (two nodes never get the
// same one); leases are timed by the database's clock (one clock for all
// nodes); every statement that adds events to a job first locks the job's row,
// so event ids are given in commit order and a reader on any node sees them
// without gaps. The schema is versioned (table schema_version) and migrated at
// start; a database with a newer schema than this lightfarmd knows is refused.
//
// One connection behind a mutex, like the SQLite store. A lost connection
// (database restarted, network cut) fails the call in progress with a
// StoreError, and the next call connects again.
#pragma once

#include "job_store.h"

#include <atomic>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

struct pg_conn;
struct pg_result;

namespace lf::server {

class PostgresJobStore : public JobStore {
public:
    // The newest schema this lightfarmd knows (its migrations: postgres_job_store.cpp).
    static constexpr int kSchemaVersion = 1;

    // Connects to `uri` (a libpq connection URI) and migrates the schema.
    // Throws std::invalid_argument for a URI libpq cannot read, StoreError
    // when the database cannot be reached or migrated, std::runtime_error
    // when its schema is newer than kSchemaVersion.
    PostgresJobStore(const std::string& uri, NodeIdentity node = {});
    ~PostgresJobStore() override;

    std::optional<SceneRecord> scene(const std::string& id) override;
    void add_scene(const SceneRecord& scene) override;
    bool add_scene_owner(const std::string& id, const std::string& owner) override;
    bool scene_owned_by(const std::string& id, const std::string& owner) override;

    void insert_job(const JobRecord& job, const std::vector<JobEvent>& events) override;
    std::optional<JobRecord> job(const std::string& id) override;
    std::vector<JobRecord> jobs_of(const std::string& owner) override;
    int queued_count(const std::string& owner) override;
    std::map<JobState, int> count_by_state() override;
    std::optional<JobRecord> succeeded_with_key(const std::string& cache_key) override;

    std::optional<JobRecord> claim_next() override;
    bool renew_lease(const std::string& id) override;
    std::vector<JobRecord> take_over_abandoned(bool at_start) override;
    void set_progress(const std::string& id, const Progress& p) override;
    void set_latest(const std::string& id, const std::string& output, const LatestFile& file) override;
    bool requeue(const std::string& id, const JobEvent& event, bool refund_attempt) override;
    bool finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                const JobEvent& event) override;
    std::vector<JobRecord> running_jobs() override;
    bool empty() override;
    bool has_job(const std::string& id) override;

    int64_t append_event(const std::string& id, const JobEvent& event) override;
    std::vector<JobEvent> events_after(const std::string& id, int64_t after) override;
    int64_t compact_events(double finished_before) override;

    void heartbeat(const nlohmann::json& info) override;
    std::vector<NodeRecord> nodes() override;

    // "user@host:port/db": the database as messages name it (never a password).
    const std::string& where() const { return where_; }

    // Test hook: the number of statements sent so far (docs/BENCHMARKS.md's
    // per-job query counts).
    int64_t statements_sent() const { return statements_; }

private:
    class Result;
    class Transaction;
    using Param = std::optional<std::string>;  // nullopt: SQL NULL

    // Reconnects when the connection was lost; throws StoreError when it cannot.
    void connect_if_lost();
    // Runs one statement; `sql` uses '?' placeholders, as the SQLite store's.
    // Throws StoreError naming `what` on failure.
    Result run(const char* what, const std::string& sql, const std::vector<Param>& params = {});
    void migrate();
    std::vector<JobRecord> jobs_from(const Result& rows, int first_column = 0) const;
    std::vector<JobRecord> select_jobs(const char* what, const std::string& where, const std::vector<Param>& params);
    int64_t insert_event_locked(const std::string& id, const JobEvent& event);

    std::mutex mutex_;
    pg_conn* conn_ = nullptr;
    std::string uri_;
    std::string where_;
    std::atomic<int64_t> statements_{0};
};

}  // namespace lf::server
