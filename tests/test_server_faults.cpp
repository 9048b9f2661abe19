// Every call of lightfarmd and its SQLite store that changes a file, under
// ENOSPC and under EIO (issue #33; the harness: fault_harness.h): nothing
// accepted is lost, and no job fails for a fault of the machine. The
// scenario, lightfarmd with the fake engine (server_harness.h): start,
// upload a scene, submit a job, run it, stop, start again. Every answer is
// 2xx or 503 (retried), never a 4xx or 500; the job succeeds, no attempt
// spent on the machine's fault; the accepted scene and job are there after
// the restart. No GL: ctest runs it beside other tests.
#include "cli_runner.h"
#include "fault_harness.h"
#include "postgres_server.h"

#include <atomic>
#include <mutex>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;

const std::string kToken = "fault-token-0123456789";

// ---------------------------------------------------------------- lightfarmd

// The server's scenario, in phases; a fault is armed at the start of each
// phase in which the dry run saw its site written, so that one run fails the
// site's first write in each. "check" (the restart after the stop, and what
// it finds) is never armed: it is where nothing accepted may be missing.
const std::vector<std::string> kServerPhases = {"start", "upload", "job", "run", "stop"};

class ServerScenario {
public:
    // `armed`: the phases to arm the shim's fault in (none for a dry run).
    // `store`: lightfarmd's --store (empty: SQLite in its data directory);
    // `recover`: waits until the store is back after a fault was taken (a
    // PostgreSQL that crashed restarts by itself).
    ServerScenario(
        const fs::path& dir, const FaultShim& shim, std::set<std::string> armed, const std::string& store = "",
        std::function<void()> recover = [] {})
        : shim_(shim),
          armed_(std::move(armed)),
          recover_(std::move(recover)),
          engine_(dir / "engine"),
          server_(dir / "data", dir / "tokens", engine_.script, lightfarmd_args(store), shim.environment()) {
        write_text(dir / "tokens", kToken + "\n");
    }
    // Runs every phase; returns what each armed phase's fault did, in the table's words.
    std::map<std::string, std::string> run();

private:
    static std::vector<std::string> lightfarmd_args(const std::string& store) {
        std::vector<std::string> args = {"--workers", "1", "--node-name", "node"};
        // The default lease (30 s): its first renewal, a commit of its own,
        // comes 10 s after the start, after the scenario's phases, whose
        // commits are then their requests' own from run to run.
        if (!store.empty()) args.insert(args.end(), {"--store", store});
        return args;
    }
    void enter(const std::string& phase);
    void leave();
    std::string start();
    std::string post(const std::string& path, const std::string& body, const std::string& type, std::string& id);
    void wait_for_worker();
    bool finished_requeued(const std::string& job);
    void check_nothing_lost(const std::string& scene, const std::string& job);
    std::map<std::string, std::string> effects_of_armed_phases() const;
    std::map<std::string, std::string> gave_up();

    const FaultShim& shim_;
    std::set<std::string> armed_;
    std::function<void()> recover_;
    FakeEngine engine_;
    Lightfarmd server_;
    std::string phase_;
    std::map<std::string, std::string> effects_;
};

void ServerScenario::enter(const std::string& phase) {
    phase_ = phase;
    shim_.mark(phase);
    if (armed_.count(phase)) shim_.arm();
}

// The phase's effect stands as found, or "not reached" when its fault was not taken.
void ServerScenario::leave() {
    if (!armed_.count(phase_)) return;
    if (!shim_.fired()) effects_[phase_] = "not reached";
    else recover_();
    shim_.disarm();
}

// A start the fault stops is refused with a message (the log says what),
// never a server that runs without what it could not write; then it starts.
std::string ServerScenario::start() {
    try {
        server_.start();
        return "no effect";
    } catch (const std::exception&) {
        shim_.disarm();
        recover_();
        server_.start();
        return "refuses to start, then starts";
    }
}

