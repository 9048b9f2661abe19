// The CLI's remote commands (client_cli/remote.cpp) against a real lightfarmd
// on loopback with the fake engine: submit --wait downloads the results,
// jobs/fetch/cancel work, and a server error is one line and exit 1.
#include "server_harness.h"

#include "remote.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <sstream>

namespace lf::test {
namespace {

using nlohmann::json;

const std::string kToken = "remote-test-token";

// Runs `lightfarm ARGS...` through run_remote_command, capturing stdout and stderr.
struct CliRun {
    int status;
    std::string out, err;
};
CliRun run(std::vector<std::string> args) {
    args.insert(args.begin(), "lightfarm");
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    std::ostringstream out, err;
    auto* old_out = std::cout.rdbuf(out.rdbuf());
    auto* old_err = std::cerr.rdbuf(err.rdbuf());
    const int status = cli::run_remote_command(args[1], int(argv.size()), argv.data());
    std::cout.rdbuf(old_out);
    std::cerr.rdbuf(old_err);
    return {status, out.str(), err.str()};
}

class RemoteTest : public ::testing::Test {
protected:
    void SetUp() override {
        write_text(tmp.path / "tokens", kToken + "\n");
        server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script);
        server->start();
        write_text(tmp.path / "scene.glb", std::string("glTF\x02\x00\x00\x00", 8) + " remote");
        // A .gltf with a buffer file beside it, as multipart.
        write_text(tmp.path / "gltf" / "scene.gltf",
                   R"({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 4, "uri": "bin/data%20a.bin"}]})");
        write_text(tmp.path / "gltf" / "bin" / "data a.bin", "abcd");
    }
    std::vector<std::string> common() { return {"--server", server->url, "--token", kToken}; }
    // A lightfarmd on `data` with one worker, running a job of scene.glb
    // held at its start (the fake engine's gate, until engine.dir/gate goes):
    // the next job queues behind it. Returns the running job's id ("" when
    // it could not be submitted).
    // With `finished_first`, a job of scene.glb runs to its end before: the
    // one the farm prices a queued job by (server/queue_estimate.h); its id
    // in *finished_first.
    std::string one_worker_busy(const std::string& data, std::string* finished_first = nullptr) {
        server->stop();
        server = std::make_unique<Lightfarmd>(tmp.path / data, tmp.path / "tokens", engine.script,
                                              std::vector<std::string>{"--workers", "1"});
        server->start();
        if (finished_first) {
            const CliRun done = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--passes", "2", "--seed",
                                                 "7", "--wait", "--out", (tmp.path / data / "first").string()}));
            EXPECT_EQ(done.status, 0) << done.err;
            *finished_first = done.out.substr(0, done.out.find('\n'));
        }
        engine.set("gate", "");
        const CliRun first =
            run(with_common({"submit", (tmp.path / "scene.glb").string(), "--passes", "2", "--seed", "1"}));
        EXPECT_EQ(first.status, 0) << first.err;
        if (first.status != 0) return "";
        const std::string running = first.out.substr(0, first.out.find('\n'));
        auto c = server->client(kToken);
        wait_for_job(c, running, [](const json& s) { return s["state"] == "running"; });
        return running;
    }
    std::vector<std::string> with_common(std::vector<std::string> args) {
        for (const std::string& a : common()) args.push_back(a);
        return args;
    }
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    std::unique_ptr<Lightfarmd> server;
};

