// lightfarmd with the real engine (the lightfarm binary of this build) on
// loopback: hostile scenes are refused at upload by the engine's own loader
// in a separate process; a bake of the Cornell box through the service equals,
// bit for bit, the same bake run by `lightfarm bake` with the same seed; and
// a job whose worker, or whose server, is killed with SIGKILL mid-bake still
// completes with whole artifacts that again equal the CLI's bake, resumed
// from its last snapshot.
#include "server_harness.h"

#include "bake_settings.h"

#include "io/image_files.h"

#include "subprocess.h"

#include <gtest/gtest.h>
#include <signal.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

const std::string kToken = "e2e-token";

fs::path scenes_dir() {
    const char* env = std::getenv("LIGHTFARM_SCENES");
    return env && *env ? fs::path(env) : fs::path(LIGHTFARM_EXAMPLES);
}

// Every channel of an EXR (RGB, and the direct/indirect layers, sample counts
// and error estimates the engine writes), as floats: half -> float is exact,
// so equal floats are equal files' pixels.
using ExrImage = lf::FloatImage;
using lf::read_exr;

// Bit-for-bit equality of every channel; describes the first difference.
::testing::AssertionResult same_pixels(const fs::path& a_path, const fs::path& b_path) {
    const ExrImage a = read_exr(a_path), b = read_exr(b_path);
    if (a.width != b.width || a.height != b.height)
        return ::testing::AssertionFailure()
               << "sizes differ: " << a.width << "x" << a.height << " vs " << b.width << "x" << b.height;
    std::string names_a, names_b;
    for (const auto& [name, _] : a.channels) names_a += name + " ";
    for (const auto& [name, _] : b.channels) names_b += name + " ";
    if (names_a != names_b) return ::testing::AssertionFailure() << "channels differ: " << names_a << "vs " << names_b;
    for (const auto& [name, pa] : a.channels) {
        const std::vector<float>& pb = b.channels.at(name);
        size_t differing = 0, first = 0;
        for (size_t i = 0; i < pa.size(); ++i) {
            if (std::memcmp(&pa[i], &pb[i], sizeof(float)) != 0 && differing++ == 0) first = i;
        }
        if (differing)
            return ::testing::AssertionFailure()
                   << differing << " texels of channel " << name << " differ; first at (" << first % size_t(a.width)
                   << ", " << first / size_t(a.width) << "): " << pa[first] << " vs " << pb[first];
    }
    return ::testing::AssertionSuccess() << a.channels.size() << " channels equal";
}

// The lightmap settings of a job, and the same as `lightfarm bake` options.
struct Bake {
    int res = 64;
    int passes = 16;
    int seed = 3;
    json spec(const std::string& scene) const {
        return {{"scene", scene},
                {"outputs", {{"lightmap", {{"passes", passes}}}}},
                {"atlas", {{"res", res}}},
                {"seed", seed}};
    }
};

