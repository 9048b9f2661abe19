// lightfarmd end to end on loopback, with a fake engine (tests/server_harness.cpp)
// standing in for `lightfarm` so that crashes, hangs and restarts can be
// staged: authentication and isolation, limits, bad uploads and specs, the
// event stream, artifacts, retries, cancel, restart survival, the bake cache,
// and the API document against the route table.
#include "server_harness.h"

#include "hash.h"
#include "service.h"

#include <gtest/gtest.h>

#include <fstream>
#include <set>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;

const std::string kAlice = "alice-token-0123456789";
const std::string kBob = "bob-token-9876543210";

// A body that passes for a .glb with the fake engine: the magic, then a tag
// that makes it unique (or tells the fake loader to fail: BROKEN, SEGV).
std::string glb(const std::string& tag) { return std::string("glTF\x02\x00\x00\x00", 8) + " " + tag; }

class ServerTest : public ::testing::Test {
protected:
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    std::unique_ptr<Lightfarmd> server;

    void start(std::vector<std::string> extra = {}) {
        write_text(tmp.path / "tokens", "# test tokens\n\n" + kAlice + "\n  " + kBob + "  \n");
        server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script, std::move(extra));
        server->start();
    }
    void TearDown() override {
        if (HasFailure() && server) std::cerr << "---- lightfarmd log ----\n" << server->log();
    }
    httplib::Client client(const std::string& token = kAlice) { return server->client(token); }

    // Uploads a fake .glb; returns its id.
    std::string upload(const std::string& token = kAlice, const std::string& tag = "scene") {
        auto r = client(token).Post("/v1/scenes", glb(tag), "model/gltf-binary");
        EXPECT_TRUE(r && (r->status == 201 || r->status == 200)) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    httplib::Result post_job(const json& spec, const std::string& token = kAlice) {
        return client(token).Post("/v1/jobs", spec.dump(), "application/json");
    }
    std::string submit(const std::string& scene, json lightmap = {{"passes", 4}}, uint64_t seed = 1,
                       const std::string& token = kAlice, json limits = nullptr) {
        json spec = {{"scene", scene}, {"outputs", {{"lightmap", lightmap}}}, {"seed", seed}};
        if (!limits.is_null()) spec["limits"] = limits;
        auto r = post_job(spec, token);
        EXPECT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    json wait_finished(const std::string& id, std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
        auto c = client();
        return wait_for_job(c, id, is_finished, timeout);
    }
    std::vector<protocol::JobEvent> events(const std::string& id, int64_t last = -1, size_t stop_after = 0) {
        return read_events(server->host, server->port, kAlice, id, last, stop_after);
    }
};

std::vector<std::string> types_of(const std::vector<protocol::JobEvent>& events) {
    std::vector<std::string> types;
    for (const auto& e : events) types.push_back(e.type);
    return types;
}

TEST_F(ServerTest, HealthzIsOpenEverythingElseNeedsAToken) {
    start();
    httplib::Client anonymous(server->host, server->port);
    auto r = anonymous.Get("/healthz");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 200);
    for (const char* path : {"/v1/jobs", "/metrics", "/v1/jobs/abc", "/v1/scenes/abc"}) {
        r = anonymous.Get(path);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 401) << path;
        EXPECT_TRUE(json::parse(r->body).contains("error")) << path;
        r = client("not-a-token").Get(path);
        EXPECT_EQ(r->status, 401) << path;
    }
    r = anonymous.Post("/v1/scenes", "glTF....", "model/gltf-binary");
    EXPECT_EQ(r->status, 401);
    r = anonymous.Post("/v1/jobs", "{}", "application/json");
    EXPECT_EQ(r->status, 401);
    // The status page asks for a token instead of showing anything.
    r = anonymous.Get("/");
    EXPECT_EQ(r->status, 401);
    EXPECT_EQ(r->body.find("/v1/jobs"), std::string::npos);
    r = anonymous.Get("/no/such/route");
    EXPECT_EQ(r->status, 404);
}

