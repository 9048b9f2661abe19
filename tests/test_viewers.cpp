// scene.unlit.glb in a viewer that knows nothing of lightfarm (issue #36):
// a stock three.js (GLTFLoader, a default WebGLRenderer, no lights) in a
// real headless Chromium, and Blender's own glTF importer, show it as
// lightfarm's own 3D view shows scene.lit.glb (tests/web/any_viewer.mjs and
// tests/blender/render_glb.py render from one camera).
#include "cli_runner.h"
#include "gpu_fixture.h"
#include "server_harness.h"

#include "display_tone.h"
#include "io/image_files.h"
#include "png.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <stb/stb_image.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
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

// Renders a glb with Debian's Blender and its own glTF importer
// (tests/blender/render_glb.py: any_viewer.mjs's camera, SIZE² pixels) into
// `png`; Blender's output in `out`. True when it rendered.
bool run_blender(const fs::path& glb, const fs::path& png, int size, std::string& out) {
    const std::string command = "blender -b --factory-startup --python " + std::string(LIGHTFARM_SOURCE_DIR) +
                                "/tests/blender/render_glb.py -- " + glb.string() + " " + png.string() + " " +
                                std::to_string(size) + " 2>&1";
    FILE* pipe = popen(command.c_str(), "r");
    if (!pipe) return false;
    char buffer[4096];
    for (size_t n; (n = fread(buffer, 1, sizeof buffer, pipe)) > 0;) out.append(buffer, n);
    return pclose(pipe) == 0 && fs::exists(png);
}

// Two renders of one size (8-bit PNGs) compared over the pixels either
// covers (not black): their absolute differences (0-255, every channel),
// mean and 99th percentile, the share of the frame covered, and each one's
// mean colour there. With `block` > 1, over the means of block x block
// squares of pixels instead (the covered ones in either): light, not
// texture filtering (Cycles samples a texture at full resolution where a
// WebGL viewer reads its mipmaps).
struct RenderDifference {
    double mean = 0.0, p99 = 0.0, covered_fraction = 0.0;
    std::array<double, 3> mean_a{}, mean_b{};
};

RenderDifference compare_renders(const fs::path& a_png, const fs::path& b_png, int block = 1) {
    int wa = 0, ha = 0, wb = 0, hb = 0, n = 0;
    std::unique_ptr<unsigned char, void (*)(void*)> a(stbi_load(a_png.c_str(), &wa, &ha, &n, 3), stbi_image_free),
        b(stbi_load(b_png.c_str(), &wb, &hb, &n, 3), stbi_image_free);
    if (!a || !b || wa != wb || ha != hb) throw std::runtime_error("renders of different sizes, or unreadable");
    RenderDifference d;
    std::vector<double> differences;
    size_t covered = 0;
    for (int by = 0; by + block <= ha; by += block)
        for (int bx = 0; bx + block <= wa; bx += block) {
            std::array<double, 3> x{}, y{};
            int count = 0;
            for (int j = by; j < by + block; ++j)
                for (int i = bx; i < bx + block; ++i) {
                    const size_t p = size_t(j) * size_t(wa) + size_t(i);
                    const unsigned char *u = a.get() + 3 * p, *v = b.get() + 3 * p;
                    if (u[0] + u[1] + u[2] + v[0] + v[1] + v[2] == 0) continue;
                    ++count;
                    for (size_t c = 0; c < 3; ++c) {
                        x[c] += u[c];
                        y[c] += v[c];
                    }
                }
            if (count == 0) continue;
            covered += size_t(count);
            for (size_t c = 0; c < 3; ++c) {
                differences.push_back(std::abs(x[c] - y[c]) / count);
                d.mean_a[c] += x[c];
                d.mean_b[c] += y[c];
            }
        }
    if (covered == 0) return d;
    for (size_t c = 0; c < 3; ++c) {
        d.mean_a[c] /= double(covered);
        d.mean_b[c] /= double(covered);
    }
    d.covered_fraction = double(covered) / (double(wa) * double(ha));
    for (double v : differences) d.mean += v;
    d.mean /= double(differences.size());
    std::nth_element(differences.begin(), differences.begin() + std::ptrdiff_t(differences.size() * 99 / 100),
                     differences.end());
    d.p99 = differences[differences.size() * 99 / 100];
    return d;
}