// `lightfarm bake` of the Cornell box into `out`; returns its wall time.
double local_bake(const Bake& b, const fs::path& out) {
    fs::create_directories(out);
    const auto t0 = Clock::now();
    const server::RunResult cli = server::run_command(
        {LIGHTFARM_ENGINE, "bake", (scenes_dir() / "cornell_box.gltf").string(), "--out", out.string(), "--json",
         "--res", std::to_string(b.res), "--passes", std::to_string(b.passes), "--seed", std::to_string(b.seed)},
        std::chrono::seconds(300));
    EXPECT_TRUE(cli.status.success()) << cli.status.describe() << ": " << cli.err_last_line;
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

class EndToEnd : public ::testing::Test {
protected:
    void SetUp() override {
        ASSERT_TRUE(fs::exists(LIGHTFARM_ENGINE)) << "no engine at " << LIGHTFARM_ENGINE << " (built with the tests)";
        write_text(tmp.path / "tokens", kToken + "\n");
        server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", LIGHTFARM_ENGINE,
                                              std::vector<std::string>{"--stall-timeout", "120"});
        server->start();
    }
    void TearDown() override {
        if (HasFailure() && server) std::cerr << "---- lightfarmd log ----\n" << server->log();
    }

    httplib::Client client() {
        auto c = server->client(kToken);
        c.set_read_timeout(120);
        return c;
    }
    std::string upload_cornell_box() {
        auto r = client().Post("/v1/scenes", read_text(scenes_dir() / "cornell_box.gltf"), "model/gltf+json");
        EXPECT_TRUE(r && (r->status == 201 || r->status == 200)) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    // Uploads a scene folder (the .gltf, its buffers and textures) as one multipart request.
    json upload_folder(const fs::path& dir) {
        httplib::MultipartFormDataItems files;
        for (const fs::directory_entry& e : fs::recursive_directory_iterator(dir)) {
            if (!e.is_regular_file() || e.path().extension() == ".md") continue;
            const std::string name = fs::relative(e.path(), dir).string();
            files.push_back({"file", read_text(e.path()), name, "application/octet-stream"});
        }
        auto r = client().Post("/v1/scenes", files);
        EXPECT_TRUE(r && (r->status == 201 || r->status == 200)) << (r ? r->body : "no answer");
        return r ? json::parse(r->body) : json::object();
    }
    std::string submit(const json& spec) {
        auto r = client().Post("/v1/jobs", spec.dump(), "application/json");
        EXPECT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    fs::path job_dir(const std::string& id) const { return tmp.path / "data" / "jobs" / id; }
    // Downloads an artifact into tmp/NAME-PREFIX; returns the path.
    fs::path download(const std::string& id, const std::string& name, const std::string& prefix) {
        auto r = client().Get("/v1/jobs/" + id + "/artifacts/" + name);
        EXPECT_TRUE(r && r->status == 200) << name << ": " << (r ? r->body : "no answer");
        if (r) {
            EXPECT_EQ(r->get_header_value("Content-Length"), std::to_string(r->body.size()));
        }
        const fs::path path = tmp.path / (prefix + "-" + name);
        write_text(path, r ? r->body : "");
        return path;
    }
    // A bake long enough to be interrupted mid-way on this device: the CLI bake
    // (which the test needs anyway, as the reference) is run with more passes
    // until it takes a couple of seconds. Returns the settings; the reference
    // lightmap is in tmp/local.
    Bake long_bake() {
        Bake b;
        b.passes = 256;
        b.seed = 11;
        for (;;) {
            fs::remove_all(tmp.path / "local");
            const double seconds = local_bake(b, tmp.path / "local");
            if (seconds > 1.5 || b.passes >= 16384) return b;
            b.passes *= 4;
        }
    }
    // Waits until the job is running with a snapshot (and so a saved state) of pass `pass` or later.
    json wait_snapshot_past(const std::string& id, int pass) {
        auto c = client();
        return wait_for_job(
            c, id,
            [&](const json& s) {
                return s["state"] == "running" &&
                       s.value("latest", json::object()).value("lightmap", json::object()).value("pass", 0) >= pass;
            },
            std::chrono::seconds(60));
    }
    // The pass each attempt's worker resumed after (0: from the start), in order.
    std::vector<int> resumed_after(const std::string& id) {
        std::vector<int> passes;
        for (const auto& e : read_events(server->host, server->port, kToken, id))
            if (e.type == "started")
                passes.push_back(
                    e.data.value("resumed", json::object()).value("lightmap", json::object()).value("pass", 0));
        return passes;
    }
    json wait_finished(const std::string& id) {
        auto c = client();
        return wait_for_job(c, id, is_finished, std::chrono::seconds(120));
    }
    // Every artifact listed is downloadable and whole: EXRs decode, JSON parses.
    void expect_whole_artifacts(const std::string& id) {
        auto r = client().Get("/v1/jobs/" + id + "/artifacts");
        ASSERT_TRUE(r && r->status == 200);
        const json listing = json::parse(r->body);
        std::set<std::string> names;
        for (const json& a : listing["artifacts"]) {
            const std::string name = a["name"];
            names.insert(name);
            EXPECT_EQ(name.find(".tmp"), std::string::npos) << name;
            const fs::path path = download(id, name, "whole");
            EXPECT_EQ(fs::file_size(path), a["size"].get<uintmax_t>()) << name;
            if (fs::path(name).extension() == ".exr") {
                EXPECT_NO_THROW(read_exr(path)) << name << " does not decode";
            } else if (fs::path(name).extension() == ".json") {
                EXPECT_FALSE(json::parse(read_text(path), nullptr, false).is_discarded()) << name;
            }
        }
        EXPECT_TRUE(names.count("lightmap.exr"));
        EXPECT_TRUE(names.count("manifest.json"));
    }

    TempDir tmp;
    std::unique_ptr<Lightfarmd> server;
};

std::vector<std::string> types_of(const std::vector<protocol::JobEvent>& events) {
    std::vector<std::string> types;
    for (const auto& e : events) types.push_back(e.type);
    return types;
}

bool contains(const std::vector<std::string>& v, const std::string& s) {
    return std::find(v.begin(), v.end(), s) != v.end();
}

// True while `pid` runs a bake into `dir` (a zombie or a reused pid does not).
bool bakes_into(pid_t pid, const fs::path& dir) {
    const std::string args = read_text("/proc/" + std::to_string(pid) + "/cmdline");
    return args.find(dir.string()) != std::string::npos;
}

pid_t worker_pid(const fs::path& dir) {
    std::ifstream in(dir / ".worker.pid");
    pid_t pid = 0;
    in >> pid;
    return pid;
}

// The commands a first start prints run as printed from any directory
// (they named `lightfarm`, which nothing put on PATH: "command not found").
TEST(FirstStart, TheBannersCommandsRunAsPrinted) {
    TempDir tmp;
    const fs::path data = tmp.path / "data", log = tmp.path / "lightfarmd.log";
    pid_t pid = spawn_lightfarmd({"--listen", "127.0.0.1:0", "--data", data.string()}, log);
    wait_until_ready(pid, log, [&] { return !read_text(data / "lightfarmd.url").empty(); });
    std::string submit, upload;
    for (int tries = 0; tries < 100 && (submit.empty() || upload.empty()); ++tries) {
        std::istringstream lines(read_text(log));
        for (std::string line; std::getline(lines, line);) {
            if (line.find("submit a bake:") != std::string::npos) submit = line.substr(line.find(':') + 1);
            if (line.find("with curl:") != std::string::npos) upload = line.substr(line.find(':') + 1);
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    ASSERT_FALSE(submit.empty()) << read_text(log);
    ASSERT_FALSE(upload.empty()) << read_text(log);
    fs::copy_file(scenes_dir() / "monkey.glb", tmp.path / "scene.glb");
    // As a person pastes them, in the scene's folder, with a short bake's options added.
    const std::string in_dir = "cd '" + tmp.path.string() + "' && env -u LIGHTFARM_TOKEN PATH=/usr/bin:/bin ";
    EXPECT_EQ(std::system((in_dir + "bash -c \"" + upload + " -s -o /dev/null -w '%{http_code}' > code\"").c_str()), 0);
    EXPECT_TRUE(read_text(tmp.path / "code") == "201" || read_text(tmp.path / "code") == "200")
        << read_text(tmp.path / "code");
    EXPECT_EQ(
        std::system((in_dir + "bash -c '" + submit + " --passes 2 --res 64 --out result > out.txt 2>&1'").c_str()), 0)
        << read_text(tmp.path / "out.txt");
    EXPECT_TRUE(fs::exists(tmp.path / "result" / "lightmap.exr")) << read_text(tmp.path / "out.txt");
    stop_process(pid);
}

TEST_F(EndToEnd, EveryBadSceneIsAClear4xxAndTheServerStaysHealthy) {
    auto c = client();
    int tried = 0;
    for (const fs::directory_entry& e : fs::directory_iterator(scenes_dir() / "bad")) {
        const std::string name = e.path().filename().string();
        const std::string bytes = read_text(e.path());
        httplib::Result r =
            e.path().extension() == ".glb"
                ? c.Post("/v1/scenes", bytes, "model/gltf-binary")
                : c.Post("/v1/scenes", httplib::MultipartFormDataItems{{"scene", bytes, name, "model/gltf+json"}});
        ASSERT_TRUE(r) << name;
        EXPECT_TRUE(r->status >= 400 && r->status < 500) << name << ": " << r->status << " " << r->body;
        const json body = json::parse(r->body, nullptr, false);
        EXPECT_TRUE(body.is_object() && body.contains("error")) << name << ": " << r->body;
        ++tried;
    }
    EXPECT_GT(tried, 10);
    EXPECT_EQ(c.Get("/healthz")->status, 200);
    // And a good scene still goes through the same path.
    auto r = c.Post("/v1/scenes", read_text(scenes_dir() / "cornell_box.gltf"), "model/gltf+json");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 201) << r->body;
    EXPECT_GT(json::parse(r->body).value("triangles", 0), 0) << r->body;
}

// What can be known at submit is refused at submit, from the engine's own
// summary of the upload: a lightmap of a scene with no light (the breakfast
// room, lit only through its windows) is a 400 naming `env` and the fix; an
// atlas smaller than the staircase's 9,121 charts need is a 400 naming
// `atlas.res` and the smallest that fits. No job is created, no worker runs;
// the same jobs with the fix are accepted.
TEST_F(EndToEnd, WhatIsKnownAtSubmitIsRefusedAtSubmit) {
    const json room = upload_folder(scenes_dir() / "real" / "breakfast_room");
    EXPECT_EQ(room.value("source", ""), "breakfast_room.gltf") << "the uploaded name, never a server path";
    json spec = {{"scene", room.value("id", "")}, {"outputs", {{"lightmap", json::object()}}}};
    auto r = client().Post("/v1/jobs", spec.dump(), "application/json");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 400) << r->body;
    EXPECT_EQ(json::parse(r->body).value("field", ""), "env");
    EXPECT_NE(r->body.find("breakfast_room.gltf"), std::string::npos) << r->body;

    const json stairs = upload_folder(scenes_dir() / "real" / "wooden_staircase");
    const int smallest = stairs.value("min_atlas_res", 0);
    EXPECT_GT(smallest, 256);
    spec = {{"scene", stairs.value("id", "")}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"res", 256}}}};
    r = client().Post("/v1/jobs", spec.dump(), "application/json");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 400) << r->body;
    EXPECT_EQ(json::parse(r->body).value("field", ""), "atlas.res");
    EXPECT_NE(r->body.find(std::to_string(smallest)), std::string::npos) << r->body;
    auto jobs = client().Get("/v1/jobs");
    ASSERT_TRUE(jobs);
    EXPECT_TRUE(json::parse(jobs->body)["jobs"].empty()) << "a refused spec creates no job";

    for (const json& fixed :
         {json{{"scene", room.value("id", "")}, {"outputs", {{"lightmap", {{"passes", 1}}}}}, {"env", {1, 1, 1}}},
          json{{"scene", stairs.value("id", "")},
               {"outputs", {{"lightmap", {{"passes", 1}}}}},
               {"atlas", {{"res", smallest}}}}}) {
        const std::string id = submit(fixed);
        ASSERT_FALSE(id.empty());
        client().Post("/v1/jobs/" + id + "/cancel", "", "application/json");
    }
}