TEST_F(RemoteTest, SubmitWaitDownloadsTheResults) {
    const fs::path out = tmp.path / "out";
    const CliRun r = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--passes", "3", "--seed", "9",
                                      "--wait", "--out", out.string()}));
    ASSERT_EQ(r.status, 0) << r.err;
    const std::string id = r.out.substr(0, r.out.find('\n'));
    EXPECT_EQ(id.size(), 24u) << r.out;
    EXPECT_EQ(read_text(out / "lightmap.exr"), read_text(engine.dir / "snapshot.exr"));
    EXPECT_TRUE(fs::exists(out / "manifest.json"));
    // --wait downloads the final files only; fetch --snapshots brings the rest.
    const auto snapshots_in = [](const fs::path& dir) {
        size_t n = 0;
        for (const auto& entry : fs::directory_iterator(dir))
            n += entry.path().filename().string().find(".pass-") != std::string::npos;
        return n;
    };
    EXPECT_EQ(snapshots_in(out), 0u);
    const json spec = json::parse(read_text(engine.dir / "last_spec.json"));
    EXPECT_EQ(spec["outputs"]["lightmap"]["passes"], 3);
    EXPECT_EQ(spec["seed"], 9);

    const CliRun list = run(with_common({"jobs"}));
    EXPECT_EQ(list.status, 0);
    EXPECT_NE(list.out.find(id + "  succeeded"), std::string::npos) << list.out;

    const CliRun latest = run(with_common({"fetch", id, "--latest", "--out", (tmp.path / "latest").string()}));
    EXPECT_EQ(latest.status, 0) << latest.err;
    // Done: the newest file of the lightmap is its final one.
    EXPECT_TRUE(fs::exists(tmp.path / "latest" / "lightmap.exr"));
    EXPECT_FALSE(fs::exists(tmp.path / "latest" / "lightmap.pass-0002.exr"));
    const CliRun all = run(with_common({"fetch", id, "--snapshots", "--out", (tmp.path / "all").string()}));
    EXPECT_EQ(all.status, 0) << all.err;
    EXPECT_GT(snapshots_in(tmp.path / "all"), 0u);
    EXPECT_TRUE(fs::exists(tmp.path / "all" / "lightmap.exr"));
    const CliRun both = run(with_common({"fetch", id, "--snapshots", "--latest"}));
    EXPECT_EQ(both.status, 2) << both.err;

    const CliRun w = run(with_common({"watch", id, "--json"}));
    EXPECT_EQ(w.status, 0);
    EXPECT_NE(w.out.find("\"event\":\"done\""), std::string::npos) << w.out;
}

// `submit --wait` behind a running job says that its job is queued and
// where (issue #54: it was silent for 131 s): the line comes from the
// job's status, read as soon as the job exists, before any event. The
// running job is held at its start until 3 s after the second exists.
TEST_F(RemoteTest, SubmitWaitSaysWhereAQueuedJobStands) {
    const std::string scene = (tmp.path / "scene.glb").string();
    std::string finished;
    ASSERT_FALSE(one_worker_busy("data-queue", &finished).empty());
    // The estimate of its start: the running job has no ETA yet (held
    // before its first event), so it is priced as a typical job, the median
    // of those that finished: the one job that did.
    const json first = json::parse(server->client(kToken).Get("/v1/jobs/" + finished)->body);
    const double typical = first["finished_at"].get<double>() - first["started_at"].get<double>();
    std::thread open([&] {
        auto poll = server->client(kToken);
        for (int i = 0; i < 600; ++i) {
            auto r = poll.Get("/v1/jobs");
            if (r && r->status == 200 && json::parse(r->body)["jobs"].size() >= 2) break;
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        std::this_thread::sleep_for(std::chrono::seconds(3));
        fs::remove(engine.dir / "gate");
    });
    const CliRun second = run(with_common({"submit", scene, "--passes", "2", "--seed", "2", "--wait", "--json", "--out",
                                           (tmp.path / "second").string()}));
    open.join();
    ASSERT_EQ(second.status, 0) << second.err;
    std::istringstream lines(second.out);
    std::string id, queued;
    std::getline(lines, id);
    std::getline(lines, queued);
    const json said = json::parse(queued);
    EXPECT_EQ(said["event"], "queued") << second.out;
    EXPECT_EQ(said["ahead"], 0);
    EXPECT_EQ(said["running"], 1);
    ASSERT_TRUE(said["starts_in_seconds"].is_number()) << second.out;
    EXPECT_DOUBLE_EQ(said["starts_in_seconds"].get<double>(), typical);
    EXPECT_NE(second.out.find("\"event\":\"done\""), std::string::npos) << second.out;
    EXPECT_EQ(cli::queued_line("0123456789abcdef", {2, 1, 95.0}),
              "0123456789ab  queued: 2 jobs ahead of it, 1 running, starts in about 1m35s");
    EXPECT_EQ(cli::queued_line("0123456789abcdef", {0, 1, std::nullopt}),
              "0123456789ab  queued: 0 jobs ahead of it, 1 running, no estimate of its start yet (no job has "
              "finished here)");
}

// Ctrl-C on `submit --wait` (issue #54: the command died, and nothing said
// that the job went on): it says that the job goes on at the server, how
// to follow it again and how to stop it, and exits 130; the job is still
// there, not cancelled. The command runs in a child process (its handler
// ends the process), queued behind a job held at its start, so that it is
// following (its "queued" line printed) when SIGINT comes.
TEST_F(RemoteTest, CtrlCOnSubmitWaitSaysTheJobGoesOn) {
    const std::string scene = (tmp.path / "scene.glb").string();
    ASSERT_FALSE(one_worker_busy("data-ctrl-c").empty());
    auto c = server->client(kToken);

    const fs::path out = tmp.path / "ctrl-c.out", err = tmp.path / "ctrl-c.err";
    std::vector<std::string> args = with_common({"lightfarm", "submit", scene, "--passes", "2", "--seed", "2", "--wait",
                                                 "--json", "--out", (tmp.path / "second").string()});
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
        const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644),
                  e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        dup2(o, 1);
        dup2(e, 2);
        std::vector<char*> argv;
        for (std::string& a : args) argv.push_back(a.data());
        _exit(cli::run_remote_command("submit", int(argv.size()), argv.data()));
    }
    std::string said;
    for (int i = 0; i < 600 && std::count(said.begin(), said.end(), '\n') < 2; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        said = read_text(out);
    }
    ASSERT_GE(std::count(said.begin(), said.end(), '\n'), 2) << "no id and queued line: " << said << read_text(err);
    const std::string id = said.substr(0, said.find('\n'));
    ASSERT_EQ(::kill(pid, SIGINT), 0);
    int status = 0;
    ASSERT_EQ(waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFEXITED(status)) << "ended by the signal itself";
    EXPECT_EQ(WEXITSTATUS(status), 130);
    const std::string message = read_text(err);
    EXPECT_NE(message.find("job " + id + " goes on at " + server->url), std::string::npos) << message;
    EXPECT_NE(message.find("lightfarm watch " + id + " --server " + server->url), std::string::npos) << message;
    EXPECT_NE(message.find("lightfarm cancel " + id), std::string::npos) << message;
    const json job = json::parse(c.Get("/v1/jobs/" + id)->body);
    EXPECT_TRUE(job["state"] == "queued" || job["state"] == "running") << job.dump();
    fs::remove(engine.dir / "gate");
}