// POSTs until it is not a 503 (at most 5 times): every answer 2xx or 503
// (the machine's trouble, retried), never an input error or a 500. The
// outcome is told by class, each status once in the order first met
// ("503, then 201"), not by how many retries it took: on a busy machine a
// store restarting under the test answered 503 twice where it usually
// answers once (issue #55: the table compared as text failed under load).
std::string ServerScenario::post(const std::string& path, const std::string& body, const std::string& type,
                                 std::string& id) {
    auto c = server_.client(kToken);
    std::string answers;
    int last = -1;
    for (int i = 0; i < 5; ++i) {
        auto r = c.Post(path, body, type);
        const int status = r ? r->status : 0;
        if (status != last) answers += (answers.empty() ? "" : ", then ") + std::to_string(status);
        last = status;
        EXPECT_TRUE(status == 200 || status == 201 || status == 503)
            << phase_ << ": " << path << " answered " << status << ": " << (r ? r->body : "nothing");
        if (status == 503) {
            EXPECT_FALSE(r->get_header_value("Retry-After").empty()) << r->body;
        }
        if (status == 200 || status == 201) {
            id = json::parse(r->body)["id"];
            return answers == "201" || answers == "200" ? "no effect" : answers;
        }
        if (status != 503) break;
        shim_.disarm();
        recover_();
    }
    ADD_FAILURE() << phase_ << ": " << path << " never accepted: " << answers;
    return answers;
}

// Waits until the job's worker has started (its spec and pid file written)
// and waits at the fake engine's gate: after a spec that could not be
// written, the job is back in the queue and a later worker starts.
void ServerScenario::wait_for_worker() {
    for (int i = 0; i < 500 && engine_.runs() == 0; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(20));
    EXPECT_GE(engine_.runs(), 1) << phase_ << ": the job's worker did not start";
}

// The job, once finished: it succeeded, at no attempt's cost; whether a
// fault of the machine put it back in the queue.
bool ServerScenario::finished_requeued(const std::string& job) {
    auto c = server_.client(kToken);
    const json status = wait_for_job(c, job, is_finished);
    EXPECT_EQ(status.value("state", ""), "succeeded") << status.dump();
    EXPECT_EQ(status.value("attempts", 0), 1) << "a fault of the machine cost the job an attempt: " << status.dump();
    bool requeued = false;
    for (const auto& e : read_events(server_.host, server_.port, kToken, job))
        requeued |= e.type == "retrying" && e.data.value("server_fault", false);
    return requeued;
}

std::map<std::string, std::string> ServerScenario::run() {
    enter("start");
    effects_["start"] = start();
    leave();
    enter("upload");
    std::string scene, job;
    const std::string glb = read_text(example_scene("flower.glb"));
    effects_["upload"] = post("/v1/scenes?name=flower.glb", glb, "model/gltf-binary", scene);
    leave();
    if (scene.empty()) return gave_up();
    enter("job");
    engine_.set("gate", "");  // the worker waits at its start until "run"
    const json spec = {{"scene", scene}, {"outputs", {{"lightmap", {{"passes", 2}}}}}};
    effects_["job"] = post("/v1/jobs", spec.dump(), "application/json", job);
    if (job.empty()) return gave_up();
    wait_for_worker();
    const bool fired_in_job = shim_.fired();
    leave();
    enter("run");
    fs::remove(engine_.dir / "gate");
    effects_["run"] = "no effect";
    if (finished_requeued(job)) effects_[fired_in_job ? "job" : "run"] = "requeued at no cost";
    leave();
    enter("stop");
    server_.stop();
    effects_["stop"] = "no effect";
    leave();
    enter("check");
    if (start() != "no effect") effects_["stop"] = "the next start refused, then starts";
    check_nothing_lost(scene, job);
    std::map<std::string, std::string> effects = effects_of_armed_phases();
    server_.kill9();  // nothing left to save: a stop would only wait for it (0.1 s a run)
    return effects;
}