// Every numeric setting at both ends of its range, each alone on the Cornell
// box (the rest small: 2 passes, a 64² atlas, one probe), on a server with caps (passes
// 4, time_limit 10 s, res 256): each spec is refused at submit with a 400
// naming its field (above a cap, or knowable from the scene: a grid of too
// many probes, an atlas too small for the charts), or its job succeeds. A
// job that the server accepts and the worker then fails is what issue #33
// found eight of; this tries them all, the exclusive minimums as 1e-6.
TEST_F(EndToEnd, EverySettingsExtremesAreRefusedAtSubmitOrBake) {
    server->stop();
    server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", LIGHTFARM_ENGINE,
                                          std::vector<std::string>{"--stall-timeout", "120", "--limit", "passes=4",
                                                                   "--limit", "time_limit=10", "--limit", "res=256"});
    server->start();
    const std::string scene = upload_cornell_box();
    ASSERT_FALSE(scene.empty());
    const std::map<std::string, std::string> passes_of = {
        {"lightmap", "passes"}, {"sh", "sh_passes"}, {"probes", "probe_passes"}, {"ao", "ao_passes"}};
    struct Tried {
        std::string what, id;
    };
    std::vector<Tried> accepted;
    std::string problems;
    int refused = 0;
    for (const protocol::Setting& s : protocol::setting_catalog()) {
        if (s.type != protocol::SettingType::Integer && s.type != protocol::SettingType::Number) continue;
        for (const double value : {s.min_exclusive ? s.min + 1e-6 : s.min, s.max}) {
            const std::string output = passes_of.count(s.group) ? s.group : "lightmap";
            json spec = {
                {"scene", scene}, {"outputs", {{output, {{passes_of.at(output), 2}}}}}, {"atlas", {{"res", 64}}}};
            // One probe where the grid is not what is tried: a probe_res of
            // 256 over the default grid is a valid job of two minutes here.
            if (output == "probes" && s.name != "probe_spacing")
                spec["outputs"]["probes"]["probe_positions"] = {{{"position", {0.278, 0.27, 0.28}}}};
            const json v = s.type == protocol::SettingType::Integer ? json(int64_t(value)) : json(value);
            if (s.group.empty()) {
                spec[s.name] = v;
            } else if (s.group == "atlas") {
                if (s.name != "subsamples") spec["atlas"].erase("res");  // res, or what sizes the atlas instead
                spec["atlas"][s.name] = v;
            } else {
                spec["outputs"][output][s.name] = v;
            }
            const std::string what = s.field() + " = " + v.dump();
            auto r = client().Post("/v1/jobs", spec.dump(), "application/json");
            if (!r) {
                problems += what + ": no answer\n";
            } else if (r->status == 400) {
                const json body = json::parse(r->body, nullptr, false);
                if (!body.is_object() || body.value("field", "").empty() || body.value("error", "").empty())
                    problems += what + ": a 400 without its field and error: " + r->body + "\n";
                ++refused;
            } else if (r->status == 201) {
                accepted.push_back({what, json::parse(r->body).value("id", "")});
            } else {
                problems += what + ": " + std::to_string(r->status) + " " + r->body + "\n";
            }
        }
    }
    for (const Tried& t : accepted) {
        auto c = client();
        const auto t0 = Clock::now();
        const json status = wait_for_job(c, t.id, is_finished, std::chrono::seconds(120));
        std::printf("  %-40s %s after %.1f s more\n", t.what.c_str(), status.value("state", "").c_str(),
                    std::chrono::duration<double>(Clock::now() - t0).count());
        if (status.value("state", "") != "succeeded") problems += t.what + ": accepted, then " + status.dump() + "\n";
    }
    std::printf("%d extremes refused at submit, %zu baked\n", refused, accepted.size());
    EXPECT_TRUE(problems.empty()) << problems;
    EXPECT_GT(accepted.size(), 20u) << "the small ends bake";
}

