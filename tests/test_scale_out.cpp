// Many lightfarmd nodes on one PostgreSQL database and one data directory
// (issue #9), on loopback with the fake engine: jobs submitted across the
// nodes finish exactly once, each on one node; a node killed with SIGKILL
// loses its job to another after the lease, and nothing is lost; the database
// restarted mid-run loses and duplicates nothing. PostgreSQL is started by
// the test (postgres_server.h).
//
// The Figures tests measure what docs/BENCHMARKS.md reports ("Scale-out on
// PostgreSQL"). They are benchmarks, so disabled in the suite (CI's 20
// minutes; the tests above check the same paths): run them with
// --gtest_also_run_disabled_tests --gtest_filter='*Figures*', small by
// default (they check that every job ran once and print what they saw), or
// with LIGHTFARM_SCALE_OUT_BENCH=1 at the size of the published figures (1,
// 2 and 4 nodes; leases of 2, 5 and 10 s).
#include "events.h"
#include "metrics.h"
#include "postgres_job_store.h"
#include "postgres_server.h"
#include "server_harness.h"
#include "supervisor.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <map>
#include <numeric>
#include <set>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;
using namespace std::chrono_literals;

const std::string kToken = "scale-out-token-0123456789";

PostgresServer& postgres() {
    static PostgresServer server;
    return server;
}

// One lightfarmd node: its own name, port and log; the store and the data
// directory shared. (Harness's Lightfarmd keeps its URL and log in the data
// directory, one per directory.)
class Node {
public:
    Node(std::string name, std::vector<std::string> args, fs::path log_dir)
        : name(std::move(name)), args_(std::move(args)), log_dir_(std::move(log_dir)) {}
    ~Node() { stop(); }

    void start() {
        port = free_loopback_port();
        std::vector<std::string> args = {"--listen", "127.0.0.1:" + std::to_string(port), "--node-name", name};
        args.insert(args.end(), args_.begin(), args_.end());
        const fs::path log = log_path(++starts_);
        pid_ = spawn_lightfarmd(args, log);
        try {
            wait_until_ready(pid_, log, [&] { return answers_health(port); });
        } catch (const std::runtime_error& e) {
            throw std::runtime_error("node " + name + ": " + e.what());
        }
    }
    void kill9() { kill_process(pid_); }
    void stop() { stop_process(pid_); }
    httplib::Client client() const {
        httplib::Client c("127.0.0.1", port);
        c.set_connection_timeout(2);
        c.set_read_timeout(10);
        c.set_default_headers(bearer(kToken));
        return c;
    }
    std::string log() const {
        std::string all;
        for (int i = 1; i <= starts_; ++i) all += "---- " + name + " ----\n" + read_text(log_path(i));
        return all;
    }

    std::string name;
    int port = 0;

private:
    std::string log_path(int start) const {
        return (log_dir_ / (name + "-" + std::to_string(start) + ".log")).string();
    }
    std::vector<std::string> args_;
    fs::path log_dir_;
    pid_t pid_ = -1;
    int starts_ = 0;
};

class ScaleOut : public ::testing::Test {
protected:
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    std::string uri = postgres().create_database();
    std::vector<std::unique_ptr<Node>> nodes;

