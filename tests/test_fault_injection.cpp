// Every write of lightfarmd, its SQLite store and the lightfarm worker, under
// ENOSPC and under EIO (issue #33): nothing accepted is lost, and no job
// fails for a fault of the machine.
//
// The faults come from an LD_PRELOAD shim (fault_shim.cpp) rather than a
// seam in our write functions: the store's writes are SQLite's, the EXR
// writes OpenEXR's, and a seam sees only the writes someone remembered to
// route through it. The shim sees them all (write, writev, pwrite, pwritev,
// fsync, fdatasync), and names each by its "site": the process and the
// file's path in the data or output directory, ids and numbers as '#'.
//
// Each test first runs its scenario once without a fault (the dry run),
// which lists the sites it writes, then runs it again for each site and each
// error, failing that site's first write (in the server's scenario, its
// first write in each phase where the dry run saw it):
//  - lightfarmd with the fake engine (server_harness.h): start, upload a
//    scene, submit a job, run it, stop, start again. Every answer is 2xx or
//    503 (retried), never a 4xx or 500; the job succeeds, no attempt spent
//    on the machine's fault; the accepted scene and job are there after the
//    restart.
//  - `lightfarm bake` of the Cornell box, one output at a time, tiny: a
//    failed write exits kExitMachineFault (the machine's trouble, requeued by
//    the server at no cost), never an input error, naming the file.
// The tables of sites and results in docs/service.md must be the ones these
// tests find: a site added or a result changed fails the test, which prints
// the new table.
#include "cli_runner.h"
#include "server_harness.h"
#include "worker_protocol.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <map>
#include <regex>
#include <set>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;

const std::string kToken = "fault-token-0123456789";

const std::vector<std::string> kErrors = {"ENOSPC", "EIO"};

fs::path shared_scene(const std::string& name) {
    const char* env = std::getenv("LIGHTFARM_SCENES");
    return fs::path(env ? env : LIGHTFARM_SHARED_SCENES) / name;
}

// The shim's settings, as environment variables of the processes this test
// starts while a FaultShim lives (posix_spawn and popen pass environ on).
class FaultShim {
public:
    // `site` empty: a dry run, which logs every write's site.
    FaultShim(const fs::path& root, const fs::path& dir, const std::string& site = "", const std::string& error = "")
        : log_(dir / "writes.log"), armed_(dir / "armed") {
        set("LD_PRELOAD", LIGHTFARM_FAULT_SHIM);
        set("LF_FAULT_ROOT", fs::weakly_canonical(root).string());
        set("LF_FAULT_ARMED", armed_.string());
        if (site.empty()) set("LF_FAULT_LOG", log_.string());
        else {
            set("LF_FAULT_SITE", site);
            set("LF_FAULT_ERRNO", error);
        }
    }
    ~FaultShim() {
        for (const char* name :
             {"LD_PRELOAD", "LF_FAULT_ROOT", "LF_FAULT_ARMED", "LF_FAULT_LOG", "LF_FAULT_SITE", "LF_FAULT_ERRNO"})
            unsetenv(name);
    }
    // From now on the site's next write fails, once: the shim appends an 'x'.
    void arm() const { write_text(armed_, ""); }
    bool fired() const { return read_text(armed_).rfind('x', 0) == 0; }
    // No fault from now on, if none was taken.
    void disarm() const {
        if (read_text(armed_).empty()) write_text(armed_, "-");
    }
    // A line of the harness's own in the log: where a phase of the scenario begins.
    void mark(const std::string& phase) const { std::ofstream(log_, std::ios::app) << "@" << phase << "\n"; }
    // The dry run's sites in the order first written, each as "PHASE SITE".
    std::vector<std::string> sites() const {
        std::vector<std::string> sites;
        std::string phase = "start", line;
        std::ifstream in(log_);
        while (std::getline(in, line)) {
            if (line.rfind('@', 0) == 0) phase = line.substr(1);
            else if (std::find(sites.begin(), sites.end(), phase + " " + line) == sites.end())
                sites.push_back(phase + " " + line);
        }
        return sites;
    }

private:
    static void set(const char* name, const std::string& value) { setenv(name, value.c_str(), 1); }
    fs::path log_, armed_;
};