std::map<std::string, std::string> ServerScenario::effects_of_armed_phases() const {
    std::map<std::string, std::string> armed;
    for (const auto& [phase, effect] : effects_)
        if (armed_.count(phase)) armed[phase] = effect;
    if (::testing::Test::HasFailure()) std::cerr << "---- lightfarmd log ----\n" << server_.log();
    return armed;
}

// A scenario that cannot go on (its upload or job never accepted: already
// a failure) ends here, saying what it found.
std::map<std::string, std::string> ServerScenario::gave_up() {
    shim_.disarm();
    return effects_of_armed_phases();
}

// After a restart, the accepted scene and job are there, the job succeeded.
void ServerScenario::check_nothing_lost(const std::string& scene, const std::string& job) {
    auto c = server_.client(kToken);
    auto s = c.Get("/v1/scenes/" + scene);
    EXPECT_TRUE(s && s->status == 200) << "the accepted scene is lost: " << (s ? s->body : "no answer");
    auto j = c.Get("/v1/jobs/" + job);
    ASSERT_TRUE(j && j->status == 200) << "the accepted job is lost: " << (j ? j->body : "no answer");
    EXPECT_EQ(json::parse(j->body).value("state", ""), "succeeded") << j->body;
}

// site -> phase -> error -> call -> what failing that call did.
using PhaseEffects = std::map<std::string, std::map<std::string, std::map<std::string, std::map<int, std::string>>>>;

// The docs' table of the server's scenario: a row per site and phase, in
// the phases' order, with what each error did at each call.
std::string phase_table(const std::string& who, const PhaseEffects& effects,
                        std::map<std::string, std::map<std::string, int>>& sites) {
    std::string table =
        row({"site (" + who + ")", "phase", "calls", "ENOSPC", "EIO"}) + row({"---", "---", "---", "---", "---"});
    for (const auto& [site, by_phase] : effects)
        for (const std::string& phase : kServerPhases)
            if (by_phase.count(phase))
                table += row({"`" + operation_and_path(site) + "`", phase, calls_cell(sites[site][phase]),
                              summary(by_phase.at(phase).at("ENOSPC"), sites[site][phase]),
                              summary(by_phase.at(phase).at("EIO"), sites[site][phase])});
    return table;
}

// One run of the server's scenario under a fault: the site, which of its
// calls fails, with what error, armed in which phases.
struct FaultRun {
    std::string site;
    int nth;
    std::string error;
    std::set<std::string> armed;
};

// Calls run(i) for every i < n on `threads` threads: the scenario's runs
// mostly wait on lightfarmd and its fake engine, so four side by side take
// about a quarter of the time (CI's 20 minutes), each with its own
// lightfarmd, directory and shim (FaultShim::Export::kExplicitly). `run`
// throws nothing: an exception would end the test process.
void side_by_side(size_t n, int threads, const std::function<void(size_t)>& run) {
    std::atomic<size_t> next{0};
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t)
        pool.emplace_back([&] {
            for (size_t i = next++; i < n; i = next++) run(i);
        });
    for (std::thread& thread : pool) thread.join();
}