// The Blender add-on (blender/lightfarm_blender) driven headless by
// tests/blender/import_bake.py with ARGS: its last line that is a JSON
// object (what it imported, or its error), and whether it exited 0.
bool run_blender_add_on(const std::string& args, std::string& report) {
    const std::string command = "blender -b --factory-startup --python " + std::string(LIGHTFARM_SOURCE_DIR) +
                                "/tests/blender/import_bake.py -- " + args + " 2>&1";
    FILE* pipe = popen(command.c_str(), "r");
    if (!pipe) return false;
    std::string out;
    char buffer[4096];
    for (size_t n; (n = fread(buffer, 1, sizeof buffer, pipe)) > 0;) out.append(buffer, n);
    const bool ok = pclose(pipe) == 0;
    report = out;
    std::istringstream lines(out);
    for (std::string line; std::getline(lines, line);)
        if (!line.empty() && line[0] == '{') report = line;
    return ok;
}

// A linear render (Blender's EXR) shown as lightfarm's view shows light:
// the lightmap's exposure, the view's filmic curve, sRGB, 8 bits.
void tone_map_as_the_view(const fs::path& exr, double exposure, const fs::path& png) {
    const FloatImage linear = read_exr(exr);
    std::vector<uint8_t> pixels;
    for (size_t i = 0; i < linear.at("R").size(); ++i) {
        const std::array<float, 3> shown =
            protocol::aces_filmic({linear.at("R")[i], linear.at("G")[i], linear.at("B")[i]}, float(exposure));
        for (float c : shown) pixels.push_back(protocol::encode_srgb8(c));
    }
    std::ofstream(png, std::ios::binary) << protocol::encode_png(pixels.data(), linear.width, linear.height, 3);
}

// A lightmap's automatic exposure (the view's and scene.unlit.glb's).
double exposure_of(const FloatImage& lightmap) {
    std::vector<float> rgb;
    for (size_t i = 0; i < lightmap.at("R").size(); ++i)
        for (const char* c : {"R", "G", "B"}) rgb.push_back(lightmap.at(c)[i]);
    return protocol::automatic_exposure(rgb);
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
    const test::CliRun bake = test::run_lightfarm("bake " + test::example_scene("cornell_box.gltf") +
                                                  " --res 128 --passes 64 --out " + out.string());
    ASSERT_EQ(bake.exit_code, 0) << bake.err;
    const double exposure = exposure_of(read_exr(out / "lightmap.exr"));

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

    // Blender's own glTF importer (Debian's Blender 3.4, Cycles,
    // tests/blender/render_glb.py) shows the same scene.unlit.glb as
    // lightfarm's view shows scene.lit.glb. Blender shows an unlit surface
    // as its texture under the "Standard" view transform (its default,
    // Filmic, is a tone curve of its own over the one the texture holds:
    // what a user turns off to see a baked look as baked). Measured
    // 2026-11-28: a mean difference of 1.02 of 255 (Blender 0.8 brighter
    // in every channel: its 8-bit rounding), the 99th percentile 1. The
    // bounds, mean 2.5 and 99th percentile 6, hold that with room; under
    // Filmic the mean is 5.7 and the 99th percentile 16.
    std::string blender;
    ASSERT_TRUE(run_blender(out / "scene.unlit.glb", out / "renders" / "blender.png", 320, blender)) << blender;
    const RenderDifference d = compare_renders(out / "renders" / "blender.png", out / "renders" / "lit.png");
    std::printf("Blender against lightfarm's view: mean %.3f, p99 %.1f, covered %.3f\n", d.mean, d.p99,
                d.covered_fraction);
    EXPECT_NEAR(d.covered_fraction, r["covered_fraction"].get<double>(), 0.01) << "the same camera";
    EXPECT_LT(d.mean, 2.5);
    EXPECT_LT(d.p99, 6.0);
    for (size_t c = 0; c < 3; ++c) EXPECT_NEAR(d.mean_a[c], d.mean_b[c], 2.0) << "channel " << c;
    fs::remove_all(out);
}