// A file name as the shim writes it in a site: any word with a digit, or of
// 8 hex digits or more, as '#' ("lightmap.pass-0004.exr" -> "lightmap.pass-#.exr").
std::string as_in_site(const std::string& name) {
    static const std::regex word("[A-Za-z0-9]+"), numeric(".*[0-9].*|[0-9a-f]{8,}");
    std::string out;
    size_t at = 0;
    for (auto it = std::sregex_iterator(name.begin(), name.end(), word); it != std::sregex_iterator(); ++it) {
        out += name.substr(at, size_t(it->position()) - at);
        out += std::regex_match(it->str(), numeric) ? "#" : it->str();
        at = size_t(it->position() + it->length());
    }
    return out + name.substr(at);
}

// Every file left under `root` was seen written by the shim: a file written
// through a path the shim cannot see (glibc's stdio) would be missing. Files
// are written under a temporary name and renamed, so a file counts as seen
// when a site's last part contains its name ("lightmap.exr" is written as
// ".lightmap.exr.tmp-#"). `skip`: files this check is not about.
void expect_every_file_seen(const fs::path& root, const std::vector<std::string>& sites,
                            const std::function<bool(const std::string&)>& skip) {
    for (const auto& entry : fs::recursive_directory_iterator(root)) {
        if (!entry.is_regular_file() || entry.file_size() == 0) continue;
        const std::string name = as_in_site(entry.path().filename().string());
        if (skip(fs::relative(entry.path(), root).string())) continue;
        bool seen = false;
        for (const std::string& site : sites)
            seen |= fs::path(site).filename().string().find(name) != std::string::npos;
        EXPECT_TRUE(seen) << entry.path() << " was written by no write the shim saw";
    }
}

// The table between "<!-- NAME table: ... -->" and "<!-- end of the NAME
// table -->" in docs/service.md must be `table`: a site added, gone or
// answered otherwise fails here, printing the table to put there. With
// LIGHTFARM_WRITE_FAULT_TABLES=1 the test writes it there itself.
void expect_doc_table(const std::string& name, const std::string& table) {
    const fs::path doc = fs::path(LIGHTFARM_SOURCE_DIR) / "docs" / "service.md";
    std::string text = read_text(doc);
    const std::string begin_mark = "<!-- " + name + " table:", end_mark = "<!-- end of the " + name + " table -->";
    const size_t begin = text.find('\n', text.find(begin_mark)) + 1, end = text.find(end_mark);
    ASSERT_TRUE(text.find(begin_mark) != std::string::npos && end != std::string::npos && begin <= end)
        << doc << " has no " << begin_mark << " ... " << end_mark;
    if (std::getenv("LIGHTFARM_WRITE_FAULT_TABLES")) {
        text.replace(begin, end - begin, table);
        std::ofstream(doc, std::ios::binary) << text;
        return;
    }
    EXPECT_EQ(text.substr(begin, end - begin), table)
        << "docs/service.md's " << name << " table is not what the harness finds; it should read:\n"
        << table;
}

// One markdown row.
std::string row(const std::vector<std::string>& cells) {
    std::string line = "|";
    for (const std::string& c : cells) line += " " + c + " |";
    return line + "\n";
}

// ---------------------------------------------------------------- lightfarmd

// The server's scenario, in phases; a fault is armed at the start of each
// phase in which the dry run saw its site written, so that one run fails the
// site's first write in each. "check" (the restart after the stop, and what
// it finds) is never armed: it is where nothing accepted may be missing.
const std::vector<std::string> kServerPhases = {"start", "upload", "job", "run", "stop"};

class ServerScenario {
public:
    // `armed`: the phases to arm the shim's fault in (none for a dry run).
    ServerScenario(const fs::path& dir, const FaultShim& shim, std::set<std::string> armed)
        : shim_(shim),
          armed_(std::move(armed)),
          engine_(dir / "engine"),
          server_(dir / "data", dir / "tokens", engine_.script, {"--workers", "1", "--node-name", "node"}) {
        write_text(dir / "tokens", kToken + "\n");
    }
    // Runs every phase; returns what each armed phase's fault did, in the table's words.
    std::map<std::string, std::string> run();

private:
    void enter(const std::string& phase);
    void leave();
    std::string start();
    std::string post(const std::string& path, const std::string& body, const std::string& type, std::string& id);
    void wait_for_worker();
    bool finished_requeued(const std::string& job);
    void check_nothing_lost(const std::string& scene, const std::string& job);

