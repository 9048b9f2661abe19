// The ao output against closed forms. Cosine-weighted directions project to
// points uniform on the unit disk (Malley), so the occluded fraction of a
// point on a floor is an area of that disk: an infinite wall at distance x,
// reached by rays of length D, occludes the directions whose horizontal
// component towards it exceeds c = x/D, the disk's segment beyond the chord
// at c. Every texel is compared with the mean of the closed form over its
// own sample points, within its own standard error; and the mean over all
// texels, where a bias would show, within the standard error of that mean.
#include "bake/ambient_occlusion_method.h"
#include "atlas/texel_samples.h"
#include "gpu_fixture.h"
#include "io/image_files.h"
#include "scene_builders.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <memory>

namespace lf {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = 3.14159265358979323846;

// Area of the unit disk beyond the chord u = c (c >= 0).
double segment(double c) { return c >= 1.0 ? 0.0 : std::acos(c) - c * std::sqrt(1.0 - c * c); }

// Area of the unit disk where u > a and v > b (a, b >= 0).
double quadrant_beyond(double a, double b) {
    if (a * a + b * b >= 1.0) return 0.0;
    const auto g = [b](double u) { return 0.5 * (u * std::sqrt(1.0 - u * u) + std::asin(u)) - b * u; };
    return g(std::sqrt(1.0 - b * b)) - g(a);
}

// AO of a floor point at distance x from one infinite wall, rays of length d.
double ao_beside_wall(double x, double d) { return 1.0 - segment(x / d) / kPi; }

// AO of a floor point at distances x, z from two perpendicular infinite walls.
double ao_in_corner(double x, double z, double d) {
    const double a = std::min(1.0, x / d), b = std::min(1.0, z / d);
    return (kPi - segment(a) - segment(b) + quadrant_beyond(a, b)) / kPi;
}

struct AoBake {
    std::unique_ptr<PreparedScene> prepared;
    FloatImage image;  // ao.exr
};

// Bakes the ao output of `scene` (its UV1 as authored) at res² for `passes`.
AoBake bake_ao(const Scene& scene, int res, nlohmann::json ao_settings, int passes) {
    test::gpu();
    AoBake bake;
    bake.prepared = std::make_unique<PreparedScene>();
    PreparedScene& p = *bake.prepared;
    p.file = "test.glb";
    p.scene = scene;
    p.atlas_scene = scene;
    p.atlas.width = p.atlas.height = res;
    p.texels = rasterize_texel_samples(*p.atlas_scene, res, res, 2);
    p.tracer = std::make_unique<Tracer>(p.scene);
    ao_settings["ao_passes"] = passes;
    AmbientOcclusionMethod method(p, protocol::parse_bake_settings({{"outputs", {{"ao", ao_settings}}}}));
    PassStats stats;
    while (stats.pass < passes) stats = method.run_passes(std::min(method.max_batch(), passes - stats.pass)).back();
    const fs::path dir = fs::temp_directory_path() / ("lf-ao-" + std::to_string(::getpid()));
    fs::create_directories(dir);
    method.finish(dir, stats);
    bake.image = read_exr(dir / "ao.exr");
    fs::remove_all(dir);
    return bake;
}

// Every covered texel whose samples face `normal` against the mean of
// `expected` over those samples: within 5 of its standard errors each, and
// the mean difference within 4 standard errors of the mean. Returns the
// texels checked.
size_t expect_texels_match(const AoBake& bake, glm::vec3 normal, const std::function<double(glm::vec3)>& expected) {
    const TexelSamples& t = bake.prepared->texels;
    const auto &ao = bake.image.at("R"), &error = bake.image.at("error");
    size_t checked = 0;
    double difference = 0.0, variance = 0.0;
    for (size_t i = 0; i < t.covered_count(); ++i) {
        if (glm::dot(t.samples[t.first_sample[i]].normal, normal) < 0.99f) continue;
        double truth = 0.0;
        for (uint32_t k = t.first_sample[i]; k < t.first_sample[i + 1]; ++k) truth += expected(t.samples[k].position);
        truth /= t.sample_count(i);
        const uint32_t pixel = t.texels[i];
        const double sigma = std::max(double(error[pixel]), 1e-3);
        EXPECT_NEAR(ao[pixel], truth, 5.0 * sigma) << "texel " << pixel;
        difference += ao[pixel] - truth;
        variance += sigma * sigma;
        ++checked;
    }
    EXPECT_GT(checked, 0u);
    EXPECT_LT(std::abs(difference / double(checked)), 4.0 * std::sqrt(variance) / double(checked) + 1e-4)
        << "a bias over " << checked << " texels";
    return checked;
}

// A plane with nothing above it: 1 everywhere, at any distance (auto too).
TEST(AmbientOcclusion, AnOpenPlaneIsUnoccluded) {
    Scene s;
    test::add_quad(s, {-1, 0, 1}, {2, 0, 0}, {0, 0, -2}, test::add_material(s, glm::vec3(0.5f)));
    for (const nlohmann::json& distance : {nlohmann::json("auto"), nlohmann::json(100.0)}) {
        const AoBake bake = bake_ao(s, 16, {{"ao_distance", distance}}, 8);
        const TexelSamples& t = bake.prepared->texels;
        ASSERT_GT(t.covered_count(), 0u);
        for (size_t i = 0; i < t.covered_count(); ++i) EXPECT_EQ(bake.image.at("R")[t.texels[i]], 1.0f);
    }
}

// A floor beside a wall taller and wider than the AO distance: the wall is
// infinite to every ray. From 1 at distance D or more down to 1/2 at its foot.
TEST(AmbientOcclusion, AFloorBesideAWallMatchesTheDiskSegment) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    const float d = 1.0f;
    // The floor x in [0, 1.5], z in [-1, 1], facing +y; its UV1 the left half.
    test::add_quad(s, {0, 0, 1}, {1.5f, 0, 0}, {0, 0, -2}, grey, {0, 0, 0.5f, 1});
    // The wall x = 0, facing +x, 3 m high, z in [-3, 3]; UV1 the right half.
    test::add_quad(s, {0, 0, -3}, {0, 3, 0}, {0, 0, 6}, grey, {0.5f, 0, 1, 1});
    const AoBake bake = bake_ao(s, 48, {{"ao_distance", d}}, 256);
    const size_t texels =
        expect_texels_match(bake, {0, 1, 0}, [&](glm::vec3 p) { return ao_beside_wall(double(p.x), double(d)); });
    EXPECT_GT(texels, 300u);
}