TEST_F(EndToEnd, CornellBoxThroughTheServiceEqualsTheCli) {
    const Bake bake;  // res 64, 16 passes, seed 3: a snapshot at pass 1, more as the schedule's budget allows
    const std::string id = submit(bake.spec(upload_cornell_box()));
    ASSERT_FALSE(id.empty());

    const auto events = read_events(server->host, server->port, kToken, id, -1, 0, std::chrono::seconds(120));
    ASSERT_FALSE(events.empty());
    ASSERT_EQ(events.back().type, "done") << events.back().data.dump();
    std::vector<std::string> snapshots;
    for (size_t i = 0; i < events.size(); ++i) {
        EXPECT_EQ(events[i].id, int64_t(i + 1));
        if (events[i].type == "snapshot") snapshots.push_back(events[i].data["file"]);
    }
    EXPECT_GE(snapshots.size(), 1u) << "snapshot events before done";
    EXPECT_EQ(events.back().data["pass"], bake.passes);
    EXPECT_EQ(events.back().data["cached"], false);
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    EXPECT_EQ(status["attempts"], 1);

    // Each snapshot an event named is an artifact that decodes.
    for (const std::string& name : snapshots) EXPECT_NO_THROW(read_exr(download(id, name, "snapshot"))) << name;

    const fs::path served = download(id, "lightmap.exr", "served");
    local_bake(bake, tmp.path / "local");
    EXPECT_TRUE(same_pixels(served, tmp.path / "local" / "lightmap.exr"))
        << "the served bake and `lightfarm bake` with the same seed";

    // The service's preview of the final lightmap is the preview.png the
    // CLI's bake writes beside it (issue #54), and the worker's artifact.
    auto png = client().Get("/v1/jobs/" + id + "/preview.png");
    ASSERT_TRUE(png);
    EXPECT_EQ(png->status, 200);
    EXPECT_EQ(png->body.substr(1, 3), "PNG");
    EXPECT_EQ(png->body, read_text(tmp.path / "local" / "preview.png")) << "the CLI's preview.png";
    EXPECT_EQ(png->body, read_text(download(id, "preview.png", "served"))) << "the job's own preview.png";
}

