// Every call of `lightfarm bake` that changes a file, under ENOSPC and
// under EIO (issue #33; the harness: fault_harness.h): the Cornell box, one
// output at a time, tiny. A failed call exits kExitMachineFault (the
// machine's trouble, requeued by the server at no cost), never an input
// error, naming the file, and leaves no temporary file.
#include "cli_runner.h"
#include "fault_harness.h"
#include "worker_protocol.h"

#include <sstream>

namespace lf::test {
namespace {

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
    return run_lightfarm("bake " + example_scene("cornell_box.gltf").string() + " --out " + out.string() + " --json " +
                         scenario.flags);
}

// A bake whose write failed: exits kExitMachineFault (never an input
// error), its last line naming the file and the error, and leaves no
// temporary file behind.
std::string worker_effect(const CliRun& run, const std::string& site, const std::string& error, const fs::path& out) {
    const std::string last = run.err.substr(run.err.rfind('\n', run.err.size() - 2) + 1);
    const std::string words = error == "EIO" ? "Input/output error" : "No space left on device";
    std::string file = file_of(site);  // ".lightmap.exr.tmp-#", "lightmap.exr", ".resume"
    if (file[0] == '.') file = file.substr(1);
    file = file.substr(0, file.find(".tmp"));  // "lightmap.exr", "resume"
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

// Every directory a bake makes (its output directory and the parents it
// lacks, .resume) is synced into its parent after it is made and before
// anything is created in it: the files' commits sync their names in the
// directory, and a power loss must not drop the directory's own name.
TEST(WorkerFaults, EveryDirectoryItMakesIsSyncedIntoItsParentFirst) {
    TempDir tmp;
    const FaultShim dry(tmp.path / "root", tmp.path);
    const CliRun run = bake(worker_scenarios(tmp.path)[0], tmp.path / "root" / "a" / "b");
    ASSERT_EQ(run.exit_code, 0) << run.err;
    std::vector<std::string> calls;  // "PHASE lightfarm OP PATH", in order
    for (const auto& [site, n] : dry.calls_in_order()) calls.push_back(site);
    // The first call from `from` on that matches.
    using Match = std::function<bool(const std::string& op, const fs::path& path)>;
    const auto first = [&](size_t from, const Match& match) {
        for (size_t i = from; i < calls.size(); ++i) {
            std::istringstream words(calls[i]);
            std::string phase, process, op, path;
            words >> phase >> process >> op >> path;
            if (match(op, path)) return i;
        }
        return calls.size();
    };
    for (const fs::path made : {"a/b", "a/b/.resume"}) {
        SCOPED_TRACE(made.string());
        const size_t mkdir =
            first(0, [&](const std::string& op, const fs::path& p) { return op == "mkdir" && p == made; });
        ASSERT_LT(mkdir, calls.size()) << "never made";
        const size_t synced = first(
            mkdir, [&](const std::string& op, const fs::path& p) { return op == "sync" && p == made.parent_path(); });
        const size_t used = first(mkdir, [&](const std::string& op, const fs::path& p) {
            return op != "mkdir" && op != "sync" && p.parent_path() == made;
        });
        ASSERT_LT(used, calls.size()) << "nothing written in it";
        EXPECT_LT(synced, used) << "a file is created in it before its name is synced in its parent";
    }
}

TEST(WorkerFaults, EveryCallOfABake) {
    TempDir tmp;
    const std::vector<WorkerScenario> scenarios = worker_scenarios(tmp.path);
    // Each site with the first scenario that calls it and how many calls
    // that scenario made there, in the scenarios' order, then by name (the
    // table's order).
    struct Site {
        std::string site;
        const WorkerScenario* scenario;
        int calls;
    };
    std::vector<Site> sites;
    for (const WorkerScenario& scenario : scenarios) {
        const fs::path dir = tmp.path / ("dry-" + scenario.output);
        const FaultShim dry(dir / "out", dir);
        const CliRun run = bake(scenario, dir / "out");
        ASSERT_EQ(run.exit_code, 0) << run.err;
        expect_every_file_seen(dir / "out", dry.sites(), [](const std::string&) { return false; });
        std::map<std::string, int> new_sites;
        for (const auto& [s, calls] : dry.calls()) {
            const std::string site = s.substr(s.find(' ') + 1);
            bool known = false;
            for (const Site& seen : sites) known |= seen.site == site;
            if (!known) new_sites[site] = calls;
        }
        for (const auto& [site, calls] : new_sites) sites.push_back({site, &scenario, calls});
    }
    // Each call of each site fails in turn (every one up to three: calls_to_fail).
    std::string table =
        row({"site (lightfarm bake)", "output", "calls", "ENOSPC", "EIO"}) + row({"---", "---", "---", "---", "---"});
    int runs = 0;
    for (const Site& site : sites) {
        std::map<std::string, std::map<int, std::string>> effect;
        for (int nth : calls_to_fail(site.calls)) {
            for (const std::string& error : kErrors) {
                const fs::path dir = tmp.path / std::to_string(++runs);
                const FaultShim shim(dir / "out", dir, site.site, error, nth);
                shim.arm();
                const CliRun run = bake(*site.scenario, dir / "out");
                EXPECT_TRUE(shim.fired()) << site.site << " call " << nth << " was not made";
                effect[error][nth] = worker_effect(run, site.site, error, dir / "out");
            }
        }
        table += row({"`" + operation_and_path(site.site) + "`", site.scenario->output, calls_cell(site.calls),
                      summary(effect["ENOSPC"], site.calls), summary(effect["EIO"], site.calls)});
    }
    std::cerr << runs << " bakes\n";
    expect_doc_table("worker write-fault", table);
}

}  // namespace
}  // namespace lf::test