// Atlas pages (issue #36) in a stock viewer: monkey.glb (five meshes) at
// 70 texels/m on pages of 256² takes three, primitives split across pages,
// each piece on its page's material. Its scene.unlit.glb in a stock
// three.js, and its scene.lit.glb in lightfarm's view, look as the same
// scene's baked on one page (324²): a piece on the wrong page's texture, or
// a v not moved onto its page, shows another page's charts. Each page file
// is its rows of the stacked lightmap.exr, and every glb passes the Khronos
// validator.
TEST(AnyViewer, ABakeOnPagesLooksAsTheSameBakeOnOnePage) {
    const fs::path out = fs::temp_directory_path() / ("lightfarm-pages-viewer-" + std::to_string(getpid()));
    fs::remove_all(out);
    for (const char* max_res : {"256", "512"}) {
        const test::CliRun bake =
            test::run_lightfarm("bake " + test::example_scene("monkey.glb") + " --texel-density 70 --max-res " +
                                max_res + " --passes 16 --out " + (out / max_res).string());
        ASSERT_EQ(bake.exit_code, 0) << bake.err;
    }
    const fs::path paged = out / "256", single = out / "512";
    const nlohmann::json atlas =
        nlohmann::json::parse(std::ifstream(paged / "manifest.json"))["lightmap"]["settings"]["atlas"];
    ASSERT_EQ(atlas["pages"].get<int>(), 3) << atlas.dump();
    const FloatImage stacked = read_exr(paged / "lightmap.exr");
    const int rows = atlas["page_height"].get<int>(), stride = rows + atlas["page_gap"].get<int>();
    for (int page = 0; page < 3; ++page) {
        const FloatImage one = read_exr(paged / ("lightmap.page-" + std::to_string(page) + ".exr"));
        ASSERT_EQ(one.width, 256);
        ASSERT_EQ(one.height, rows);
        for (const auto& [channel, values] : stacked.channels) {
            const auto first = values.begin() + std::ptrdiff_t(size_t(page) * size_t(stride) * 256);
            EXPECT_TRUE(std::equal(first, first + std::ptrdiff_t(size_t(rows) * 256), one.at(channel).begin()))
                << "page " << page << " channel " << channel;
        }
    }
    EXPECT_FALSE(fs::exists(paged / "lightmap.page-3.exr"));
    EXPECT_FALSE(fs::exists(single / "lightmap.page-0.exr")) << "one page: lightmap.exr alone";

    std::string validator;
    EXPECT_TRUE(run_node("validate_gltf.mjs",
                         (paged / "scene.lightmapped.glb").string() + " " + (paged / "scene.lit.glb").string() + " " +
                             (paged / "scene.unlit.glb").string(),
                         validator))
        << validator;

    // Each file against the one-page bake's, as a stock viewer shows the
    // unlit one and as lightfarm's view shows the lit one (any_viewer.mjs
    // renders a file by what it is). Measured 2026-11-28 (SwiftShader): a
    // mean difference of 3.0 (unlit) and 1.9 (lit) of 255, the two bakes'
    // noise at 16 passes and their different texel grids; the same file
    // against itself: 0. With each vertex's v put on the next page (a
    // deliberate fault): 68.7 and 30.4. The bound, 6, holds the one with
    // room and fails the other fivefold or more.
    const double exposure = exposure_of(read_exr(single / "lightmap.exr"));
    for (const char* file : {"scene.unlit.glb", "scene.lit.glb"}) {
        std::string report;
        const bool ran = run_node("any_viewer.mjs",
                                  (paged / file).string() + " " + (single / file).string() + " " +
                                      std::to_string(exposure) + " " + (out / "renders").string(),
                                  report);
        ASSERT_TRUE(ran) << report;
        std::printf("%s: %s", file, report.c_str());  // the figures, for the log
        const nlohmann::json r = nlohmann::json::parse(report);
        EXPECT_GT(r["covered_fraction"].get<double>(), 0.03) << report;
        EXPECT_LT(r["mean_difference"].get<double>(), 6.0) << file << ": " << report;
    }
    fs::remove_all(out);
}