// A probes job through the service (issue #52): the same probes as
// `lightfarm bake --probes` with the same settings and seed (probes.exr
// pixel for pixel: radiance, distances, corner and centre rays), so
// `lightfarm probe-eval` gives the same numbers from either, at points by a
// wall, on the floor between the blocks and behind one.
TEST_F(EndToEnd, AProbesJobThroughTheServiceEqualsTheCli) {
    const json positions = json::array({json{{"position", {0.278, 0.3545, 0.2795}}},
                                        json{{"position", {0.1, 0.05, 0.45}}}, json{{"position", {0.45, 0.45, 0.1}}}});
    const json probes = {{"probe_positions", positions}, {"probe_res", 32}, {"probe_m", 8}, {"probe_passes", 4}};
    const std::string id = submit({{"scene", upload_cornell_box()}, {"outputs", {{"probes", probes}}}, {"seed", 3}});
    ASSERT_EQ(wait_finished(id)["state"], "succeeded");
    const fs::path served = tmp.path / "served-probes";
    fs::create_directories(served);
    fs::copy_file(download(id, "probes.json", "probes"), served / "probes.json");
    fs::copy_file(download(id, "probes.exr", "probes"), served / "probes.exr");

    const fs::path local = tmp.path / "local-probes", positions_file = tmp.path / "probe-positions.json";
    write_text(positions_file, positions.dump());
    const server::RunResult cli =
        server::run_command({LIGHTFARM_ENGINE, "bake", (scenes_dir() / "cornell_box.gltf").string(), "--probes",
                             "--probe-positions", positions_file.string(), "--probe-res", "32", "--probe-m", "8",
                             "--probe-passes", "4", "--seed", "3", "--out", local.string()},
                            std::chrono::seconds(300));
    ASSERT_TRUE(cli.status.success()) << cli.status.describe() << ": " << cli.err_last_line;
    EXPECT_TRUE(same_pixels(served / "probes.exr", local / "probes.exr"));

    const fs::path points = tmp.path / "shading-points.json";
    write_text(points, json::array({json{{"position", {0.01, 0.2, 0.3}}, {"normal", {1, 0, 0}}},
                                    json{{"position", {0.3, 0.001, 0.45}}, {"normal", {0, 1, 0}}},
                                    json{{"position", {0.4, 0.01, 0.5}}, {"normal", {0, 0, 1}}},
                                    json{{"position", {0.2, 0.4, 0.2}}, {"normal", {0, -1, 0}}}})
                           .dump());
    const auto evaluate = [&](const fs::path& dir) {
        const server::RunResult r =
            server::run_command({LIGHTFARM_ENGINE, "probe-eval", (dir / "probes.json").string(), points.string()},
                                std::chrono::seconds(60));
        EXPECT_TRUE(r.status.success()) << r.status.describe() << ": " << r.err_last_line;
        return json::parse(r.out);
    };
    const json from_server = evaluate(served), from_cli = evaluate(local);
    ASSERT_EQ(from_server["points"].size(), 4u);
    EXPECT_EQ(from_server, from_cli);
    EXPECT_GT(from_server["points"][1]["polygon_to_point"][1].get<double>(), 0.0) << "the floor is lit";
}

// `node SCRIPT ARGS...` from tests/web (its packages in web/node_modules,
// installed by the scripts); stdout and stderr in `output`.
int run_node(const std::string& script, const std::vector<std::string>& args, std::string& output) {
    std::vector<std::string> command = {"node", std::string(LIGHTFARM_SOURCE_DIR) + "/tests/web/" + script};
    command.insert(command.end(), args.begin(), args.end());
    const server::RunResult r = server::run_command(command, std::chrono::seconds(240));
    output = r.out + r.err_last_line;
    return r.status.success() ? 0 : 1;
}

// Atlas pages through the service (issue #36): monkey.glb at 100 texels/m
// in atlases of at most 256² (its charts take three pages) bakes on pages:
// each page is an artifact that downloads whole, the manifest says the
// pages, the served pages equal `lightfarm bake`'s with the same settings
// and seed, pixel for pixel, and the status page's 3D view shows the job as
// its scene.lit.glb shows. A job asking more pages than the
// server allows is refused at submit, naming the limit.
TEST_F(EndToEnd, ABakeOnAtlasPagesThroughTheServiceEqualsTheCli) {
    auto r = client().Post("/v1/scenes", read_text(scenes_dir() / "monkey.glb"), "model/gltf-binary");
    ASSERT_TRUE(r && (r->status == 201 || r->status == 200)) << (r ? r->body : "no answer");
    const std::string scene = json::parse(r->body).value("id", "");
    const json atlas = {{"texel_density", 100}, {"max_res", 256}};
    const std::string id =
        submit({{"scene", scene}, {"outputs", {{"lightmap", {{"passes", 16}}}}}, {"atlas", atlas}, {"seed", 3}});
    ASSERT_EQ(wait_finished(id)["state"], "succeeded");
    expect_whole_artifacts(id);
    const json manifest = json::parse(read_text(download(id, "manifest.json", "pages")));
    const json& baked_atlas = manifest["lightmap"]["settings"]["atlas"];
    ASSERT_EQ(baked_atlas["pages"], 3) << baked_atlas.dump();
    EXPECT_EQ(baked_atlas["texel_density"], 100.0);

    const fs::path local = tmp.path / "local-pages";
    const server::RunResult cli =
        server::run_command({LIGHTFARM_ENGINE, "bake", (scenes_dir() / "monkey.glb").string(), "--out", local.string(),
                             "--passes", "16", "--texel-density", "100", "--max-res", "256", "--seed", "3"},
                            std::chrono::seconds(300));
    ASSERT_TRUE(cli.status.success()) << cli.status.describe() << ": " << cli.err_last_line;
    for (int page = 0; page < 3; ++page) {
        const std::string name = "lightmap.page-" + std::to_string(page) + ".exr";
        EXPECT_TRUE(same_pixels(download(id, name, "pages"), local / name)) << name;
    }

    // The status page's 3D view of the job on pages (its stacked lightmap,
    // each primitive on its page through its extras) draws as the job's own
    // scene.lit.glb (each page's material its page's lightmap) does, opened
    // in the view: run_node's status_page_3d.mjs measures the two canvases.
    const fs::path lit = download(id, "scene.lit.glb", "pages");
    const std::string url = "http://" + server->host + ":" + std::to_string(server->port);
    std::string browser;
    ASSERT_EQ(
        run_node("status_page_3d.mjs", {url, kToken, id, (tmp.path / "pages.png").string(), lit.string()}, browser), 0)
        << browser;
    // Measured 2026-11-28 (SwiftShader, 16 passes): 2.25 of 255 (the file's
    // exposure from its 8-bit pages, 4% off the job's from the float
    // lightmap); with the view's page offsets left out (a deliberate fault):
    // 18.1.
    const json view = json::parse(browser.substr(browser.find('{')));
    std::printf("the view on pages: %s\n", view.dump().c_str());
    EXPECT_LT(view["file_against_job"].get<double>(), 6.0) << browser;

    auto refused = client().Post(
        "/v1/jobs",
        json{{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"max_pages", 17}}}}.dump(),
        "application/json");
    ASSERT_TRUE(refused);
    EXPECT_EQ(refused->status, 400) << refused->body;
    EXPECT_NE(refused->body.find("atlas.max_pages"), std::string::npos) << refused->body;
    EXPECT_NE(refused->body.find("limit 16"), std::string::npos) << refused->body;
}