// The terminal's progress line: a bar with its percentage of passes or time,
// whichever the server's ETA says stops first; nothing claimed before the
// ETA is known.
TEST(ProgressLine, ABarWithItsPercentageAndTheEta) {
    protocol::Progress p;
    p.pass = 108;
    p.seconds = 10.0;
    p.eta_seconds = 30.0;
    p.error_estimate = 0.03125;
    EXPECT_EQ(cli::progress_line("3cfd1af2a543f2c834404872", "lightmap", p),
              "3cfd1af2a543 lightmap  [######------------------]  25%  pass 108  error 0.0312  ETA 30s");
    p.eta_seconds.reset();
    p.error_estimate.reset();
    EXPECT_EQ(cli::progress_line("3cfd1af2a543", "", p), "3cfd1af2a543  [------------------------]   0%  pass 108");
    p.eta_seconds = 0.0;
    EXPECT_NE(cli::progress_line("3cfd1af2a543", "sh", p).find("[########################] 100%"), std::string::npos);
    p.eta_seconds = 30.0;
    p.prepare_seconds = 20.0;  // preparation is done work too: 30 of 60 s
    EXPECT_NE(cli::progress_line("3cfd1af2a543", "", p).find("[############------------]  50%"), std::string::npos);
}

// Before the first pass: the stage preparing, the seconds so far and
// preparation's time left when known; the local bar and `watch` alike.
TEST(ProgressLine, PreparationSaysItsStageAndTimeLeft) {
    EXPECT_EQ(cli::preparing_line("3cfd1af2a543f2c834404872", protocol::PrepareEvent{"atlas", 3.0, 12.0}),
              "3cfd1af2a543  preparing: atlas  3s  ETA 12s");
    EXPECT_EQ(cli::preparing_line("", protocol::PrepareEvent{"load", 0.0, {}}), "preparing: load  0s");
}

// `lightfarm bake`'s own bar is the same line, its ETA from the output's
// stop rules: under --time-limit it fills by time (it stayed empty at
// "pass 32/100000"), under --target-error by the error's 1/sqrt(passes).
TEST(ProgressLine, TheLocalBarFollowsWhicheverStopRuleEndsFirst) {
    protocol::Progress p;
    p.pass = 32;
    p.seconds = 2.0;
    p.eta_seconds = protocol::estimate_eta({100000, 0.0, 10.0}, p);
    EXPECT_EQ(cli::progress_line("", "lightmap", p), "lightmap  [#####-------------------]  20%  pass 32  ETA 8s");
    p.error_estimate = 0.02;
    p.eta_seconds = protocol::estimate_eta({100000, 0.01, 0.0}, p);  // 4x the passes: 6 s left of 8
    EXPECT_NE(cli::progress_line("", "sh", p).find("[######------------------]  25%"), std::string::npos)
        << cli::progress_line("", "sh", p);
}