    // `count` nodes named n1, n2, ... on one database and one data directory.
    void add_nodes(int count, double lease_seconds) {
        write_text(tmp.path / "tokens", kToken + "\n");
        for (int i = 0; i < count; ++i) {
            const std::string name = "n" + std::to_string(nodes.size() + 1);
            nodes.push_back(std::make_unique<Node>(
                name,
                std::vector<std::string>{"--data", (tmp.path / "data").string(), "--tokens",
                                         (tmp.path / "tokens").string(), "--engine", engine.script.string(), "--store",
                                         uri, "--lease-seconds", std::to_string(lease_seconds)},
                tmp.path));
        }
    }
    void TearDown() override {
        if (HasFailure())
            for (const auto& n : nodes) std::cerr << n->log();
    }
    std::string upload(Node& node, const std::string& tag) {
        auto r =
            node.client().Post("/v1/scenes", std::string("glTF\x02\x00\x00\x00", 8) + " " + tag, "model/gltf-binary");
        EXPECT_TRUE(r && (r->status == 201 || r->status == 200)) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    std::string submit(Node& node, const std::string& scene, int seed, int passes) {
        const json spec = {{"scene", scene}, {"seed", seed}, {"outputs", {{"lightmap", {{"passes", passes}}}}}};
        auto r = node.client().Post("/v1/jobs", spec.dump(), "application/json");
        EXPECT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    json wait_finished(Node& node, const std::string& id, std::chrono::milliseconds timeout = 30s) {
        auto c = node.client();
        return wait_for_job(c, id, is_finished, timeout);
    }
    // The job's whole event stream as `node` serves it.
    std::vector<protocol::JobEvent> events(Node& node, const std::string& id) {
        return read_events("127.0.0.1", node.port, kToken, id, -1, 0, 20s);
    }
    // Workers started, on every node: the fake engine appends a line per run
    // (its `runs` counter is not safe for workers running at once).
    int worker_runs() const {
        const std::string all = read_text(engine.dir / "all_args");
        return int(std::count(all.begin(), all.end(), '\n'));
    }
    // Which node the store says ran the job last.
    std::string node_of(const std::string& id) {
        server::PostgresJobStore store(uri, {"test-reader", 30});
        const auto job = store.job(id);
        return job ? job->node : "";
    }
};

// Every event once, in order; exactly one final event, the last.
void expect_one_clean_stream(const std::vector<protocol::JobEvent>& events, const std::string& id) {
    ASSERT_FALSE(events.empty()) << id;
    int done = 0;
    for (size_t i = 0; i < events.size(); ++i) {
        if (i > 0) {
            EXPECT_LT(events[i - 1].id, events[i].id) << id << ": event ids must only grow";
        }
        done += events[i].type == "done" ? 1 : 0;
    }
    EXPECT_EQ(done, 1) << id;
    EXPECT_EQ(events.back().type, "done") << id;
}

TEST_F(ScaleOut, JobsSubmittedAcrossThreeNodesEachFinishOnceOnOneNode) {
    add_nodes(3, 5);
    for (auto& n : nodes) n->start();
    engine.set("delay", "0.05");
    // The same bytes uploaded to two nodes are one scene.
    const std::string scene = upload(*nodes[0], "shared");
    EXPECT_EQ(upload(*nodes[1], "shared"), scene);
    size_t scene_dirs = 0;
    for ([[maybe_unused]] const auto& d : fs::directory_iterator(tmp.path / "data" / "scenes")) ++scene_dirs;
    EXPECT_EQ(scene_dirs, 1u);

    constexpr int kJobs = 12;
    std::vector<std::string> ids;
    for (int i = 0; i < kJobs; ++i) ids.push_back(submit(*nodes[size_t(i) % 3], scene, 100 + i, 4));
    std::set<std::string> ran_on;
    for (size_t i = 0; i < ids.size(); ++i) {
        // Status and events through another node than the one it was submitted to.
        Node& reader = *nodes[(i + 1) % 3];
        const json status = wait_finished(reader, ids[i]);
        EXPECT_EQ(status.value("state", ""), "succeeded") << status.dump();
        EXPECT_EQ(status.value("attempts", 0), 1) << status.dump();
        const auto stream = events(reader, ids[i]);
        expect_one_clean_stream(stream, ids[i]);
        int started = 0;
        for (const auto& e : stream) started += e.type == "started" ? 1 : 0;
        EXPECT_EQ(started, 1) << ids[i] << ": run by one node, once";
        ran_on.insert(node_of(ids[i]));
    }
    EXPECT_EQ(worker_runs(), kJobs) << "one worker run per job";
    EXPECT_GE(ran_on.size(), 2u) << "the nodes share the queue";
    for (const std::string& name : ran_on) EXPECT_TRUE(name == "n1" || name == "n2" || name == "n3") << name;

    // Every node sees every node.
    auto r = nodes[2]->client().Get("/v1/nodes");
    ASSERT_TRUE(r && r->status == 200);
    const json listed = json::parse(r->body)["nodes"];
    ASSERT_EQ(listed.size(), 3u) << listed.dump();
    for (const json& n : listed) EXPECT_TRUE(n["alive"].get<bool>()) << n.dump();
    EXPECT_EQ(listed[2]["self"], true);
    auto metrics = nodes[0]->client().Get("/metrics");
    ASSERT_TRUE(metrics && metrics->status == 200);
    EXPECT_NE(metrics->body.find("lightfarm_node_info{node=\"n1\"} 1"), std::string::npos);
    EXPECT_NE(metrics->body.find("lightfarm_node_up{node=\"n3\"} 1"), std::string::npos);
}

TEST_F(ScaleOut, AnEventStreamOnAnotherNodeFollowsARunningJobLiveAndResumesOnAThird) {
    add_nodes(3, 5);
    Node& runner = *nodes[0];
    runner.start();
    engine.set("delay", "0.25");
    // ~7.5 s of passes; at most 32, whose progress events are all kept (no
    // coalescing to tell apart from a lost event).
    const std::string id = submit(runner, upload(runner, "live"), 1, 30);
    nodes[1]->start();
    nodes[2]->start();
    auto c = nodes[1]->client();
    const json before = wait_for_job(c, id, [](const json& s) { return s.value("state", "") == "running"; });
    ASSERT_EQ(before.value("state", ""), "running");
    const int pass_at_open = before.value("progress", json::object()).value("pass", 0);
    // Node 2 follows the job node 1 runs for 4.5 s: the passes node 1 stores
    // meanwhile reach it, live (a stream reads the store at least every 2 s).
    const auto live = read_events("127.0.0.1", nodes[1]->port, kToken, id, -1, 0, 4500ms);
    ASSERT_FALSE(live.empty());
    int newest_pass = 0;
    for (const auto& e : live) {
        EXPECT_FALSE(protocol::is_final_event(e.type)) << "the job ended already: the test saw nothing live";
        if (e.type == "progress") newest_pass = std::max(newest_pass, e.data.value("pass", 0));
    }
    EXPECT_GT(newest_pass, pass_at_open + 2) << "passes run after the stream opened came through another node";
    // Node 3 takes the stream over where node 2 left it, as a client
    // resuming with Last-Event-ID does.
    const auto rest = read_events("127.0.0.1", nodes[2]->port, kToken, id, live.back().id, 0, 20s);
    EXPECT_EQ(wait_finished(*nodes[2], id).value("state", ""), "succeeded");
    std::vector<protocol::JobEvent> joined = live;
    joined.insert(joined.end(), rest.begin(), rest.end());
    expect_one_clean_stream(joined, id);
    // The same events, ids and order as the runner's own stream from the start.
    const auto whole = events(runner, id);
    ASSERT_EQ(joined.size(), whole.size());
    for (size_t i = 0; i < whole.size(); ++i) {
        EXPECT_EQ(joined[i].id, whole[i].id);
        EXPECT_EQ(joined[i].type, whole[i].type);
    }
}

TEST_F(ScaleOut, AJobOfAKilledNodeIsFinishedByAnotherAfterTheLease) {
    constexpr double kLease = 2;
    add_nodes(2, kLease);
    Node& a = *nodes[0];
    Node& b = *nodes[1];
    a.start();
    engine.set("delay", "0.25");
    const std::string id = submit(a, upload(a, "killed"), 1, 12);  // ~3 s of passes
    auto ca = a.client();
    ASSERT_EQ(
        wait_for_job(ca, id, [](const json& s) { return s.value("progress", json::object()).value("pass", 0) >= 2; })
            .value("state", ""),
        "running");
    b.start();  // after the claim: the job is a's
    ASSERT_EQ(node_of(id), "n1");

    a.kill9();
    const auto killed = std::chrono::steady_clock::now();
    auto cb = b.client();
    // Taken over: queued again by b (attempt counted), then run by b.
    const json again = wait_for_job(
        cb, id, [](const json& s) { return s.value("attempts", 0) == 2 || is_finished(s); }, 20s);
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - killed).count();
    EXPECT_EQ(again.value("attempts", 0), 2) << again.dump();
    // The lease was renewed at most a third of it before the kill; b looks every third.
    EXPECT_GE(waited, kLease * 2 / 3 - 0.2);
    EXPECT_LE(waited, kLease + kLease / 3 + 1.5);
    std::cerr << "taken over " << waited << " s after the kill (lease " << kLease << " s)\n";

    const json done = wait_finished(b, id);
    EXPECT_EQ(done.value("state", ""), "succeeded") << done.dump();
    EXPECT_EQ(node_of(id), "n2");
    const auto stream = events(b, id);
    expect_one_clean_stream(stream, id);
    bool retried = false;
    for (const auto& e : stream)
        if (e.type == "retrying")
            retried = e.data.value("cause", "").find("node n1 stopped renewing its lease") != std::string::npos;
    EXPECT_TRUE(retried) << "the stream says why the job ran again";
    // b's worker continued from the state a's saved with its last snapshot
    // on the shared data dir, not from pass 0.
    std::vector<json> started;
    for (const auto& e : stream)
        if (e.type == "started") started.push_back(e.data);
    ASSERT_EQ(started.size(), 2u);
    EXPECT_FALSE(started[0].contains("resumed"));
    const int resumed_after =
        started[1].value("resumed", json::object()).value("lightmap", json::object()).value("pass", 0);
    EXPECT_GE(resumed_after, 1) << started[1].dump();
    int first_pass_of_b = 0;
    for (auto e = stream.rbegin(); e != stream.rend() && e->type != "retrying"; ++e)
        if (e->type == "progress") first_pass_of_b = e->data.value("pass", 0);
    EXPECT_EQ(first_pass_of_b, resumed_after + 1) << "b's first pass follows the resumed one";
    const std::string args = read_text(engine.dir / "all_args");
    EXPECT_EQ(args.find("--resume"), args.rfind("--resume")) << "only the second run resumes: " << args;
    EXPECT_NE(args.find("--resume"), std::string::npos) << args;
    auto artifacts = cb.Get("/v1/jobs/" + id + "/artifacts");
    ASSERT_TRUE(artifacts && artifacts->status == 200);
    EXPECT_NE(artifacts->body.find("lightmap.exr"), std::string::npos) << artifacts->body;
}

// A second node with a live node's name is refused (it would renew and take
// over that node's leases); the same name comes back at once after a crash,
// once its heartbeat is seen to have stopped.
TEST_F(ScaleOut, ANameALiveNodeHasIsRefusedAndFreeAgainAfterItsCrash) {
    add_nodes(1, 2);
    Node& a = *nodes[0];
    a.start();
    Node twin("n1",
              {"--data", (tmp.path / "data").string(), "--tokens", (tmp.path / "tokens").string(), "--engine",
               engine.script.string(), "--store", uri, "--lease-seconds", "2"},
              tmp.path / "twin");
    fs::create_directories(tmp.path / "twin");
    try {
        twin.start();
        ADD_FAILURE() << "a second node named n1 started";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("--node-name n1 is taken"), std::string::npos) << e.what();
    }
    auto r = a.client().Get("/healthz");
    EXPECT_TRUE(r && r->status == 200) << "the first n1 is untouched";