TEST_F(ServerTest, ATokenSeesOnlyItsOwnScenesAndJobs) {
    start();
    const std::string scene = upload(kAlice);
    const std::string job = submit(scene);
    wait_finished(job);
    auto bob = client(kBob);
    for (const std::string& path : {"/v1/jobs/" + job, "/v1/jobs/" + job + "/events", "/v1/jobs/" + job + "/artifacts",
                                    "/v1/jobs/" + job + "/artifacts/lightmap.exr", "/v1/jobs/" + job + "/preview.png",
                                    "/v1/scenes/" + scene}) {
        auto r = bob.Get(path);
        ASSERT_TRUE(r) << path;
        EXPECT_EQ(r->status, 404) << path;
    }
    // The same answer as for a job that never existed.
    EXPECT_EQ(bob.Get("/v1/jobs/0123456789abcdef01234567")->status, 404);
    auto r = bob.Post("/v1/jobs/" + job + "/cancel", "", "application/json");
    EXPECT_EQ(r->status, 404);
    r = post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}}, kBob);
    EXPECT_EQ(r->status, 404);
    EXPECT_EQ(json::parse(r->body)["field"], "scene");
    r = bob.Get("/v1/jobs");
    EXPECT_EQ(json::parse(r->body)["jobs"].size(), 0u);
    r = client(kAlice).Get("/v1/jobs");
    EXPECT_EQ(json::parse(r->body)["jobs"].size(), 1u);
}

TEST_F(ServerTest, ScenesAreStoredByContentHash) {
    start();
    const std::string body = glb("the same bytes");
    auto r = client().Post("/v1/scenes", body, "model/gltf-binary");
    ASSERT_EQ(r->status, 201) << r->body;
    const json first = json::parse(r->body);
    EXPECT_EQ(first["id"], server::sha256_hex(body));
    EXPECT_EQ(first["triangles"], 12);  // the inspect summary comes along
    r = client().Post("/v1/scenes", body, "model/gltf-binary");
    EXPECT_EQ(r->status, 200);
    EXPECT_EQ(json::parse(r->body)["id"], first["id"]);
    r = client(kBob).Post("/v1/scenes", body, "model/gltf-binary");
    EXPECT_EQ(r->status, 201);  // new to Bob
    r = client().Get("/v1/scenes/" + first["id"].get<std::string>());
    EXPECT_EQ(r->status, 200);
    EXPECT_EQ(json::parse(r->body)["triangles"], 12);
}

TEST_F(ServerTest, BadUploadsAreClear4xxAndTheServerStaysUp) {
    engine.set("triangles", "5000");
    start({"--limit", "upload_bytes=4096", "--limit", "triangles=1000"});
    auto c = client();
    auto r = c.Post("/v1/scenes", std::string(5000, 'x'), "model/gltf-binary");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 413);
    EXPECT_NE(json::parse(r->body)["error"].get<std::string>().find("4096"), std::string::npos) << r->body;

    r = c.Post("/v1/scenes", glb("big"), "model/gltf-binary");
    EXPECT_EQ(r->status, 413);
    EXPECT_EQ(json::parse(r->body)["error"], "triangles: 5000 exceeds the limit 1000");
    EXPECT_EQ(json::parse(r->body)["field"], "triangles");
    engine.set("triangles", "12");

    r = c.Post("/v1/scenes", "not a glb at all", "model/gltf-binary");
    EXPECT_EQ(r->status, 400);
    r = c.Post("/v1/scenes", glb("BROKEN"), "model/gltf-binary");
    EXPECT_EQ(r->status, 400);
    EXPECT_NE(json::parse(r->body)["error"].get<std::string>().find("not a glTF"), std::string::npos) << r->body;
    // A file that crashes the loader costs a 400, not the server.
    r = c.Post("/v1/scenes", glb("SEGV"), "model/gltf-binary");
    EXPECT_EQ(r->status, 400);
    EXPECT_NE(json::parse(r->body)["error"].get<std::string>().find("crashed"), std::string::npos) << r->body;
    r = c.Post("/v1/scenes", "", "model/gltf-binary");
    EXPECT_EQ(r->status, 400);
    EXPECT_EQ(c.Get("/healthz")->status, 200);
}

