// lightfarmd end to end on loopback, with a fake engine (tests/server_harness.cpp)
// standing in for `lightfarm` so that crashes, hangs and restarts can be
// staged: authentication and isolation, limits, bad uploads and specs, the
// event stream, artifacts, retries, cancel, restart survival, the bake cache,
// and the API document against the route table.
#include "server_harness.h"

#include "hash.h"
#include "http_error.h"
#include "preview_cache.h"
#include "service.h"
#include "queue_estimate.h"
#include "supervisor.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <random>
#include <set>
#include <thread>
#include <tuple>

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
    // `lightmap`: the lightmap's settings, and "res", which is the atlas's.
    std::string submit(const std::string& scene, json lightmap = {{"passes", 4}}, uint64_t seed = 1,
                       const std::string& token = kAlice, json limits = nullptr) {
        json spec = {{"scene", scene}, {"seed", seed}};
        if (lightmap.contains("res")) {
            spec["atlas"]["res"] = lightmap["res"];
            lightmap.erase("res");
        }
        spec["outputs"]["lightmap"] = lightmap;
        if (!limits.is_null()) spec["limits"] = limits;
        auto r = post_job(spec, token);
        EXPECT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    json wait_finished(const std::string& id, std::chrono::milliseconds timeout = std::chrono::seconds(20)) {
        auto c = client();
        return wait_for_job(c, id, is_finished, timeout);
    }
    // A job whose worker's first run failed for the machine, not for the
    // job's settings (as the fake engine's mode says): retried and succeeded,
    // that attempt refunded. Returns the "retrying" event's cause.
    std::string expect_retried_at_no_cost() {
        const std::string id = submit(upload());
        const json status = wait_finished(id, std::chrono::seconds(30));
        EXPECT_EQ(status["state"], "succeeded") << status.dump();
        EXPECT_EQ(status["attempts"], 1) << status.dump();
        EXPECT_EQ(engine.runs(), 2);
        const auto all = events(id);
        if (all.size() < 2) {
            ADD_FAILURE() << "no retrying event";
            return "";
        }
        EXPECT_EQ(all[1].type, "retrying");
        EXPECT_EQ(all[1].data["server_fault"], true);
        return all[1].data.value("cause", "");
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

TEST_F(ServerTest, WithTheEmbeddedStoreNodesListsThisNodeAloneAndItsJobs) {
    start({"--node-name", "solo", "--lease-seconds", "1"});
    engine.set("delay", "0.3");
    const std::string id = submit(upload(), {{"passes", 10}});  // 3 s: three leases
    auto c = client();
    ASSERT_EQ(wait_for_job(c, id, [](const json& s) { return s.value("state", "") == "running"; }).value("state", ""),
              "running");
    const json nodes = json::parse(c.Get("/v1/nodes")->body)["nodes"];
    ASSERT_EQ(nodes.size(), 1u) << nodes.dump();
    EXPECT_EQ(nodes[0]["name"], "solo");
    EXPECT_EQ(nodes[0]["alive"], true);
    EXPECT_EQ(nodes[0]["self"], true);
    EXPECT_EQ(nodes[0]["lease_seconds"], 1.0);
    EXPECT_EQ(nodes[0]["running"], 1);
    EXPECT_EQ(nodes[0]["jobs"], json::array({id}));
    EXPECT_EQ(json::parse(client(kBob).Get("/v1/nodes")->body)["nodes"][0]["jobs"], json::array())
        << "another token's job ids are not shown";
    EXPECT_NE(c.Get("/metrics")->body.find("lightfarm_node_running_jobs{node=\"solo\"} 1"), std::string::npos);
    // Renewed every third of a second while it runs: its lease never runs out under it.
    EXPECT_EQ(wait_finished(id).value("attempts", 0), 1);
}

TEST_F(ServerTest, ATokenSeesOnlyItsOwnScenesAndJobs) {
    start();
    const std::string scene = upload(kAlice);
    const std::string job = submit(scene);
    wait_finished(job);
    auto bob = client(kBob);
    for (const std::string& path :
         {"/v1/jobs/" + job, "/v1/jobs/" + job + "/events", "/v1/jobs/" + job + "/artifacts",
          "/v1/jobs/" + job + "/artifacts/lightmap.exr", "/v1/jobs/" + job + "/preview.png", "/v1/scenes/" + scene}) {
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
    // The 12-character id a person reads on screen names the job for its
    // owner only; a prefix shorter than 6 names nothing.
    EXPECT_EQ(bob.Get("/v1/jobs/" + job.substr(0, 12))->status, 404);
    r = client(kAlice).Get("/v1/jobs/" + job.substr(0, 12));
    ASSERT_EQ(r->status, 200);
    EXPECT_EQ(json::parse(r->body)["id"], job);
    EXPECT_EQ(client(kAlice).Get("/v1/jobs/" + job.substr(0, 12) + "/artifacts")->status, 200);
    EXPECT_EQ(client(kAlice).Get("/v1/jobs/" + job.substr(0, 5))->status, 404);
}

// Which job a short id names: an unambiguous prefix of 6 or more hex
// digits; ambiguous is a 409 that says so.
// FIPS 180-2's first example, "abc", in both encodings (scene ids and cache
// keys in hex; a Content-Security-Policy hash in base64).
TEST(Sha256, KnownDigestsInHexAndBase64) {
    EXPECT_EQ(server::sha256_hex("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    EXPECT_EQ(server::sha256_base64("abc"), "ungWv48Bz+pBQUDeXa4iI7ADYaOWF3qctBD/YfIAFa0=");
    EXPECT_EQ(server::sha256_base64(""), "47DEQpj8HBSa+/TImW+5JCeuQeRkm5NMpJWZG3hSuFU=");
}

// The previews kept in memory stay within their budget (issue #55: 240
// cached jobs' previews held 1 GB for good): the least recently shown job's
// leave first; a set larger than the budget is not kept; a job's new
// lightmap replaces its old previews.
TEST(PreviewCache, KeepsTheRecentlyShownWithinItsBudget) {
    using server::PreviewCache, server::PreviewKind, server::Preview;
    const auto previews = [](size_t bytes) {
        return std::map<PreviewKind, Preview>{{PreviewKind::Tonemapped, {std::string(bytes, 'x'), {}}}};
    };
    PreviewCache cache(1000);
    cache.keep("a", "a.exr:1", previews(400));
    cache.keep("b", "b.exr:1", previews(400));
    EXPECT_EQ(cache.bytes(), 800u);
    ASSERT_TRUE(cache.find("a", "a.exr:1"));  // a shown again: b is now the oldest
    EXPECT_FALSE(cache.find("a", "a.exr:2")) << "another version of the file";
    cache.keep("c", "c.exr:1", previews(400));
    EXPECT_TRUE(cache.find("a", "a.exr:1"));
    EXPECT_FALSE(cache.find("b", "b.exr:1")) << "the least recently shown left";
    EXPECT_TRUE(cache.find("c", "c.exr:1"));
    EXPECT_EQ(cache.bytes(), 800u);
    cache.keep("a", "a.exr:2", previews(100));  // a's lightmap changed
    EXPECT_FALSE(cache.find("a", "a.exr:1"));
    EXPECT_EQ(cache.bytes(), 500u);
    cache.keep("huge", "huge.exr:1", previews(2000));
    EXPECT_FALSE(cache.find("huge", "huge.exr:1"));
    EXPECT_EQ(cache.jobs(), 2u);
    for (int i = 0; i < 1000; ++i) cache.keep("job" + std::to_string(i), "x", previews(300));
    EXPECT_LE(cache.bytes(), 1000u);
    EXPECT_EQ(cache.jobs(), 3u);
}

TEST(JobIdPrefix, NamesOneJobOrIsAConflict) {
    std::vector<server::JobRecord> jobs(3);
    jobs[0].status.id = "abcdef000000000000000001";
    jobs[1].status.id = "abcdef000000000000000002";
    jobs[2].status.id = "123456789abc000000000000";
    EXPECT_EQ(server::job_by_id_prefix("123456789abc", jobs)->status.id, jobs[2].status.id);
    EXPECT_EQ(server::job_by_id_prefix("abcdef000000000000000002", jobs)->status.id, jobs[1].status.id);
    EXPECT_FALSE(server::job_by_id_prefix("12345", jobs)) << "shorter than 6";
    EXPECT_FALSE(server::job_by_id_prefix("fedcba", jobs));
    EXPECT_FALSE(server::job_by_id_prefix("ABCDEF", jobs)) << "ids are lower-case hex";
    try {
        server::job_by_id_prefix("abcdef0000", jobs);
        FAIL() << "an ambiguous prefix named a job";
    } catch (const server::HttpError& e) {
        EXPECT_EQ(e.status(), 409);
        EXPECT_NE(std::string(e.what()).find("ambiguous: 2 jobs"), std::string::npos) << e.what();
    }
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
    // Bob's upload of bytes Alice had was checked again, as a first upload
    // is, so its answer took as long (a 1 ms answer told Bob the bytes were
    // known, issue #33); Alice's own second upload was not.
    const std::string inspects = read_text(engine.dir / "inspects");
    EXPECT_EQ(std::count(inspects.begin(), inspects.end(), '\n'), 2) << inspects;
}

// Same bytes, two tenants (issue #33): each sees the scene only under the
// name it uploaded it as, in the upload's answer, GET /v1/scenes/{id}, its
// jobs, the status page, a cached job's manifest.json, a bake's and a
// failure's; Bob's upload of Alice's bytes ran the same check as a first
// upload (no quick answer that tells him they were known).
TEST_F(ServerTest, TenantsOfTheSameBytesEachSeeOnlyTheirOwnName) {
    start();
    const std::string body = glb("shared bytes");
    auto a = client(kAlice).Post("/v1/scenes?name=alice-secret-plan.glb", body, "model/gltf-binary");
    ASSERT_EQ(a->status, 201) << a->body;
    auto b = client(kBob).Post("/v1/scenes?name=bob.glb", body, "model/gltf-binary");
    ASSERT_EQ(b->status, 201) << b->body;  // new to Bob, as for a first upload
    const std::string scene = json::parse(a->body)["id"];
    EXPECT_EQ(json::parse(b->body)["id"], scene);
    EXPECT_EQ(json::parse(a->body)["source"], "alice-secret-plan.glb");
    EXPECT_EQ(json::parse(b->body)["source"], "bob.glb");
    // Bob's upload went through `lightfarm inspect` as a first one does, under his name.
    const std::string inspects = read_text(engine.dir / "inspects");
    EXPECT_EQ(std::count(inspects.begin(), inspects.end(), '\n'), 2) << inspects;
    EXPECT_NE(inspects.find("/bob.glb\n"), std::string::npos) << inspects;
    // Bob's second upload under another name keeps his first; Alice's is untouched.
    auto again = client(kBob).Post("/v1/scenes?name=renamed.glb", body, "model/gltf-binary");
    EXPECT_EQ(again->status, 200);
    EXPECT_EQ(json::parse(again->body)["source"], "bob.glb");
    EXPECT_EQ(json::parse(client(kAlice).Get("/v1/scenes/" + scene)->body)["source"], "alice-secret-plan.glb");
    EXPECT_EQ(json::parse(client(kBob).Get("/v1/scenes/" + scene)->body)["source"], "bob.glb");

    // Alice bakes; Bob's identical job is baked again (the cache does not
    // cross tenants, issue #55), and so is a second one of his: its worker
    // bakes the file under Bob's name.
    const std::string alices = submit(scene, {{"passes", 2}}, 7, kAlice);
    ASSERT_EQ(wait_finished(alices)["state"], "succeeded");
    const std::string bobs_same = submit(scene, {{"passes", 2}}, 7, kBob);
    // A bake of Bob's own: its worker bakes the file under Bob's name.
    const std::string bobs_baked = submit(scene, {{"passes", 2}}, 8, kBob);
    auto bob = client(kBob);
    ASSERT_EQ(wait_for_job(bob, bobs_baked, is_finished, std::chrono::seconds(20))["state"], "succeeded");
    ASSERT_EQ(wait_for_job(bob, bobs_same, is_finished, std::chrono::seconds(20))["state"], "succeeded");
    EXPECT_EQ(json::parse(client(kAlice).Get("/v1/jobs/" + alices + "/artifacts/manifest.json")->body)["scene"],
              "alice-secret-plan.glb");
    for (const std::string& job : {bobs_same, bobs_baked}) {
        const json status = json::parse(bob.Get("/v1/jobs/" + job)->body);
        EXPECT_EQ(status["scene_name"], "bob.glb") << job;
        auto manifest = bob.Get("/v1/jobs/" + job + "/artifacts/manifest.json");
        ASSERT_EQ(manifest->status, 200) << job;
        EXPECT_EQ(json::parse(manifest->body)["scene"], "bob.glb") << manifest->body;
    }
    EXPECT_EQ(json::parse(bob.Get("/v1/jobs/" + bobs_same)->body)["cached"], false);
    const json listing = json::parse(bob.Get("/v1/jobs")->body);
    ASSERT_EQ(listing["jobs"].size(), 2u);
    for (const json& job : listing["jobs"]) EXPECT_EQ(job["scene_name"], "bob.glb") << job.dump();
    EXPECT_EQ(json::parse(client(kAlice).Get("/v1/jobs/" + alices)->body)["scene_name"], "alice-secret-plan.glb");
    // A failure names Bob's file as Bob named it.
    engine.set("mode", "input_error");
    const std::string bobs_failed = submit(scene, {{"passes", 2}}, 9, kBob);
    const json failed = wait_for_job(bob, bobs_failed, is_finished, std::chrono::seconds(20));
    EXPECT_NE(failed["cause"].get<std::string>().find("bob.glb: nothing to bake"), std::string::npos) << failed;
    // Nowhere Bob can read names Alice's file.
    std::string everything = bob.Get("/")->body + bob.Get("/v1/jobs")->body + bob.Get("/v1/scenes/" + scene)->body;
    for (const std::string& job : {bobs_same, bobs_baked, bobs_failed}) {
        everything += bob.Get("/v1/jobs/" + job)->body + bob.Get("/v1/jobs/" + job + "/artifacts")->body;
        for (const auto& e : read_events(server->host, server->port, kBob, job)) everything += e.data.dump();
    }
    everything += bob.Get("/v1/jobs/" + bobs_same + "/artifacts/manifest.json")->body;
    EXPECT_EQ(everything.find("alice-secret"), std::string::npos) << everything;
}

// A bare .glb body keeps its own name (?name=): the summary and the job
// list showed every such upload as scene.glb. A name of the wrong kind, or
// one no upload may have, is a 400.
TEST_F(ServerTest, ABareUploadIsListedUnderItsOwnName) {
    start();
    auto r = client().Post("/v1/scenes?name=stairs%20v2.glb", glb("named"), "model/gltf-binary");
    ASSERT_TRUE(r);
    ASSERT_TRUE(r->status == 201 || r->status == 200) << r->body;
    EXPECT_EQ(json::parse(r->body)["source"], "stairs v2.glb") << r->body;
    const std::string id = submit(json::parse(r->body)["id"]);
    wait_finished(id);
    EXPECT_EQ(json::parse(client().Get("/v1/jobs/" + id)->body)["scene_name"], "stairs v2.glb");
    auto wrong = client().Post("/v1/scenes?name=stairs.gltf", glb("named2"), "model/gltf-binary");
    EXPECT_EQ(wrong->status, 400) << wrong->body;
    EXPECT_EQ(json::parse(wrong->body)["field"], "name");
    auto unsafe = client().Post("/v1/scenes?name=..%2Fx.glb", glb("named3"), "model/gltf-binary");
    EXPECT_EQ(unsafe->status, 400) << unsafe->body;
}

// Names that cannot be stored, or read other than they are, are a 400
// naming the file (a 300-byte name and a file that is also a folder were
// 500s; U+202E was accepted).
TEST_F(ServerTest, BadFileNamesAreA400NamingTheFile) {
    start();
    const std::string gltf = "{\"asset\": {\"version\": \"2.0\"}}";
    const std::vector<std::pair<httplib::MultipartFormDataItems, std::string>> cases = {
        {{{"scene", gltf, std::string(300, 'a') + ".gltf", "model/gltf+json"}}, "longer than 255"},
        {{{"scene", gltf, "scene.gltf", "model/gltf+json"},
          {"tex", "x", "tex", "image/png"},
          {"tex2", "y", "tex/inner.png", "image/png"}},
         "also the folder"},
        {{{"scene", gltf, "gpj\u202e.gltf", "model/gltf+json"}}, "bidirectional"},
        {{{"scene", gltf, "bad\xff.gltf", "model/gltf+json"}}, "not UTF-8"},
    };
    for (const auto& [items, words] : cases) {
        auto r = client().Post("/v1/scenes", items);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 400) << words << ": " << r->body;
        EXPECT_NE(r->body.find(words), std::string::npos) << r->body;
    }
    // A name's control characters and non-UTF-8 bytes are shown as \xNN:
    // the message is whole, not cut at a NUL (issue #55). (A query's name
    // with them is refused before, by the gate, in words of its own.)
    const std::vector<std::tuple<std::string, std::string, std::string>> named = {
        {std::string("a\0b.gltf", 8), "a\\x00b.gltf", "contains a control character"},
        {"tab\t.gltf", "tab\\x09.gltf", "contains a control character"},
        {"bad\xff.gltf", "bad\\xFF.gltf", "is not UTF-8"},
    };
    for (const auto& [name, shown, why] : named) {
        auto r = client().Post("/v1/scenes", httplib::MultipartFormDataItems{{"scene", gltf, name, "model/gltf+json"}});
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 400) << shown << ": " << r->body;
        const std::string error = json::parse(r->body)["error"];
        EXPECT_EQ(error, "file name '" + shown + "' " + why);
        EXPECT_EQ(json::parse(r->body)["field"], shown);
    }
    EXPECT_EQ(client().Get("/healthz")->status, 200);
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
    const json ok = {{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"res", 256}}}};
    json j = ok;
    j["atlas"]["res"] = 100000;
    expect_400(j.dump(), "atlas.res: 100000 exceeds the maximum 16384");
    j["atlas"]["res"] = 10000;
    expect_400(j.dump(), "atlas.res: 10000 exceeds this server's limit 8192");
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
    expect_400(j.dump(), "limits.max_attempts: must be at least 1");
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

// A listing grows by a job's status, not by its spec (issue #55: one token's
// 300 cached jobs of a 0.6 MB spec made one listing 881 MB): jobs whose spec
// names 4,000 probe positions (about 150 KB each) are listed in a few
// hundred bytes each, without their spec, which each job's own GET has.
TEST_F(ServerTest, AListingHoldsNoSpecs) {
    start();
    const std::string scene = upload();
    json positions = json::array();
    for (int i = 0; i < 4000; ++i) positions.push_back({{"position", {0.001 * i, 0.5, -0.25}}});
    const json spec = {{"scene", scene}, {"outputs", {{"probes", {{"probe_positions", positions}}}}}};
    std::vector<std::string> ids;
    for (int seed = 1; seed <= 5; ++seed) {
        json s = spec;
        s["seed"] = seed;
        auto r = post_job(s);
        ASSERT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        ids.push_back(json::parse(r->body)["id"]);
    }
    const size_t spec_bytes = spec.dump().size();
    auto listing = client().Get("/v1/jobs");
    ASSERT_EQ(listing->status, 200);
    const json jobs = json::parse(listing->body)["jobs"];
    ASSERT_EQ(jobs.size(), ids.size());
    for (const json& job : jobs) EXPECT_FALSE(job.contains("spec")) << job.dump().substr(0, 200);
    EXPECT_LT(listing->body.size(), spec_bytes) << "five jobs listed in less than one spec";
    const json one = json::parse(client().Get("/v1/jobs/" + ids[0])->body);
    EXPECT_EQ(one["spec"]["outputs"]["probes"]["probe_positions"].size(), 4000u);
    EXPECT_LT(client().Get("/")->body.size(), spec_bytes) << "the status page lists them without specs too";
}

// With no --workers, lightfarmd asks the engine how many GPUs there are and
// runs two workers on each (one job's preparation overlaps another's
// passes): four jobs at once land two on gpu:0 and two on gpu:1.
TEST_F(ServerTest, TwoWorkersPerGpuEachPinnedToItsDevice) {
    engine.set("gpus", "2");
    engine.set("delay", "0.3");
    start();
    const std::string scene = upload();
    std::vector<std::string> jobs;
    for (int seed = 1; seed <= 4; ++seed) jobs.push_back(submit(scene, {{"passes", 3}, {"res", 64}}, seed));
    for (const std::string& id : jobs) EXPECT_EQ(wait_finished(id)["state"], "succeeded");
    const std::string args = read_text(engine.dir / "all_args");
    auto count = [&](const std::string& what) {
        size_t n = 0;
        for (size_t at = args.find(what); at != std::string::npos; at = args.find(what, at + 1)) ++n;
        return n;
    };
    EXPECT_EQ(count("--device gpu:0"), 2u) << args;
    EXPECT_EQ(count("--device gpu:1"), 2u) << args;
    EXPECT_NE(server->log().find("2 GPU(s), 4 worker(s)"), std::string::npos) << server->log();
}

TEST(ServerConfig, WorkerCountIsTwoPerGpuOneWithoutOrAsAsked) {
    server::ServerConfig config;
    EXPECT_EQ(server::worker_count(config, 0), 1);
    EXPECT_EQ(server::worker_count(config, 1), 2);
    EXPECT_EQ(server::worker_count(config, 8), 16);
    config.workers = 3;
    EXPECT_EQ(server::worker_count(config, 0), 3);
    EXPECT_EQ(server::worker_count(config, 8), 3);
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
    EXPECT_EQ(all.back().data["final"], json({{"lightmap", "lightmap.exr"}}));
    // The worker gets the job's own spec, written into the job directory, not a translation into flags.
    const std::string args = read_text(engine.dir / "last_args");
    const fs::path job_dir = tmp.path / "data" / "jobs" / id;
    EXPECT_NE(args.find("--out " + job_dir.string() + " --json --spec " + (job_dir / ".spec.json").string() + "\n"),
              std::string::npos)
        << args;
    const json spec = json::parse(read_text(engine.dir / "last_spec.json"));
    EXPECT_EQ(spec["outputs"]["lightmap"]["passes"], 4);
    EXPECT_EQ(spec["atlas"]["res"], 64);
    EXPECT_EQ(spec["seed"], 42);

    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "succeeded");
    EXPECT_EQ(status["attempts"], 1);
    EXPECT_EQ(status["progress"]["pass"], 4);
    EXPECT_EQ(status["progress"]["rays"], 4000);
    EXPECT_EQ(status["latest"], json({{"lightmap", {{"file", "lightmap.exr"}, {"pass", 4}, {"final", true}}}}));

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
    EXPECT_EQ(c.Get("/v1/jobs/" + id + "/artifacts/.spec.json")->status, 404);
    EXPECT_EQ(c.Get("/v1/jobs/" + id + "/artifacts/nothing.exr")->status, 404);
    EXPECT_EQ(c.Get("/v1/jobs/" + id + "/artifacts/..%2Fjobs.sqlite")->status, 404);

    // Ranges (issue #55): one range, or a few apart, are served; a thousand
    // copies of one range (1,000 times the file for a few bytes asked), more
    // than 16 ranges, overlapping ranges or one past the end are refused.
    const std::string artifact = "/v1/jobs/" + id + "/artifacts/lightmap.exr",
                      whole = read_text(engine.dir / "snapshot.exr");
    ASSERT_GT(whole.size(), 40u);
    r = c.Get(artifact, {{"Range", "bytes=0-9"}});
    ASSERT_EQ(r->status, 206);
    EXPECT_EQ(r->body, whole.substr(0, 10));
    EXPECT_EQ(c.Get(artifact, {{"Range", "bytes=0-1,4-5,-3"}})->status, 206);
    std::string copies = "bytes=0-9";
    for (int i = 1; i < 1000; ++i) copies += ",0-9";
    std::string many = "bytes=0-0";
    for (int i = 1; i < 17; ++i) many += "," + std::to_string(2 * i) + "-" + std::to_string(2 * i);
    for (const std::string& range :
         {copies, many, std::string("bytes=0-9,5-14"), "bytes=" + std::to_string(whole.size()) + "-"}) {
        r = c.Get(artifact, {{"Range", range}});
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 416) << range.substr(0, 40) << ": " << r->body.size() << " bytes";
        EXPECT_LT(r->body.size(), 1000u) << range.substr(0, 40);
    }
    // Anything else is answered whole, whatever the Range header asks.
    r = c.Get("/v1/jobs/" + id, {{"Range", copies}});
    ASSERT_EQ(r->status, 200);
    EXPECT_EQ(json::parse(r->body)["id"], id);

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
    EXPECT_EQ(all[1].data["cause"], "worker exited with status 1: lightfarm bake: error: lost the GPU context");
    EXPECT_EQ(engine.runs(), 2);
}