    a.kill9();
    const auto restarted = std::chrono::steady_clock::now();
    a.start();  // its own last heartbeat is recent: watched for a third of the lease, then taken
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - restarted).count();
    EXPECT_LT(waited, 2.0 / 3 + 1 + 3) << "one renewal period, not a whole lease or more";
    auto listed = a.client().Get("/v1/nodes");
    ASSERT_TRUE(listed && listed->status == 200);
    EXPECT_EQ(json::parse(listed->body)["nodes"].size(), 1u);
}

// A node stopped cleanly signs off: the nodes list says it is not alive,
// and it starts again under its name at once, where after a crash it
// watches its own last heartbeat for a renewal period (above). With a lease
// of 30 s that watch is 11 s, which every clean restart used to wait.
TEST_F(ScaleOut, ANodeStoppedCleanlySignsOffAndItsNameIsFreeAtOnce) {
    add_nodes(2, 30);
    Node& a = *nodes[0];
    Node& b = *nodes[1];
    a.start();
    b.start();
    a.stop();
    auto listed = b.client().Get("/v1/nodes");
    ASSERT_TRUE(listed && listed->status == 200);
    // (The parsed body in a variable: a range-for over a member of a
    // temporary iterates a destroyed object.)
    const json after_stop = json::parse(listed->body)["nodes"];
    ASSERT_EQ(after_stop.size(), 2u) << listed->body;
    for (const json& n : after_stop) EXPECT_EQ(n.value("alive", true), n.value("name", "") == "n2") << n.dump();
    const auto restarted = std::chrono::steady_clock::now();
    a.start();
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - restarted).count();
    EXPECT_LT(waited, 5.0) << "a clean stop's name watched as a crashed one's (11 s)";
    EXPECT_EQ(a.log().find("watching it"), std::string::npos) << a.log();
    listed = b.client().Get("/v1/nodes");
    ASSERT_TRUE(listed && listed->status == 200);
    const json after_start = json::parse(listed->body)["nodes"];
    ASSERT_EQ(after_start.size(), 2u) << listed->body;
    for (const json& n : after_start) EXPECT_TRUE(n.value("alive", false)) << n.dump();
}