TEST_F(ServerTest, MultipartGltfMustNotReachOutsideTheUpload) {
    start();
    auto gltf = [](const std::string& uri) {
        return json{{"asset", {{"version", "2.0"}}}, {"buffers", {{{"byteLength", 4}, {"uri", uri}}}}}.dump();
    };
    auto c = client();
    for (const std::string uri : {"../secret.bin", "/etc/passwd", "$(touch pwned).bin", "sub/../../x.bin",
                                   "file:///etc/passwd", "missing.bin", "%2e%2e/secret.bin"}) {
        httplib::MultipartFormDataItems items = {{"scene", gltf(uri), "scene.gltf", "model/gltf+json"},
                                                 {"bin", "abcd", "data.bin", "application/octet-stream"}};
        auto r = c.Post("/v1/scenes", items);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 400) << uri;
        EXPECT_EQ(json::parse(r->body)["field"], "buffers[0].uri") << uri << ": " << r->body;
    }
    httplib::MultipartFormDataItems evil_name = {{"scene", gltf("data.bin"), "scene.gltf", "model/gltf+json"},
                                                 {"bin", "abcd", "../data.bin", "application/octet-stream"}};
    EXPECT_EQ(c.Post("/v1/scenes", evil_name)->status, 400);
    httplib::MultipartFormDataItems good = {{"scene", gltf("bin/data.bin"), "scene.gltf", "model/gltf+json"},
                                            {"bin", "abcd", "bin/data.bin", "application/octet-stream"}};
    auto r = c.Post("/v1/scenes", good);
    EXPECT_EQ(r->status, 201) << r->body;
    EXPECT_FALSE(fs::exists(tmp.path / "pwned"));
}

TEST_F(ServerTest, BadJobSpecsNameTheField) {
    start();
    const std::string scene = upload();
    auto expect_400 = [&](const std::string& body, const std::string& error) {
        auto r = client().Post("/v1/jobs", body, "application/json");
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 400) << body;
        EXPECT_EQ(json::parse(r->body)["error"].get<std::string>().rfind(error, 0), 0u) << r->body;
    };
    expect_400("{not json", "the request body is not JSON");
    const json ok = {{"scene", scene}, {"outputs", {{"lightmap", {{"res", 256}}}}}};
    json j = ok;
    j["outputs"]["lightmap"]["res"] = 100000;
    expect_400(j.dump(), "lightmap.res: 100000 exceeds the limit 8192");
    j = ok;
    j["priority"] = 1;
    expect_400(j.dump(), "priority: unknown field");
    j = ok;
    j["outputs"]["lightmap"]["passes"] = "ten";
    expect_400(j.dump(), "lightmap.passes: must be a number, not a string");
    j = ok;
    j["outputs"]["lightmap"]["passes"] = 1e9;
    expect_400(j.dump(), "lightmap.passes: must be an integer");
    j = ok;
    j["limits"] = {{"max_attempts", 0}};
    expect_400(j.dump(), "limits.max_attempts: 0 is below the minimum 1");
    auto r = post_job(ok);
    EXPECT_EQ(r->status, 201);
    EXPECT_EQ(json::parse(r->body)["state"], "queued");
}

TEST_F(ServerTest, QueuedJobsPerTokenAreLimited) {
    engine.set("mode", "hang_always");
    start({"--limit", "queued_jobs=2"});
    const std::string scene = upload();
    const std::string running = submit(scene, {{"passes", 1}}, 1);
    auto c = client();
    wait_for_job(c, running, [](const json& s) { return s["state"] == "running"; });
    submit(scene, {{"passes", 1}}, 2);
    submit(scene, {{"passes", 1}}, 3);
    auto r = post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"seed", 4}});
    EXPECT_EQ(r->status, 429);
    EXPECT_EQ(json::parse(r->body)["field"], "queued_jobs");
    // Another token has its own allowance.
    EXPECT_EQ(post_job({{"scene", upload(kBob)}, {"outputs", {{"lightmap", json::object()}}}}, kBob)->status, 201);
}