// ---- Faults of the machine are never the job's (issue #33) ----

// A full disk refuses new work with a 503 that says so and stores nothing;
// reads go on.
TEST_F(ServerTest, AFullDiskRefusesNewWorkAndStoresNothing) {
    start({"--limit", "free_disk_bytes=1e18"});
    auto up = client().Post("/v1/scenes", glb("full"), "model/gltf-binary");
    ASSERT_TRUE(up);
    EXPECT_EQ(up->status, 503) << up->body;
    EXPECT_EQ(json::parse(up->body)["field"], "free_disk_bytes");
    EXPECT_FALSE(up->get_header_value("Retry-After").empty());
    auto job = post_job({{"scene", std::string(64, 'a')}, {"outputs", {{"lightmap", json::object()}}}});
    ASSERT_TRUE(job);
    EXPECT_EQ(job->status, 503) << job->body;
    EXPECT_TRUE(answers_health(server->port));
    auto jobs = client().Get("/v1/jobs");
    ASSERT_TRUE(jobs);
    EXPECT_EQ(jobs->status, 200);
    EXPECT_TRUE(json::parse(jobs->body)["jobs"].empty());
}

// A queued job says where it stands (issue #54: `submit --wait` behind a
// running job said nothing for 131 s): with one worker held at its start,
// the job behind it has 0 ahead and 1 running, the next 1 ahead; the running
// one says nothing of a queue, and neither does any once they are done.
TEST_F(ServerTest, AQueuedJobSaysWhereItStands) {
    engine.set("gate", "");
    start({"--workers", "1"});
    const std::string scene = upload();
    const std::string first = submit(scene, {{"passes", 2}}, 1);
    auto c = client();
    wait_for_job(c, first, [](const json& s) { return s["state"] == "running"; });
    const std::string second = submit(scene, {{"passes", 2}}, 2), third = submit(scene, {{"passes", 2}}, 3);
    const json running = json::parse(c.Get("/v1/jobs/" + first)->body);
    EXPECT_FALSE(running.contains("queue")) << running.dump();
    // No job has finished here: nothing prices the running one (no ETA
    // before its first pass) or the one ahead, so no start is promised.
    EXPECT_EQ(json::parse(c.Get("/v1/jobs/" + second)->body)["queue"],
              json({{"ahead", 0}, {"running", 1}, {"starts_in_seconds", nullptr}}));
    EXPECT_EQ(json::parse(c.Get("/v1/jobs/" + third)->body)["queue"],
              json({{"ahead", 1}, {"running", 1}, {"starts_in_seconds", nullptr}}));
    fs::remove(engine.dir / "gate");
    for (const std::string& id : {first, second, third}) {
        const json done = wait_finished(id);
        EXPECT_EQ(done["state"], "succeeded") << done.dump();
        EXPECT_FALSE(done.contains("queue"));
    }
}

