// lightfarmd with the real engine (the lightfarm binary of this build) on
// loopback: hostile scenes are refused at upload by the engine's own loader
// in a separate process, and a bake of the Cornell box through the service
// equals the same bake run by `lightfarm bake` with the same seed.
#include "server_harness.h"

#include "subprocess.h"

#include <OpenEXR/ImfArray.h>
#include <OpenEXR/ImfRgbaFile.h>
#include <gtest/gtest.h>

namespace lf::test {
namespace {

using nlohmann::json;

const std::string kToken = "e2e-token";
const fs::path kScenes = LIGHTFARM_SHARED_SCENES;

// True when this build's lightfarm knows `bake` (it is written in parallel
// with the service; until then the bake test skips).
bool engine_can_bake() {
    const server::RunResult r = server::run_command({LIGHTFARM_ENGINE, "bake", "--help"}, std::chrono::seconds(30));
    return r.out.find("unknown command") == std::string::npos && r.err_last_line.find("unknown command") == std::string::npos &&
           !(r.status.exited && r.status.code == 2 && r.out.empty());
}

class EndToEnd : public ::testing::Test {
protected:
    void SetUp() override {
        if (!fs::exists(LIGHTFARM_ENGINE)) GTEST_SKIP() << "no engine at " << LIGHTFARM_ENGINE;
        write_text(tmp.path / "tokens", kToken + "\n");
        server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", LIGHTFARM_ENGINE,
                                              std::vector<std::string>{"--stall-timeout", "120"});
        server->start();
    }
    void TearDown() override {
        if (HasFailure() && server) std::cerr << "---- lightfarmd log ----\n" << server->log();
    }
    TempDir tmp;
    std::unique_ptr<Lightfarmd> server;
};

struct Image {
    int width = 0, height = 0;
    std::vector<Imf::Rgba> pixels;
};
Image read_exr(const fs::path& path) {
    Imf::RgbaInputFile file(path.c_str());
    const Imath::Box2i dw = file.dataWindow();
    Image img;
    img.width = dw.max.x - dw.min.x + 1;
    img.height = dw.max.y - dw.min.y + 1;
    img.pixels.resize(size_t(img.width) * size_t(img.height));
    file.setFrameBuffer(img.pixels.data() - dw.min.x - dw.min.y * img.width, 1, size_t(img.width));
    file.readPixels(dw.min.y, dw.max.y);
    return img;
}

TEST_F(EndToEnd, EveryBadSceneIsAClear4xxAndTheServerStaysHealthy) {
    auto c = server->client(kToken);
    c.set_read_timeout(120);
    int tried = 0;
    for (const fs::directory_entry& e : fs::directory_iterator(kScenes / "bad")) {
        const std::string name = e.path().filename().string();
        const std::string bytes = read_text(e.path());
        httplib::Result r = e.path().extension() == ".glb"
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
    auto r = c.Post("/v1/scenes", read_text(kScenes / "cornell_box.gltf"), "model/gltf+json");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 201) << r->body;
    EXPECT_GT(json::parse(r->body).value("triangles", 0), 0) << r->body;
}

TEST_F(EndToEnd, CornellBoxThroughTheServiceEqualsTheCli) {
    if (!engine_can_bake()) GTEST_SKIP() << LIGHTFARM_ENGINE << " has no bake command yet";
    auto c = server->client(kToken);
    c.set_read_timeout(120);
    auto up = c.Post("/v1/scenes", read_text(kScenes / "cornell_box.gltf"), "model/gltf+json");
    ASSERT_EQ(up->status, 201) << up->body;
    const std::string scene = json::parse(up->body)["id"];
    const json spec = {{"scene", scene}, {"outputs", {{"lightmap", {{"res", 64}, {"passes", 8}}}}}, {"seed", 3}};
    auto created = c.Post("/v1/jobs", spec.dump(), "application/json");
    ASSERT_EQ(created->status, 201) << created->body;
    const std::string id = json::parse(created->body)["id"];

    const auto events = read_events(server->host, server->port, kToken, id, -1, 0, std::chrono::seconds(300));
    ASSERT_FALSE(events.empty());
    ASSERT_EQ(events.back().type, "done") << events.back().data.dump();
    int snapshots = 0;
    for (const auto& e : events) snapshots += e.type == "snapshot";
    EXPECT_GE(snapshots, 2);

    auto exr = c.Get("/v1/jobs/" + id + "/artifacts/lightmap.exr");
    ASSERT_EQ(exr->status, 200);
    write_text(tmp.path / "served.exr", exr->body);

    const fs::path local = tmp.path / "local";
    fs::create_directories(local);
    const server::RunResult cli = server::run_command(
        {LIGHTFARM_ENGINE, "bake", (kScenes / "cornell_box.gltf").string(), "--out", local.string(), "--json", "--res",
         "64", "--passes", "8", "--seed", "3"},
        std::chrono::seconds(300));
    ASSERT_TRUE(cli.status.success()) << cli.status.describe() << ": " << cli.err_last_line;

    const Image a = read_exr(tmp.path / "served.exr");
    const Image b = read_exr(local / "lightmap.exr");
    ASSERT_EQ(a.width, b.width);
    ASSERT_EQ(a.height, b.height);
    size_t differing = 0;
    for (size_t i = 0; i < a.pixels.size(); ++i) {
        const Imf::Rgba& p = a.pixels[i];
        const Imf::Rgba& q = b.pixels[i];
        differing += p.r.bits() != q.r.bits() || p.g.bits() != q.g.bits() || p.b.bits() != q.b.bits();
    }
    EXPECT_EQ(differing, 0u) << "texels that differ between the served and the CLI bake";

    auto png = c.Get("/v1/jobs/" + id + "/preview.png");
    EXPECT_EQ(png->status, 200);
}

}  // namespace
}  // namespace lf::test