// With no --workers, lightfarmd asks the engine how many GPUs there are and
// runs one worker on each: two jobs at once land on gpu:0 and gpu:1.
TEST_F(ServerTest, OneWorkerPerGpuEachOnItsOwnDevice) {
    engine.set("gpus", "2");
    engine.set("delay", "0.3");
    start();
    const std::string scene = upload();
    const std::string a = submit(scene, {{"passes", 3}, {"res", 64}}, 1);
    const std::string b = submit(scene, {{"passes", 3}, {"res", 64}}, 2);
    EXPECT_EQ(wait_finished(a)["state"], "succeeded");
    EXPECT_EQ(wait_finished(b)["state"], "succeeded");
    const std::string args = read_text(engine.dir / "all_args");
    EXPECT_NE(args.find("--device gpu:0"), std::string::npos) << args;
    EXPECT_NE(args.find("--device gpu:1"), std::string::npos) << args;
    EXPECT_NE(server->log().find("2 GPU(s), 2 worker(s)"), std::string::npos) << server->log();
}

TEST_F(ServerTest, AJobRunsToDoneWithEventsArtifactsAndPreview) {
    start();
    const std::string scene = upload();
    const std::string id = submit(scene, {{"passes", 4}, {"res", 64}}, 42);
    const auto all = events(id);
    EXPECT_EQ(types_of(all), (std::vector<std::string>{"started", "progress", "snapshot", "progress", "snapshot",
                                                           "progress", "progress", "snapshot", "done"}));
    for (size_t i = 0; i < all.size(); ++i) EXPECT_EQ(all[i].id, int64_t(i + 1));
    ASSERT_GE(all.size(), 3u);
    EXPECT_EQ(all[2].data["file"], "lightmap.pass-0001.exr");
    EXPECT_EQ(all.back().data["files"], json({"lightmap.exr", "manifest.json"}));
    const std::string args = read_text(engine.dir / "last_args");
    EXPECT_NE(args.find("--json --lightmap --res 64 --passes 4 --seed 42\n"), std::string::npos) << args;

    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded");
    EXPECT_EQ(status["attempts"], 1);
    EXPECT_EQ(status["progress"]["pass"], 4);
    EXPECT_EQ(status["progress"]["rays"], 4000);

    auto c = client();
    auto r = c.Get("/v1/jobs/" + id + "/artifacts");
    const json listing = json::parse(r->body);
    std::set<std::string> names;
    for (const json& a : listing["artifacts"]) {
        names.insert(a["name"].get<std::string>());
        if (a["name"] == "lightmap.exr") {
            EXPECT_EQ(a["content_type"], "image/x-exr");
        }
        if (a["name"] == "manifest.json") {
            EXPECT_EQ(a["content_type"], "application/json");
        }
    }
    EXPECT_EQ(names, (std::set<std::string>{"lightmap.exr", "lightmap.pass-0001.exr", "lightmap.pass-0002.exr",
                                            "lightmap.pass-0004.exr", "manifest.json"}));
    r = c.Get("/v1/jobs/" + id + "/artifacts/lightmap.exr");
    ASSERT_EQ(r->status, 200);
    EXPECT_EQ(r->get_header_value("Content-Type"), "image/x-exr");
    EXPECT_EQ(r->get_header_value("Content-Length"), std::to_string(r->body.size()));
    EXPECT_EQ(r->body, read_text(engine.dir / "snapshot.exr"));
    EXPECT_EQ(c.Get("/v1/jobs/" + id + "/artifacts/.worker.pid")->status, 404);
    EXPECT_EQ(c.Get("/v1/jobs/" + id + "/artifacts/nothing.exr")->status, 404);
    EXPECT_EQ(c.Get("/v1/jobs/" + id + "/artifacts/..%2Fjobs.sqlite")->status, 404);

    r = c.Get("/v1/jobs/" + id + "/preview.png");
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
    EXPECT_EQ(r->body.substr(1, 3), "PNG");
}

TEST_F(ServerTest, EventsResumeWithLastEventIdWithoutLossOrRepetition) {
    engine.set("delay", "0.05");
    start();
    const std::string id = submit(upload(), {{"passes", 8}});
    const auto head = events(id, -1, 3);
    ASSERT_EQ(head.size(), 3u);
    const auto tail = events(id, head.back().id);
    ASSERT_FALSE(tail.empty());
    EXPECT_EQ(tail.back().type, "done");
    // After the end, a reader without Last-Event-ID gets the whole history.
    const auto all = events(id);
    ASSERT_EQ(all.size(), head.size() + tail.size());
    for (size_t i = 0; i < all.size(); ++i) {
        const auto& part = i < head.size() ? head[i] : tail[i - head.size()];
        EXPECT_EQ(part.id, all[i].id);
        EXPECT_EQ(part.type, all[i].type);
        EXPECT_EQ(part.data, all[i].data);
    }
    // Resuming after the last event ends at once with nothing.
    EXPECT_TRUE(events(id, all.back().id).empty());
    auto r = client().Get("/v1/jobs/" + id + "/events", {{"Last-Event-ID", "x"}});
    EXPECT_EQ(r->status, 400);
}