// The Blender add-on (issue #54's road into engines): Debian's Blender
// imports a bake with blender/lightfarm_blender (scene.lightmapped.glb, each
// material's base colour times the lightmap on TEXCOORD_1 plus its
// emission), renders it linear with the stock viewer's camera, and that
// render, put through the view's exposure and curve, is lightfarm's own
// view of scene.lit.glb. The staircase (262,663 triangles, 25 textured
// materials, glass) baked on seven pages of 128², and monkey.glb (no UVs,
// no materials: the glTF default) on one, compared over 8 x 8 pixel blocks:
// Cycles samples the staircase's wallpaper at full resolution (one sample
// a pixel) where the WebGL view reads its mipmaps, and the pattern aliases.
// Measured 2026-12-07: a mean difference of 2.9 of 255 (staircase: its
// wallpaper's moire, blue stripes, the light alike) and 0.15 (monkey);
// each triangle on the next page's image: 79; the lightmap read on
// TEXCOORD_0: 51 and 72. The bounds, 5 and 1, hold the first with room
// and fail the faults tenfold.
constexpr int kLightBlock = 8;
TEST(BlenderAddOn, ImportsABakeAsLightfarmsViewShowsIt) {
    const fs::path out = fs::temp_directory_path() / ("lightfarm-blender-add-on-" + std::to_string(getpid()));
    fs::remove_all(out);
    struct Case {
        std::string name, scene, settings;
        int pages;
        double bound;  // of the mean difference, and of each channel's mean
    };
    const std::vector<Case> cases = {{"staircase", test::example_scene("real/wooden_staircase/wooden_staircase.gltf"),
                                      "--res 128 --passes 4", 7, 5.0},
                                     {"monkey", test::example_scene("monkey.glb"), "--res 128 --passes 8", 1, 1.0}};
    for (const Case& c : cases) {
        SCOPED_TRACE(c.name);
        const fs::path bake = out / c.name;
        const test::CliRun run = test::run_lightfarm("bake " + c.scene + " " + c.settings + " --out " + bake.string());
        ASSERT_EQ(run.exit_code, 0) << run.err;
        const double exposure = exposure_of(read_exr(bake / "lightmap.exr"));
        std::string view;
        ASSERT_TRUE(run_node("any_viewer.mjs",
                             (bake / "scene.unlit.glb").string() + " " + (bake / "scene.lit.glb").string() + " " +
                                 std::to_string(exposure) + " " + (bake / "renders").string(),
                             view))
            << view;
        std::string report;
        ASSERT_TRUE(run_blender_add_on(bake.string() + " " + (bake / "blender.exr").string() + " 320", report))
            << report;
        const nlohmann::json imported = nlohmann::json::parse(report);
        int pages = 0;
        for (const auto& image : imported["images"]) pages += image.get<std::string>().rfind("lightmap", 0) == 0;
        EXPECT_EQ(pages, c.pages) << report;
        tone_map_as_the_view(bake / "blender.exr", exposure, bake / "renders" / "blender.png");
        const RenderDifference d =
            compare_renders(bake / "renders" / "blender.png", bake / "renders" / "lit.png", kLightBlock);
        std::printf("%s: the Blender add-on against lightfarm's view: mean %.3f, p99 %.1f, covered %.3f\n",
                    c.name.c_str(), d.mean, d.p99, d.covered_fraction);
        EXPECT_GT(d.covered_fraction, 0.3);
        EXPECT_LT(d.mean, c.bound);
        for (size_t k = 0; k < 3; ++k) EXPECT_NEAR(d.mean_a[k], d.mean_b[k], c.bound) << "channel " << k;
    }
    // A folder that holds no bake: refused, naming it and what is missing.
    fs::create_directories(out / "empty");
    std::string refused;
    EXPECT_FALSE(run_blender_add_on((out / "empty").string() + " " + (out / "empty.exr").string() + " 64", refused));
    EXPECT_NE(refused.find((out / "empty").string() + ": no scene.lightmapped.glb"), std::string::npos) << refused;
    if (!HasFailure()) fs::remove_all(out);  // kept to look at when it failed
}

// The add-on's other road: the open scene (the Cornell box, opened in
// Blender) sent to a running lightfarmd, baked there, and the result
// imported and rendered as lightfarm's view shows the server's own files.
// Measured 2026-12-07: a mean difference of 0.86 of 255 (pixel by pixel).
TEST(BlenderAddOn, SendsTheOpenSceneToALightfarmdAndImportsTheBake) {
    test::TempDir tmp;
    const std::string token = "blender-add-on-token";
    test::write_text(tmp.path / "tokens", token + "\n");
    test::Lightfarmd server(tmp.path / "data", tmp.path / "tokens", LIGHTFARM_BIN);
    server.start();
    const fs::path bake = tmp.path / "bake";
    std::string report;
    ASSERT_TRUE(run_blender_add_on("--send " + server.url + " " + token + " " +
                                       test::example_scene("cornell_box.gltf") + " " + bake.string() + " " +
                                       (tmp.path / "blender.exr").string() + " 320",
                                   report))
        << report << "\n"
        << server.log();
    const nlohmann::json imported = nlohmann::json::parse(report);
    ASSERT_EQ(imported["job"].get<std::string>().size(), 24u) << report;
    EXPECT_GT(imported["baked_looks"].get<int>(), 0) << report;
    const double exposure = exposure_of(read_exr(bake / "lightmap.exr"));
    std::string view;
    ASSERT_TRUE(run_node("any_viewer.mjs",
                         (bake / "scene.unlit.glb").string() + " " + (bake / "scene.lit.glb").string() + " " +
                             std::to_string(exposure) + " " + (tmp.path / "renders").string(),
                         view))
        << view;
    tone_map_as_the_view(tmp.path / "blender.exr", exposure, tmp.path / "renders" / "blender.png");
    const RenderDifference d = compare_renders(tmp.path / "renders" / "blender.png", tmp.path / "renders" / "lit.png");
    std::printf("sent from Blender, against lightfarm's view: mean %.3f, p99 %.1f, covered %.3f\n", d.mean, d.p99,
                d.covered_fraction);
    EXPECT_GT(d.covered_fraction, 0.3);
    EXPECT_LT(d.mean, 2.0);
}

}  // namespace
}  // namespace lf