TEST(ServerFaults, EveryCallOfTheServerAndItsStore) {
    constexpr auto kExplicitly = FaultShim::Export::kExplicitly;
    TempDir tmp;
    std::map<std::string, std::map<std::string, int>> sites;
    {
        const fs::path dir = tmp.path / "dry";
        const FaultShim dry(dir / "data", dir, "", "", 1, kExplicitly);
        ServerScenario(dir, dry, {}).run();
        ASSERT_FALSE(::testing::Test::HasFailure()) << "the scenario fails without a fault";
        sites = calls_by_site(dry.calls());
        // A 201 is on the disk when it is answered: the phases that answer
        // one (an upload, a job) sync the store's WAL, as a power loss needs.
        for (const std::string phase : {"upload", "job"})
            EXPECT_GT(sites["lightfarmd sync jobs.sqlite-wal"][phase], 0)
                << "the store's WAL is not synced before a 201 in " << phase;
        expect_every_file_seen(dir / "data", dry.sites(), [](const std::string& path) {
            // The fake engine's files, which it writes through cp and mv.
            const std::string name = fs::path(path).filename().string();
            return name == "lightmap.exr" || name == "manifest.json" || name.rfind("lightmap.pass-", 0) == 0;
        });
    }
    // Each call of each site fails in turn (the first, middle and last of a
    // phase's calls where it makes more than three), in one run for each
    // call number and error; a run fails that call in every phase with it.
    std::vector<FaultRun> runs;
    for (const auto& [site, calls] : sites) {
        std::map<int, std::set<std::string>> phases_by_call;
        for (const auto& [phase, n] : calls)
            if (std::find(kServerPhases.begin(), kServerPhases.end(), phase) != kServerPhases.end())
                for (int nth : calls_to_fail(n)) phases_by_call[nth].insert(phase);
        EXPECT_FALSE(phases_by_call.empty())
            << site << " is called only where no fault is tried: " << calls.begin()->first;
        for (const auto& [nth, armed] : phases_by_call)
            for (const std::string& error : kErrors) runs.push_back({site, nth, error, armed});
    }
    PhaseEffects effects;
    std::mutex effects_mutex;
    side_by_side(runs.size(), 4, [&](size_t i) {
        const auto& [site, nth, error, armed] = runs[i];
        const fs::path dir = tmp.path / std::to_string(i + 1);
        const FaultShim shim(dir / "data", dir, site, error, nth, kExplicitly);
        SCOPED_TRACE(site + ", call " + std::to_string(nth) + ", " + error);
        std::map<std::string, std::string> found;
        try {
            found = ServerScenario(dir, shim, armed).run();
        } catch (const std::exception& e) {  // lightfarmd would not start
            ADD_FAILURE() << "run " << i + 1 << ": " << e.what();
        }
        for (const auto& [phase, effect] : found) {
            EXPECT_NE(effect, "not reached") << site << " call " << nth << " in " << phase << " under " << error;
            const std::lock_guard<std::mutex> lock(effects_mutex);
            effects[site][phase][error][nth] = effect;
        }
    });
    std::cerr << runs.size() << " runs of the scenario, four side by side\n";
    expect_doc_table("server write-fault", phase_table("lightfarmd", effects, sites));
}

// ---------------------------------------------------------------- PostgreSQL

// The scale-out store's own disk. Every commit lightfarmd makes waits for
// PostgreSQL to write its WAL and sync it (synchronous_commit on, its
// default), so those two calls are failed, in each phase of the server's
// scenario above, under ENOSPC and EIO. PostgreSQL takes either as a PANIC:
// it drops every connection, recovers from its WAL and starts again by
// itself. (It writes its data files at checkpoints, apart from any commit:
// a failure there fails the checkpoint, which it retries; lightfarmd never
// sees it.) lightfarmd answers 503 meanwhile and loses nothing it answered
// 2xx; the job succeeds at no attempt's cost.
const std::vector<std::string> kWalSites = {"postgres write pg_wal/#", "postgres sync pg_wal/#"};

class PostgresFaults {
public:
    PostgresFaults() : postgres_(/*durable=*/true) {}
    // The server's scenario on a new database of a PostgreSQL whose
    // processes carry the shim: `site` empty for a dry run. Returns the
    // effects of the armed phases; `calls` gets the dry run's calls.
    std::map<std::string, std::string> run(const std::string& name, const std::string& site, const std::string& error,
                                           int nth, const std::set<std::string>& armed,
                                           std::map<std::string, int>* calls = nullptr) {
        const fs::path dir = postgres_.shared_dir() / "faults" / name;
        FaultShim shim(postgres_.data_dir(), dir, site, error, nth, FaultShim::Export::kExplicitly);
        shim.count_only("postgres");
        postgres_.stop();
        postgres_.start(shim.environment());
        const std::string uri = postgres_.create_database();
        std::map<std::string, std::string> effects =
            ServerScenario(dir, shim, armed, uri, [&] { postgres_.wait_until_ready(); }).run();
        if (calls) *calls = shim.calls();
        return effects;
    }

private:
    PostgresServer postgres_;
};