// Jobs queued when the disk fills up wait, costing no attempt and never
// failing, and run once it has room again (before, every queued job failed
// "not retried": its worker read an empty spec).
TEST_F(ServerTest, QueuedJobsWaitOutAFullDiskAndThenRun) {
    engine.set("delay", "0.3");
    start({"--workers", "1"});
    const std::string scene = upload();
    std::vector<std::string> ids;
    for (int seed = 1; seed <= 3; ++seed) ids.push_back(submit(scene, {{"passes", 4}}, uint64_t(seed)));
    server->stop();  // the running job goes back to the queue, its attempt not counted
    const int runs_before = engine.runs();

    server =
        std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script,
                                     std::vector<std::string>{"--workers", "1", "--limit", "free_disk_bytes=1e18"});
    server->start();
    std::this_thread::sleep_for(std::chrono::seconds(3));
    EXPECT_EQ(engine.runs(), runs_before) << "no worker starts on a full disk";
    for (const std::string& id : ids) {
        const json s = json::parse(client().Get("/v1/jobs/" + id)->body);
        EXPECT_EQ(s["state"], "queued") << s.dump();
    }
    EXPECT_NE(server->log().find("the machine's fault, not the job's"), std::string::npos) << server->log();
    server->stop();

    server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script,
                                          std::vector<std::string>{"--workers", "1"});
    server->start();
    for (const std::string& id : ids) {
        const json s = wait_finished(id, std::chrono::seconds(30));
        EXPECT_EQ(s["state"], "succeeded") << s.dump();
        EXPECT_LE(s["attempts"].get<int>(), 2) << "a restart's requeue may count; the full disk did not: " << s.dump();
    }
}

// A spec the server cannot write (here its place is taken by a directory,
// as a full disk fails the write) is the server's fault: the job is given
// back without an attempt counted and runs once the write succeeds.
TEST_F(ServerTest, ASpecThatCannotBeWrittenCostsTheJobNothing) {
    engine.set("delay", "0.3");
    start({"--workers", "1"});
    const std::string scene = upload();
    const std::string first = submit(scene, {{"passes", 8}}, 1);
    const std::string second = submit(scene, {{"passes", 2}}, 2);
    const fs::path blocked = tmp.path / "data" / "jobs" / second / ".spec.json" / "blocked";
    fs::create_directories(blocked);
    EXPECT_EQ(wait_finished(first)["state"], "succeeded");
    // It tries, backs off, tries again: never failed, never an attempt spent.
    std::this_thread::sleep_for(std::chrono::seconds(2));
    json s = json::parse(client().Get("/v1/jobs/" + second)->body);
    EXPECT_NE(s["state"], "failed") << s.dump();
    EXPECT_NE(server->log().find("cannot put the job's spec in place"), std::string::npos) << server->log();
    fs::remove_all(blocked.parent_path());
    s = wait_finished(second, std::chrono::seconds(40));
    EXPECT_EQ(s["state"], "succeeded") << s.dump();
    EXPECT_EQ(s["attempts"], 1) << "the failed spec writes were not attempts: " << s.dump();
}

// A scene on record whose files are not on the disk of the node that runs
// its job (issue #55: a dropped mount, a node with a data directory of its
// own; the job failed for good as "these settings (not retried)", and a new
// upload answered 200 and restored nothing): the job is given back, no
// attempt counted and no path of the server's in its cause, until an upload
// of the same bytes, which puts the files back; then it runs.
TEST_F(ServerTest, ASceneMissingOnTheNodeWaitsForItsFilesAndCostsTheJobNothing) {
    start({"--workers", "1"});
    const std::string scene = upload();
    const fs::path files = tmp.path / "data" / "scenes" / scene;
    ASSERT_TRUE(fs::is_directory(files));
    fs::remove_all(files);
    const std::string id = submit(scene, {{"passes", 2}}, 1);
    std::this_thread::sleep_for(std::chrono::seconds(2));
    json s = json::parse(client().Get("/v1/jobs/" + id)->body);
    EXPECT_EQ(s["state"], "queued") << s.dump();
    EXPECT_EQ(engine.runs(), 0) << "no worker starts without the scene's files";
    const auto so_far = events(id, -1, 2);
    ASSERT_GE(so_far.size(), 2u);
    EXPECT_EQ(so_far[1].type, "retrying");
    EXPECT_EQ(so_far[1].data["server_fault"], true);
    const std::string cause = so_far[1].data.value("cause", "");
    EXPECT_NE(cause.find("not on this node's disk"), std::string::npos) << cause;
    EXPECT_EQ(cause.find((tmp.path / "data").string()), std::string::npos) << "no server path in the cause: " << cause;

    auto again = client().Post("/v1/scenes", glb("scene"), "model/gltf-binary");
    ASSERT_TRUE(again);
    EXPECT_EQ(again->status, 200) << again->body;
    EXPECT_EQ(json::parse(again->body)["id"], scene);
    EXPECT_TRUE(fs::is_directory(files)) << "the upload put the files back";
    s = wait_finished(id, std::chrono::seconds(40));
    EXPECT_EQ(s["state"], "succeeded") << s.dump();
    EXPECT_EQ(s["attempts"], 1) << "the missing files were not attempts: " << s.dump();

    // Another tenant's upload of the same bytes under its own name puts them
    // back too, under the name on record.
    const std::string stored = json::parse(client().Get("/v1/scenes/" + scene)->body)["source"];
    fs::remove_all(files);
    auto bobs = client(kBob).Post("/v1/scenes?name=bobs.glb", glb("scene"), "model/gltf-binary");
    ASSERT_TRUE(bobs);
    EXPECT_EQ(bobs->status, 201) << bobs->body;
    EXPECT_TRUE(fs::is_regular_file(files / stored)) << stored;
    EXPECT_FALSE(fs::exists(files / "bobs.glb"));
}