TEST_F(ServerTest, ACrashedWorkerCostsOneAttempt) {
    engine.set("mode", "crash_first");
    start();
    const std::string id = submit(upload());
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    EXPECT_EQ(status["attempts"], 2);
    const auto all = events(id);
    ASSERT_GE(all.size(), 2u);
    EXPECT_EQ(all[1].type, "retrying");
    EXPECT_EQ(all[1].data["cause"], "worker exited with status 3: lightfarm bake: error: lost the GPU context");
    EXPECT_EQ(engine.runs(), 2);
}

TEST_F(ServerTest, AWorkerThatAlwaysDiesFailsTheJobWithTheCause) {
    engine.set("mode", "always_crash");
    start({"--attempts", "3"});
    const std::string id = submit(upload());
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "failed");
    EXPECT_EQ(status["attempts"], 3);
    EXPECT_EQ(status["error"], "bake failed after 3 attempts");
    EXPECT_NE(status["cause"].get<std::string>().find("killed by signal 9"), std::string::npos) << status.dump();
    EXPECT_EQ(engine.runs(), 3);
    const auto all = events(id);
    EXPECT_EQ(all.back().type, "failed");
    EXPECT_EQ(client().Get("/healthz")->status, 200);
    auto metrics = client().Get("/metrics")->body;
    EXPECT_NE(metrics.find("lightfarm_worker_failures_total 3"), std::string::npos) << metrics;
}

TEST_F(ServerTest, AHungWorkerIsKilledAndRetried) {
    engine.set("mode", "hang_first");
    start({"--stall-timeout", "1"});
    const std::string id = submit(upload());
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    EXPECT_EQ(status["attempts"], 2);
    const auto all = events(id);
    ASSERT_GE(all.size(), 2u);
    EXPECT_EQ(all[1].type, "retrying");
    EXPECT_NE(all[1].data["cause"].get<std::string>().find("printed nothing for 1 s"), std::string::npos);
}

TEST_F(ServerTest, AnAttemptPastItsDeadlineIsKilled) {
    engine.set("mode", "hang_always");
    start();
    const std::string id = submit(upload(), {{"passes", 1}}, 1, kAlice, {{"max_seconds", 0.5}, {"max_attempts", 1}});
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "failed");
    EXPECT_NE(status["cause"].get<std::string>().find("deadline of 0.5 s"), std::string::npos) << status.dump();
}

TEST_F(ServerTest, CancelKillsTheWorker) {
    engine.set("mode", "hang_always");
    start();
    const std::string id = submit(upload());
    auto c = client();
    wait_for_job(c, id, [](const json& s) { return s["state"] == "running"; });
    auto r = c.Post("/v1/jobs/" + id + "/cancel", "", "application/json");
    ASSERT_EQ(r->status, 200) << r->body;
    EXPECT_EQ(json::parse(r->body)["state"], "cancelled");
    EXPECT_EQ(events(id).back().type, "cancelled");
    r = c.Post("/v1/jobs/" + id + "/cancel", "", "application/json");
    EXPECT_EQ(r->status, 409);
    // The worker is gone: the next job gets the (only) worker.
    engine.set("mode", "ok");
    const std::string next = submit(upload(kAlice, "another"));
    EXPECT_EQ(wait_finished(next)["state"], "succeeded");
    EXPECT_EQ(wait_finished(id)["state"], "cancelled");
}