TEST(StoreFaults, EveryWalCallOfPostgreSQLUnderTheServer) {
    PostgresFaults postgres;
    std::map<std::string, int> dry_calls;
    postgres.run("dry", "", "", 1, {}, &dry_calls);
    ASSERT_FALSE(::testing::Test::HasFailure()) << "the scenario fails without a fault";
    std::map<std::string, std::map<std::string, int>> sites = calls_by_site(dry_calls);
    // Every phase that answers a 2xx commits, so writes and syncs the WAL.
    for (const std::string& site : kWalSites)
        for (const std::string phase : {"start", "upload", "job", "run"})
            EXPECT_GT(sites[site][phase], 0) << site << " is not called in " << phase;
    PhaseEffects effects;
    int runs = 0;
    for (const std::string& site : kWalSites) {
        // Each call where a phase makes up to three (an upload's and a
        // job's commits); where it makes more (the schema at start, the
        // progress of a run) the first only: how many WAL writes those
        // take depends on PostgreSQL's WAL writer's timing, so no middle or
        // last call is the same from run to run.
        std::map<int, std::set<std::string>> phases_by_call;
        for (const auto& [phase, n] : sites[site])
            if (std::find(kServerPhases.begin(), kServerPhases.end(), phase) != kServerPhases.end())
                for (int nth : n <= 3 ? calls_to_fail(n) : std::set<int>{1}) phases_by_call[nth].insert(phase);
        for (const auto& [nth, armed] : phases_by_call)
            for (const std::string& error : kErrors) {
                SCOPED_TRACE(site + ", call " + std::to_string(nth) + ", " + error);
                for (const auto& [phase, effect] : postgres.run(std::to_string(++runs), site, error, nth, armed)) {
                    EXPECT_NE(effect, "not reached") << site << " call " << nth << " in " << phase;
                    effects[site][phase][error][nth] = effect;
                }
            }
    }
    std::cerr << runs << " runs of the scenario on PostgreSQL\n";
    expect_doc_table("postgresql write-fault", phase_table("PostgreSQL under lightfarmd", effects, sites));
}

// ---------------------------------------------------------------- the client

// A finished job of the fake engine on a lightfarmd without faults, for the
// client to fetch: its id.
std::string finished_job(Lightfarmd& server) {
    auto c = server.client(kToken);
    auto up = c.Post("/v1/scenes?name=flower.glb", read_text(example_scene("flower.glb")), "model/gltf-binary");
    EXPECT_TRUE(up && up->status == 201) << (up ? up->body : "no answer");
    if (!up || up->status != 201) return "";
    const json spec = {{"scene", json::parse(up->body)["id"]}, {"outputs", {{"lightmap", {{"passes", 2}}}}}};
    auto job = c.Post("/v1/jobs", spec.dump(), "application/json");
    EXPECT_TRUE(job && job->status == 201) << (job ? job->body : "no answer");
    if (!job || job->status != 201) return "";
    const std::string id = json::parse(job->body)["id"];
    EXPECT_EQ(wait_for_job(c, id, is_finished).value("state", ""), "succeeded");
    return id;
}

// Each file under `dir` by its name, with its bytes.
std::map<std::string, std::string> files_in(const fs::path& dir) {
    std::map<std::string, std::string> files;
    for (const auto& entry : fs::recursive_directory_iterator(dir))
        if (entry.is_regular_file()) files[fs::relative(entry.path(), dir).string()] = read_text(entry.path());
    return files;
}