// A worker that could not read the spec it was given (exit 4).
TEST_F(ServerTest, AWorkerThatCannotReadItsSpecIsRetriedAtNoCost) {
    engine.set("mode", "spec_unreadable_first");
    start();
    expect_retried_at_no_cost();
}

// A worker that could not write its files (exit 5: a full disk, an I/O
// error): the cause says so, without the server's paths.
TEST_F(ServerTest, AWorkerThatCannotWriteItsFilesIsRetriedAtNoCost) {
    engine.set("mode", "write_fails_first");
    start();
    const std::string cause = expect_retried_at_no_cost();
    EXPECT_NE(cause.find("could not write its files"), std::string::npos) << cause;
    EXPECT_NE(cause.find("No space left on device"), std::string::npos) << cause;
    EXPECT_EQ(cause.find((tmp.path / "data").string()), std::string::npos) << "no server path in the cause: " << cause;
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
    // What each killed worker was writing is gone (issue #55: it was left).
    std::vector<std::string> left;
    for (const auto& e : fs::recursive_directory_iterator(tmp.path / "data" / "jobs" / id))
        if (e.path().filename().string().find(".tmp-") != std::string::npos) left.push_back(e.path().string());
    EXPECT_TRUE(left.empty()) << left.front();
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

// An attempt past its job's deadline is killed; one that saved no snapshot
// before it is not retried (issue #55: max_seconds 1 cost three worker runs,
// each ending where the last did), and the error says to raise the limit.
TEST_F(ServerTest, AnAttemptPastItsDeadlineIsKilled) {
    engine.set("mode", "hang_always");
    start();
    const std::string id = submit(upload(), {{"passes", 1}}, 1, kAlice, {{"max_seconds", 1}, {"max_attempts", 3}});
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "failed");
    EXPECT_NE(status["cause"].get<std::string>().find("deadline of 1 s"), std::string::npos) << status.dump();
    EXPECT_NE(status["error"].get<std::string>().find("raise it (not retried)"), std::string::npos) << status.dump();
    EXPECT_EQ(status["attempts"], 1) << status.dump();
    EXPECT_EQ(engine.runs(), 1);
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

// Issue #36: a cancel SIGKILLed the worker, and the job's newest snapshot
// stayed the last one its schedule took (pass 47 of a bake cancelled at
// pass 90). Now the worker gets SIGTERM and a grace to write one last
// snapshot, which becomes the job's `latest`; the job's status and its
// final event carry no ETA (a cancelled job kept its last one).
TEST_F(ServerTest, ACancelledJobsNewestSnapshotIsWhereItWasCancelledAndItHasNoEta) {
    engine.set("mode", "snapshot_on_term");
    engine.set("delay", "0.02");
    start();
    const std::string id = submit(upload(), {{"passes", 100000}});
    auto c = client();
    const json mid = wait_for_job(c, id, [](const json& s) { return s["progress"].value("pass", 0) >= 12; });
    ASSERT_EQ(mid["state"], "running");
    EXPECT_FALSE(mid["progress"]["eta_seconds"].is_null()) << "a running job has an ETA";
    auto r = c.Post("/v1/jobs/" + id + "/cancel", "", "application/json");
    ASSERT_EQ(r->status, 200) << r->body;
    const json at_cancel = json::parse(r->body);
    EXPECT_TRUE(at_cancel["progress"]["eta_seconds"].is_null()) << at_cancel.dump();
    const int cancelled_at = at_cancel["progress"]["pass"];
    const json status = wait_for_job(
        c, id, [&](const json& s) { return s["latest"]["lightmap"].value("pass", 0) >= cancelled_at; },
        std::chrono::seconds(15));
    EXPECT_EQ(status["state"], "cancelled");
    EXPECT_GE(status["latest"]["lightmap"].value("pass", 0), cancelled_at)
        << "the newest snapshot is not where the bake stood: " << status.dump();
    EXPECT_GE(cancelled_at, 12);
    EXPECT_EQ(status["latest"]["lightmap"].value("file", ""),
              protocol::snapshot_file_name("lightmap", status["latest"]["lightmap"]["pass"], "exr"));
    EXPECT_TRUE(fs::exists(tmp.path / "data" / "jobs" / id / status["latest"]["lightmap"].value("file", "")));
    EXPECT_EQ(status["progress"]["pass"], status["latest"]["lightmap"]["pass"]) << status.dump();
    EXPECT_TRUE(status["progress"]["eta_seconds"].is_null()) << status.dump();
    // The events: progress with an ETA while it ran; the cancelled event
    // last, with no ETA, and nothing after it.
    const std::vector<protocol::JobEvent> all = events(id);
    ASSERT_FALSE(all.empty());
    EXPECT_EQ(all.back().type, "cancelled");
    EXPECT_FALSE(all.back().data.contains("eta_seconds")) << all.back().data.dump();
    EXPECT_FALSE(all.back().data.value("progress", json::object()).contains("eta_seconds"));
    const bool any_eta = std::any_of(all.begin(), all.end(), [](const protocol::JobEvent& e) {
        return e.type == "progress" && e.data.contains("eta_seconds") && !e.data["eta_seconds"].is_null();
    });
    EXPECT_TRUE(any_eta);
    // And the job list says the same.
    auto list = c.Get("/v1/jobs");
    ASSERT_EQ(list->status, 200);
    const json jobs = json::parse(list->body);  // held: a range over a temporary's member would dangle
    for (const json& j : jobs["jobs"]) {
        if (j["id"] == id) {
            EXPECT_TRUE(j["progress"]["eta_seconds"].is_null()) << j.dump();
        }
    }
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

// A store that lost some records while keeping others (a SQLite WAL lost
// after a checkpoint: the newest jobs' rows gone, their directories still in
// DATA/jobs). Their ids are not silent 404s (issue #33: a log line was all):
// GET answers 410 saying the record was lost, /healthz and /metrics count
// them; the jobs the store kept answer as before.
TEST_F(ServerTest, JobsWhoseRecordsTheStoreLostAreReportedNotSilent404s) {
    start();
    const std::string scene = upload();
    const std::string kept = submit(scene, {{"passes", 2}}, 1);
    ASSERT_EQ(wait_finished(kept)["state"], "succeeded");
    server->stop();
    const std::string lost = "0123456789abcdef01234567";
    fs::create_directories(tmp.path / "data" / "jobs" / lost);
    write_text(tmp.path / "data" / "jobs" / lost / "manifest.json", "{}");
    server->start();
    auto c = client();
    const auto gone = c.Get("/v1/jobs/" + lost);
    ASSERT_TRUE(gone);
    EXPECT_EQ(gone->status, 410) << gone->body;
    EXPECT_EQ(json::parse(gone->body)["record_lost"], true) << gone->body;
    EXPECT_NE(gone->body.find("lost its record"), std::string::npos) << gone->body;
    EXPECT_EQ(gone->body.find(tmp.path.string()), std::string::npos) << "no server path in an answer";
    EXPECT_EQ(c.Get("/v1/jobs/" + kept)->status, 200);
    EXPECT_EQ(c.Get("/v1/jobs/ffffffffffffffffffffffff")->status, 404) << "an id never seen is still a 404";
    EXPECT_EQ(json::parse(c.Get("/healthz")->body)["jobs_without_records"], 1);
    EXPECT_NE(c.Get("/metrics")->body.find("lightfarm_jobs_without_records 1"), std::string::npos);
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
    // One payload, whoever finished the job: the same fields, the same files.
    const json baked = events(first).back().data, cached = events(second).back().data;
    for (auto it = baked.begin(); it != baked.end(); ++it)
        EXPECT_TRUE(cached.contains(it.key())) << it.key() << " missing from the cached job's done event";
    EXPECT_EQ(baked["cached"], false);
    EXPECT_EQ(cached["cached"], true);
    EXPECT_EQ(cached["cached_from"], first);
    EXPECT_EQ(baked["final"], cached["final"]);

    // Another seed is another bake.
    const std::string third = submit(scene, {{"passes", 2}}, 6);
    EXPECT_EQ(wait_finished(third)["cached"], false);
    EXPECT_EQ(engine.runs(), runs + 1);
}

// The status page's data block for the caller's jobs (web/ui/status.html),
// which lightfarmd fills in and status.js reads.
const std::string kInitialJobs = R"(<script type="application/json" id="initial-jobs">)";

// The jobs a status page came with, parsed as status.js parses them.
json initial_jobs(const std::string& page) {
    const size_t start = page.find(kInitialJobs);
    if (start == std::string::npos) return "no " + kInitialJobs + " in the page";
    const size_t from = start + kInitialJobs.size();
    return json::parse(page.substr(from, page.find("</script>", from) - from));
}

TEST_F(ServerTest, MetricsAndTheStatusPage) {
    start();
    const std::string id = submit(upload());
    wait_finished(id);
    auto c = client();
    const std::string metrics = c.Get("/metrics")->body;
    for (const char* name : {"lightfarm_jobs{state=\"succeeded\"} 1", "lightfarm_queue_depth 0",
                             "lightfarm_worker_starts_total 1", "lightfarm_rays_total 4000",
                             "lightfarm_rays_per_second", "lightfarm_http_request_seconds_bucket{route=\"/v1/jobs\""})
        EXPECT_NE(metrics.find(name), std::string::npos) << name << "\n" << metrics;

    auto page = c.Get("/");
    ASSERT_EQ(page->status, 200);
    EXPECT_NE(page->body.find("<script src=\"/ui/status.js\">"), std::string::npos);
    EXPECT_EQ(page->body.find("http://"), std::string::npos);  // nothing fetched from elsewhere
    EXPECT_EQ(page->body.find("https://"), std::string::npos);
    // The jobs come with the page (no blank first second), with what a
    // person recognises: the scene's name and size, the times.
    const json initial = initial_jobs(page->body);
    ASSERT_TRUE(initial.contains("jobs")) << initial.dump();
    ASSERT_EQ(initial["jobs"].size(), 1u) << initial.dump();
    EXPECT_EQ(initial["jobs"][0]["id"], id);
    const json listed = json::parse(c.Get("/v1/jobs")->body)["jobs"][0];
    EXPECT_FALSE(listed.value("scene_name", "").empty()) << listed.dump();
    EXPECT_TRUE(listed.contains("scene_triangles"));
    EXPECT_GT(listed["finished_at"].get<double>(), 0.0);

    // A browser trades ?token= for a cookie; the cookie reads, never writes.
    httplib::Client browser(server->host, server->port);
    auto login = browser.Get("/?token=" + kAlice);
    EXPECT_EQ(login->status, 303);
    const std::string cookie = login->get_header_value("Set-Cookie");
    EXPECT_NE(cookie.find("HttpOnly"), std::string::npos);
    const httplib::Headers with_cookie = {{"Cookie", cookie.substr(0, cookie.find(';'))}};
    EXPECT_EQ(browser.Get("/v1/jobs", with_cookie)->status, 200);
    EXPECT_EQ(browser.Post("/v1/jobs/" + id + "/cancel", with_cookie, "", "application/json")->status, 401);

    // Login CSRF (issue #55): a link on another site to /?token=ATTACKER
    // must not replace a person's cookie; the address bar and this
    // server's own pages may sign in.
    const std::string self = "http://" + server->host + ":" + std::to_string(server->port);
    const std::vector<std::pair<httplib::Headers, int>> cases = {{{{"Sec-Fetch-Site", "cross-site"}}, 403},
                                                                 {{{"Sec-Fetch-Site", "same-site"}}, 403},
                                                                 {{{"Referer", "https://evil.example/page"}}, 403},
                                                                 {{{"Origin", "https://evil.example"}}, 403},
                                                                 {{{"Sec-Fetch-Site", "none"}}, 303},
                                                                 {{{"Sec-Fetch-Site", "same-origin"}}, 303},
                                                                 {{{"Referer", self + "/"}}, 303},
                                                                 {{}, 303}};
    for (const auto& [headers, status] : cases) {
        auto r = browser.Get("/?token=" + kAlice, headers);
        ASSERT_TRUE(r);
        const std::string said =
            headers.empty() ? "no header" : headers.begin()->first + ": " + headers.begin()->second;
        EXPECT_EQ(r->status, status) << said;
        EXPECT_EQ(r->has_header("Set-Cookie"), status == 303);
    }
}

// The page's three.js is behind the API's rules (a token or the page's
// cookie), and when it is missing the answer names no server path.
TEST_F(ServerTest, TheViewersLibraryNeedsATokenAndNamesNoPath) {
    const fs::path web = tmp.path / "empty-web";
    fs::create_directories(web);
    start({"--web-dir", web.string()});
    httplib::Client anonymous(server->host, server->port);
    EXPECT_EQ(anonymous.Get("/ui/three/build/three.module.js")->status, 401);
    auto r = client().Get("/ui/three/build/three.module.js");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 404);
    EXPECT_NE(r->body.find("three.js is not installed"), std::string::npos) << r->body;
    EXPECT_EQ(r->body.find(tmp.path.string()), std::string::npos) << "no server path: " << r->body;
}

// The status page is markup; its styles and scripts are web/ui's files,
// served byte for byte from the copy in lightfarmd, with their types, to a
// token or the page's cookie.
TEST_F(ServerTest, TheStatusPagesStylesAndScriptsAreWebUisFiles) {
    start();
    const std::string page = client().Get("/")->body;
    for (const char* tag : {R"(<link rel="stylesheet" href="/ui/status.css">)", R"(<script src="/ui/status.js">)",
                            R"(<script type="module" src="/ui/status-view3d.js">)"}) {
        EXPECT_NE(page.find(tag), std::string::npos) << tag << " in\n" << page;
    }
    // No styles or scripts inline: only three.js's import map and the jobs' data block.
    EXPECT_EQ(page.find("<style"), std::string::npos);
    EXPECT_EQ(page.find(" style="), std::string::npos);
    for (size_t at = page.find("<script"); at != std::string::npos; at = page.find("<script", at + 1)) {
        const std::string tag = page.substr(at, page.find('>', at) - at + 1);
        const bool allowed = tag.find(" src=") != std::string::npos || tag == R"(<script type="importmap">)" ||
                             tag == R"(<script type="application/json" id="initial-jobs">)";
        EXPECT_TRUE(allowed) << "an inline script: " << tag;
    }

    httplib::Client browser(server->host, server->port);
    const std::string cookie = browser.Get("/?token=" + kAlice)->get_header_value("Set-Cookie");
    const httplib::Headers with_cookie = {{"Cookie", cookie.substr(0, cookie.find(';'))}};
    const std::map<std::string, std::string> types = {{"status.css", "text/css; charset=utf-8"},
                                                      {"status.js", "text/javascript; charset=utf-8"},
                                                      {"status-view3d.js", "text/javascript; charset=utf-8"}};
    for (const auto& [name, type] : types) {
        const std::string source = read_text(fs::path(LIGHTFARM_WEB_DIR) / "ui" / name);
        ASSERT_FALSE(source.empty()) << name;
        const auto expect_the_file = [&](const httplib::Result& r, const std::string& who) {
            ASSERT_TRUE(r) << name << " for " << who;
            EXPECT_EQ(r->status, 200) << name << " for " << who << ": " << r->body;
            EXPECT_EQ(r->get_header_value("Content-Type"), type) << name;
            EXPECT_EQ(r->get_header_value("Cache-Control"), "no-cache") << name;
            EXPECT_EQ(r->get_header_value("X-Content-Type-Options"), "nosniff") << name;
            EXPECT_TRUE(r->body == source) << name << " for " << who << " is not web/ui/" << name << " byte for byte";
        };
        expect_the_file(client().Get("/ui/" + name), "the token");
        expect_the_file(browser.Get("/ui/" + name, with_cookie), "the page's cookie");
        auto anonymous = browser.Get("/ui/" + name);
        ASSERT_TRUE(anonymous);
        EXPECT_EQ(anonymous->status, 401) << name;
    }
}

// /ui/{file} serves the page's styles and scripts and nothing else: not the
// pages (/ has the one with the caller's jobs), not a name outside web/ui.
TEST_F(ServerTest, OnlyThePagesStylesAndScriptsAreServedUnderUi) {
    start();
    for (const char* path : {"/ui/nothing.js", "/ui/status.html", "/ui/login.html", "/ui/three", "/ui/STATUS.JS",
                             "/ui/.css", "/ui/status.js.map"}) {
        auto r = client().Get(path);
        ASSERT_TRUE(r) << path;
        EXPECT_EQ(r->status, 404) << path << ": " << r->body;
        const std::string error = json::parse(r->body).value("error", "");
        EXPECT_NE(error.find("no such file of the status page"), std::string::npos) << path << ": " << r->body;
        EXPECT_NE(error.find("status.css, status.js"), std::string::npos) << "names what there is: " << error;
    }
    // `..` and `/` (sent as they are, or %-encoded) reach no file of web/ui's
    // folder or above it.
    for (const char* path :
         {"/ui/..", "/ui/%2e%2e", "/ui/../CMakeLists.txt", "/ui/..%2fCMakeLists.txt", "/ui/%2e%2e%2fpackage.json",
          "/ui/..%2f..%2fREADME.md", "/ui/ui%2fstatus.js", "/ui//status.js", "/ui/./status.js", "/ui/"}) {
        auto r = client().Get(path);
        ASSERT_TRUE(r) << path;
        EXPECT_EQ(r->status, 404) << path << ": " << r->body;
    }
}

// The jobs inlined in the status page cannot end its script or open a
// comment, whatever a name holds; every answer says how it may be shown.
TEST(StatusPage, InlinedJsonCannotEndTheScriptOrOpenAComment) {
    const json hostile = {{"name", "<!--<script>.gltf"}, {"x", "</script><b>&amp;"}, {"lines", "a\u2028b\u2029c"}};
    const std::string text = server::json_for_script(hostile);
    for (const char* bad : {"<", ">", "&", "\u2028", "\u2029"}) EXPECT_EQ(text.find(bad), std::string::npos) << bad;
    EXPECT_EQ(json::parse(text), hostile) << "the same value";
}

TEST_F(ServerTest, AHostileSceneNameLeavesTheStatusPageWhole) {
    start();
    const std::string gltf = "{\"asset\": {\"version\": \"2.0\"}}";
    httplib::MultipartFormDataItems items = {{"scene", gltf, "<!--<script>.gltf", "model/gltf+json"}};
    auto up = client().Post("/v1/scenes", items);
    ASSERT_TRUE(up);
    ASSERT_TRUE(up->status == 201 || up->status == 200) << up->body;
    const std::string id = submit(json::parse(up->body)["id"]);
    wait_finished(id);
    auto page = client().Get("/");
    ASSERT_EQ(page->status, 200);
    const size_t embedded = page->body.find(kInitialJobs);
    ASSERT_NE(embedded, std::string::npos);
    EXPECT_EQ(page->body.find("<!--<script>", embedded), std::string::npos) << "the name is escaped";
    EXPECT_NE(page->body.find("\\u003c!--\\u003cscript\\u003e.gltf", embedded), std::string::npos);
    EXPECT_EQ(initial_jobs(page->body)["jobs"][0]["scene_name"], "<!--<script>.gltf") << "and reads back whole";
    for (const char* header : {"Content-Security-Policy", "X-Frame-Options", "X-Content-Type-Options"}) {
        EXPECT_FALSE(page->get_header_value(header).empty()) << header;
        EXPECT_FALSE(client().Get("/v1/jobs")->get_header_value(header).empty()) << header;
    }
    EXPECT_EQ(page->get_header_value("X-Content-Type-Options"), "nosniff");
    // No inline script or style runs: the page's one inline script, its
    // import map, by its hash alone (the Chromium test loads the page under
    // this policy and fails on any violation).
    const std::string policy = page->get_header_value("Content-Security-Policy");
    EXPECT_EQ(policy.find("unsafe-inline"), std::string::npos) << policy;
    const std::string open = "<script type=\"importmap\">";
    const size_t from = page->body.find(open), to = page->body.find("</script>", from);
    ASSERT_NE(from, std::string::npos);
    const std::string import_map = page->body.substr(from + open.size(), to - from - open.size());
    EXPECT_NE(policy.find("script-src 'self' 'sha256-" + server::sha256_base64(import_map) + "'"), std::string::npos)
        << policy;
    EXPECT_NE(policy.find("style-src 'self';"), std::string::npos) << policy;
}

// ---- What the scene or the settings make impossible is a 400 at submit, naming the field.

TEST_F(ServerTest, EdgeValuesAreRefusedAtSubmitNamingTheField) {
    start();
    const std::string scene = upload();
    auto expect_400 = [&](json spec, const std::string& field) {
        spec["scene"] = scene;
        auto r = post_job(spec);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 400) << spec.dump() << ": " << r->body;
        const json body = json::parse(r->body);
        EXPECT_EQ(body.value("field", ""), field) << spec.dump() << ": " << r->body;
        EXPECT_EQ(body.value("error", "").rfind(field + ": ", 0), 0u) << r->body;
    };
    expect_400({{"outputs", {{"sh", {{"sh_bands", 0}}}}}}, "sh.sh_bands");
    expect_400({{"outputs", {{"sh", {{"sh_bands", 9}}}}}}, "sh.sh_bands");
    expect_400({{"outputs", {{"sh", {{"sh_bounces", 7}}}}}}, "sh.sh_bounces");
    expect_400({{"outputs", {{"lightmap", json::object()}}}, {"seed", 4294967296ull}}, "seed");
    expect_400({{"outputs", {{"lightmap", json::object()}}}, {"seed", -1}}, "seed");
    // The service reads no file a job names: an environment is a uniform sky.
    expect_400({{"outputs", {{"sh", json::object()}}}, {"env", "sky.exr"}}, "env");
    expect_400({{"outputs", {{"sh", json::object()}}}, {"env", "/etc/passwd"}}, "env");
    expect_400({{"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"res", 0}}}}, "atlas.res");
    // The values next to them are accepted ("auto" is a value of its own).
    for (const json& bake : {json{{"outputs", {{"sh", {{"sh_bands", "auto"}}}}}},
                             json{{"outputs", {{"sh", {{"sh_bands", 4}, {"sh_bounces", 4}}}}}, {"seed", 4294967295ull}},
                             json{{"outputs", {{"sh", json::object()}}}, {"env", {0.5, 0.6, 0.8}}}}) {
        json spec = bake;
        spec["scene"] = scene;
        auto r = post_job(spec);
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 201) << spec.dump() << ": " << r->body;
    }
}

TEST_F(ServerTest, ASceneWithoutLightNeedsAnEnvironment) {
    engine.set("summary", R"({"source": "dark.glb", "triangles": 12, "emissive_triangles": 0,
                             "punctual_light_count": 0, "has_lightmap_uvs": true, "min_atlas_res": 0})");
    start();
    const std::string scene = upload();
    auto r = post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 400) << r->body;
    const json body = json::parse(r->body);
    EXPECT_EQ(body["field"], "env");
    const std::string error = body["error"];
    EXPECT_NE(error.find("scene.glb"), std::string::npos) << error;           // the file as uploaded
    EXPECT_NE(error.find("\"env\": [R, G, B]"), std::string::npos) << error;  // and the fix
    EXPECT_EQ(error.find(tmp.path.string()), std::string::npos) << error;
    EXPECT_EQ(engine.runs(), 0);
    // With a sky it bakes; SH transfer needs no light at all.
    EXPECT_EQ(post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"env", {1, 1, 1}}})->status,
              201);
    EXPECT_EQ(post_job({{"scene", scene}, {"outputs", {{"sh", json::object()}}}})->status, 201);
}