// The same wall see-through (issue #35): it occludes in proportion to the
// share of it that stops light, 1 - its transmittance. Cut out or clear
// glass: 1 everywhere, exactly (every ray passes); blended at alpha 0.4:
// 1 - 0.4 x the disk segment.
TEST(AmbientOcclusion, ASeeThroughWallOccludesWhatItStops) {
    struct Case {
        const char* name;
        Material::AlphaMode mode;
        float alpha, transmission;
        double stops;
    };
    for (const Case& c : {Case{"cut out", Material::AlphaMode::Mask, 0.0f, 0.0f, 0.0},
                          Case{"clear glass", Material::AlphaMode::Opaque, 1.0f, 1.0f, 0.0},
                          Case{"blended", Material::AlphaMode::Blend, 0.4f, 0.0f, 0.4}}) {
        SCOPED_TRACE(c.name);
        Scene s;
        const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
        const uint32_t wall = test::add_material(s, glm::vec3(0.5f));
        s.materials[wall].alpha_mode = c.mode;
        s.materials[wall].base_color.a = c.alpha;
        s.materials[wall].transmission = c.transmission;
        test::add_quad(s, {0, 0, 1}, {1.5f, 0, 0}, {0, 0, -2}, grey, {0, 0, 0.5f, 1});
        test::add_quad(s, {0, 0, -3}, {0, 3, 0}, {0, 0, 6}, wall, {0.5f, 0, 1, 1});
        const AoBake bake = bake_ao(s, 48, {{"ao_distance", 1.0}}, c.stops == 0.0 ? 8 : 256);
        if (c.stops == 0.0) {
            const TexelSamples& t = bake.prepared->texels;
            for (size_t i = 0; i < t.covered_count(); ++i) {
                if (t.samples[t.first_sample[i]].normal.y > 0.99f) {
                    ASSERT_EQ(bake.image.at("R")[t.texels[i]], 1.0f);
                }
            }
        } else {
            expect_texels_match(bake, {0, 1, 0},
                                [&](glm::vec3 p) { return 1.0 - c.stops * (1.0 - ao_beside_wall(double(p.x), 1.0)); });
        }
    }
}