    const FaultShim& shim_;
    std::set<std::string> armed_;
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
        server_.start();
        return "refuses to start, then starts";
    }
}

// POSTs until it is not a 503 (at most 5 times): every answer 2xx or 503
// (the machine's trouble, retried), never an input error or a 500.
std::string ServerScenario::post(const std::string& path, const std::string& body, const std::string& type,
                                 std::string& id) {
    auto c = server_.client(kToken);
    std::string answers;
    for (int i = 0; i < 5; ++i) {
        auto r = c.Post(path, body, type);
        const int status = r ? r->status : 0;
        answers += (answers.empty() ? "" : ", then ") + std::to_string(status);
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
    const std::string glb = read_text(shared_scene("flower.glb"));
    effects_["upload"] = post("/v1/scenes?name=flower.glb", glb, "model/gltf-binary", scene);
    leave();
    enter("job");
    engine_.set("gate", "");  // the worker waits at its start until "run"
    const json spec = {{"scene", scene}, {"outputs", {{"lightmap", {{"passes", 2}}}}}};
    effects_["job"] = post("/v1/jobs", spec.dump(), "application/json", job);
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
    std::map<std::string, std::string> armed;
    for (const auto& [phase, effect] : effects_)
        if (armed_.count(phase)) armed[phase] = effect;
    if (::testing::Test::HasFailure()) std::cerr << "---- lightfarmd log ----\n" << server_.log();
    return armed;
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

// The phases of the dry run in which each site was written: "lightfarmd
// jobs.sqlite-wal" -> {"start", "upload", …}.
std::map<std::string, std::set<std::string>> phases_by_site(const std::vector<std::string>& sites) {
    std::map<std::string, std::set<std::string>> phases;
    for (const std::string& s : sites) {
        const size_t space = s.find(' ');
        phases[s.substr(space + 1)].insert(s.substr(0, space));
    }
    return phases;
}

TEST(ServerFaults, EveryWriteOfTheServerAndItsStore) {
    TempDir tmp;
    std::map<std::string, std::set<std::string>> sites;
    {
        const fs::path dir = tmp.path / "dry";
        const FaultShim dry(dir / "data", dir);
        ServerScenario(dir, dry, {}).run();
        ASSERT_FALSE(::testing::Test::HasFailure()) << "the scenario fails without a fault";
        sites = phases_by_site(dry.sites());
        expect_every_file_seen(dir / "data", dry.sites(), [](const std::string& path) {
            // The fake engine's files, which it writes through cp and mv.
            const std::string name = fs::path(path).filename().string();
            return name == "lightmap.exr" || name == "manifest.json" || name.rfind("lightmap.pass-", 0) == 0;
        });
    }
    // site -> phase -> error -> effect
    std::map<std::string, std::map<std::string, std::map<std::string, std::string>>> effects;
    int n = 0;
    for (const auto& [site, phases] : sites) {
        std::set<std::string> armed;
        for (const std::string& p : phases)
            if (std::find(kServerPhases.begin(), kServerPhases.end(), p) != kServerPhases.end()) armed.insert(p);
        EXPECT_FALSE(armed.empty()) << site << " is written only where no fault is tried: " << *phases.begin();
        for (const std::string& error : kErrors) {
            const fs::path dir = tmp.path / std::to_string(++n);
            const FaultShim shim(dir / "data", dir, site, error);
            for (const auto& [phase, effect] : ServerScenario(dir, shim, armed).run()) {
                EXPECT_NE(effect, "not reached") << site << " in " << phase << " under " << error;
                effects[site][phase][error] = effect;
            }
        }
    }
    std::string table = row({"site (lightfarmd)", "phase", "ENOSPC", "EIO"}) + row({"---", "---", "---", "---"});
    for (const auto& [site, by_phase] : effects)
        for (const std::string& phase : kServerPhases)
            if (by_phase.count(phase))
                table += row({"`" + site.substr(site.find(' ') + 1) + "`", phase, by_phase.at(phase).at("ENOSPC"),
                              by_phase.at(phase).at("EIO")});
    expect_doc_table("server write-fault", table);
}

// ---------------------------------------------------------------- the worker

// One output at a time, as small as it bakes (about half a second each on
// llvmpipe): every file a bake writes is one of these outputs' files.
struct WorkerScenario {
    std::string output, flags;
};

std::vector<WorkerScenario> worker_scenarios(const fs::path& dir) {
    write_text(dir / "one_probe.json", R"([{"position": [0, 1, 0]}])");
    return {{"lightmap", "--lightmap --res 16 --passes 2"},
            {"sh", "--sh --sh-passes 2"},
            {"ao", "--ao --res 16 --ao-passes 2"},
            {"probes", "--probes --probe-res 16 --probe-m 8 --probe-passes 2 --probe-positions " +
                           (dir / "one_probe.json").string()}};
}

CliRun bake(const WorkerScenario& scenario, const fs::path& out) {
    return run_lightfarm("bake " + shared_scene("cornell_box.gltf").string() + " --out " + out.string() + " --json " +
                         scenario.flags);
}

// A bake whose write failed: exits kExitMachineFault (never an input
// error), its last line naming the file and the error, and leaves no
// temporary file behind.
std::string worker_effect(const CliRun& run, const std::string& site, const std::string& error, const fs::path& out) {
    const std::string last = run.err.substr(run.err.rfind('\n', run.err.size() - 2) + 1);
    const std::string words = error == "EIO" ? "Input/output error" : "No space left on device";
    std::string file = fs::path(site).filename().string();  // ".lightmap.exr.tmp-#"
    file = file.substr(1, file.find(".tmp") - 1);           // "lightmap.exr"
    const std::string named = std::regex_replace(file, std::regex("#"), "");
    EXPECT_EQ(run.exit_code, protocol::kExitMachineFault) << site << " " << error << ": " << run.err;
    EXPECT_NE(last.find(words), std::string::npos) << site << " " << error << ": " << last;
    EXPECT_NE(last.find(named.substr(0, named.find('.'))), std::string::npos) << site << ": " << last;
    for (const auto& entry : fs::recursive_directory_iterator(out)) {
        EXPECT_EQ(entry.path().filename().string().find(".tmp"), std::string::npos)
            << site << " " << error << " left " << entry.path();
    }
    return run.exit_code == protocol::kExitMachineFault ? "exit 5, names the file and the error"
                                                        : "exit " + std::to_string(run.exit_code) + ": " + last;
}

TEST(WorkerFaults, EveryWriteOfABake) {
    TempDir tmp;
    const std::vector<WorkerScenario> scenarios = worker_scenarios(tmp.path);
    // Each site with the first scenario that writes it, in the scenarios'
    // order, then by name (the table's order).
    std::vector<std::pair<std::string, const WorkerScenario*>> sites;
    for (const WorkerScenario& scenario : scenarios) {
        const fs::path dir = tmp.path / ("dry-" + scenario.output);
        const FaultShim dry(dir / "out", dir);
        const CliRun run = bake(scenario, dir / "out");
        ASSERT_EQ(run.exit_code, 0) << run.err;
        expect_every_file_seen(dir / "out", dry.sites(), [](const std::string&) { return false; });
        std::set<std::string> new_sites;
        for (const std::string& s : dry.sites()) {
            const std::string site = s.substr(s.find(' ') + 1);
            bool known = false;
            for (const auto& [seen, by] : sites) known |= seen == site;
            if (!known) new_sites.insert(site);
        }
        for (const std::string& site : new_sites) sites.emplace_back(site, &scenario);
    }
    std::string table = row({"site (lightfarm bake)", "output", "ENOSPC", "EIO"}) + row({"---", "---", "---", "---"});
    int n = 0;
    for (const auto& [site, scenario] : sites) {
        std::map<std::string, std::string> effect;
        for (const std::string& error : kErrors) {
            const fs::path dir = tmp.path / std::to_string(++n);
            const FaultShim shim(dir / "out", dir, site, error);
            shim.arm();
            const CliRun run = bake(*scenario, dir / "out");
            EXPECT_TRUE(shim.fired()) << site << " was not written";
            effect[error] = worker_effect(run, site, error, dir / "out");
        }
        table += row({"`" + site.substr(site.find(' ') + 1) + "`", scenario->output, effect["ENOSPC"], effect["EIO"]});
    }
    expect_doc_table("worker write-fault", table);
}

}  // namespace
}  // namespace lf::test