// What a studio gets back: scene.lit.glb, downloaded from the service, passes
// the Khronos validator; the status page's 3D view, in a real headless
// Chromium, draws the scene lit by the bake in each of its modes (lit,
// lightmap only, per-texel error) and the downloaded scene.lit.glb opened
// from disk by its own embedded lightmap, with no console error; three.js is
// served from the npm install and nothing outside it.
TEST_F(EndToEnd, AStudioGetsAValidLitSceneAndA3DViewOfIt) {
    // With three probes in the box (issue #34): the view shows them too, and
    // their probes.json opens there alone.
    const json probes = {
        {"probe_positions",
         {{{"position", {0.2, 0.3, 0.2}}}, {{"position", {0.4, 0.1, 0.35}}}, {{"position", {0.1, 0.45, 0.3}}}}},
        {"probe_res", 16},
        {"probe_m", 4},
        {"probe_passes", 4}};
    const std::string id = submit({{"scene", upload_cornell_box()},
                                   {"outputs", {{"lightmap", {{"passes", 32}}}, {"probes", probes}}},
                                   {"atlas", {{"res", 96}}}});
    ASSERT_FALSE(id.empty());
    ASSERT_EQ(wait_finished(id)["state"], "succeeded");
    // A newer job, which the page would show first: the view must show the
    // one the URL names by the 12 characters the page shows (#job=).
    const std::string newer = submit({{"scene", upload_cornell_box()},
                                      {"outputs", {{"lightmap", {{"passes", 2}}}}},
                                      {"atlas", {{"res", 32}}},
                                      {"seed", 9}});
    ASSERT_EQ(wait_finished(newer)["state"], "succeeded");

    std::string report;
    const fs::path lit = download(id, "scene.lit.glb", "studio");
    EXPECT_EQ(run_node("validate_gltf.mjs", {lit.string()}, report), 0) << report;
    auto rgbm = client().Get("/v1/jobs/" + id + "/lightmap.rgbm.png");
    ASSERT_TRUE(rgbm);
    EXPECT_EQ(rgbm->status, 200) << rgbm->body;
    EXPECT_GT(std::stod(rgbm->get_header_value("X-Lightfarm-Rgbm-Range")), 0.0);
    EXPECT_EQ(rgbm->get_header_value("X-Lightfarm-Pass"), "32");
    auto error = client().Get("/v1/jobs/" + id + "/error.png");
    ASSERT_TRUE(error);
    EXPECT_EQ(error->status, 200) << error->body;
    auto three = client().Get("/ui/three/build/three.module.js");
    ASSERT_TRUE(three);
    EXPECT_EQ(three->status, 200) << "three.js is installed by the scripts (npm ci in web/)";
    for (const char* outside : {"/ui/three/../../package.json", "/ui/three/package.json", "/ui/three/%2e%2e/x.js"}) {
        auto r = client().Get(outside);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 404) << outside;
    }

    const fs::path screenshot = tmp.path / "view3d.png";
    const fs::path probes_json = download(id, "probes.json", "studio");
    const std::string url = "http://" + server->host + ":" + std::to_string(server->port);
    std::string browser;
    EXPECT_EQ(run_node("status_page_3d.mjs", {url, kToken, id, screenshot.string(), lit.string(), probes_json.string()},
                       browser),
              0)
        << browser;
    EXPECT_NE(browser.find("\"file\":{"), std::string::npos) << "the lit glb opened in the view: " << browser;
    std::printf("the view: %s\n", browser.c_str());
    const json view = json::parse(browser.substr(browser.find('{')));
    EXPECT_LT(view.value("file_against_job", 255.0), 6.0) << "the file draws as the job: " << browser;
    EXPECT_NE(browser.find("\"probes_file\":{"), std::string::npos) << "probes.json opened in the view: " << browser;
    EXPECT_GT(fs::exists(screenshot) ? fs::file_size(screenshot) : 0u, 1000u) << browser;
}