TEST_F(ServerTest, AnAtlasThatCannotFitIsRefusedWithTheSmallestThatDoes) {
    engine.set("summary", R"({"source": "stairs.glb", "triangles": 12, "emissive_triangles": 2,
                             "punctual_light_count": 0, "has_lightmap_uvs": false, "min_atlas_res": 300})");
    start();
    const std::string scene = upload();
    auto r = post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"res", 256}}}});
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 400) << r->body;
    const json body = json::parse(r->body);
    EXPECT_EQ(body["field"], "atlas.res");
    EXPECT_NE(body["error"].get<std::string>().find("300"), std::string::npos) << r->body;
    EXPECT_EQ(engine.runs(), 0);
    EXPECT_EQ(
        post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"res", 300}}}})->status,
        201);
    EXPECT_EQ(post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"seed", 2}})->status,
              201);  // res auto
}

// Every mistake the stored summary can answer is a 400 at submit naming the
// field, not a job that the worker fails three times (each case below was
// accepted, then failed by the worker, before): a probe grid or a capture
// over the limits, mesh indices the scene does not draw, a max_res below
// the smallest atlas, a deadline no worker can meet, an unbounded list. One
// step inside each edge is accepted.
TEST_F(ServerTest, EveryKnowableMistakeIsA400AtSubmitNamingTheField) {
    engine.set("summary", R"({"source": "stairs.glb", "triangles": 12, "emissive_triangles": 2,
                             "punctual_light_count": 0, "has_lightmap_uvs": false, "min_atlas_res": 286,
                             "meshes": 4, "probe_nodes": 0, "bounds": {"lo": [0, 0, 0], "hi": [1, 1, 1]}})");
    start();
    const std::string scene = upload();
    json points = json::array();
    for (int k = 0; k < 100; ++k) points.push_back({{"position", {0.01 * k, 0.5, 0.5}}});
    const std::vector<std::tuple<json, std::string, std::string>> refused = {
        {{{"probes", {{"probe_spacing", 0.001}}}}, "probes.probe_spacing", "1000000000 probes"},
        {{{"probes", {{"probe_positions", points}, {"probe_res", 256}}}}, "probes.probe_res", "lower probe_res"},
        {{{"sh", {{"sh_occluders", {99}}}}}, "sh.sh_occluders", "mesh 99 is not drawn"},
        {{{"sh", {{"sh_receivers", {4}}}}}, "sh.sh_receivers", "0 to 3"},
        {{{"sh", {{"sh_receivers", json(std::vector<int>(70000, 0))}}}}, "sh.sh_receivers", "maximum 65536"},
    };
    for (const auto& [outputs, field, words] : refused) {
        auto r = post_job({{"scene", scene}, {"outputs", outputs}});
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 400) << r->body;
        EXPECT_EQ(json::parse(r->body)["field"], field) << r->body;
        EXPECT_NE(r->body.find(words), std::string::npos) << r->body;
    }
    auto low = post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"max_res", 256}}}});
    EXPECT_EQ(low->status, 400) << low->body;
    EXPECT_EQ(json::parse(low->body)["field"], "atlas.max_res");
    EXPECT_NE(low->body.find("286"), std::string::npos) << low->body;
    auto unscaled = post_job(
        {{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"mesh_scale", {{"4", 2}}}}}});
    EXPECT_EQ(unscaled->status, 400) << unscaled->body;
    EXPECT_EQ(json::parse(unscaled->body)["field"], "atlas.mesh_scale");
    EXPECT_NE(unscaled->body.find("mesh 4 is not drawn"), std::string::npos) << unscaled->body;
    // Every mesh at scale 0: no texel to bake (issue #55: the worker failed after preparing).
    auto nothing = post_job({{"scene", scene},
                             {"outputs", {{"lightmap", json::object()}}},
                             {"atlas", {{"mesh_scale", {{"0", 0}, {"1", 0}, {"2", 0}, {"3", 0}}}}}});
    EXPECT_EQ(nothing->status, 400) << nothing->body;
    EXPECT_EQ(json::parse(nothing->body)["field"], "atlas.mesh_scale");
    EXPECT_NE(nothing->body.find("no texel is left"), std::string::npos) << nothing->body;
    auto instant =
        post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"limits", {{"max_seconds", 1e-9}}}});
    EXPECT_EQ(instant->status, 400) << instant->body;
    EXPECT_EQ(json::parse(instant->body)["field"], "limits.max_seconds");
    auto huge = client().Post("/v1/jobs", std::string(2 << 20, ' '), "application/json");
    ASSERT_TRUE(huge);
    EXPECT_EQ(huge->status, 413) << huge->body;
    EXPECT_EQ(json::parse(huge->body)["field"], "spec_bytes");
    EXPECT_EQ(engine.runs(), 0);

    // One step inside each edge.
    json many = json::array();
    for (int k = 0; k < 2; ++k) many.push_back({{"position", {0.5, 0.5, 0.01 * k}}});
    for (const json& outputs : {json{{"probes", {{"probe_spacing", 1.0 / 16}}}},
                                json{{"probes", {{"probe_positions", many}, {"probe_res", 256}}}},
                                json{{"sh", {{"sh_occluders", {3}}, {"sh_receivers", {0, 1, 2, 3}}}}}}) {
        auto r = post_job({{"scene", scene}, {"outputs", outputs}});
        ASSERT_TRUE(r);
        EXPECT_EQ(r->status, 201) << outputs.dump() << ": " << r->body;
    }
    EXPECT_EQ(post_job({{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"max_res", 286}}}})
                  ->status,
              201);
    EXPECT_EQ(
        post_job(
            {{"scene", scene}, {"outputs", {{"lightmap", json::object()}}}, {"atlas", {{"mesh_scale", {{"3", 2}}}}}})
            ->status,
        201);
    auto one_left = post_job({{"scene", scene},
                              {"outputs", {{"lightmap", json::object()}}},
                              {"atlas", {{"mesh_scale", {{"0", 0}, {"1", 0}, {"2", 0}}}}}});
    EXPECT_EQ(one_left->status, 201) << "one mesh keeps its texels: " << one_left->body;
}