// `lightfarm fetch` of a finished job's files: a call that fails exits 1,
// its last line naming the file and the error; it leaves neither a
// temporary file nor a file cut short (each file there is whole); fetched
// again without the fault, every file arrives. (Before: a write that failed
// at close left a file cut short, renamed into place.)
TEST(ClientFaults, EveryCallOfAFetch) {
    TempDir tmp;
    FakeEngine engine(tmp.path / "engine");
    write_text(tmp.path / "tokens", kToken + "\n");
    Lightfarmd server(tmp.path / "data", tmp.path / "tokens", engine.script, {"--workers", "1"});
    server.start();
    const std::string job = finished_job(server);
    ASSERT_FALSE(job.empty());
    auto fetch = [&](const fs::path& out) {
        return run_lightfarm("fetch " + job + " --server " + server.url + " --token " + kToken + " --out " +
                             out.string());
    };
    std::map<std::string, std::string> whole;
    std::map<std::string, int> sites;
    {
        // The shim's root holds the fetch's directory: its mkdir counts.
        const fs::path dir = tmp.path / "dry";
        const FaultShim dry(dir / "root", dir);
        const CliRun run = fetch(dir / "root" / "out");
        ASSERT_EQ(run.exit_code, 0) << run.err;
        whole = files_in(dir / "root" / "out");
        ASSERT_GE(whole.size(), 2u) << "the fake engine's job has a lightmap and a manifest";
        expect_every_file_seen(dir / "root", dry.sites(), [](const std::string&) { return false; });
        for (const auto& [s, calls] : dry.calls()) sites[s.substr(s.find(' ') + 1)] = calls;
    }
    std::string table = row({"site (lightfarm fetch)", "calls", "ENOSPC", "EIO"}) + row({"---", "---", "---", "---"});
    int runs = 0;
    for (const auto& [site, calls] : sites) {
        std::map<std::string, std::map<int, std::string>> effect;
        for (int nth : calls_to_fail(calls)) {
            for (const std::string& error : kErrors) {
                SCOPED_TRACE(site + ", call " + std::to_string(nth) + ", " + error);
                const fs::path dir = tmp.path / std::to_string(++runs), out = dir / "root" / "out";
                {
                    const FaultShim shim(dir / "root", dir, site, error, nth);
                    shim.arm();
                    const CliRun run = fetch(out);
                    EXPECT_TRUE(shim.fired()) << "the call was not made";
                    const std::string last = run.err.substr(run.err.rfind('\n', run.err.size() - 2) + 1);
                    const std::string words = error == "EIO" ? "Input/output error" : "No space left on device";
                    EXPECT_EQ(run.exit_code, 1) << run.err;
                    EXPECT_NE(last.find(words), std::string::npos) << last;
                    std::string file = file_of(site);
                    if (file[0] == '.') file = file.substr(1);
                    EXPECT_NE(last.find(file.substr(0, file.find(".tmp"))), std::string::npos) << last;
                    if (fs::exists(out))
                        for (const auto& [name, bytes] : files_in(out)) {
                            EXPECT_EQ(name.find(".tmp"), std::string::npos) << "left " << name;
                            EXPECT_TRUE(whole.count(name) && whole[name] == bytes) << name << " is not whole";
                        }
                    effect[error][nth] = run.exit_code == 1 && last.find(words) != std::string::npos
                                             ? "exit 1, names the file and the error"
                                             : "exit " + std::to_string(run.exit_code) + ": " + last;
                }
                const CliRun again = fetch(out);
                EXPECT_EQ(again.exit_code, 0) << again.err;
                EXPECT_EQ(files_in(out), whole) << "fetched again, not every file arrived whole";
            }
        }
        table += row({"`" + operation_and_path(site) + "`", calls_cell(calls), summary(effect["ENOSPC"], calls),
                      summary(effect["EIO"], calls)});
    }
    expect_doc_table("client write-fault", table);
}

}  // namespace
}  // namespace lf::test