// The previews follow the output registry (issue #56: an AO-only job had
// none, and the status page said "No lightmap or probes snapshot yet"): the
// first image output the job has (here its ambient occlusion, the only
// one), or the one `?output=` names; a preview of an output the job does
// not bake is a 404 that says which, of one that has no image (SH) a 400.
// The status page's 3D view draws the job's occlusion on its scene in each
// of its modes, with no error.
TEST_F(EndToEnd, AnAoOnlyJobHasAPreviewOfItsOcclusion) {
    json spec = Bake{}.spec(upload_cornell_box());
    spec["outputs"] = {{"ao", {{"ao_passes", 4}}}};
    const std::string id = submit(spec);
    ASSERT_FALSE(id.empty());
    const json status = wait_finished(id);
    ASSERT_EQ(status["state"], "succeeded") << status.dump();
    for (const std::string route : {"/preview.png", "/preview.png?output=ao", "/lightmap.rgbm.png"}) {
        auto png = client().Get("/v1/jobs/" + id + route);
        ASSERT_TRUE(png);
        EXPECT_EQ(png->status, 200) << route << ": " << png->body;
        EXPECT_EQ(png->get_header_value("X-Lightfarm-Output"), "ao") << route;
        EXPECT_EQ(png->get_header_value("X-Lightfarm-Source"), "ao.exr") << route;
        EXPECT_EQ(png->body.substr(1, 3), "PNG") << route;
    }
    auto none = client().Get("/v1/jobs/" + id + "/preview.png?output=lightmap");
    ASSERT_TRUE(none);
    EXPECT_EQ(none->status, 404);
    EXPECT_NE(none->body.find("no lightmap snapshot"), std::string::npos) << none->body;
    auto sh = client().Get("/v1/jobs/" + id + "/preview.png?output=sh");
    ASSERT_TRUE(sh);
    EXPECT_EQ(sh->status, 400) << sh->body;

    const fs::path screenshot = tmp.path / "ao-view.png";
    const std::string url = "http://" + server->host + ":" + std::to_string(server->port);
    std::string browser;
    EXPECT_EQ(run_node("status_page_3d.mjs", {url, kToken, id, screenshot.string()}, browser), 0) << browser;
    EXPECT_GT(fs::exists(screenshot) ? fs::file_size(screenshot) : 0u, 1000u) << browser;
}

TEST_F(EndToEnd, AWorkerKilledMidBakeIsRetriedAndTheResultStillEqualsTheCli) {
    const Bake bake = long_bake();
    const std::string id = submit(bake.spec(upload_cornell_box()));
    ASSERT_FALSE(id.empty());
    const json mid = wait_snapshot_past(id, 4);
    ASSERT_EQ(mid["state"], "running") << "the bake ended before it could be interrupted: " << mid.dump();
    const int snapshot_pass = mid["latest"]["lightmap"]["pass"];
    const pid_t pid = worker_pid(job_dir(id));
    ASSERT_GT(pid, 1);
    ASSERT_TRUE(bakes_into(pid, job_dir(id)));
    ASSERT_EQ(::kill(pid, SIGKILL), 0);

    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    EXPECT_EQ(status["attempts"], 2);
    EXPECT_EQ(status["progress"]["pass"], bake.passes);
    const auto events = read_events(server->host, server->port, kToken, id);
    const auto types = types_of(events);
    ASSERT_TRUE(contains(types, "retrying"));
    for (const auto& e : events) {
        if (e.type == "retrying") {
            EXPECT_NE(e.data.value("cause", "").find("signal 9"), std::string::npos) << e.data.dump();
        }
    }
    EXPECT_EQ(types.back(), "done");

    // The retry continued from the state saved with the last snapshot, and
    // traced exactly the rays the uninterrupted bake did after it.
    const std::vector<int> resumed = resumed_after(id);
    ASSERT_EQ(resumed.size(), 2u);
    EXPECT_EQ(resumed[0], 0);
    EXPECT_GE(resumed[1], snapshot_pass);
    EXPECT_FALSE(fs::exists(job_dir(id) / ".resume")) << "a finished job keeps no state";

    expect_whole_artifacts(id);
    EXPECT_TRUE(same_pixels(download(id, "lightmap.exr", "served"), tmp.path / "local" / "lightmap.exr"))
        << "the retried bake and `lightfarm bake` with the same seed";
}