// ---- Supervision: input errors, deadlines, stored specs, the newest snapshot.

TEST_F(ServerTest, AnInputErrorFailsTheJobAtOnceNamingTheUsersFile) {
    engine.set("mode", "input_error");
    start({"--attempts", "3"});
    const std::string id = submit(upload());
    const json status = wait_finished(id);
    EXPECT_EQ(status["state"], "failed") << status.dump();
    EXPECT_EQ(status["attempts"], 1);
    EXPECT_EQ(engine.runs(), 1) << "an input error costs one worker run, not three";
    const std::string cause = status["cause"];
    EXPECT_NE(cause.find("scene.glb: nothing to bake"), std::string::npos) << cause;
    EXPECT_EQ(cause.find((tmp.path / "data").string()), std::string::npos) << cause;
    EXPECT_EQ(cause.find("/scenes/"), std::string::npos) << cause;
    const auto all = events(id);
    ASSERT_FALSE(all.empty());
    EXPECT_EQ(all.back().type, "failed");
    for (const auto& e : all) EXPECT_NE(e.type, "retrying");
}

TEST_F(ServerTest, TheDeadlineHoldsWhileTheWorkerPrintsEveryPass) {
    engine.set("delay", "0.05");  // a progress line every ~50 ms, for 1200 passes (a minute)
    start();
    const std::string scene = upload();
    const auto t0 = std::chrono::steady_clock::now();
    const std::string id = submit(scene, {{"passes", 1200}}, 1, kAlice, {{"max_seconds", 4}, {"max_attempts", 1}});
    const json status = wait_finished(id, std::chrono::seconds(15));
    const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(status["state"], "failed") << status.dump();
    EXPECT_NE(status.value("cause", "").find("deadline of 4 s"), std::string::npos) << status.dump();
    EXPECT_GT(status["progress"]["pass"].get<int>(), 10) << "the worker was printing";
    EXPECT_GE(took, 3.9);
    EXPECT_LE(took, 7.0) << "the job ended " << took << " s after submit, its deadline was 4 s";
}

TEST_F(ServerTest, AQueuedJobStillRunsAfterARestartWithALowerLimit) {
    engine.set("mode", "hang_always");
    start({"--workers", "1"});
    const std::string scene = upload();
    const std::string blocker = submit(scene, {{"passes", 1}}, 1);
    auto c = client();
    wait_for_job(c, blocker, [](const json& s) { return s["state"] == "running"; });
    const std::string queued = submit(scene, {{"passes", 50}}, 2);
    server->stop();

    engine.set("mode", "ok");
    server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script,
                                          std::vector<std::string>{"--workers", "1", "--limit", "passes=10"});
    server->start();
    const json status = wait_finished(queued);
    EXPECT_EQ(status["state"], "succeeded") << "validated at submit, under the limits of that day: " << status.dump();
    EXPECT_EQ(status["progress"]["pass"], 50);
    EXPECT_EQ(wait_finished(blocker)["state"], "succeeded");
    // A new job meets the new limit.
    auto r = post_job({{"scene", scene}, {"outputs", {{"lightmap", {{"passes", 50}}}}}, {"seed", 3}});
    EXPECT_EQ(r->status, 400);
    EXPECT_EQ(json::parse(r->body)["field"], "lightmap.passes") << r->body;
}

