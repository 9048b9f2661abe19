// The store never lies (issue #15): a write that cannot be stored throws
// StoreError and stores nothing; the supervisor keeps a job's updates and its
// end until the store takes them; progress events are coalesced without
// breaking the event stream's resume; a lost store is refused at start; one
// lightfarmd per data directory; data files 0600 and folders 0700; upload
// checks bounded in number and memory.
//
// A full disk is staged with SqliteJobStore::simulate_full_disk_for_tests (a
// VFS whose writes fail with SQLITE_FULL): chmod cannot stop root, and CI runs
// as root.
//
// The store's own rules (StoreTest) run against both stores: SQLite, and
// PostgreSQL started by the test itself (postgres_server.h). So do leases and
// concurrent claims by several nodes; PostgresStore adds what only a network
// store has: a lost connection, schema versions.
#include "postgres_server.h"
#include "server_harness.h"

#include "config.h"
#include "events.h"
#include "hash.h"
#include "http_error.h"
#include "metrics.h"
#include "postgres_job_store.h"
#include "scene_store.h"
#include "service.h"
#include "sqlite_job_store.h"
#include "subprocess.h"
#include "supervisor.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <map>
#include <set>
#include <sstream>
#include <thread>

extern char** environ;

namespace lf::test {
namespace {

using nlohmann::json;
using server::JobRecord;
using server::JobState;
using server::JobStore;
using server::NodeIdentity;
using server::PostgresJobStore;
using server::SqliteJobStore;
using server::StoreError;

const std::string kAlice = "alice-token-0123456789";

// Every store of this test program goes through the test VFS: installed
// before the first store opens, writes working until a test fails them.
struct FullDisk {
    FullDisk() { SqliteJobStore::simulate_full_disk_for_tests(true); }
    ~FullDisk() { SqliteJobStore::simulate_full_disk_for_tests(false); }
};
const bool kVfsInstalled = [] {
    SqliteJobStore::simulate_full_disk_for_tests(false);
    return true;
}();

JobRecord queued_job(const std::string& id, const std::string& scene = "scene-1", int passes = 4) {
    JobRecord job;
    job.status.id = id;
    job.status.scene = scene;
    job.status.state = JobState::Queued;
    job.status.spec = {{"scene", scene}, {"seed", 1}, {"outputs", {{"lightmap", {{"passes", passes}}}}}};
    job.status.max_attempts = 3;
    job.owner = server::sha256_hex(kAlice);
    job.cache_key = "key-" + id;
    job.max_seconds = 60;
    return job;
}

json progress_data(int pass, const std::string& output = "lightmap") {
    return {
        {"output", output}, {"pass", pass}, {"rays", pass * 1000}, {"seconds", pass}, {"error_estimate", 1.0 / pass}};
}

// ---------------------------------------------------------------- the store

TEST(Store, AFailedWriteThrowsAndStoresNothing) {
    ASSERT_TRUE(kVfsInstalled);
    TempDir tmp;
    SqliteJobStore store((tmp.path / "jobs.sqlite").string());
    {
        FullDisk full;
        EXPECT_THROW(store.insert_job(queued_job("j1"), {{0, "done", {{"cached", true}}}}), StoreError);
        EXPECT_THROW(store.add_scene({"scene-1", "scene.glb", {{"triangles", 12}}}), StoreError);
        EXPECT_THROW(store.add_scene_owner("scene-1", "owner", "scene.glb"), StoreError);
        // Reads still work, and show that nothing was stored.
        EXPECT_FALSE(store.job("j1"));
        EXPECT_TRUE(store.events_after("j1", 0).empty());
        EXPECT_FALSE(store.scene("scene-1"));
        EXPECT_TRUE(store.empty());
    }
    // Once the disk has room again, the same store carries on.
    store.insert_job(queued_job("j1"), {});
    store.add_scene({"scene-1", "scene.glb", {{"triangles", 12}}});
    EXPECT_TRUE(store.add_scene_owner("scene-1", "owner", "scene.glb"));
    ASSERT_TRUE(store.job("j1"));
    EXPECT_EQ(store.job("j1")->status.state, JobState::Queued);
    EXPECT_FALSE(store.empty());
}

TEST(Store, EveryTransactionFailsWholeOnAFullDisk) {
    TempDir tmp;
    SqliteJobStore store((tmp.path / "jobs.sqlite").string());
    store.insert_job(queued_job("j1"), {});
    {
        FullDisk full;
        EXPECT_THROW(store.claim_next(), StoreError);
    }
    EXPECT_EQ(store.job("j1")->status.state, JobState::Queued) << "a failed claim leaves the job queued";
    EXPECT_EQ(store.job("j1")->status.attempts, 0);
    ASSERT_TRUE(store.claim_next());
    {
        FullDisk full;
        EXPECT_THROW(store.append_event("j1", {0, "started", {{"attempt", 1}}}), StoreError);
        server::Progress p;
        p.pass = 3;
        EXPECT_THROW(store.set_progress("j1", p), StoreError);
        EXPECT_THROW(store.set_latest("j1", "lightmap", {"lightmap.pass-0001.exr", 1, false}), StoreError);
        EXPECT_THROW(store.requeue("j1", {0, "retrying", {{"attempt", 1}}}, false), StoreError);
        EXPECT_THROW(store.finish("j1", JobState::Succeeded, "", "", {0, "done", json::object()}), StoreError);
    }
    EXPECT_EQ(store.job("j1")->status.state, JobState::Running);
    EXPECT_EQ(store.job("j1")->status.progress.pass, 0);
    EXPECT_TRUE(store.events_after("j1", 0).empty());
    EXPECT_EQ(store.append_event("j1", {0, "started", {{"attempt", 1}}}), 1);
    EXPECT_TRUE(store.finish("j1", JobState::Succeeded, "", "", {0, "done", json::object()}));
    const auto events = store.events_after("j1", 0);
    ASSERT_EQ(events.size(), 2u);
    EXPECT_EQ(events[1].id, 2);
    EXPECT_EQ(events[1].type, "done");
}

// A tenant is told why the store refused in its own terms, never the
// database's internals (issue #55: PostgreSQL's file path, HINT and
// address reached tenants' messages): StoreError::cause, from SQLite's
// result code or PostgreSQL's SQLSTATE; what() keeps the whole story for
// the log.
TEST(Store, ATenantIsToldWhyInTheStoresTermsNotItsInternals) {
    TempDir tmp;
    const std::string path = (tmp.path / "jobs.sqlite").string();
    SqliteJobStore store(path);
    {
        FullDisk full;
        try {
            store.insert_job(queued_job("j1"), {});
            ADD_FAILURE() << "a full disk stored a job";
        } catch (const StoreError& e) {
            EXPECT_EQ(e.cause(), "its disk is full");
            EXPECT_EQ(e.cause().find(tmp.path.string()), std::string::npos);
            EXPECT_NE(std::string(e.what()).find("job store"), std::string::npos) << "the log's story: " << e.what();
        }
    }
    EXPECT_EQ(server::sqlite_store_cause(SQLITE_FULL), "its disk is full");
    EXPECT_EQ(server::sqlite_store_cause(SQLITE_IOERR_WRITE), "its disk answered with an I/O error");
    EXPECT_EQ(server::sqlite_store_cause(SQLITE_READONLY_DBMOVED), "it is read-only");
    EXPECT_EQ(server::sqlite_store_cause(SQLITE_ERROR), StoreError::kFailed);
    EXPECT_EQ(server::postgres_store_cause("53100", false), "its disk is full");
    EXPECT_EQ(server::postgres_store_cause("53200", false), "it is out of resources");
    EXPECT_EQ(server::postgres_store_cause("08006", false), "it cannot be reached");
    EXPECT_EQ(server::postgres_store_cause("", true), "it cannot be reached");
    EXPECT_EQ(server::postgres_store_cause("25006", false), "it is read-only");
    EXPECT_EQ(server::postgres_store_cause("57014", false), "it is busy");
    EXPECT_EQ(server::postgres_store_cause("58030", false), "its disk answered with an I/O error");
    EXPECT_EQ(server::postgres_store_cause("42P01", false), StoreError::kFailed);
}

// One PostgreSQL server for the whole program, started by the first test that
// needs it, stopped at exit; each test gets a database of its own.
PostgresServer& postgres() {
    static PostgresServer server;
    return server;
}

// The store a StoreTest runs against, and more nodes on the same one.
class StoreTest : public testing::TestWithParam<std::string> {
protected:
    void SetUp() override {
        if (GetParam() == "postgresql") location_ = postgres().create_database();
        else location_ = (tmp_.path / "jobs.sqlite").string();
        store_ = open(NodeIdentity{"node-a", 30});
    }
    // Another node (or the same one again) on this test's store.
    std::unique_ptr<JobStore> open(const NodeIdentity& node) const {
        if (GetParam() == "postgresql") return std::make_unique<PostgresJobStore>(location_, node);
        return std::make_unique<SqliteJobStore>(location_, node);
    }
    JobStore& store() { return *store_; }

private:
    TempDir tmp_;
    std::string location_;
    std::unique_ptr<JobStore> store_;
};

INSTANTIATE_TEST_SUITE_P(BothStores, StoreTest, testing::Values("sqlite", "postgresql"),
                         [](const testing::TestParamInfo<std::string>& p) { return p.param; });

// A running job with `passes` progress events and a snapshot at each power of two.
void run_progress(JobStore& store, const std::string& id, int passes, const std::string& output = "lightmap") {
    for (int p = 1; p <= passes; ++p) {
        ASSERT_GT(store.append_event(id, {0, "progress", progress_data(p, output)}), 0);
        if ((p & (p - 1)) == 0) {
            ASSERT_GT(store.append_event(id, {0, "snapshot", {{"output", output}, {"pass", p}}}), 0);
        }
    }
}

TEST_P(StoreTest, ProgressEventsAreCoalescedSoTheStoreGrowsWithJobsNotPasses) {
    JobStore& store = this->store();
    store.insert_job(queued_job("j1"), {});
    ASSERT_TRUE(store.claim_next());
    store.append_event("j1", {0, "started", {{"attempt", 1}}});
    run_progress(store, "j1", 5000);
    const auto events = store.events_after("j1", 0);
    // started, 13 snapshots, progress of passes 1..32, 64 .. 4096 (7) and the newest (5000).
    std::vector<int> progress_passes;
    int snapshots = 0;
    for (const auto& e : events) {
        if (e.type == "progress") progress_passes.push_back(e.data["pass"].get<int>());
        if (e.type == "snapshot") ++snapshots;
    }
    EXPECT_EQ(snapshots, 13);
    ASSERT_EQ(progress_passes.size(), 32u + 7u + 1u);
    EXPECT_EQ(progress_passes.front(), 1);
    EXPECT_EQ(progress_passes[31], 32);
    EXPECT_EQ(progress_passes[32], 64);
    EXPECT_EQ(progress_passes.back(), 5000) << "the newest progress is always there";
    // Ids only grow, and the newest is the number of events appended: none reused.
    for (size_t i = 1; i < events.size(); ++i) EXPECT_LT(events[i - 1].id, events[i].id);
    EXPECT_EQ(events.back().id, 1 + 5000 + 13);
}

// What prices a queued job's wait (server/queue_estimate.h): the wall
// times of the jobs that ran and succeeded, newest first; not a cache hit
// (born succeeded, it never ran), not a failed job.
TEST_P(StoreTest, RecentJobSecondsAreOfTheJobsThatRanAndSucceeded) {
    JobStore& store = this->store();
    EXPECT_TRUE(store.recent_job_seconds(20).empty());
    for (const char* id : {"ran", "broke"}) {
        store.insert_job(queued_job(id), {});
        ASSERT_TRUE(store.claim_next());
    }
    ASSERT_TRUE(store.finish("ran", JobState::Succeeded, "", "", {0, "done", json::object()}));
    ASSERT_TRUE(store.finish("broke", JobState::Failed, "bad", "", {0, "failed", json::object()}));
    JobRecord hit = queued_job("hit");
    hit.status.state = JobState::Succeeded;
    hit.status.cached = true;
    hit.status.finished_at = hit.status.created_at = server::now_seconds();
    store.insert_job(hit, {{0, "done", json::object()}});
    const std::vector<double> seconds = store.recent_job_seconds(20);
    ASSERT_EQ(seconds.size(), 1u);
    const JobRecord ran = *store.job("ran");
    EXPECT_DOUBLE_EQ(seconds[0], ran.status.finished_at - ran.status.started_at);
    EXPECT_GE(seconds[0], 0.0);
    EXPECT_TRUE(store.recent_job_seconds(0).empty());
}

// Lines said again (a long stage or pass, marked "again" by the
// supervisor) do not pile up: the store keeps the first of each stage and
// pass, and only the newest line said again.
TEST_P(StoreTest, LinesSaidAgainKeepOnlyTheNewest) {
    JobStore& store = this->store();
    store.insert_job(queued_job("j1"), {});
    ASSERT_TRUE(store.claim_next());
    for (const char* stage : {"atlas", "methods"}) {
        store.append_event("j1", {0, "preparing", {{"stage", stage}, {"seconds", 1.0}}});
        for (int i = 0; i < 5; ++i)
            store.append_event("j1",
                               {0, "preparing", {{"stage", stage}, {"seconds", 2.0 + i}, {server::kAgain, true}}});
    }
    store.append_event("j1", {0, "started", {{"attempt", 1}}});
    store.append_event("j1", {0, "progress", progress_data(16)});
    for (int i = 0; i < 5; ++i) {
        json again = progress_data(16);
        again[server::kAgain] = true;
        store.append_event("j1", {0, "progress", again});
    }
    std::vector<std::string> kept;
    for (const auto& e : store.events_after("j1", 0))
        kept.push_back(e.type + (e.data.value(server::kAgain, false) ? " again" : ""));
    EXPECT_EQ(kept, (std::vector<std::string>{"preparing", "preparing", "preparing again", "started", "progress",
                                              "progress again"}));
}

TEST_P(StoreTest, ResumingAfterAnyEventGetsEveryLaterEventOnceAndNoReplacedProgress) {
    JobStore& store = this->store();
    store.insert_job(queued_job("j1"), {});
    ASSERT_TRUE(store.claim_next());
    // A reader that resumes (Last-Event-ID) after every few appends, as a
    // client reconnecting does, sees every non-progress event exactly once,
    // in order, and ids that only grow.
    int64_t last = 0;
    std::vector<std::string> seen_snapshots;
    std::vector<std::string> appended_snapshots;
    std::set<int64_t> seen_ids;
    for (int p = 1; p <= 300; ++p) {
        store.append_event("j1", {0, "progress", progress_data(p)});
        if (p % 7 == 0) {
            const std::string name = "snap-" + std::to_string(p);
            store.append_event("j1", {0, "snapshot", {{"output", "lightmap"}, {"file", name}}});
            appended_snapshots.push_back(name);
        }
        if (p % 5 == 0 || p % 13 == 0) {
            for (const auto& e : store.events_after("j1", last)) {
                EXPECT_GT(e.id, last);
                EXPECT_TRUE(seen_ids.insert(e.id).second) << "event " << e.id << " twice";
                last = e.id;
                if (e.type == "snapshot") seen_snapshots.push_back(e.data["file"]);
            }
        }
    }
    EXPECT_TRUE(store.finish("j1", JobState::Succeeded, "", "", {0, "done", json::object()}));
    const auto rest = store.events_after("j1", last);
    ASSERT_FALSE(rest.empty());
    for (const auto& e : rest)
        if (e.type == "snapshot") seen_snapshots.push_back(e.data["file"]);
    EXPECT_EQ(rest.back().type, "done");
    EXPECT_EQ(seen_snapshots, appended_snapshots);
    // A progress event replaced right after it was the newest: its id is not
    // given again, so a reader that had it gets the next one.
    const auto all = store.events_after("j1", 0);
    EXPECT_EQ(all.back().id, 300 + 300 / 7 + 1);
}

TEST_P(StoreTest, RetentionKeepsOnlyTheNewestProgressOfOldFinishedJobs) {
    JobStore& store = this->store();
    store.insert_job(queued_job("old"), {});
    store.insert_job(queued_job("running"), {});
    ASSERT_EQ(store.claim_next()->status.id, "old");
    ASSERT_EQ(store.claim_next()->status.id, "running");
    run_progress(store, "old", 100, "lightmap");
    run_progress(store, "old", 40, "sh");
    run_progress(store, "running", 100);
    ASSERT_TRUE(store.finish("old", JobState::Succeeded, "", "", {0, "done", json::object()}));
    const size_t before_old = store.events_after("old", 0).size();
    const size_t before_running = store.events_after("running", 0).size();
    const double now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();

    EXPECT_EQ(store.compact_events(now - 3600), 0) << "a job finished just now keeps its events";
    EXPECT_EQ(store.events_after("old", 0).size(), before_old);

    EXPECT_GT(store.compact_events(now + 1), 0);
    const auto old = store.events_after("old", 0);
    std::map<std::string, int> progress;
    int snapshots = 0;
    for (const auto& e : old) {
        if (e.type == "progress") progress[e.data["output"]] = e.data["pass"];
        if (e.type == "snapshot") ++snapshots;
    }
    EXPECT_EQ(progress, (std::map<std::string, int>{{"lightmap", 100}, {"sh", 40}}));
    EXPECT_EQ(snapshots, 7 + 6) << "every other event is kept";
    EXPECT_EQ(old.back().type, "done");
    EXPECT_EQ(store.events_after("running", 0).size(), before_running) << "a running job is not compacted";
}

TEST_P(StoreTest, AJobIsTheClaimingNodesUntilItsLeaseExpiresThenAnotherTakesItOver) {
    // Node a claims with a 1 s lease; node b shares the store.
    std::unique_ptr<JobStore> a = open({"node-a", 1});
    std::unique_ptr<JobStore> b = open({"node-b", 1});
    a->insert_job(queued_job("j1"), {});
    const std::optional<JobRecord> claimed = a->claim_next();
    ASSERT_TRUE(claimed);
    EXPECT_EQ(claimed->node, "node-a");
    EXPECT_EQ(claimed->status.attempts, 1);
    EXPECT_FALSE(b->claim_next()) << "a running job is not claimed twice";
    // Only the running node writes into the attempt.
    EXPECT_EQ(b->append_event("j1", {0, "started", {{"attempt", 1}}}), 0);
    EXPECT_FALSE(b->renew_lease("j1"));
    EXPECT_FALSE(b->requeue("j1", {0, "retrying", json::object()}, false));
    EXPECT_EQ(a->append_event("j1", {0, "started", {{"attempt", 1}}}), 1);
    EXPECT_TRUE(a->renew_lease("j1"));
    EXPECT_TRUE(b->take_over_abandoned(false).empty()) << "a renewed lease is not taken over";

    std::this_thread::sleep_for(std::chrono::milliseconds(1300));  // a stops renewing: its lease expires
    const std::vector<JobRecord> taken = b->take_over_abandoned(false);
    ASSERT_EQ(taken.size(), 1u);
    EXPECT_EQ(taken[0].status.id, "j1");
    EXPECT_EQ(taken[0].node, "node-a") << "the node that lost it, for the log";
    EXPECT_TRUE(b->take_over_abandoned(false).empty()) << "taken over once";
    EXPECT_FALSE(a->renew_lease("j1")) << "a learns the job is no longer its own";
    EXPECT_EQ(a->append_event("j1", {0, "progress", progress_data(1)}), 0);
    ASSERT_TRUE(b->requeue("j1", {0, "retrying", {{"attempt", 1}, {"cause", "node-a lost"}}}, false));
    const std::optional<JobRecord> again = b->claim_next();
    ASSERT_TRUE(again);
    EXPECT_EQ(again->status.attempts, 2) << "the lost attempt counts";
    EXPECT_EQ(again->node, "node-b");
    const auto events = b->events_after("j1", 0);
    ASSERT_EQ(events.size(), 2u);
    EXPECT_EQ(events[1].type, "retrying");
}

TEST_P(StoreTest, AtStartANodeTakesOverTheJobsItsPreviousProcessHeld) {
    std::unique_ptr<JobStore> before = open({"node-a", 30});
    before->insert_job(queued_job("j1"), {});
    ASSERT_TRUE(before->claim_next());
    before.reset();  // lightfarmd killed: the lease has 30 s to go
    if (GetParam() == "postgresql") {
        // (With SQLite, one lightfarmd per file: at start, every running job is its predecessor's.)
        std::unique_ptr<JobStore> other = open({"node-b", 30});
        EXPECT_TRUE(other->take_over_abandoned(true).empty()) << "not before its lease expires, for another node";
    }
    std::unique_ptr<JobStore> after = open({"node-a", 30});
    const auto taken = after->take_over_abandoned(true);
    ASSERT_EQ(taken.size(), 1u);
    EXPECT_TRUE(after->requeue("j1", {0, "retrying", json::object()}, false));
}

TEST_P(StoreTest, NodesClaimingAtOnceGetEachJobExactlyOnce) {
    constexpr int kJobs = 60;
    for (int i = 0; i < kJobs; ++i) store().insert_job(queued_job("j" + std::to_string(i)), {});
    std::mutex mutex;
    std::map<std::string, std::string> claimed_by;  // job -> node
    int duplicates = 0;
    std::vector<std::thread> nodes;
    for (const std::string name : {"n1", "n2", "n3"}) {
        nodes.emplace_back([&, name] {
            std::unique_ptr<JobStore> node = open({name, 30});
            while (std::optional<JobRecord> job = node->claim_next()) {
                std::lock_guard lock(mutex);
                duplicates += claimed_by.count(job->status.id) ? 1 : 0;
                claimed_by[job->status.id] = name;
            }
        });
    }
    for (std::thread& t : nodes) t.join();
    EXPECT_EQ(duplicates, 0);
    EXPECT_EQ(claimed_by.size(), size_t(kJobs));
    for (const JobRecord& job : store().running_jobs()) {
        EXPECT_EQ(job.status.attempts, 1);
        EXPECT_EQ(job.node, claimed_by[job.status.id]);
    }
}

TEST_P(StoreTest, NodesReportTheirHeartbeats) {
    std::unique_ptr<JobStore> b = open({"node-b", 30});
    store().heartbeat({{"gpus", 2}, {"workers", 2}});
    b->heartbeat({{"gpus", 0}, {"workers", 1}});
    const auto nodes = store().nodes();
    ASSERT_EQ(nodes.size(), 2u);
    EXPECT_EQ(nodes[0].name, "node-a");
    EXPECT_EQ(nodes[0].info["gpus"], 2);
    EXPECT_EQ(nodes[1].name, "node-b");
    EXPECT_LT(nodes[1].heartbeat_age, 5.0);
}

// One scene's bytes, two owners, two names (issue #33): each owner reads
// its own; an owner's second add keeps its first name; no owner, no scene.
TEST_P(StoreTest, EachOwnerOfASceneHasItsOwnNameForIt) {
    JobStore& store = this->store();
    store.add_scene({"scene-1", "first.glb", {{"triangles", 12}, {"source", "first.glb"}}});
    EXPECT_TRUE(store.add_scene_owner("scene-1", "alice", "first.glb"));
    EXPECT_TRUE(store.add_scene_owner("scene-1", "bob", "mine.glb"));
    EXPECT_FALSE(store.add_scene_owner("scene-1", "bob", "renamed.glb"));
    EXPECT_EQ(store.scene_for("scene-1", "alice")->name, "first.glb");
    const std::optional<server::SceneRecord> bobs = store.scene_for("scene-1", "bob");
    ASSERT_TRUE(bobs);
    EXPECT_EQ(bobs->name, "mine.glb");
    EXPECT_EQ(bobs->main_file, "first.glb") << "the bytes are stored once";
    EXPECT_EQ(bobs->summary["triangles"], 12);
    EXPECT_FALSE(store.scene_for("scene-1", "carol"));
    EXPECT_FALSE(store.scene_for("scene-2", "alice"));
    EXPECT_EQ(store.scene("scene-1")->name, "");
}

// A store from before names per owner: every owner keeps the name the scene
// was stored under. SQLite: the column added at open; PostgreSQL: migration 2.
TEST(Store, AnSqliteStoreFromBeforeNamesPerOwnerKeepsTheStoredName) {
    TempDir tmp;
    const std::string path = (tmp.path / "jobs.sqlite").string();
    {
        SqliteJobStore store(path);
        store.add_scene({"scene-1", "stored.glb", {{"triangles", 12}}});
        store.add_scene_owner("scene-1", "alice", "ignored.glb");
    }
    {
        sqlite3* db = nullptr;
        ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
        // The table as lightfarmd created it before this column.
        EXPECT_EQ(sqlite3_exec(db, "ALTER TABLE scene_owners DROP COLUMN name", nullptr, nullptr, nullptr), SQLITE_OK)
            << sqlite3_errmsg(db);
        sqlite3_close(db);
    }
    SqliteJobStore store(path);
    ASSERT_TRUE(store.scene_for("scene-1", "alice"));
    EXPECT_EQ(store.scene_for("scene-1", "alice")->name, "stored.glb");
    EXPECT_TRUE(store.add_scene_owner("scene-1", "bob", "bobs.glb"));
    EXPECT_EQ(store.scene_for("scene-1", "bob")->name, "bobs.glb");
}

TEST(PostgresStore, MigrationTwoGivesEveryOwnerTheStoredName) {
    const std::string uri = postgres().create_database();
    {
        PostgresJobStore store(uri);
        store.add_scene({"scene-1", "stored.glb", {{"triangles", 12}}});
        store.add_scene_owner("scene-1", "alice", "ignored.glb");
    }
    // Back to schema version 1, as lightfarmd left it before this column.
    postgres().sql(uri, "ALTER TABLE scene_owners DROP COLUMN name; DELETE FROM schema_version WHERE version >= 2");
    PostgresJobStore store(uri);
    ASSERT_TRUE(store.scene_for("scene-1", "alice"));
    EXPECT_EQ(store.scene_for("scene-1", "alice")->name, "stored.glb");
    EXPECT_TRUE(store.add_scene_owner("scene-1", "bob", "bobs.glb"));
    EXPECT_EQ(store.scene_for("scene-1", "bob")->name, "bobs.glb");
}

TEST(Config, TheScaleOutOptionsAreCheckedWithMessagesThatSayWhatToWrite) {
    bool help = false;
    const server::ServerConfig c = server::parse_server_args(
        {"--store", "postgresql://lf@db:5432/lf", "--node-name", "gpu-07", "--lease-seconds", "12"}, help);
    EXPECT_EQ(c.store, "postgresql://lf@db:5432/lf");
    EXPECT_EQ(c.node_name, "gpu-07");
    EXPECT_EQ(c.lease_seconds, 12);
    EXPECT_EQ(server::parse_server_args({}, help).lease_seconds, 30) << "the default lease";
    EXPECT_TRUE(server::parse_server_args({}, help).store.empty()) << "SQLite by default";
    auto refused = [&](const std::vector<std::string>& args) {
        try {
            server::parse_server_args(args, help);
        } catch (const std::invalid_argument& e) {
            return std::string(e.what());
        }
        return std::string("accepted");
    };
    EXPECT_NE(refused({"--store", "mysql://db/lf"}).find("write postgresql://USER@HOST:PORT/DB"), std::string::npos);
    EXPECT_NE(refused({"--lease-seconds", "0.5"}).find("--lease-seconds must be at least 1"), std::string::npos);
    EXPECT_NE(refused({"--node-name", "two words"}).find("--node-name"), std::string::npos);
}

// Every --limit key: a good value is read into its field, and each kind of
// bad value is refused with a message that names the key (a negative count
// wrapped round to a huge unsigned limit; a drain of -1 s or of infinity
// stopped nothing).
TEST(Config, EveryLimitIsReadAndABadValueIsRefusedNamingItsKey) {
    bool help = false;
    auto limits = [&](const std::vector<std::string>& assignments) {
        std::vector<std::string> args;
        for (const std::string& a : assignments) args.insert(args.end(), {"--limit", a});
        return server::parse_server_args(args, help).limits;
    };
    const server::ServerLimits l = limits({"upload_bytes=1000",
                                           "spec_bytes=2000",
                                           "triangles=3000",
                                           "texture_size=512",
                                           "queued_jobs=7",
                                           "free_disk_bytes=1e9",
                                           "header_seconds=2.5",
                                           "request_seconds=30",
                                           "keep_alive_seconds=4",
                                           "drain_seconds=0.5",
                                           "header_bytes=9000",
                                           "connections=100",
                                           "connections_per_address=9",
                                           "event_streams=2",
                                           "event_streams_per_token=3",
                                           "event_streams_per_address=6",
                                           "body_reads=7",
                                           "body_reads_per_token=4",
                                           "body_reads_per_address=5",
                                           "passes=99",
                                           "res=2048"});
    EXPECT_EQ(l.upload_bytes, 1000u);
    EXPECT_EQ(l.spec_bytes, 2000u);
    EXPECT_EQ(l.triangles, 3000);
    EXPECT_EQ(l.texture_size, 512);
    EXPECT_EQ(l.queued_jobs, 7);
    EXPECT_EQ(l.free_disk_bytes, 1000000000u);
    EXPECT_EQ(l.header_seconds, 2.5);
    EXPECT_EQ(l.request_seconds, 30);
    EXPECT_EQ(l.keep_alive_seconds, 4);
    EXPECT_EQ(l.drain_seconds, 0.5);
    EXPECT_EQ(l.header_bytes, 9000);
    EXPECT_EQ(l.connections, 100);
    EXPECT_EQ(l.connections_per_address, 9);
    EXPECT_EQ(l.event_streams, 2);
    EXPECT_EQ(l.event_streams_per_token, 3);
    EXPECT_EQ(l.event_streams_per_address, 6);
    EXPECT_EQ(l.body_reads, 7);
    EXPECT_EQ(l.body_reads_per_token, 4);
    EXPECT_EQ(l.body_reads_per_address, 5);
    EXPECT_EQ(l.spec.cap("passes"), 99);
    EXPECT_EQ(l.spec.cap("res"), 2048);
    EXPECT_EQ(limits({"drain_seconds=0"}).drain_seconds, 0) << "no drain at all is a choice";
    EXPECT_EQ(limits({}).connections_per_address, 64) << "an eighth of the 512 connections";
    EXPECT_EQ(limits({}).body_reads_per_token, 0) << "0: an eighth of --http-threads (the service sets it)";
    EXPECT_EQ(limits({}).event_streams_per_address, 0) << "0: half of event_streams (the service sets it)";
    EXPECT_EQ(limits({}).body_reads, 0) << "0: half of --http-threads (the service sets it)";

    auto refused = [&](const std::string& assignment) {
        try {
            limits({assignment});
        } catch (const std::invalid_argument& e) {
            return std::string(e.what());
        }
        return std::string("accepted");
    };
    for (const std::string key :
         {"upload_bytes", "spec_bytes", "triangles", "texture_size", "queued_jobs", "free_disk_bytes", "header_bytes",
          "connections", "connections_per_address", "event_streams", "event_streams_per_token",
          "event_streams_per_address", "body_reads", "body_reads_per_token", "body_reads_per_address"}) {
        for (const std::string bad : {"-1", "2.5", "inf", "nan", "1e30", "ten", ""}) {
            const std::string message = refused(key + "=" + bad);
            EXPECT_NE(message.find(key), std::string::npos) << key << "=" << bad << ": " << message;
        }
    }
    for (const std::string key : {"header_seconds", "request_seconds", "keep_alive_seconds", "drain_seconds"}) {
        for (const std::string bad : {"-1", "inf", "nan", "soon"}) {
            const std::string message = refused(key + "=" + bad);
            EXPECT_NE(message.find(key), std::string::npos) << key << "=" << bad << ": " << message;
        }
    }
    for (const std::string key : {"res", "passes", "time_limit", "max_seconds", "max_attempts"}) {
        for (const std::string bad : {"0", "-5", "inf"}) {
            const std::string message = refused(key + "=" + bad);
            EXPECT_NE(message.find(key), std::string::npos) << key << "=" << bad << ": " << message;
        }
    }
    EXPECT_NE(refused("sparkle=1").find("unknown key 'sparkle'"), std::string::npos);
    EXPECT_NE(refused("drain_seconds").find("KEY=VALUE"), std::string::npos);
}

// ------------------------------------------------ what only PostgreSQL has

TEST(PostgresStore, ANewerSchemaIsRefusedWithAClearMessage) {
    const std::string uri = postgres().create_database();
    { PostgresJobStore migrated(uri); }
    { PostgresJobStore again(uri); }  // a known version: nothing to do
    postgres().sql(uri, "INSERT INTO schema_version(version) VALUES(" +
                            std::to_string(PostgresJobStore::kSchemaVersion + 1) + ")");
    try {
        PostgresJobStore newer(uri);
        FAIL() << "a newer schema was accepted";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("schema version " + std::to_string(PostgresJobStore::kSchemaVersion + 1)),
                  std::string::npos)
            << e.what();
        EXPECT_NE(std::string(e.what()).find("newer than this lightfarmd knows"), std::string::npos) << e.what();
    }
}

TEST(PostgresStore, AnUnreachableDatabaseOrABadUriIsAnErrorThatNamesIt) {
    try {
        PostgresJobStore store("postgresql://nobody@127.0.0.1:1/none");
        FAIL() << "connected to nothing";
    } catch (const StoreError& e) {
        EXPECT_NE(std::string(e.what()).find("cannot connect to PostgreSQL at nobody@127.0.0.1:1/none"),
                  std::string::npos)
            << e.what();
    }
    EXPECT_THROW(PostgresJobStore("postgresql://[oops"), std::invalid_argument);
}

TEST(PostgresStore, ALostConnectionFailsTheCallAndTheNextCallReconnects) {
    const std::string uri = postgres().create_database();
    PostgresJobStore store(uri);
    store.insert_job(queued_job("j1"), {});
    postgres().stop();
    try {
        store.job("j1");
        ADD_FAILURE() << "read from a stopped database";
    } catch (const StoreError& e) {
        EXPECT_NE(std::string(e.what()).find("cannot read a job"), std::string::npos) << e.what();
    }
    EXPECT_THROW(store.insert_job(queued_job("j2"), {}), StoreError);
    postgres().start();
    ASSERT_TRUE(store.job("j1")) << "the store reconnected";
    EXPECT_FALSE(store.job("j2")) << "nothing of the failed call was stored";
    store.insert_job(queued_job("j2"), {});
    EXPECT_TRUE(store.has_job("j2"));
}

// ----------------------------------------------------------- the supervisor

struct SupervisorRig {
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    server::ServerConfig config;
    std::unique_ptr<SqliteJobStore> store;
    server::ChangeSignal changes;
    server::Metrics metrics;
    std::unique_ptr<server::Supervisor> supervisor;