TEST_F(ServerTest, JobsSurviveAKilledServer) {
    start();
    const std::string scene = upload();
    const std::string finished = submit(scene, {{"passes", 2}}, 1);
    ASSERT_EQ(wait_finished(finished)["state"], "succeeded");

    engine.set("delay", "0.2");
    const std::string running = submit(scene, {{"passes", 10}}, 2);
    const std::string queued = submit(scene, {{"passes", 2}}, 3);
    auto c = client();
    wait_for_job(c, running, [](const json& s) { return s["progress"]["pass"].get<int>() >= 2; });
    server->kill9();

    engine.set("delay", "0");
    server->start();
    auto c2 = client();
    EXPECT_EQ(wait_for_job(c2, finished, is_finished)["state"], "succeeded");
    const json r = wait_finished(running);
    EXPECT_EQ(r["state"], "succeeded") << r.dump();
    EXPECT_EQ(r["attempts"], 2);
    EXPECT_EQ(wait_finished(queued)["state"], "succeeded");
    auto exr = c2.Get("/v1/jobs/" + running + "/artifacts/lightmap.exr");
    ASSERT_EQ(exr->status, 200);
    EXPECT_EQ(exr->body, read_text(engine.dir / "snapshot.exr"));
    // The stream tells the whole story: the interrupted attempt, the retry, done.
    const auto all = events(running);
    const auto types = types_of(all);
    EXPECT_NE(std::find(types.begin(), types.end(), "retrying"), types.end());
    EXPECT_EQ(types.back(), "done");
}

// A normal stop (SIGTERM, as systemd or `docker stop` send) ends the running
// worker and puts its job back in the queue without counting the attempt: the
// interruption is not the job's fault. A queued job stays queued. Both finish
// after the restart, and the server logs a clean exit.
TEST_F(ServerTest, AStoppedServerRequeuesItsJobsWithoutCostingAnAttempt) {
    engine.set("delay", "0.2");
    start();
    const std::string scene = upload();
    const std::string running = submit(scene, {{"passes", 10}}, 1);
    const std::string queued = submit(scene, {{"passes", 2}}, 2);
    auto c = client();
    const json mid = wait_for_job(c, running, [](const json& s) { return s["progress"]["pass"].get<int>() >= 2; });
    ASSERT_EQ(mid["state"], "running") << mid.dump();

    const auto t0 = std::chrono::steady_clock::now();
    server->stop();
    EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(4)) << "SIGTERM did not stop lightfarmd";
    const std::string log = server->log();
    EXPECT_NE(log.find("lightfarmd: stopping (Terminated)"), std::string::npos) << log;
    EXPECT_NE(log.find("lightfarmd: stopped\n"), std::string::npos) << log;
    EXPECT_EQ(engine.runs(), 1);

    engine.set("delay", "0");
    server->start();
    auto c2 = client();
    const json r = wait_finished(running);
    EXPECT_EQ(r["state"], "succeeded") << r.dump();
    EXPECT_EQ(r["attempts"], 1) << "a normal stop costs the job no attempt";
    const json q = wait_finished(queued);
    EXPECT_EQ(q["state"], "succeeded") << q.dump();
    EXPECT_EQ(q["attempts"], 1);
    EXPECT_EQ(engine.runs(), 3);
    const auto all = events(running);
    bool retried = false;
    for (const auto& e : all) {
        if (e.type != "retrying") continue;
        retried = true;
        EXPECT_EQ(e.data["cause"], "lightfarmd stopped");
    }
    EXPECT_TRUE(retried);
    ASSERT_FALSE(all.empty());
    EXPECT_EQ(all.back().type, "done");
    auto exr = c2.Get("/v1/jobs/" + running + "/artifacts/lightmap.exr");
    ASSERT_EQ(exr->status, 200);
    EXPECT_EQ(exr->body, read_text(engine.dir / "snapshot.exr"));
}