TEST_F(ScaleOut, ADatabaseRestartedMidRunLosesAndDuplicatesNothing) {
    add_nodes(2, 10);
    for (auto& n : nodes) n->start();
    engine.set("delay", "0.1");
    const std::string scene = upload(*nodes[0], "restart");
    std::vector<std::string> ids;
    for (int i = 0; i < 6; ++i) ids.push_back(submit(*nodes[size_t(i) % 2], scene, 200 + i, 10));  // ~1 s each
    std::this_thread::sleep_for(1500ms);  // some done, some running, some queued
    postgres().stop();
    std::this_thread::sleep_for(1500ms);  // the nodes' calls fail meanwhile; their workers bake on
    postgres().start();
    for (const std::string& id : ids) {
        const json status = wait_finished(*nodes[1], id, 40s);
        EXPECT_EQ(status.value("state", ""), "succeeded") << status.dump();
        // A restart shorter than the lease costs no attempt.
        EXPECT_EQ(status.value("attempts", 0), 1) << status.dump();
        const auto stream = events(*nodes[0], id);
        expect_one_clean_stream(stream, id);
        // While the store is away a worker's progress updates are coalesced
        // in memory (the newest kept); every other event is kept, once.
        int last_pass = 0;
        std::vector<int> snapshots;
        for (const auto& e : stream) {
            if (e.type == "progress") {
                EXPECT_GT(e.data.value("pass", 0), last_pass) << id << ": progress stored twice or out of order";
                last_pass = e.data.value("pass", 0);
            }
            if (e.type == "snapshot") snapshots.push_back(e.data.value("pass", 0));
        }
        EXPECT_EQ(last_pass, 10) << id;
        EXPECT_EQ(snapshots, (std::vector<int>{1, 2, 4, 8})) << id << ": a snapshot lost or repeated";
    }
    EXPECT_EQ(worker_runs(), 6);
    bool outage_seen = false;  // the restart did hit the nodes mid-run
    for (const auto& n : nodes)
        outage_seen = outage_seen || n->log().find("connection to PostgreSQL") != std::string::npos ||
                      n->log().find("cannot connect to PostgreSQL") != std::string::npos;
    EXPECT_TRUE(outage_seen);
}