    SupervisorRig() {
        config.data_dir = (tmp.path / "data").string();
        config.engine = engine.script.string();
        config.workers = 1;
        fs::create_directories(tmp.path / "data" / "jobs");
        fs::create_directories(tmp.path / "data" / "scenes" / "scene-1");
        write_text(tmp.path / "data" / "scenes" / "scene-1" / "scene.glb", "glTF");
        open();
        store->add_scene({"scene-1", "scene.glb", {{"triangles", 12}, {"emissive_triangles", 2}}});
    }
    void open() { store = std::make_unique<SqliteJobStore>((tmp.path / "data" / "jobs.sqlite").string()); }
    void start() {
        supervisor = std::make_unique<server::Supervisor>(*store, config, changes, metrics);
        supervisor->start();
    }
    JobRecord wait_for(const std::string& id, const std::function<bool(const JobRecord&)>& pred,
                       std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
        const auto deadline = std::chrono::steady_clock::now() + timeout;
        std::optional<JobRecord> job;
        while (std::chrono::steady_clock::now() < deadline) {
            try {
                job = store->job(id);
                if (job && pred(*job)) return *job;
            } catch (const StoreError&) {
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        }
        ADD_FAILURE() << "job " << id << " did not get there; state "
                      << (job ? protocol::to_string(job->status.state) : std::string("none"));
        return job.value_or(JobRecord{});
    }
};

void expect_well_formed(const std::vector<server::JobEvent>& events) {
    ASSERT_FALSE(events.empty());
    for (size_t i = 1; i < events.size(); ++i) EXPECT_LT(events[i - 1].id, events[i].id);
    for (size_t i = 0; i + 1 < events.size(); ++i) EXPECT_FALSE(protocol::is_final_event(events[i].type)) << i;
    EXPECT_TRUE(protocol::is_final_event(events.back().type));
}

// The disk fills while a worker bakes: its updates wait, the bake goes on,
// and when the disk has room again the job ends succeeded with all its
// events, the final one last. It is never left running without a worker.
TEST(SupervisorOnAFullDisk, AJobBakesOnAndEndsOnceTheStoreTakesItsUpdates) {
    SupervisorRig rig;
    rig.engine.set("delay", "0.1");
    rig.store->insert_job(queued_job("j1", "scene-1", 12), {});
    rig.start();
    rig.wait_for("j1", [](const JobRecord& j) { return j.status.progress.pass >= 2; });
    {
        FullDisk full;
        // The worker finishes meanwhile (12 passes of 0.1 s); its end cannot be stored.
        std::this_thread::sleep_for(std::chrono::milliseconds(2000));
        EXPECT_EQ(rig.store->job("j1")->status.state, JobState::Running) << "no state the store did not take";
    }
    const JobRecord done = rig.wait_for("j1", [](const JobRecord& j) { return protocol::is_final(j.status.state); });
    EXPECT_EQ(done.status.state, JobState::Succeeded);
    EXPECT_EQ(done.status.attempts, 1) << "a full disk costs the job no attempt";
    EXPECT_EQ(done.status.progress.pass, 12);
    const auto events = rig.store->events_after("j1", 0);
    expect_well_formed(events);
    EXPECT_EQ(events.back().type, "done");
    int snapshots = 0;
    for (const auto& e : events) snapshots += e.type == "snapshot";
    EXPECT_EQ(snapshots, 4) << "passes 1, 2, 4, 8: none lost";
    rig.supervisor->stop();
}

// lightfarmd stops while its store cannot take a job's end: the job stays
// running in the store, and the next start queues it again (one attempt
// counted) and runs it to the end.
TEST(SupervisorOnAFullDisk, AJobWhoseEndWasNotStoredRunsAgainAtTheNextStart) {
    SupervisorRig rig;
    rig.engine.set("delay", "0.3");
    rig.store->insert_job(queued_job("j1", "scene-1", 4), {});
    rig.start();
    rig.wait_for("j1", [](const JobRecord& j) { return j.status.progress.pass >= 1; });
    {
        FullDisk full;
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
        rig.supervisor->stop();
        EXPECT_EQ(rig.store->job("j1")->status.state, JobState::Running);
    }
    rig.supervisor.reset();
    rig.open();  // as a new lightfarmd would
    rig.engine.set("delay", "0");
    rig.start();
    const JobRecord done = rig.wait_for("j1", [](const JobRecord& j) { return protocol::is_final(j.status.state); });
    EXPECT_EQ(done.status.state, JobState::Succeeded);
    EXPECT_EQ(done.status.attempts, 2);
    const auto events = rig.store->events_after("j1", 0);
    expect_well_formed(events);
    bool retried = false;
    for (const auto& e : events)
        retried = retried ||
                  (e.type == "retrying" && e.data.value("cause", "").find("lightfarmd stopped") != std::string::npos);
    EXPECT_TRUE(retried);
    rig.supervisor->stop();
}

// While the disk is full no job is taken from the queue (a claim that
// cannot be stored); once it has room the queue runs.
TEST(SupervisorOnAFullDisk, NoJobIsTakenWhileTheClaimCannotBeStored) {
    SupervisorRig rig;
    {
        FullDisk full;
        EXPECT_THROW(rig.store->insert_job(queued_job("lost"), {}), StoreError);
    }
    rig.store->insert_job(queued_job("j1"), {});
    {
        FullDisk full;
        rig.start();
        std::this_thread::sleep_for(std::chrono::milliseconds(1500));
        EXPECT_EQ(rig.store->job("j1")->status.state, JobState::Queued);
        EXPECT_EQ(rig.engine.runs(), 0);
    }
    EXPECT_EQ(rig.wait_for("j1", [](const JobRecord& j) { return protocol::is_final(j.status.state); }).status.state,
              JobState::Succeeded);
    EXPECT_EQ(rig.engine.runs(), 1);
    EXPECT_FALSE(rig.store->job("lost"));
    rig.supervisor->stop();
}

// A store whose first claim is stored and then answered with an error, as
// a commit cut off after it reached the disk (the PostgreSQL fault harness's
// "requeued at no cost" rows).
class ClaimAnswerLost : public SqliteJobStore {
public:
    using SqliteJobStore::SqliteJobStore;
    std::optional<JobRecord> claim_next() override {
        std::optional<JobRecord> job = SqliteJobStore::claim_next();
        if (job && !lost_.exchange(true)) throw StoreError("the claim's answer was lost (a test)");
        return job;
    }

private:
    std::atomic<bool> lost_{false};
};

// The slot whose claim failed queues the job again itself as soon as the
// store answers (Supervisor::worker_loop, requeue_unrun_claims), not the
// lease thread at its next renewal: on a lease of an hour (renewals 20
// minutes apart) the job still runs at once, on one worker run, its lost
// claim refunded and said in a "retrying" event.
TEST(SupervisorOnAFullDisk, AClaimWhoseAnswerWasLostIsQueuedAgainByItsSlotAtOnce) {
    SupervisorRig rig;
    rig.store = std::make_unique<ClaimAnswerLost>((rig.tmp.path / "data" / "jobs.sqlite").string(),
                                                  server::NodeIdentity{"node-1", 3600});
    rig.store->insert_job(queued_job("j1"), {});
    rig.start();
    const JobRecord done = rig.wait_for("j1", [](const JobRecord& j) { return protocol::is_final(j.status.state); });
    EXPECT_EQ(done.status.state, JobState::Succeeded);
    EXPECT_EQ(rig.engine.runs(), 1);
    EXPECT_EQ(done.status.attempts, 1) << "the lost claim is refunded: no worker ran";
    const std::vector<server::JobEvent> events = rig.store->events_after("j1", 0);
    const bool said = std::any_of(events.begin(), events.end(), [](const server::JobEvent& e) {
        return e.type == "retrying" && e.data.dump().find("lost the answer to its claim") != std::string::npos;
    });
    EXPECT_TRUE(said) << "no retrying event says the claim's answer was lost";
    rig.supervisor->stop();
}

// ------------------------------------------------------ the HTTP routes (in process)

// A full disk answers POST /v1/jobs with 503 (Retry-After), never 201 for a
// job that is not stored; once it has room the same server carries on.
// (Needs service.cpp to answer StoreError with 503.)
TEST(ServiceOnAFullDisk, NoJobIsAnswered201UnlessItIsStored) {
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    server::ServerConfig config;
    config.host = "127.0.0.1";
    config.port = 0;
    config.data_dir = (tmp.path / "data").string();
    config.engine = engine.script.string();
    config.workers = 1;
    fs::create_directories(config.data_dir);
    server::Service service(config, {kAlice});
    const int port = service.bind();
    std::thread runner([&] { service.run(); });
    httplib::Client c("127.0.0.1", port);
    c.set_connection_timeout(2);
    c.set_read_timeout(10);
    c.set_default_headers(bearer(kAlice));
    auto up = c.Post("/v1/scenes", std::string("glTF\x02\x00\x00\x00 scene", 14), "model/gltf-binary");
    ASSERT_TRUE(up && up->status == 201) << (up ? up->body : "no answer");
    const std::string scene = json::parse(up->body)["id"];
    const json spec = {{"scene", scene}, {"seed", 1}, {"outputs", {{"lightmap", {{"passes", 2}}}}}};
    {
        FullDisk full;
        for (int i = 0; i < 5; ++i) {
            json s = spec;
            s["seed"] = 100 + i;
            auto r = c.Post("/v1/jobs", s.dump(), "application/json");
            ASSERT_TRUE(r);
            EXPECT_NE(r->status, 201) << r->body;
            EXPECT_EQ(r->status, 503) << r->body;
            EXPECT_TRUE(r->has_header("Retry-After")) << r->body;
            EXPECT_EQ(r->body.find(config.data_dir), std::string::npos) << "no server path: " << r->body;
        }
        auto again = c.Post("/v1/scenes", std::string("glTF\x02\x00\x00\x00 other", 14), "model/gltf-binary");
        ASSERT_TRUE(again);
        EXPECT_EQ(again->status, 503) << again->body;
    }
    auto list = c.Get("/v1/jobs");
    ASSERT_TRUE(list && list->status == 200);
    const json listed = json::parse(list->body);
    EXPECT_EQ((listed.is_array() ? listed : listed["jobs"]).size(), 0u) << list->body;
    auto r = c.Post("/v1/jobs", spec.dump(), "application/json");
    ASSERT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
    const std::string id = json::parse(r->body)["id"];
    json status;
    for (int i = 0; i < 400; ++i) {
        auto g = c.Get("/v1/jobs/" + id);
        if (g && g->status == 200 && is_finished(status = json::parse(g->body))) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(25));
    }
    EXPECT_EQ(status.value("state", ""), "succeeded") << status;
    service.stop();
    runner.join();
}

// ------------------------------------------------------------ upload checks

// A checker that notes when each run starts and ends, its memory limit, and
// takes 0.3 s.
void write_slow_inspector(const fs::path& path) {
    write_text(path, R"sh(#!/bin/sh
state="$(dirname "$0")"
if [ "$1" = devices ]; then echo '{"gpus": 0}'; exit 0; fi
echo start >> "$state/log"
ulimit -v > "$state/ulimit"
sleep 0.3
echo end >> "$state/log"
echo '{"source": "x", "triangles": 12, "textures": [], "emissive_triangles": 2, "punctual_light_count": 0, "max_texture_size": 0, "has_lightmap_uvs": true, "min_atlas_res": 0}'
)sh");
    fs::permissions(path, fs::perms::owner_all);
}

int most_at_once(const std::string& log) {
    int now = 0, most = 0;
    std::istringstream in(log);
    for (std::string line; std::getline(in, line);) {
        now += line == "start" ? 1 : -1;
        most = std::max(most, now);
    }
    return most;
}

TEST(UploadChecks, RunAtMostMaxInspectsAtOnceUnderAMemoryLimit) {
    TempDir tmp;
    write_slow_inspector(tmp.path / "engine" / "lightfarm");
    server::ServerConfig config;
    config.data_dir = (tmp.path / "data").string();
    config.engine = (tmp.path / "engine" / "lightfarm").string();
    config.max_inspects = 2;
    config.inspect_memory_bytes = 512ull << 20;
    fs::create_directories(tmp.path / "data");
    SqliteJobStore store((tmp.path / "data" / "jobs.sqlite").string());
    server::SceneStore scenes(config, store);
    std::atomic<int> ok{0}, busy{0};
    std::vector<std::thread> uploads;
    for (int i = 0; i < 6; ++i)
        uploads.emplace_back([&, i] {
            try {
                scenes.upload({{"scene.glb", "glTF upload " + std::to_string(i)}}, "owner");
                ++ok;
            } catch (const server::HttpError& e) {
                if (e.status() == 503) ++busy;
            }
        });
    for (auto& t : uploads) t.join();
    EXPECT_EQ(ok, 6) << "6 uploads fit 2 running + 8 waiting";
    EXPECT_EQ(most_at_once(read_text(tmp.path / "engine" / "log")), 2);
    EXPECT_EQ(read_text(tmp.path / "engine" / "ulimit"), std::to_string((512ull << 20) / 1024) + "\n");
}

TEST(UploadChecks, BeyondTheWaitingRoomAnUploadIs503WithRetryAfter) {
    TempDir tmp;
    write_slow_inspector(tmp.path / "engine" / "lightfarm");
    server::ServerConfig config;
    config.data_dir = (tmp.path / "data").string();
    config.engine = (tmp.path / "engine" / "lightfarm").string();
    config.max_inspects = 1;  // 1 running, 4 waiting
    fs::create_directories(tmp.path / "data");
    SqliteJobStore store((tmp.path / "data" / "jobs.sqlite").string());
    server::SceneStore scenes(config, store);
    std::atomic<int> ok{0}, busy{0};
    std::vector<std::thread> uploads;
    for (int i = 0; i < 10; ++i)
        uploads.emplace_back([&, i] {
            try {
                scenes.upload({{"scene.glb", "glTF upload " + std::to_string(i)}}, "owner");
                ++ok;
            } catch (const server::HttpError& e) {
                if (e.status() == 503 && e.body().value("retry_after", 0) > 0) ++busy;
            }
        });
    for (auto& t : uploads) t.join();
    EXPECT_EQ(ok + busy, 10);
    EXPECT_GE(busy, 1);
    EXPECT_GE(ok, 5);
    EXPECT_EQ(most_at_once(read_text(tmp.path / "engine" / "log")), 1);
}

TEST(UploadChecks, AChildOverItsMemoryLimitFailsNotTheServer) {
    server::SpawnLimits limits;
    limits.address_space_bytes = 256ull << 20;
    const auto r = server::run_command({"sh", "-c", "ulimit -v; head -c 400000000 /dev/zero | sort > /dev/null"},
                                       std::chrono::seconds(20), 1 << 20, limits);
    EXPECT_EQ(r.out, std::to_string((256ull << 20) / 1024) + "\n");
    EXPECT_FALSE(r.status.success()) << "sort of 400 MB in 256 MiB of address space";
    // Without a limit the same spawn path is posix_spawn, unchanged.
    const auto plain = server::run_command({"sh", "-c", "echo fine"}, std::chrono::seconds(5));
    EXPECT_EQ(plain.out, "fine\n");
    EXPECT_THROW(server::run_command({"/nonexistent/lightfarm"}, std::chrono::seconds(5), 1 << 20, limits),
                 std::runtime_error);
}

// ---------------------------------------------------- lightfarmd, the process

class DataDirTest : public ::testing::Test {
protected:
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    std::unique_ptr<Lightfarmd> server;