TEST_F(ServerTest, TheNewestSnapshotComesFromTheEventsNotFromNames) {
    // pass-16384 sorts before pass-2048, and an SH snapshot after both.
    engine.set("snapshot_passes", "2048 16384");
    engine.set("mode", "no_done");
    start();
    const std::string scene = upload();
    json spec = {{"scene", scene},
                 {"outputs", {{"lightmap", json::object()}, {"sh", json::object()}}},
                 {"limits", {{"max_attempts", 1}}}};
    auto r = post_job(spec);
    ASSERT_EQ(r->status, 201) << r->body;
    const std::string id = json::parse(r->body)["id"];
    json status = wait_finished(id);
    EXPECT_EQ(status["state"], "failed");  // no done: the snapshots are all there is
    EXPECT_EQ(status["latest"]["lightmap"],
              json({{"file", "lightmap.pass-16384.exr"}, {"pass", 16384}, {"final", false}}));
    EXPECT_EQ(status["latest"]["sh"]["file"], "sh_transfer.pass-0001.bin");
    auto png = client().Get("/v1/jobs/" + id + "/preview.png");
    ASSERT_EQ(png->status, 200) << png->body;
    EXPECT_EQ(png->get_header_value("X-Lightfarm-Source"), "lightmap.pass-16384.exr");

    // Once done, each output's newest file is its final one.
    engine.set("mode", "ok");
    spec["seed"] = 2;
    r = post_job(spec);
    ASSERT_EQ(r->status, 201) << r->body;
    const std::string done = json::parse(r->body)["id"];
    status = wait_finished(done);
    EXPECT_EQ(status["state"], "succeeded") << status.dump();
    EXPECT_EQ(status["latest"]["lightmap"], json({{"file", "lightmap.exr"}, {"pass", 16384}, {"final", true}}));
    EXPECT_EQ(status["latest"]["sh"], json({{"file", "scene.sh.glb"}, {"pass", 1}, {"final", true}}));
    png = client().Get("/v1/jobs/" + done + "/preview.png");
    EXPECT_EQ(png->get_header_value("X-Lightfarm-Source"), "lightmap.exr");

    // A cached copy of that bake has the same newest files.
    r = post_job(spec);
    ASSERT_EQ(r->status, 201);
    EXPECT_EQ(json::parse(r->body)["cached"], true);
    const json cached = wait_finished(json::parse(r->body)["id"]);
    EXPECT_EQ(cached["latest"], status["latest"]);
}

// ---- queued_start_estimate: when a queued job starts (issue #54).

// Slots free as their jobs end (an ETA, or a typical job's time for one
// without), the jobs ahead each take the first slot free for a typical
// job's time; unknown only where a typical job must be priced and none
// finished. Against a brute-force schedule over drawn farms.
TEST(QueuedStartEstimate, TheFirstSlotFreeAfterTheJobsAhead) {
    using server::queued_start_estimate;
    EXPECT_EQ(queued_start_estimate(0, 2, {}, std::nullopt), 0.0) << "a free worker: at once";
    EXPECT_EQ(queued_start_estimate(0, 1, {30.0}, std::nullopt), 30.0) << "when the running job ends";
    EXPECT_EQ(queued_start_estimate(0, 1, {std::nullopt}, std::nullopt), std::nullopt);
    EXPECT_EQ(queued_start_estimate(0, 1, {std::nullopt}, 50.0), 50.0);
    EXPECT_EQ(queued_start_estimate(1, 2, {10.0, 40.0}, 100.0), 40.0) << "the one ahead takes the slot free at 10";
    EXPECT_EQ(queued_start_estimate(2, 2, {10.0, 40.0}, 100.0), 110.0);
    EXPECT_EQ(queued_start_estimate(1, 1, {5.0}, std::nullopt), std::nullopt) << "nothing prices the one ahead";
    EXPECT_EQ(queued_start_estimate(0, 0, {}, std::nullopt), 0.0) << "no worker known: the next to come";
    std::mt19937 rng(54);
    std::printf("  seed 54\n");
    for (int trial = 0; trial < 200; ++trial) {
        const int slots = 1 + int(rng() % 6), running = int(rng() % (slots + 1)), ahead = int(rng() % 12);
        const double typical = 1.0 + double(rng() % 1000);
        std::vector<std::optional<double>> left;
        std::vector<double> free_at(size_t(slots), 0.0);
        for (int r = 0; r < running; ++r) {
            left.push_back(rng() % 4 ? std::optional<double>(double(rng() % 500)) : std::nullopt);
            free_at[size_t(r)] = left.back().value_or(typical);
        }
        for (int k = 0; k <= ahead; ++k) {  // the jobs ahead, then this one
            const auto first = std::min_element(free_at.begin(), free_at.end());
            if (k == ahead) {
                EXPECT_DOUBLE_EQ(*queued_start_estimate(ahead, slots, left, typical), *first);
            }
            *first += typical;
        }
    }
    EXPECT_EQ(server::typical_job_seconds({}), std::nullopt);
    EXPECT_EQ(server::typical_job_seconds({30.0, 10.0, 20.0}), 20.0);
}

// ---- apply_worker_event: one event in, what to store out. No process, no store.

protocol::BakeSettings lightmap_and_sh() {
    return protocol::parse_bake_settings(
        {{"outputs", {{"lightmap", {{"passes", 100}}}, {"sh", {{"sh_passes", 10}, {"sh_time_limit", 5}}}}}});
}

TEST(ApplyWorkerEvent, StartBecomesAStartedEventOfTheAttempt) {
    protocol::StartEvent start;
    start.renderer = "llvmpipe";
    start.triangles = 36;
    const server::AttemptUpdate u = server::apply_worker_event({}, start, lightmap_and_sh(), "job1", 2);
    ASSERT_TRUE(u.event);
    EXPECT_EQ(u.event->type, "started");
    EXPECT_EQ(u.event->data["attempt"], 2);
    EXPECT_EQ(u.event->data["renderer"], "llvmpipe");
    EXPECT_FALSE(u.event->data.contains("event"));
    EXPECT_FALSE(u.progress);
    EXPECT_TRUE(u.latest.empty());
    EXPECT_TRUE(u.ignored.empty());
}

// Before the first pass the job's progress names the stage preparing and
// preparation's time left; the event stream gets a "preparing" event.
TEST(ApplyWorkerEvent, PrepareEventsSayTheStageAndPreparationsTimeLeft) {
    const server::AttemptUpdate u =
        server::apply_worker_event({}, protocol::PrepareEvent{"atlas", 1.5, 12.0}, lightmap_and_sh(), "job1", 1);
    ASSERT_TRUE(u.progress);
    EXPECT_EQ(u.progress->preparing, "atlas");
    EXPECT_DOUBLE_EQ(u.progress->prepare_seconds, 1.5);
    EXPECT_EQ(u.progress->prepare_eta_seconds, 12.0);
    EXPECT_FALSE(u.progress->eta_seconds) << "the job's own ETA waits for its first pass";
    ASSERT_TRUE(u.event);
    EXPECT_EQ(u.event->type, "preparing");
    EXPECT_EQ(u.event->data["stage"], "atlas");
    EXPECT_EQ(u.event->data["eta_seconds"], 12.0);
    EXPECT_FALSE(u.event->data.contains("event"));
    const json j = protocol::to_json(*u.progress);
    EXPECT_EQ(j["preparing"], "atlas");
    EXPECT_EQ(protocol::progress_from_json(j).preparing, "atlas");
    // Once passes run, the progress says nothing of preparing.
    protocol::ProgressEvent p{"lightmap", {}};
    p.progress.pass = 1;
    EXPECT_FALSE(protocol::to_json(*server::apply_worker_event(u.state, p, lightmap_and_sh(), "job1", 1).progress)
                     .contains("preparing"));
}

// A worker says its last line again while a stage or a pass runs long
// (gi/bake/event_heartbeat.h, "again": true): the stream gets each, marked
// so, and the store keeps only the newest of them.
TEST(ApplyWorkerEvent, ALineSaidAgainIsMarkedSo) {
    const auto bake = lightmap_and_sh();
    server::AttemptUpdate u = server::apply_worker_event({}, protocol::PrepareEvent{"methods", 1.0, 9.0}, bake, "j", 1);
    EXPECT_FALSE(u.event->data.contains(server::kAgain));
    u = server::apply_worker_event(u.state, protocol::PrepareEvent{"methods", 2.0, 8.0, true}, bake, "j", 1);
    EXPECT_EQ(u.event->data.value(server::kAgain, false), true);
    EXPECT_DOUBLE_EQ(u.progress->prepare_seconds, 2.0) << "its seconds count";
    u = server::apply_worker_event(u.state, protocol::StartEvent{}, bake, "j", 1);
    protocol::ProgressEvent p{"lightmap", {}};
    p.progress.pass = 16;
    p.progress.rays = 100;
    p.progress.seconds = 4.0;
    u = server::apply_worker_event(u.state, p, bake, "j", 1);
    EXPECT_FALSE(u.event->data.contains(server::kAgain));
    p.progress.seconds = 5.0;
    p.again = true;
    u = server::apply_worker_event(u.state, p, bake, "j", 1);
    EXPECT_EQ(u.event->data.value(server::kAgain, false), true);
    EXPECT_EQ(u.new_rays, 0u) << "nothing traced twice";
    EXPECT_DOUBLE_EQ(u.progress->seconds, 5.0);
}

// The job's done fraction counts its preparation: 8 s preparing and 2 s of
// passes with 2 s left is 10 of 12 s done, not 2 of 4.
TEST(ApplyWorkerEvent, TheDoneFractionIncludesPreparation) {
    const protocol::BakeSettings bake = protocol::parse_bake_settings({{"outputs", {{"lightmap", {{"passes", 20}}}}}});
    protocol::StartEvent start;
    start.prepare_seconds = 8.0;
    const server::AttemptUpdate started = server::apply_worker_event({}, start, bake, "job1", 1);
    protocol::ProgressEvent p{"lightmap", {}};
    p.progress.pass = 10;
    p.progress.seconds = 2.0;
    const server::AttemptUpdate u = server::apply_worker_event(started.state, p, bake, "job1", 1);
    ASSERT_TRUE(u.progress);
    EXPECT_DOUBLE_EQ(u.progress->prepare_seconds, 8.0);
    ASSERT_TRUE(protocol::done_fraction(*u.progress));
    EXPECT_DOUBLE_EQ(*protocol::done_fraction(*u.progress), 10.0 / 12.0);
    EXPECT_DOUBLE_EQ(protocol::to_json(*u.progress)["fraction"].get<double>(), 10.0 / 12.0);
    protocol::DoneEvent done;
    done.progress = p.progress;
    const server::AttemptUpdate finished = server::apply_worker_event(u.state, done, bake, "job1", 1);
    EXPECT_DOUBLE_EQ(*protocol::done_fraction(*finished.progress), 1.0);
    EXPECT_FALSE(protocol::done_fraction(protocol::Progress{})) << "no fraction claimed before the ETA is known";

    // A retry starts its passes again (or from its last snapshot), but the
    // job's bar stays where its last attempt left it (issue #54).
    server::AttemptState retry;
    retry.shown_fraction = 10.0 / 12.0;
    const server::AttemptUpdate again = server::apply_worker_event(retry, start, bake, "job1", 2);
    protocol::ProgressEvent first{"lightmap", {}};
    first.progress.pass = 1;
    first.progress.seconds = 0.2;
    const server::AttemptUpdate shown = server::apply_worker_event(again.state, first, bake, "job1", 2);
    EXPECT_DOUBLE_EQ(*protocol::done_fraction(*shown.progress), 10.0 / 12.0);
}