TEST_F(ScaleOut, AJobCancelledOnOneNodeStopsItsWorkerOnAnother) {
    add_nodes(2, 3);
    Node& a = *nodes[0];
    Node& b = *nodes[1];
    a.start();
    engine.set("delay", "0.5");
    const std::string id = submit(a, upload(a, "cancel"), 1, 40);  // 20 s unless stopped
    auto ca = a.client();
    ASSERT_EQ(wait_for_job(ca, id, [](const json& s) { return s.value("state", "") == "running"; }).value("state", ""),
              "running");
    b.start();
    auto cb = b.client();
    auto r = cb.Post("/v1/jobs/" + id + "/cancel");
    ASSERT_TRUE(r && r->status == 200) << (r ? r->body : "no answer");
    // a learns it at its next renewal (every lease / 3 = 1 s) and kills the worker.
    const auto until = std::chrono::steady_clock::now() + 5s;
    while (std::chrono::steady_clock::now() < until && a.log().find("no longer runs on this node") == std::string::npos)
        std::this_thread::sleep_for(50ms);
    EXPECT_NE(a.log().find("no longer runs on this node"), std::string::npos);
    const auto stream = read_events("127.0.0.1", a.port, kToken, id, -1, 0, 5s);
    ASSERT_FALSE(stream.empty());
    EXPECT_EQ(stream.back().type, "cancelled");
}