    void SetUp() override { write_text(tmp.path / "tokens", kAlice + "\n"); }
    std::unique_ptr<Lightfarmd> make(std::vector<std::string> extra = {}) {
        return std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script, std::move(extra));
    }
    void TearDown() override {
        if (HasFailure() && server) std::cerr << "---- lightfarmd log ----\n" << server->log();
    }
    std::string upload_and_bake(int passes = 2) {
        auto c = server->client(kAlice);
        auto up = c.Post("/v1/scenes", std::string("glTF\x02\x00\x00\x00 scene", 14), "model/gltf-binary");
        EXPECT_TRUE(up && (up->status == 201 || up->status == 200)) << (up ? up->body : "no answer");
        const std::string scene = up ? json::parse(up->body).value("id", "") : "";
        auto r = c.Post("/v1/jobs",
                        json({{"scene", scene}, {"seed", 1}, {"outputs", {{"lightmap", {{"passes", passes}}}}}}).dump(),
                        "application/json");
        EXPECT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        const std::string id = r ? json::parse(r->body).value("id", "") : "";
        EXPECT_EQ(wait_for_job(c, id, is_finished)["state"], "succeeded");
        return id;
    }
};

TEST_F(DataDirTest, ASecondServerOnTheSameDataDirectoryRefusesToStart) {
    server = make();
    server->start();
    auto second = make();
    try {
        second->start();
        ADD_FAILURE() << "the second lightfarmd started";
    } catch (const std::runtime_error& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("another lightfarmd (pid "), std::string::npos) << what;
        EXPECT_NE(what.find("is using the data directory"), std::string::npos) << what;
        EXPECT_NE(what.find("--data"), std::string::npos) << what;
    }
    EXPECT_FALSE(second->running());
    // The first one serves on, and its jobs run.
    upload_and_bake();
    // Once it is gone (even by kill -9), the directory is free again.
    server->kill9();
    server = make();
    server->start();
}