// A floor in the corner of two walls: the two segments less their overlap;
// a quarter at the corner itself.
TEST(AmbientOcclusion, AFloorInACornerMatchesTheDiskLessTwoSegments) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    const float d = 1.0f;
    test::add_quad(s, {0, 0, 1.5f}, {1.5f, 0, 0}, {0, 0, -1.5f}, grey, {0, 0, 0.5f, 0.5f});  // floor, +y
    test::add_quad(s, {0, 0, 0}, {0, 3, 0}, {0, 0, 3}, grey, {0.5f, 0, 1, 0.5f});            // x = 0, facing +x
    test::add_quad(s, {0, 0, 0}, {3, 0, 0}, {0, 3, 0}, grey, {0, 0.5f, 1, 1});               // z = 0, facing +z
    EXPECT_NEAR(ao_in_corner(0, 0, 1), 0.25, 1e-12);
    EXPECT_NEAR(ao_in_corner(0.5, 2, 1), ao_beside_wall(0.5, 1), 1e-12);
    const AoBake bake = bake_ao(s, 48, {{"ao_distance", d}}, 256);
    expect_texels_match(bake, {0, 1, 0},
                        [&](glm::vec3 p) { return ao_in_corner(double(p.x), double(p.z), double(d)); });
}

// --ao-target-error stops the passes once the occlusion's relative standard
// error is below it (the counts are read back for that only: without a
// target no estimate is made).
TEST(AmbientOcclusion, StopsAtItsTargetError) {
    test::gpu();
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    test::add_quad(s, {0, 0, 1}, {1.5f, 0, 0}, {0, 0, -2}, grey, {0, 0, 0.5f, 1});
    test::add_quad(s, {0, 0, -3}, {0, 3, 0}, {0, 0, 6}, grey, {0.5f, 0, 1, 1});
    PreparedScene p;
    p.file = "test.glb";
    p.scene = s;
    p.atlas_scene = s;
    p.atlas.width = p.atlas.height = 32;
    p.texels = rasterize_texel_samples(*p.atlas_scene, 32, 32, 2);
    p.tracer = std::make_unique<Tracer>(p.scene);
    for (const double target : {0.0, 0.02}) {
        SCOPED_TRACE("target " + std::to_string(target));
        AmbientOcclusionMethod method(
            p, protocol::parse_bake_settings(
                   {{"outputs", {{"ao", {{"ao_distance", 1.0}, {"ao_passes", 2000}, {"ao_target_error", target}}}}}}));
        PassStats stats;
        while (!stop_reached(method.stop_rule(), stats)) stats = method.run_passes(8).back();
        if (target == 0.0) {
            EXPECT_EQ(stats.pass, 2000);
            EXPECT_FALSE(stats.error_estimate);
        } else {
            ASSERT_TRUE(stats.error_estimate);
            EXPECT_LE(*stats.error_estimate, target);
            EXPECT_LT(stats.pass, 2000) << "stopped by the target, not the pass count";
        }
    }
}

// Inside a closed box whose every wall is within the AO distance: 0.
TEST(AmbientOcclusion, AClosedBoxIsFullyOccluded) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    const glm::vec3 o(-1.0f), X(2, 0, 0), Y(0, 2, 0), Z(0, 0, 2);
    test::add_quad(s, o, Z, X, grey, {0, 0, 0.33f, 0.5f});
    test::add_quad(s, o + Y, X, Z, grey, {0.33f, 0, 0.66f, 0.5f});
    test::add_quad(s, o, X, Y, grey, {0.66f, 0, 1, 0.5f});
    test::add_quad(s, o + Z, Y, X, grey, {0, 0.5f, 0.33f, 1});
    test::add_quad(s, o, Y, Z, grey, {0.33f, 0.5f, 0.66f, 1});
    test::add_quad(s, o + X, Z, Y, grey, {0.66f, 0.5f, 1, 1});
    const AoBake bake = bake_ao(s, 24, {{"ao_distance", 10.0}}, 8);
    const TexelSamples& t = bake.prepared->texels;
    ASSERT_GT(t.covered_count(), 0u);
    for (size_t i = 0; i < t.covered_count(); ++i) EXPECT_EQ(bake.image.at("R")[t.texels[i]], 0.0f);
}

}  // namespace
}  // namespace lf
