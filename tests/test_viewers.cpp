// scene.unlit.glb in a viewer that knows nothing of lightfarm (issue #36):
// a stock three.js (GLTFLoader, a default WebGLRenderer, no lights) in a
// real headless Chromium shows it as lightfarm's own 3D view shows
// scene.lit.glb (tests/web/any_viewer.mjs renders both from one camera).
#include "cli_runner.h"
#include "gpu_fixture.h"

#include "display_tone.h"
#include "io/image_files.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

namespace lf {
namespace {

namespace fs = std::filesystem;

// `node tests/web/SCRIPT ARGS` (its packages in web/node_modules, installed
// by the scripts): its stdout, and whether it exited 0.
bool run_node(const std::string& script, const std::string& args, std::string& out) {
    const std::string command = "node " + std::string(LIGHTFARM_SOURCE_DIR) + "/tests/web/" + script + " " + args;
    FILE* pipe = popen(command.c_str(), "r");
    char buffer[4096];
    for (size_t n; (n = fread(buffer, 1, sizeof buffer, pipe)) > 0;) out.append(buffer, n);
    return pclose(pipe) == 0;
}

// The two views differ where they cannot agree: lightfarm's multiplies the
// albedo at full resolution by the bilinear lightmap and tone-maps each
// pixel, the unlit texture holds albedo x light tone-mapped per texel and
// is filtered after (a chart's border texels blend light and tone
// differently, and both renders' rasterizations round at edges); 8 bits
// each. Measured 2026-11-27 (SwiftShader): a mean difference of 0.29 of 255
// over the box, the 99th percentile 2, the largest 64 (an edge). The bounds,
// mean 1 and 99th percentile 6, hold that with room; an exposure a stop off,
// or a curve left out, moves the mean by tens (the first version of the
// test's own replica, which missed RGBM's alpha: 121).
TEST(AnyViewer, AStockThreeJsShowsTheUnlitSceneAsLightfarmsViewShowsTheLitOne) {
    const fs::path out = fs::temp_directory_path() / ("lightfarm-any-viewer-" + std::to_string(getpid()));
    fs::remove_all(out);
    const test::CliRun bake = test::run_lightfarm("bake " + test::shared_scene("cornell_box.gltf") +
                                                  " --res 128 --passes 64 --out " + out.string());
    ASSERT_EQ(bake.exit_code, 0) << bake.err;
    const FloatImage lightmap = read_exr(out / "lightmap.exr");
    std::vector<float> rgb;
    for (size_t i = 0; i < lightmap.at("R").size(); ++i)
        for (const char* c : {"R", "G", "B"}) rgb.push_back(lightmap.at(c)[i]);
    const double exposure = protocol::automatic_exposure(rgb);

    std::string report;
    const bool ran = run_node("any_viewer.mjs",
                              (out / "scene.unlit.glb").string() + " " + (out / "scene.lit.glb").string() + " " +
                                  std::to_string(exposure) + " " + (out / "renders").string(),
                              report);
    ASSERT_TRUE(ran) << report;
    const nlohmann::json r = nlohmann::json::parse(report);
    std::printf("%s", report.c_str());  // the figures, for the log
    EXPECT_GT(r["covered_fraction"].get<double>(), 0.3) << "the box fills the frame: " << report;
    EXPECT_LT(r["mean_difference"].get<double>(), 1.0) << report;
    EXPECT_LT(r["p99_difference"].get<double>(), 6.0) << report;
    for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(r["mean_colour"]["unlit"][c].get<double>(), r["mean_colour"]["lit"][c].get<double>(), 1.0)
            << "channel " << c << ": " << report;
    fs::remove_all(out);
}

}  // namespace
}  // namespace lf