// Another lightfarmd, with a data directory of its own, cannot take the
// port of a running one (with SO_REUSEPORT it could, and the kernel split
// the traffic between them).
TEST_F(DataDirTest, ASecondServerCannotShareThePortOfARunningOne) {
    server = make();
    server->start();
    Lightfarmd other(tmp.path / "other", tmp.path / "tokens", engine.script,
                     {"--listen", "127.0.0.1:" + std::to_string(server->port)});
    try {
        other.start();
        ADD_FAILURE() << "a second lightfarmd listens on the same port";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("cannot listen on 127.0.0.1:" + std::to_string(server->port)),
                  std::string::npos)
            << e.what();
    }
    EXPECT_FALSE(other.running());
    upload_and_bake();  // the first one serves on
}

TEST_F(DataDirTest, AStoreThatLostItsWalAfterKill9IsRefusedAtStart) {
    server = make();
    server->start();
    const std::string id = upload_and_bake();
    server->kill9();
    const fs::path data = tmp.path / "data";
    ASSERT_TRUE(fs::exists(data / "jobs.sqlite-wal")) << "the jobs are in the WAL after kill -9";
    fs::remove(data / "jobs.sqlite-wal");
    server = make();
    try {
        server->start();
        ADD_FAILURE() << "lightfarmd started on an empty store beside its jobs' directories";
    } catch (const std::runtime_error& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find("is empty, but 2 job and scene directories"), std::string::npos) << what;
        EXPECT_NE(what.find("--accept-empty-store"), std::string::npos) << what;
    }
    EXPECT_TRUE(fs::exists(data / "jobs" / id)) << "nothing is touched when it refuses";
    // The way out it names: start empty, the orphans kept aside.
    server = make({"--accept-empty-store"});
    server->start();
    auto c = server->client(kAlice);
    auto list = c.Get("/v1/jobs");
    ASSERT_TRUE(list && list->status == 200);
    const json listed = json::parse(list->body);
    EXPECT_EQ((listed.is_array() ? listed : listed["jobs"]).size(), 0u) << list->body;
    bool kept = false;
    for (const auto& entry : fs::directory_iterator(data))
        if (entry.path().filename().string().rfind("orphaned-", 0) == 0) kept = fs::exists(entry.path() / "jobs" / id);
    EXPECT_TRUE(kept) << "the orphaned job directory is moved aside, not deleted";
    EXPECT_FALSE(fs::exists(data / "jobs" / id));
    // And it works as a new service, restarting without complaint.
    upload_and_bake();
    server->stop();
    server = make();
    server->start();
}