TEST_F(RemoteTest, SubmitsAGltfWithItsFiles) {
    const CliRun r = run(with_common({"submit", (tmp.path / "gltf" / "scene.gltf").string()}));
    ASSERT_EQ(r.status, 0) << r.err;
    const std::string id = r.out.substr(0, r.out.find('\n'));
    const CliRun w = run(with_common({"watch", id}));
    EXPECT_EQ(w.status, 0) << w.err;
    // watch ends by saying how the job ended (it printed nothing after the bar).
    EXPECT_NE(w.err.find("lightfarm: job " + id + " succeeded"), std::string::npos) << w.err;
}

TEST_F(RemoteTest, CancelAndErrorsAreOneLine) {
    engine.set("mode", "hang_always");
    const CliRun r = run(with_common({"submit", (tmp.path / "scene.glb").string()}));
    ASSERT_EQ(r.status, 0) << r.err;
    const std::string id = r.out.substr(0, r.out.find('\n'));
    const CliRun c = run(with_common({"cancel", id}));
    EXPECT_EQ(c.status, 0) << c.err;
    EXPECT_EQ(c.out, id + " cancelled\n");
    const CliRun again = run(with_common({"cancel", id}));
    EXPECT_EQ(again.status, 1);
    EXPECT_EQ(again.err, "lightfarm cancel: error: job " + id + " already cancelled (HTTP 409)\n");
    EXPECT_EQ(run(with_common({"watch", id})).status, 1);
    // fetch says the job has no final files (it quietly fetched what there was).
    const CliRun f = run(with_common({"fetch", id, "--out", (tmp.path / "cancelled").string()}));
    EXPECT_EQ(f.status, 1);
    EXPECT_NE(f.err.find("job " + id + " was cancelled: it has no final files"), std::string::npos) << f.err;

    const CliRun bad_token = run({"jobs", "--server", server->url, "--token", "wrong"});
    EXPECT_EQ(bad_token.status, 1);
    EXPECT_NE(bad_token.err.find("HTTP 401"), std::string::npos) << bad_token.err;
    EXPECT_EQ(std::count(bad_token.err.begin(), bad_token.err.end(), '\n'), 1);

    // Refused by the catalog before anything is sent, under the flag's name.
    const CliRun too_big = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--res", "100000"}));
    EXPECT_EQ(too_big.status, 2);
    EXPECT_NE(too_big.err.find("--res: 100000 exceeds the maximum 16384"), std::string::npos) << too_big.err;
    // Refused by the server: it reads no file a job names.
    const CliRun env_file = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--sh", "--env", "sky.exr"}));
    EXPECT_EQ(env_file.status, 1);
    EXPECT_NE(env_file.err.find("env: an environment map file cannot be given to the service"), std::string::npos)
        << env_file.err;
    EXPECT_NE(env_file.err.find("(HTTP 400)"), std::string::npos) << env_file.err;
    EXPECT_EQ(run(with_common({"submit", (tmp.path / "scene.glb").string(), "--passes", "x"})).status, 2);
    EXPECT_EQ(run({"jobs", "--server", "http://127.0.0.1:1", "--token", "t"}).status, 1);
}

// Issue #36: `fetch` of a cancelled job says it has no final files and
// offers --latest; --latest then downloads the bake as it stood at the
// cancel (the worker's last snapshot, written on SIGTERM), not the last
// snapshot the schedule took before it.
TEST_F(RemoteTest, FetchLatestOfACancelledJobGetsTheBakeAsItStoodAtTheCancel) {
    engine.set("mode", "snapshot_on_term");
    engine.set("delay", "0.02");
    const CliRun r = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--passes", "100000"}));
    ASSERT_EQ(r.status, 0) << r.err;
    const std::string id = r.out.substr(0, r.out.find('\n'));
    auto c = server->client(kToken);
    ASSERT_GE(wait_for_job(c, id, [](const json& s) { return s["progress"].value("pass", 0) >= 12; })["progress"].value(
                  "pass", 0),
              12);
    const CliRun cancel = run(with_common({"cancel", id}));
    ASSERT_EQ(cancel.status, 0) << cancel.err;
    const int at_cancel = json::parse(c.Get("/v1/jobs/" + id)->body)["progress"].value("pass", 0);
    wait_for_job(c, id, [&](const json& s) { return s["latest"]["lightmap"].value("pass", 0) >= at_cancel; });

    const CliRun final_files = run(with_common({"fetch", id, "--out", (tmp.path / "final").string()}));
    EXPECT_EQ(final_files.status, 1);
    EXPECT_NE(final_files.err.find("job " + id + " was cancelled: it has no final files (--latest: the newest file"),
              std::string::npos)
        << final_files.err;
    EXPECT_FALSE(fs::exists(tmp.path / "final"));

    const CliRun latest = run(with_common({"fetch", id, "--latest", "--out", (tmp.path / "latest").string()}));
    ASSERT_EQ(latest.status, 0) << latest.err;
    std::vector<std::string> fetched;
    for (const auto& e : fs::directory_iterator(tmp.path / "latest")) fetched.push_back(e.path().filename().string());
    ASSERT_EQ(fetched.size(), 1u);
    const int pass = std::stoi(fetched[0].substr(fetched[0].find("pass-") + 5));
    EXPECT_GE(pass, at_cancel) << fetched[0] << ": the schedule's snapshots are passes 1, 2, 4, 8";
    EXPECT_EQ(read_text(tmp.path / "latest" / fetched[0]), read_text(engine.dir / "snapshot.exr"));
}

