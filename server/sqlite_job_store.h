// JobStore in one SQLite file (DATA/jobs.sqlite). One connection behind a
// mutex: the store is tiny next to a bake, and this keeps transactions simple.
// Every statement's and every COMMIT's result is checked: a failure is a
// StoreError and the transaction is rolled back.
#pragma once

#include "job_store.h"

#include <mutex>
#include <string>

struct sqlite3;

namespace lf::server {

class SqliteJobStore : public JobStore {
public:
    // Creates the schema if needed. `node`: who this lightfarmd is (one per file).
    explicit SqliteJobStore(const std::string& path, NodeIdentity node = {});
    ~SqliteJobStore() override;

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

    // Test hook: every SQLite database this process opens *after the first
    // call* goes through a VFS that, while `fail` is true, fails each write
    // as a full disk does (SQLITE_FULL); reads still work. lightfarmd never
    // calls it. (As root, chmod cannot make a file unwritable; this can.)
    static void simulate_full_disk_for_tests(bool fail);

private:
    class Statement;
    void exec(const char* sql);
    std::vector<JobRecord> select_jobs(const std::string& where, const std::vector<std::string>& args);
    int64_t insert_event_locked(const std::string& id, const JobEvent& event);

    std::mutex mutex_;
    sqlite3* db_ = nullptr;
    std::string path_;
};

}  // namespace lf::server