TEST_F(DataDirTest, DataFilesAre0600AndFolders0700) {
    server = make();
    server->start();
    upload_and_bake();
    server->stop();
    int files = 0;
    for (auto it = fs::recursive_directory_iterator(tmp.path / "data"); it != fs::recursive_directory_iterator();
         ++it) {
        struct stat st {};
        ASSERT_EQ(::lstat(it->path().c_str(), &st), 0);
        EXPECT_EQ(st.st_mode & 0077, 0u) << it->path() << " is " << std::oct << (st.st_mode & 0777);
        ++files;
    }
    struct stat st {};
    ASSERT_EQ(::stat((tmp.path / "data").c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & 0777, 0700u);
    EXPECT_GT(files, 8);
}

// Progress events coalesced by the store: a client following the stream live
// and clients resuming after any event id get every non-progress event once,
// in order, with ids that only grow.
TEST_F(DataDirTest, CoalescedProgressKeepsTheEventStreamsResumeExact) {
    server = make();
    server->start();
    engine.set("delay", "0.01");
    auto c = server->client(kAlice);
    auto up = c.Post("/v1/scenes", std::string("glTF\x02\x00\x00\x00 scene", 14), "model/gltf-binary");
    ASSERT_TRUE(up && up->status == 201);
    auto r = c.Post(
        "/v1/jobs",
        json({{"scene", json::parse(up->body)["id"]}, {"seed", 1}, {"outputs", {{"lightmap", {{"passes", 120}}}}}})
            .dump(),
        "application/json");
    ASSERT_TRUE(r && r->status == 201) << r->body;
    const std::string id = json::parse(r->body)["id"];
    const auto live = read_events(server->host, server->port, kAlice, id);
    const auto all = read_events(server->host, server->port, kAlice, id);
    auto non_progress = [](const std::vector<protocol::JobEvent>& events) {
        std::vector<std::pair<int64_t, std::string>> out;
        for (const auto& e : events)
            if (e.type != "progress") out.emplace_back(e.id, e.type);
        return out;
    };
    ASSERT_FALSE(all.empty());
    EXPECT_EQ(all.back().type, "done");
    EXPECT_EQ(non_progress(live), non_progress(all));
    size_t progress = 0;
    for (const auto& e : all) progress += e.type == "progress";
    EXPECT_EQ(progress, 32u + 1u + 1u) << "passes 1..32, 64 and the newest (120)";
    for (size_t k = 0; k < all.size(); k += 3) {
        const auto resumed = read_events(server->host, server->port, kAlice, id, all[k].id);
        const std::vector<protocol::JobEvent> expected(all.begin() + long(k) + 1, all.end());
        ASSERT_EQ(resumed.size(), expected.size()) << "after " << all[k].id;
        for (size_t i = 0; i < resumed.size(); ++i) EXPECT_EQ(resumed[i].id, expected[i].id);
    }
}

// Without --data, the data goes to $XDG_DATA_HOME/lightfarm (never the
// current directory, which may be a checkout).
TEST(DefaultDataDir, IsTheUsersDataHomeNotTheCurrentDirectory) {
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    const fs::path cwd = tmp.path / "checkout";
    fs::create_directories(cwd);
    const fs::path xdg = tmp.path / "xdg";
    std::vector<std::string> args = {LIGHTFARMD, "--listen", "127.0.0.1:0", "--engine", engine.script.string()};
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    std::vector<std::string> env = {"XDG_DATA_HOME=" + xdg.string(), "HOME=" + (tmp.path / "home").string(),
                                    "PATH=/usr/bin:/bin"};
    std::vector<char*> envp;
    for (std::string& e : env) envp.push_back(e.data());
    envp.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addchdir_np(&actions, cwd.c_str());
    const std::string log = (tmp.path / "log").string();
    posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_adddup2(&actions, 1, 2);
    pid_t pid = -1;
    ASSERT_EQ(posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), envp.data()), 0);
    posix_spawn_file_actions_destroy(&actions);
    const fs::path data = xdg / "lightfarm";
    bool up = false;
    for (int i = 0; i < 500 && !up; ++i) {
        up = !read_text(data / "lightfarmd.url").empty();
        if (!up) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    // SIGTERM right after start (while it may still be starting) ends it too.
    ::kill(pid, SIGTERM);
    int status = 0;
    bool ended = false;
    for (int i = 0; i < 500 && !ended; ++i) {
        ended = waitpid(pid, &status, WNOHANG) == pid;
        if (!ended) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    if (!ended) {
        ::kill(pid, SIGKILL);
        waitpid(pid, &status, 0);
    }
    EXPECT_TRUE(ended) << "SIGTERM did not stop it:\n" << read_text(log);
    EXPECT_TRUE(up) << read_text(log);
    EXPECT_TRUE(fs::exists(data / "tokens"));
    EXPECT_TRUE(fs::exists(data / "jobs.sqlite"));
    EXPECT_TRUE(fs::is_empty(cwd)) << "nothing in the current directory";
    EXPECT_NE(read_text(log).find((data / "tokens").string()), std::string::npos) << read_text(log);
}

}  // namespace
}  // namespace lf::test