TEST_F(ScaleOut, ANodeWhoseDatabaseCannotBeReachedStopsAtStartSayingWhich) {
    write_text(tmp.path / "tokens", kToken + "\n");
    Node node("lost",
              {"--data", (tmp.path / "data").string(), "--tokens", (tmp.path / "tokens").string(), "--engine",
               engine.script.string(), "--store", "postgresql://nobody@127.0.0.1:1/farm"},
              tmp.path);
    try {
        node.start();
        FAIL() << "started without its database";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("cannot connect to PostgreSQL at nobody@127.0.0.1:1/farm"),
                  std::string::npos)
            << e.what();
    }
}

// ------------------------------------------------------------------ figures

bool full_benchmark() {
    const char* v = std::getenv("LIGHTFARM_SCALE_OUT_BENCH");
    return v && std::string(v) == "1";
}

double percentile(std::vector<double> v, double q) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, size_t(q * double(v.size())))];
}

TEST_F(ScaleOut, DISABLED_FiguresJobsPerSecondByNodeCount) {
    // Small jobs (the fake engine, one pass) queued up front on every node in
    // turn: jobs/s from the first submit to the last finish, and each job's
    // wait in the queue (started_at - created_at).
    const int per_run = full_benchmark() ? 60 : 12;
    const std::vector<int> counts = full_benchmark() ? std::vector<int>{1, 2, 4} : std::vector<int>{1, 2};
    add_nodes(counts.back(), 30);
    int seed = 1000;
    const std::string scene = [&] {
        nodes[0]->start();
        return upload(*nodes[0], "figures");
    }();
    for (int count : counts) {
        for (int i = 0; i < count; ++i) nodes[size_t(i)]->start();  // no-op for those running
        std::vector<std::string> ids;
        const auto begin = std::chrono::steady_clock::now();
        for (int j = 0; j < per_run; ++j) ids.push_back(submit(*nodes[size_t(j % count)], scene, ++seed, 1));
        std::vector<double> waits;
        double first_created = 1e300, last_finished = 0;
        std::set<std::string> ran_on;
        for (const std::string& id : ids) {
            const json s = wait_finished(*nodes[0], id, 60s);
            ASSERT_EQ(s.value("state", ""), "succeeded") << s.dump();
            EXPECT_EQ(s.value("attempts", 0), 1);
            waits.push_back(s.value("started_at", 0.0) - s.value("created_at", 0.0));
            first_created = std::min(first_created, s.value("created_at", 0.0));
            last_finished = std::max(last_finished, s.value("finished_at", 0.0));
            ran_on.insert(node_of(id));
        }
        const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
        EXPECT_EQ(ran_on.size(), size_t(count)) << "every node took jobs";
        std::cerr << "FIGURE nodes=" << count << " jobs=" << per_run
                  << " jobs_per_second=" << per_run / (last_finished - first_created) << " wall_s=" << wall
                  << " queue_wait_p50_s=" << percentile(waits, 0.5) << " queue_wait_p90_s=" << percentile(waits, 0.9)
                  << "\n";
        for (int i = 1; i < count; ++i) nodes[size_t(i)]->stop();  // the next round starts them again
    }
}