// Every output of the registry, alone and beside every other, gets its
// ETA from its own stop rule (a probes job showed 0% and no ETA until it
// ended: the server knew the lightmap's and SH's stop settings only), and
// beside others the job's ETA adds the passes of each output still to come.
TEST(ApplyWorkerEvent, EveryOutputGetsAnEtaFromItsOwnStopRule) {
    json all = json::object();
    protocol::StartEvent start;  // every output: 40 passes of 50 rays
    for (const protocol::OutputKind& o : protocol::output_registry()) {
        all[o.name] = {{o.stop_prefix + "passes", 40}};
        start.outputs[o.name] = {{"rays_per_pass", 50}};
    }
    all["probes"]["probe_positions"] = json::array({{{"position", {0, 0, 0}}}});
    const auto& registry = protocol::output_registry();
    for (size_t i = 0; i < registry.size(); ++i) {
        const protocol::OutputKind& o = registry[i];
        SCOPED_TRACE(o.name);
        ASSERT_TRUE(protocol::find_setting(o.name, o.stop_prefix + "passes")) << "its stop settings are in the catalog";
        const double to_come = double(registry.size() - 1 - i) * 40 * 0.1;  // 40 passes of 50 rays at 500 rays/s each
        for (const auto& [outputs, later] : {std::pair{json{{o.name, all[o.name]}}, 0.0}, std::pair{all, to_come}}) {
            const protocol::BakeSettings bake =
                protocol::parse_bake_settings({{"outputs", outputs}, {"env", {1, 1, 1}}});
            const server::AttemptUpdate started = server::apply_worker_event({}, start, bake, "job1", 1);
            protocol::ProgressEvent p{o.name, {}};
            p.progress.pass = 10;
            p.progress.rays = 1000;
            p.progress.seconds = 2.0;
            const server::AttemptUpdate u = server::apply_worker_event(started.state, p, bake, "job1", 1);
            ASSERT_TRUE(u.progress);
            ASSERT_TRUE(u.progress->eta_seconds);
            EXPECT_DOUBLE_EQ(*u.progress->eta_seconds, 0.2 * 30 + later);  // 30 passes of 0.2 s left, then the rest
            ASSERT_TRUE(protocol::done_fraction(*u.progress));
        }
    }
}

TEST(ApplyWorkerEvent, ProgressGetsTheEtaOfTheWholeJobAndCountsRaysPerOutput) {
    const protocol::BakeSettings bake = lightmap_and_sh();
    protocol::StartEvent start;
    start.outputs = {{"lightmap", {{"rays_per_pass", 100}}}, {"sh", {{"rays_per_pass", 100}}}};
    protocol::ProgressEvent p{"lightmap", {}};
    p.progress.pass = 10;
    p.progress.rays = 1000;
    p.progress.seconds = 2.0;
    server::AttemptUpdate u = server::apply_worker_event({}, p, bake, "job1", 1);
    ASSERT_TRUE(u.progress);
    EXPECT_FALSE(u.progress->eta_seconds) << "without the start event the SH passes to come have no price";
    u = server::apply_worker_event(server::apply_worker_event({}, start, bake, "job1", 1).state, p, bake, "job1", 1);
    ASSERT_TRUE(u.progress->eta_seconds);
    // 90 lightmap passes of 0.2 s left, then 10 SH passes of 100 rays at 500 rays/s.
    EXPECT_DOUBLE_EQ(*u.progress->eta_seconds, 0.2 * 90 + 10 * 0.2);
    EXPECT_EQ(u.new_rays, 1000u);
    ASSERT_TRUE(u.rays_per_second);
    EXPECT_DOUBLE_EQ(*u.rays_per_second, 500.0);
    ASSERT_TRUE(u.event);
    EXPECT_EQ(u.event->type, "progress");
    EXPECT_EQ(u.event->data["output"], "lightmap");
    EXPECT_EQ(u.event->data["pass"], 10);

    p.progress.pass = 20;
    p.progress.rays = 2500;
    p.progress.seconds = 4.0;
    u = server::apply_worker_event(u.state, p, bake, "job1", 1);
    EXPECT_EQ(u.new_rays, 1500u);

    // The SH output's own rules: 10 passes or 5 s, whichever first; its rays start at 0.
    protocol::ProgressEvent sh{"sh", {}};
    sh.progress.pass = 2;
    sh.progress.rays = 300;
    sh.progress.seconds = 4.0;
    u = server::apply_worker_event(u.state, sh, bake, "job1", 1);
    ASSERT_TRUE(u.progress->eta_seconds);
    EXPECT_DOUBLE_EQ(*u.progress->eta_seconds, 1.0);  // the time limit, before 8 passes of 2 s
    EXPECT_EQ(u.new_rays, 300u);
    EXPECT_EQ(u.state.passes.at("lightmap"), 20);
    EXPECT_EQ(u.state.passes.at("sh"), 2);

    // An output the job did not ask for gets no ETA.
    protocol::ProgressEvent probes{"probes", p.progress};
    EXPECT_FALSE(server::apply_worker_event(u.state, probes, bake, "job1", 1).progress->eta_seconds);
}

TEST(ApplyWorkerEvent, SnapshotsAreTheNewestFileOfTheirOutput) {
    const protocol::BakeSettings bake = lightmap_and_sh();
    server::AttemptUpdate u = server::apply_worker_event(
        {}, protocol::SnapshotEvent{"lightmap", "lightmap.pass-16384.exr", 16384}, bake, "j", 1);
    ASSERT_EQ(u.latest.size(), 1u);
    EXPECT_EQ(u.latest.at("lightmap").file, "lightmap.pass-16384.exr");
    EXPECT_EQ(u.latest.at("lightmap").pass, 16384);
    EXPECT_FALSE(u.latest.at("lightmap").final_file);
    ASSERT_TRUE(u.event);
    EXPECT_EQ(u.event->type, "snapshot");
    EXPECT_EQ(u.event->data["output"], "lightmap");
    EXPECT_EQ(u.event->data["url"], "/v1/jobs/j/artifacts/lightmap.pass-16384.exr");

    for (const std::string bad : {"../jobs.sqlite", "a/b.exr", ".worker.pid", ""}) {
        u = server::apply_worker_event({}, protocol::SnapshotEvent{"lightmap", bad, 1}, bake, "j", 1);
        EXPECT_FALSE(u.ignored.empty()) << bad;
        EXPECT_TRUE(u.latest.empty()) << bad;
        EXPECT_FALSE(u.event) << bad;
    }
    // Without an output name, the job's only output; with two, nothing to guess.
    const protocol::BakeSettings only_lightmap =
        protocol::parse_bake_settings({{"outputs", {{"lightmap", json::object()}}}});
    u = server::apply_worker_event({}, protocol::SnapshotEvent{"", "lightmap.pass-0001.exr", 1}, only_lightmap, "j", 1);
    EXPECT_EQ(u.latest.count("lightmap"), 1u);
    u = server::apply_worker_event({}, protocol::SnapshotEvent{"", "x.pass-0001.exr", 1}, bake, "j", 1);
    EXPECT_FALSE(u.ignored.empty());
}

TEST(ApplyWorkerEvent, DoneIsKeptForTheEndAndNamesTheFinalFiles) {
    const protocol::BakeSettings bake = lightmap_and_sh();
    server::AttemptState state;
    state.passes = {{"lightmap", 100}, {"sh", 7}};
    protocol::DoneEvent done;
    done.progress.pass = 7;
    done.progress.rays = 700;
    done.files = {"lightmap.exr", "scene.sh.glb", "manifest.json", "../evil"};
    done.final_files = {{"lightmap", "lightmap.exr"}, {"sh", "scene.sh.glb"}};
    const server::AttemptUpdate u = server::apply_worker_event(state, done, bake, "j", 1);
    EXPECT_FALSE(u.event) << "the final event is stored when the worker has exited";
    ASSERT_TRUE(u.state.done);
    EXPECT_EQ((*u.state.done)["files"], json({"lightmap.exr", "scene.sh.glb", "manifest.json"}));
    EXPECT_EQ((*u.state.done)["final"], json({{"lightmap", "lightmap.exr"}, {"sh", "scene.sh.glb"}}));
    ASSERT_EQ(u.latest.size(), 2u);
    EXPECT_EQ(u.latest.at("lightmap").file, "lightmap.exr");
    EXPECT_EQ(u.latest.at("lightmap").pass, 100);
    EXPECT_TRUE(u.latest.at("lightmap").final_file);
    EXPECT_EQ(u.latest.at("sh").pass, 7);
    ASSERT_TRUE(u.progress);
    EXPECT_EQ(u.progress->eta_seconds, 0.0);
}

TEST(UserFacing, TheServersPathsBecomeTheUploadedName) {
    const fs::path data = "/srv/lightfarm-data";
    const fs::path scene_dir = data / "scenes" / "68b3";
    const fs::path scene = scene_dir / "breakfast_room.gltf";
    const fs::path job = data / "jobs" / "abc";
    EXPECT_EQ(server::user_facing(scene.string() + ": nothing to bake: no light", scene, "breakfast_room.gltf",
                                  scene_dir, job, data),
              "breakfast_room.gltf: nothing to bake: no light");
    EXPECT_EQ(server::user_facing("cannot read " + (scene_dir / "textures/wall.png").string(), scene,
                                  "breakfast_room.gltf", scene_dir, job, data),
              "cannot read textures/wall.png");
    const std::string other =
        server::user_facing("cannot write " + (job / "lightmap.exr").string() + " in " + (data / "tmp").string(), scene,
                            "breakfast_room.gltf", scene_dir, job, data);
    EXPECT_EQ(other.find(data.string()), std::string::npos) << other;
    EXPECT_NE(other.find("lightmap.exr"), std::string::npos) << other;
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
    for (const auto& d : documented)
        EXPECT_TRUE(served.count(d)) << "documented but not served: " << d.first << " " << d.second;
    for (const auto& s : served)
        EXPECT_TRUE(documented.count(s)) << "served but not documented: " << s.first << " " << s.second;
}

}  // namespace
}  // namespace lf::test