TEST_F(ServerTest, TheSameBakeTwiceIsServedFromTheCache) {
    start();
    const std::string scene = upload();
    const std::string first = submit(scene, {{"passes", 2}}, 5);
    ASSERT_EQ(wait_finished(first)["state"], "succeeded");
    const int runs = engine.runs();

    auto r = post_job({{"scene", scene}, {"outputs", {{"lightmap", {{"passes", 2}}}}}, {"seed", 5}});
    ASSERT_EQ(r->status, 201);
    const json answer = json::parse(r->body);
    EXPECT_EQ(answer["state"], "succeeded");
    EXPECT_EQ(answer["cached"], true);
    const std::string second = answer["id"];
    EXPECT_NE(second, first);
    EXPECT_EQ(engine.runs(), runs);
    auto exr = client().Get("/v1/jobs/" + second + "/artifacts/lightmap.exr");
    ASSERT_EQ(exr->status, 200);
    EXPECT_EQ(exr->body, read_text(engine.dir / "snapshot.exr"));
    EXPECT_EQ(events(second).back().type, "done");

    // Another seed is another bake.
    const std::string third = submit(scene, {{"passes", 2}}, 6);
    EXPECT_EQ(wait_finished(third)["cached"], false);
    EXPECT_EQ(engine.runs(), runs + 1);
}

TEST_F(ServerTest, MetricsAndTheStatusPage) {
    start();
    const std::string id = submit(upload());
    wait_finished(id);
    auto c = client();
    const std::string metrics = c.Get("/metrics")->body;
    for (const char* name : {"lightfarm_jobs{state=\"succeeded\"} 1", "lightfarm_queue_depth 0",
                             "lightfarm_worker_starts_total 1", "lightfarm_rays_total 4000", "lightfarm_rays_per_second",
                             "lightfarm_http_request_seconds_bucket{route=\"/v1/jobs\""})
        EXPECT_NE(metrics.find(name), std::string::npos) << name << "\n" << metrics;

    auto page = c.Get("/");
    ASSERT_EQ(page->status, 200);
    EXPECT_NE(page->body.find("<script>"), std::string::npos);
    EXPECT_EQ(page->body.find("http://"), std::string::npos);  // nothing fetched from elsewhere
    EXPECT_EQ(page->body.find("https://"), std::string::npos);

    // A browser trades ?token= for a cookie; the cookie reads, never writes.
    httplib::Client browser(server->host, server->port);
    auto login = browser.Get("/?token=" + kAlice);
    EXPECT_EQ(login->status, 303);
    const std::string cookie = login->get_header_value("Set-Cookie");
    EXPECT_NE(cookie.find("HttpOnly"), std::string::npos);
    const httplib::Headers with_cookie = {{"Cookie", cookie.substr(0, cookie.find(';'))}};
    EXPECT_EQ(browser.Get("/v1/jobs", with_cookie)->status, 200);
    EXPECT_EQ(browser.Post("/v1/jobs/" + id + "/cancel", with_cookie, "", "application/json")->status, 401);
}

// Every route the server registers is in protocol/openapi.json and every
// documented operation is registered, with the same authentication.
TEST(OpenApi, DocumentsExactlyTheRoutesTheServerServes) {
    std::ifstream in(LIGHTFARM_OPENAPI);
    ASSERT_TRUE(in) << LIGHTFARM_OPENAPI;
    const json doc = json::parse(in);
    EXPECT_EQ(doc["openapi"].get<std::string>().substr(0, 2), "3.");
    const bool secured_by_default = doc.contains("security") && !doc["security"].empty();

    std::set<std::pair<std::string, std::string>> documented;
    std::map<std::pair<std::string, std::string>, bool> needs_token;
    for (auto& [path, item] : doc["paths"].items())
        for (auto& [method, op] : item.items()) {
            if (method == "parameters") continue;
            std::string upper = method;
            for (char& ch : upper) ch = char(std::toupper(static_cast<unsigned char>(ch)));
            documented.insert({upper, path});
            needs_token[{upper, path}] = op.contains("security") ? !op["security"].empty() : secured_by_default;
            EXPECT_TRUE(op.contains("responses")) << upper << " " << path;
        }
    std::set<std::pair<std::string, std::string>> served;
    for (const auto& r : server::Service::route_table()) {
        served.insert({r.method, r.path});
        if (documented.count({r.method, r.path})) {
            EXPECT_EQ((needs_token[{r.method, r.path}]), r.needs_token) << r.method << " " << r.path;
        }
    }
    for (const auto& d : documented) EXPECT_TRUE(served.count(d)) << "documented but not served: " << d.first << " " << d.second;
    for (const auto& s : served) EXPECT_TRUE(documented.count(s)) << "served but not documented: " << s.first << " " << s.second;
}

}  // namespace
}  // namespace lf::test