TEST_F(ScaleOut, DISABLED_FiguresClaimLatencyByNodeCount) {
    // The claim itself (one UPDATE over SELECT ... FOR UPDATE SKIP LOCKED),
    // timed in `count` nodes claiming from one backlog at once.
    const int backlog = full_benchmark() ? 2000 : 200;
    const std::vector<int> counts = full_benchmark() ? std::vector<int>{1, 2, 4} : std::vector<int>{1, 2};
    for (int count : counts) {
        const std::string db = postgres().create_database();
        {
            server::PostgresJobStore filler(db, {"filler", 30});
            for (int j = 0; j < backlog; ++j) {
                server::JobRecord job;
                job.status.id = "j" + std::to_string(j);
                job.status.scene = "s";
                job.status.state = server::JobState::Queued;
                job.status.max_attempts = 1;
                job.status.spec = json::object();
                filler.insert_job(job, {});
            }
        }
        std::mutex mutex;
        std::vector<double> latencies;
        std::set<std::string> claimed;
        std::vector<std::thread> claimers;
        const auto begin = std::chrono::steady_clock::now();
        for (int i = 0; i < count; ++i)
            claimers.emplace_back([&, i] {
                server::PostgresJobStore node(db, {"node-" + std::to_string(i), 30});
                for (;;) {
                    const auto t0 = std::chrono::steady_clock::now();
                    const auto job = node.claim_next();
                    const double ms =
                        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
                    if (!job) return;
                    std::lock_guard lock(mutex);
                    latencies.push_back(ms);
                    EXPECT_TRUE(claimed.insert(job->status.id).second) << job->status.id << " claimed twice";
                }
            });
        for (std::thread& t : claimers) t.join();
        const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
        EXPECT_EQ(claimed.size(), size_t(backlog));
        std::cerr << "FIGURE claimers=" << count << " claims=" << backlog << " claims_per_second=" << backlog / wall
                  << " claim_ms_p50=" << percentile(latencies, 0.5) << " claim_ms_p99=" << percentile(latencies, 0.99)
                  << "\n";
    }
}

TEST_F(ScaleOut, DISABLED_FiguresStatementsPerJob) {
    // One node's supervisor, in this process, on PostgreSQL: the statements
    // one small job costs the database (submit, claim, events, progress,
    // finish), and what an idle node costs per second (queue polls,
    // heartbeats, looking for lost nodes).
    const int jobs = full_benchmark() ? 40 : 8;
    server::ServerConfig config;
    config.data_dir = (tmp.path / "data").string();
    config.engine = engine.script.string();
    config.workers = 1;
    fs::create_directories(tmp.path / "data" / "jobs");
    fs::create_directories(tmp.path / "data" / "scenes" / "scene-1");
    write_text(tmp.path / "data" / "scenes" / "scene-1" / "scene.glb", "glTF");
    server::PostgresJobStore store(uri, {"bench", 30});
    server::PostgresJobStore reader(uri, {"reader", 30});  // the test's polls: not counted in `store`
    store.add_scene({"scene-1", "scene.glb", {{"triangles", 12}, {"emissive_triangles", 2}}});
    server::ChangeSignal changes;
    server::Metrics metrics;
    server::Supervisor supervisor(store, config, changes, metrics);
    supervisor.start();
    std::this_thread::sleep_for(3s);
    const int64_t idle_from = store.statements_sent();
    std::this_thread::sleep_for(5s);
    const double idle_per_second = double(store.statements_sent() - idle_from) / 5.0;

    const int64_t from = store.statements_sent();
    const auto begin = std::chrono::steady_clock::now();
    for (int j = 0; j < jobs; ++j) {
        server::JobRecord job;
        job.status.id = "job" + std::to_string(j);
        job.status.scene = "scene-1";
        job.status.state = server::JobState::Queued;
        job.status.max_attempts = 3;
        job.status.spec = {{"scene", "scene-1"}, {"seed", j}, {"outputs", {{"lightmap", {{"passes", 4}}}}}};
        job.max_seconds = 60;
        store.insert_job(job, {});
        changes.notify();
        for (const auto until = std::chrono::steady_clock::now() + 20s; std::chrono::steady_clock::now() < until;
             std::this_thread::sleep_for(5ms))
            if (protocol::is_final(reader.job(job.status.id)->status.state)) break;
        ASSERT_EQ(reader.job(job.status.id)->status.state, server::JobState::Succeeded);
    }
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - begin).count();
    supervisor.stop();
    // Less the idle load over the same time: what the jobs cost.
    const double total = double(store.statements_sent() - from);
    std::cerr << "FIGURE jobs=" << jobs << " statements=" << total << " wall_s=" << wall
              << " idle_statements_per_second=" << idle_per_second
              << " statements_per_job=" << (total - idle_per_second * wall) / jobs << "\n";

    // The statements of one job as the supervisor issues them, counted on a
    // store of their own: no polls.
    server::PostgresJobStore alone(postgres().create_database(), {"alone", 30});
    const auto t0 = std::chrono::steady_clock::now();
    const int64_t before = alone.statements_sent();
    alone.add_scene({"scene-1", "scene.glb", json::object()});
    server::JobRecord job;
    job.status.id = "one";
    job.status.scene = "scene-1";
    job.status.state = server::JobState::Queued;
    job.status.max_attempts = 3;
    job.status.spec = json::object();
    alone.insert_job(job, {});
    const int64_t submit = alone.statements_sent() - before;
    ASSERT_TRUE(alone.claim_next());
    alone.append_event("one", {0, "started", {{"attempt", 1}}});
    for (int pass = 1; pass <= 4; ++pass) {
        server::Progress p;
        p.pass = pass;
        alone.set_progress("one", p);
        alone.append_event("one", {0, "progress", {{"output", "lightmap"}, {"pass", pass}}});
        alone.set_latest("one", "lightmap", {"lightmap.pass-0001.exr", pass, false});
        alone.append_event("one", {0, "snapshot", {{"output", "lightmap"}, {"pass", pass}}});
    }
    alone.set_progress("one", {});
    alone.set_latest("one", "lightmap", {"lightmap.exr", 4, true});
    ASSERT_TRUE(alone.renew_lease("one"));
    ASSERT_TRUE(alone.finish("one", server::JobState::Succeeded, "", "", {0, "done", json::object()}));
    const int64_t per_job = alone.statements_sent() - before;
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::cerr << "FIGURE one_job_4_passes_4_snapshots statements=" << per_job << " of_which_submit=" << submit
              << " ms=" << ms << " ms_per_statement=" << ms / double(per_job) << "\n";
    EXPECT_GT(per_job, 10);
}