// Issue #36: "under load a cancel at pass 90 left pass 47 as the newest
// snapshot". The worker was SIGKILLed at the cancel: whatever it had baked
// since its last scheduled snapshot (passes 1, 2, 4 … 64, every 10 s) was
// lost. Now a cancel sends SIGTERM; the worker writes one last snapshot of
// the pass it stands at and exits, within the server's grace
// (Supervisor::kCancelGraceSeconds), and that snapshot is the cancelled
// job's `latest` (what `fetch --latest` downloads).
TEST_F(EndToEnd, ACancelledJobsNewestSnapshotIsWhereTheBakeStoodAtTheCancel) {
    Bake bake;
    bake.passes = 100000;  // cancelled long before
    const std::string id = submit(bake.spec(upload_cornell_box()));
    ASSERT_FALSE(id.empty());
    // Some passes past its newest snapshot.
    auto c = client();
    const json mid = wait_for_job(
        c, id,
        [](const json& s) {
            const int snapshot = s.value("latest", json::object()).value("lightmap", json::object()).value("pass", 0);
            return is_finished(s) ||
                   (s["state"] == "running" && snapshot >= 4 && s["progress"].value("pass", 0) >= snapshot + 6);
        },
        std::chrono::seconds(60));
    ASSERT_EQ(mid["state"], "running") << mid.dump();
    auto r = c.Post("/v1/jobs/" + id + "/cancel", "", "application/json");
    ASSERT_TRUE(r && r->status == 200) << (r ? r->body : "no answer");
    const json at_cancel = json::parse(r->body);
    const int cancelled_at = at_cancel["progress"]["pass"];
    const int scheduled = mid["latest"]["lightmap"]["pass"];
    ASSERT_GT(cancelled_at, scheduled);

    // Within the grace, the job's newest lightmap is of the pass it stood at (or later).
    const auto deadline = Clock::now() + std::chrono::seconds(20);
    json status;
    for (;; std::this_thread::sleep_for(std::chrono::milliseconds(100))) {
        auto g = c.Get("/v1/jobs/" + id);
        ASSERT_TRUE(g && g->status == 200);
        status = json::parse(g->body);
        if (status["latest"]["lightmap"].value("pass", 0) >= cancelled_at || Clock::now() > deadline) break;
    }
    EXPECT_EQ(status["state"], "cancelled");
    const json latest = status["latest"]["lightmap"];
    EXPECT_GE(latest.value("pass", 0), cancelled_at)
        << "the newest snapshot is of pass " << latest.value("pass", 0) << ", the cancel came at pass " << cancelled_at
        << " (the last scheduled snapshot: pass " << scheduled << ")";
    EXPECT_FALSE(latest.value("final", true));
    EXPECT_EQ(status["progress"].value("pass", 0), latest.value("pass", 0)) << "its progress is that snapshot's";
    EXPECT_TRUE(status["progress"]["eta_seconds"].is_null()) << status.dump();
    const std::string file = latest.value("file", "");
    EXPECT_EQ(file, protocol::snapshot_file_name("lightmap", latest.value("pass", 0), "exr"));
    EXPECT_NO_THROW(read_exr(download(id, file, "cancelled"))) << file;
    // The worker is gone, and the cancelled event is still the job's last.
    EXPECT_FALSE(bakes_into(worker_pid(job_dir(id)), job_dir(id)));
    EXPECT_EQ(types_of(read_events(server->host, server->port, kToken, id)).back(), "cancelled");
}

TEST_F(EndToEnd, AServerKilledMidBakeFinishesTheJobAfterARestartWithWholeArtifacts) {
    const Bake bake = long_bake();
    const std::string id = submit(bake.spec(upload_cornell_box()));
    ASSERT_FALSE(id.empty());
    const json mid = wait_snapshot_past(id, 4);
    ASSERT_EQ(mid["state"], "running") << "the bake ended before it could be interrupted: " << mid.dump();
    const int snapshot_pass = mid["latest"]["lightmap"]["pass"];
    const pid_t orphan = worker_pid(job_dir(id));
    ASSERT_GT(orphan, 1);

    server->kill9();
    server->start();  // same data dir, same tokens

    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    EXPECT_EQ(status["attempts"], 2);
    EXPECT_EQ(status["progress"]["pass"], bake.passes);
    // The worker the killed server left behind is not baking any more (it
    // died writing to the dead server's pipe, or the new server ended it).
    EXPECT_FALSE(bakes_into(orphan, job_dir(id)));
    const auto types = types_of(read_events(server->host, server->port, kToken, id));
    EXPECT_TRUE(contains(types, "retrying"));
    EXPECT_EQ(types.back(), "done");

    const std::vector<int> resumed = resumed_after(id);
    ASSERT_EQ(resumed.size(), 2u);
    EXPECT_GE(resumed[1], snapshot_pass) << "the restarted server's worker resumed from the last snapshot";

    expect_whole_artifacts(id);
    EXPECT_TRUE(same_pixels(download(id, "lightmap.exr", "served"), tmp.path / "local" / "lightmap.exr"))
        << "the re-run bake and `lightfarm bake` with the same seed";
}

// A stop (SIGTERM to lightfarmd) gives each worker a grace
// (Supervisor::kStopGraceSeconds): it writes a last snapshot where the bake
// stands, its state with it, and exits by itself; the next start's worker
// resumes there. It was SIGKILLed at once and resumed from its last periodic
// snapshot, losing every pass since (issue #36).
TEST_F(EndToEnd, AStoppedServersWorkersSaveWhereTheyStoodAndResumeThere) {
    const Bake bake = long_bake();
    const std::string id = submit(bake.spec(upload_cornell_box()));
    ASSERT_FALSE(id.empty());
    const json mid = wait_snapshot_past(id, 4);
    ASSERT_EQ(mid["state"], "running") << "the bake ended before it could be stopped: " << mid.dump();
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // passes beyond that snapshot
    auto c = client();
    const json before = wait_for_job(c, id, [](const json&) { return true; });
    ASSERT_EQ(before["state"], "running") << before.dump();
    const int newest = before["latest"]["lightmap"]["pass"];  // what a SIGKILL would resume from

    server->stop();
    const std::string log = server->log();
    EXPECT_NE(log.find("job " + id + ": lightfarmd stopping; its worker stopped"), std::string::npos) << log;
    server->start();

    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    const std::vector<int> resumed = resumed_after(id);
    ASSERT_EQ(resumed.size(), 2u);
    EXPECT_GT(resumed[1], newest) << "resumed from the snapshot the worker wrote at the stop";
    EXPECT_TRUE(same_pixels(download(id, "lightmap.exr", "served"), tmp.path / "local" / "lightmap.exr"))
        << "the resumed bake and `lightfarm bake` with the same seed";
}

}  // namespace
}  // namespace lf::test