// `submit` takes every output and option of `bake`, flags as flags.
TEST_F(RemoteTest, SubmitTakesEveryBakeOption) {
    const CliRun r = run(with_common({"submit",
                                      (tmp.path / "scene.glb").string(),
                                      "--lightmap",
                                      "--sh",
                                      "--sh-bands",
                                      "auto",
                                      "--sh-bounces",
                                      "2",
                                      "--sh-per-texel",
                                      "--no-stitch",
                                      "--res",
                                      "128",
                                      "--scheme",
                                      "thesis",
                                      "--env",
                                      "0.5,0.5,1",
                                      "--seed",
                                      "5",
                                      "--wait",
                                      "--out",
                                      (tmp.path / "out").string()}));
    ASSERT_EQ(r.status, 0) << r.err;
    const json spec = json::parse(read_text(engine.dir / "last_spec.json"));
    EXPECT_EQ(spec["outputs"]["sh"]["sh_bands"], "auto");
    EXPECT_EQ(spec["outputs"]["sh"]["sh_bounces"], 2);
    EXPECT_EQ(spec["outputs"]["sh"]["sh_per_texel"], true);
    EXPECT_EQ(spec["outputs"]["lightmap"]["stitch"], false);
    EXPECT_EQ(spec["outputs"]["lightmap"]["scheme"], "thesis");
    EXPECT_EQ(spec["atlas"]["res"], 128);
    EXPECT_EQ(spec["env"], json({0.5, 0.5, 1.0}));
    EXPECT_EQ(spec["seed"], 5);
    EXPECT_TRUE(fs::exists(tmp.path / "out" / "scene.sh.glb"));

    // Giving an output's setting asks for that output alone.
    const CliRun sh_only = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--sh-bands", "2", "--wait",
                                            "--out", (tmp.path / "out2").string()}));
    ASSERT_EQ(sh_only.status, 0) << sh_only.err;
    const json sh_spec = json::parse(read_text(engine.dir / "last_spec.json"));
    EXPECT_FALSE(sh_spec["outputs"].contains("lightmap")) << sh_spec.dump();
    EXPECT_EQ(sh_spec["outputs"]["sh"]["sh_bands"], 2);

    const CliRun bad = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--sh-bands", "9"}));
    EXPECT_EQ(bad.status, 2);
    EXPECT_NE(bad.err.find("--sh-bands"), std::string::npos) << bad.err;
    EXPECT_EQ(run(with_common({"submit", (tmp.path / "scene.glb").string(), "--sh=1"})).status, 2)
        << "a flag takes no value";
}

// `fetch --latest` takes each output's newest file from the job's status (the
// worker's events), not from sorting names: pass-16384 sorts before pass-2048,
// and an SH file after both.
TEST_F(RemoteTest, FetchLatestTakesTheNewestFileOfEachOutput) {
    engine.set("snapshot_passes", "2048 16384");
    engine.set("mode", "no_done");
    const CliRun r = run(with_common({"submit", (tmp.path / "scene.glb").string(), "--lightmap", "--sh", "--wait"}));
    EXPECT_EQ(r.status, 1) << "the fake worker never reports done";
    const std::string id = r.out.substr(0, r.out.find('\n'));
    const fs::path out = tmp.path / "latest";
    const CliRun f = run(with_common({"fetch", id, "--latest", "--out", out.string()}));
    ASSERT_EQ(f.status, 0) << f.err;
    EXPECT_TRUE(fs::exists(out / "lightmap.pass-16384.exr"));
    EXPECT_TRUE(fs::exists(out / "sh_transfer.pass-0001.bin"));
    EXPECT_FALSE(fs::exists(out / "lightmap.pass-2048.exr"));
}

}  // namespace
}  // namespace lf::test