TEST_F(ScaleOut, DISABLED_FiguresTakeOverWaitByLease) {
    // The wait of a killed node's job until another node queues it again,
    // against --lease-seconds: between 2/3 of the lease (renewed just before
    // the kill) and 4/3 (the other node looks every third of a lease).
    const std::vector<double> leases = full_benchmark() ? std::vector<double>{2, 5, 10} : std::vector<double>{1};
    const int repeats = full_benchmark() ? 3 : 1;
    engine.set("delay", "0.5");
    for (double lease : leases) {
        for (int r = 0; r < repeats; ++r) {
            add_nodes(2, lease);
            Node& a = *nodes[nodes.size() - 2];
            Node& b = *nodes[nodes.size() - 1];
            a.start();
            const std::string id = submit(a, upload(a, "lease"), int(lease * 100) + r, 200);
            auto ca = a.client();
            ASSERT_EQ(wait_for_job(ca, id, [](const json& s) { return s.value("state", "") == "running"; })
                          .value("state", ""),
                      "running");
            b.start();
            a.kill9();
            const auto killed = std::chrono::steady_clock::now();
            auto cb = b.client();
            const json again = wait_for_job(
                cb, id, [](const json& s) { return s.value("attempts", 0) == 2; }, 60s);
            const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - killed).count();
            EXPECT_EQ(again.value("attempts", 0), 2);
            EXPECT_GE(waited, lease * 2 / 3 - 0.2);
            EXPECT_LE(waited, lease * 4 / 3 + 1.5);
            std::cerr << "FIGURE lease_seconds=" << lease << " take_over_wait_s=" << waited << "\n";
            ASSERT_EQ(b.client().Post("/v1/jobs/" + id + "/cancel")->status, 200);
            b.stop();
        }
    }
}

}  // namespace
}  // namespace lf::test
