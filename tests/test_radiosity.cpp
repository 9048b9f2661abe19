// The radiosity-map method against answers known in closed form, against
// properties every correct bake has, and against an independent renderer.
#include "family_errors.h"
#include "gpu_fixture.h"
#include "lightmap_closed_forms.h"
#include "sky_maps.h"
#include "scene_builders.h"

#include "atlas/atlas.h"
#include "atlas/seams.h"
#include "atlas/texel_samples.h"
#include "bake/double_sided.h"
#include "bake/light_density.h"
#include "bake/lightmap_denoiser.h"
#include "bake/radiosity_map_baker.h"
#include "trace/surface_textures.h"
#include "bake/unlit_charts.h"
#include "io/image_files.h"
#include "io/reference_error.h"
#include "probes/probe_eval.h"
#include "scene/gltf_loader.h"
#include "sh/environment.h"
#include "trace/tracer.h"
#include "shaders/buffer_bindings.glsl"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <random>

namespace lf {
namespace {

using test::bake;
using test::BakeResult;
using test::corner_form_factor;
using test::gpu;
using test::grid_cell;
using test::rectangle_form_factor;

// From the measured convergence curve (docs/BENCHMARKS.md): the default
// scheme reaches 2.7% relative RMSE against Cycles after 256 passes at 256²
// (seed 1; the error falls as 1/sqrt(passes) from there, bias -0.1%). The
// bound leaves 30% for another seed or device, and would catch a bias or a
// lost factor (a 2% bias alone already adds 2% here).
constexpr double kCornellRelativeRmseBound256 = 0.035;

// A black floor at y = 0 facing up under a black rectangular emitter of
// radiance 1 facing down: direct light only, known in closed form. By
// default a 2x2 m floor under a 1x1 m emitter at 1 m.
struct PlatesGeometry {
    float floor = 2.0f, light_x = 1.0f, light_z = 1.0f, height = 1.0f;
};

struct ParallelPlates {
    BakeResult result;
    // Per floor texel: (baked, expected) where expected is the form factor
    // averaged over the texel's sample points, as the bake averages them;
    // and the texel's index in the image.
    std::vector<std::pair<double, double>> floor_texels;
    std::vector<uint32_t> floor_texel_index;
};

ParallelPlates bake_parallel_plates(RadiosityMapSettings settings, int passes, PlatesGeometry g = {}) {
    Scene s;
    const uint32_t black = test::add_material(s, glm::vec3(0.0f));
    const uint32_t light = test::add_material(s, glm::vec3(0.0f), glm::vec3(1.0f));
    const int res = 64;
    test::add_quad(s, {-g.floor / 2, 0, g.floor / 2}, {g.floor, 0, 0}, {0, 0, -g.floor}, black, grid_cell(0, 2, res));
    test::add_quad(s, {-g.light_x / 2, g.height, -g.light_z / 2}, {g.light_x, 0, 0}, {0, 0, g.light_z}, light,
                   grid_cell(1, 2, res));
    ParallelPlates p{bake(s, res, passes, settings), {}, {}};
    const BakeResult& r = p.result;
    for (size_t i = 0; i < r.texels.covered_count(); ++i) {
        if (r.texels.samples[r.texels.first_sample[i]].position.y > g.height / 2) continue;  // the emitter's own
        double expected = 0.0;
        for (uint32_t k = r.texels.first_sample[i]; k < r.texels.first_sample[i + 1]; ++k) {
            const glm::vec3 q = r.texels.samples[k].position;
            expected +=
                rectangle_form_factor(q.x, q.z, -g.light_x / 2, g.light_x / 2, -g.light_z / 2, g.light_z / 2, g.height);
        }
        p.floor_texels.emplace_back(r.image.at("R")[r.texels.texels[i]], expected / r.texels.sample_count(i));
        p.floor_texel_index.push_back(r.texels.texels[i]);
    }
    return p;
}

TEST(RadiosityMap, FloorUnderParallelSquareEmitterMatchesFormFactor) {
    RadiosityMapSettings settings;
    settings.light_samples = 8;
    const ParallelPlates p = bake_parallel_plates(settings, 256);
    double max_rel = 0.0, sum_rel = 0.0;
    for (const auto& [baked, expected] : p.floor_texels) {
        const double rel = std::abs(baked - expected) / expected;
        max_rel = std::max(max_rel, rel);
        sum_rel += rel;
    }
    ASSERT_GT(p.floor_texels.size(), 500u);
    EXPECT_LT(sum_rel / double(p.floor_texels.size()), 0.02) << "mean relative error";
    EXPECT_LT(max_rel, 0.08) << "worst texel";
    // Directly under the centre: F = 4 x corner factor (0.5, 0.5, 1).
    EXPECT_NEAR(rectangle_form_factor(0, 0, -0.5, 0.5, -0.5, 0.5, 1.0), 4 * corner_form_factor(0.5, 0.5, 1.0), 1e-12);
}

// The Cornell box's light (0.13 x 0.105 m) 0.55 m over a 0.6 m floor:
// emitter triangles of 0.002 to 0.03 sr, sampled by solid angle with MIS
// (the default). Summed over 8x8-texel blocks, which leaves noise of about
// 0.05%, every block of the floor is within 0.3% of the closed form
// (0.16% measured), and so is their sum within 0.1% (-0.01%). With the
// solid angle from three acos (sampling.glsl), llvmpipe's worst block was
// 1.5% off and the sum +0.57% (SphericalTriangles: the solid angle itself
// 1-2% off).
TEST(RadiosityMap, SmallEmitterLightsEveryBlockOfTheFloorWithoutBias) {
    const ParallelPlates p = bake_parallel_plates({}, 256, {0.6f, 0.13f, 0.105f, 0.55f});
    const int res = 64, block = 8;
    std::vector<double> baked(size_t(res / block) * size_t(res / block)), expected(baked.size());
    for (size_t i = 0; i < p.floor_texels.size(); ++i) {
        const uint32_t t = p.floor_texel_index[i];
        const size_t b = size_t(t / res / block) * size_t(res / block) + size_t(t % res / block);
        baked[b] += p.floor_texels[i].first;
        expected[b] += p.floor_texels[i].second;
    }
    double worst = 0.0, sum_baked = 0.0, sum_expected = 0.0;
    int blocks = 0;
    for (size_t b = 0; b < baked.size(); ++b) {
        if (expected[b] <= 0.0) continue;
        worst = std::max(worst, std::abs(baked[b] / expected[b] - 1.0));
        sum_baked += baked[b];
        sum_expected += expected[b];
        ++blocks;
    }
    std::printf("small emitter: %d blocks, worst %.3f%%, bias %+.3f%%\n", blocks, 100.0 * worst,
                100.0 * (sum_baked / sum_expected - 1.0));
    ASSERT_GT(blocks, 8);
    EXPECT_LT(worst, 0.003);
    EXPECT_LT(std::abs(sum_baked / sum_expected - 1.0), 0.001);
}

// Relative RMS error of the parallel plates' direct light for one way of sampling the light.
double parallel_plate_error(LightSampling sampling, int passes, double* seconds) {
    RadiosityMapSettings settings;
    settings.light_sampling = sampling;
    const ParallelPlates p = bake_parallel_plates(settings, passes);
    *seconds = p.result.stats.seconds;
    double sum_sq = 0.0, sum_ref = 0.0;
    for (const auto& [baked, expected] : p.floor_texels) {
        sum_sq += (baked - expected) * (baked - expected);
        sum_ref += expected;
    }
    const double n = double(p.floor_texels.size());
    return std::sqrt(sum_sq / n) / (sum_ref / n);
}

Scene furnace(float rho, float le, int res);

// The thesis's future work (§6.3) asks whether sampling emitters by solid
// angle beats sampling them by area: measured here, with MIS next to both.
TEST(RadiosityMap, LightSamplingStrategiesAreUnbiasedAndMeasured) {
    const int passes = 256;
    std::printf("direct light under a 1x1 m emitter at 1 m, 64² floor, %d passes (relative RMSE vs form factor):\n",
                passes);
    double errors[3];
    for (LightSampling m : {LightSampling::Mis, LightSampling::Area, LightSampling::SolidAngle}) {
        double seconds = 0.0;
        errors[int(m)] = parallel_plate_error(m, passes, &seconds);
        std::printf("  %-12s %.4f  (%.2f s)\n", to_string(m), errors[int(m)], seconds);
        EXPECT_LT(errors[int(m)], 0.05) << to_string(m);
    }
    // Solid-angle sampling removes the 1/r² and cos_y variation: it must win here.
    EXPECT_LT(errors[int(LightSampling::SolidAngle)], errors[int(LightSampling::Area)]);

    // Next to a large emitter (the furnace's walls) area sampling alone is the
    // weak one: MIS and solid angle stay close to the answer, 5.
    const int res = 32;
    const Scene f = furnace(0.8f, 1.0f, res);
    for (LightSampling m : {LightSampling::Mis, LightSampling::Area, LightSampling::SolidAngle}) {
        RadiosityMapSettings settings;
        settings.light_sampling = m;
        const BakeResult r = bake(f, res, 128, settings);
        double sum_sq = 0.0;
        for (uint32_t t : r.texels.texels) sum_sq += std::pow(r.image.at("R")[t] - 5.0, 2);
        const double rel = std::sqrt(sum_sq / double(r.texels.covered_count())) / 5.0;
        std::printf("  furnace, %-12s relative RMSE %.4f after 128 passes\n", to_string(m), rel);
        if (m == LightSampling::Area) errors[1] = rel;
        else if (m == LightSampling::Mis) errors[0] = rel;
        else errors[2] = rel;
    }
    EXPECT_LT(errors[0], errors[1]) << "MIS should beat area sampling next to large emitters";
}

// A closed box whose every wall has albedo rho and emits Le: the radiance is
// the same everywhere, L = Le / (1 - rho), and so is every lightmap texel.
Scene furnace(float rho, float le, int res) {
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(rho), glm::vec3(le));
    const glm::vec3 o(-1.0f), X(2, 0, 0), Y(0, 2, 0), Z(0, 0, 2);
    // Six inward-facing walls.
    test::add_quad(s, o, Z, X, m, grid_cell(0, 3, res));      // floor y=-1, normal +y
    test::add_quad(s, o + Y, X, Z, m, grid_cell(1, 3, res));  // ceiling, normal -y
    test::add_quad(s, o, X, Y, m, grid_cell(2, 3, res));      // z=-1, normal +z
    test::add_quad(s, o + Z, Y, X, m, grid_cell(3, 3, res));  // z=+1, normal -z
    test::add_quad(s, o, Y, Z, m, grid_cell(4, 3, res));      // x=-1, normal +x
    test::add_quad(s, o + X, Z, Y, m, grid_cell(5, 3, res));  // x=+1, normal -x
    return s;
}

double mean_covered(const BakeResult& r, const char* channel) {
    const auto& c = r.image.at(channel);
    double sum = 0.0;
    for (uint32_t t : r.texels.texels) sum += c[t];
    return sum / double(r.texels.covered_count());
}

TEST(RadiosityMap, FurnaceConvergesToLeOverOneMinusRho) {
    const int res = 48, passes = 256;
    const Scene s = furnace(0.8f, 1.0f, res);
    RadiosityMapSettings epochs;
    const BakeResult r = bake(s, res, passes, epochs);
    const double mean = mean_covered(r, "R");
    EXPECT_NEAR(mean, 5.0, 0.02 * 5.0) << "default scheme, mean over texels";
    // Every texel, not just the mean.
    const auto& R = r.image.at("R");
    size_t off = 0;
    for (uint32_t t : r.texels.texels) off += std::abs(R[t] - 5.0f) > 0.1f * 5.0f;
    EXPECT_EQ(off, 0u) << "texels more than 10% from 5.0";

    // The thesis's single-sample transport at the same ray count keeps a bias
    // (eq. 3.17: later bounces weighted by kappa < 1), from its first pass's
    // black map (B^0 = 0) on: 3.72. While the first pass read a map that had
    // no value yet, the gather followed every path there to its end: a
    // converged first map, and 4.92.
    RadiosityMapSettings thesis;
    thesis.scheme = RadiosityScheme::Thesis;
    const BakeResult t = bake(s, res, passes, thesis);
    const double thesis_mean = mean_covered(t, "R");
    RecordProperty("thesis_scheme_mean", std::to_string(thesis_mean));
    RecordProperty("epochs_scheme_mean", std::to_string(mean));
    std::printf("furnace rho=0.8 after %d passes: epochs %.4f, thesis %.4f (exact 5)\n", passes, mean, thesis_mean);
    EXPECT_LT(thesis_mean, 0.9 * 5.0) << "the thesis scheme should still be visibly biased here";
    EXPECT_EQ(r.stats.rays, t.stats.rays) << "same ray count for both schemes";
}

// The final gather computes each indirect ray's first bounce where it lands
// (direct light there by one emitter sample) and reads only the indirect
// layer from the map: the furnace's Le / (1 - rho) as the other schemes.
TEST(RadiosityMap, FinalGatherConvergesInTheFurnace) {
    const int res = 32, passes = 256;
    const Scene s = furnace(0.8f, 1.0f, res);
    RadiosityMapSettings settings;
    settings.scheme = RadiosityScheme::FinalGather;
    const BakeResult r = bake(s, res, passes, settings);
    EXPECT_NEAR(mean_covered(r, "R"), 5.0, 0.02 * 5.0);
    const auto& R = r.image.at("R");
    size_t off = 0;
    for (uint32_t t : r.texels.texels) off += std::abs(R[t] - 5.0f) > 0.1f * 5.0f;
    EXPECT_EQ(off, 0u) << "texels more than 10% from 5.0";
}

// The mean indirect light over the covered texels of each scheme's bake
// (`passes` passes), as a ratio to the path tracer's (the unbiased baseline,
// 512 passes, baked once), on monkey.glb's generated 64² atlas: charts small
// against texels, the case where reading the map is at its worst.
std::vector<double> monkey_indirect_ratios(const std::vector<RadiosityScheme>& schemes, int passes) {
    Scene s = load_scene(test::example_scene("monkey.glb"));
    AtlasOptions options;
    options.resolution = 64;
    prepare_lightmap_atlas(s, options);
    RadiosityMapSettings reference;
    reference.scheme = RadiosityScheme::PathTracing;
    const double truth = mean_covered(bake(s, 64, 512, reference), "indirect.G");
    std::vector<double> ratios;
    for (const RadiosityScheme scheme : schemes) {
        RadiosityMapSettings tested;
        tested.scheme = scheme;
        ratios.push_back(mean_covered(bake(s, 64, passes, tested), "indirect.G") / truth);
    }
    return ratios;
}

// A lookup next to a wall whose four texels' anchors were all hidden from
// the hit point read black: on monkey.glb at 64² the indirect light was 14%
// dark (-8.6% on the whole lightmap, 1024 passes against 8192 path-traced).
// The plain lookup then stood there (-1.7% on the whole); now the ray gathers
// where it landed, as wherever a tap is cut or next to a cut texel. Here
// (512 passes against 512 path-traced, whose mean over 4,074 texels is good
// to ~0.3%) the indirect layer is 1.4% dark with epochs, 1.2% with the final
// gather (2.1% and 3.9% with the plain lookup, 6.3% for the final gather
// before it read the whole value at cut texels). The bounds are ~2x those
// (they were 0.06 and 0.08 with the plain lookup); the black lookup (14%
// dark) fails them.
TEST(RadiosityMap, SmallChartsAgreeWithThePathTracerOnAverage) {
    const std::vector<double> ratios =
        monkey_indirect_ratios({RadiosityScheme::DoublingEpochs, RadiosityScheme::FinalGather}, 512);
    const double epochs = ratios[0], final_gather = ratios[1];
    std::printf("monkey.glb 64^2, indirect / path tracer's: epochs %.4f, final-gather %.4f\n", epochs, final_gather);
    EXPECT_NEAR(epochs, 1.0, 0.03);
    EXPECT_NEAR(final_gather, 1.0, 0.03);
}

// Where radiosity maps are known to fail (issue 13's failure modes): a room
// (4 x 2.5 x 4 m, albedo 0.6) with a box standing on its floor, a thin shelf
// through one wall, a lamp's pool of light under a spot light and a closed
// crate whose inside no light reaches, lit from one side of the room so that
// one corner gets mostly indirect light;
// generated 64² atlas. The mean of a region's texels against the path
// tracer's (the unbiased baseline). Measured (epochs 256 passes against
// 1,024 path-traced, 2026-11-26): the wall under the shelf -2.1%, the floor
// at the box's foot -1.2% (its texels straddle the contact shadow), the
// shelf's top -1.0%, the ceiling over the pool -0.9%, the box -0.8%, the
// rest within 0.4%; the final gather within those. Bounds: 2x to 3x the
// largest each region has shown (-2.6% at the box's foot before rays that
// land next to cut texels gathered there), at least 3% (each region's mean
// is good to ~0.5% at these counts). Inside the crate the path tracer finds
// no light, the map 0.5% of the room's mean (5.7% while the gather read the
// map after four unbaked sides in a row): bound 1%.
struct FailureModes {
    Scene scene;
    struct Region {
        const char* name;
        std::function<bool(glm::vec3)> contains;
        double bound;  // on |epochs / path tracer - 1|
    };
    std::vector<Region> regions;
    // Where no light reaches (the inside of a closed crate whose lid was
    // authored facing in): the path tracer's mean is 0 there, and the map's
    // must stay below `bound` x the room's mean.
    Region sealed;
};

FailureModes failure_mode_room() {
    FailureModes f;
    Scene& s = f.scene;
    const uint32_t grey = test::add_material(s, glm::vec3(0.6f));
    const glm::vec3 o(-2.0f, 0.0f, -2.0f), X(4, 0, 0), Y(0, 2.5f, 0), Z(0, 0, 4);
    test::add_quad(s, o, Z, X, grey);                                    // floor, +y
    test::add_quad(s, o + Y, X, Z, grey);                                // ceiling, -y
    test::add_quad(s, o, X, Y, grey);                                    // z = -2, +z
    test::add_quad(s, o + Z, Y, X, grey);                                // z = +2, -z
    test::add_quad(s, o, Y, Z, grey);                                    // x = -2, +x
    test::add_quad(s, o + X, Z, Y, grey);                                // x = +2, -x
    test::add_box(s, {-0.4f, 0.0f, -0.4f}, {0.4f, 0.8f, 0.4f}, grey);    // standing on the floor
    test::add_box(s, {-2.3f, 1.2f, -0.6f}, {-1.4f, 1.24f, 0.6f}, grey);  // a thin shelf through the x = -2 wall
    // A closed double-sided crate hanging in the room, its lid facing in, as
    // exporters leave such panels (grey_white_room's wall panelling): rays
    // from the lid land on the backs of the other five sides, whose texels
    // hold their lit outsides.
    const uint32_t crate = test::add_material(s, glm::vec3(0.6f), glm::vec3(0.0f), true);
    const glm::vec3 c(-1.2f, 1.6f, -1.9f), cx(1.2f, 0, 0), cy(0, 0.5f, 0), cz(0, 0, 1.2f);
    test::add_quad(s, c, cx, cz, crate);       // bottom, -y (out)
    test::add_quad(s, c + cy, cx, cz, crate);  // lid, -y (in)
    test::add_quad(s, c, cz, cy, crate);       // -x (out)
    test::add_quad(s, c + cx, cy, cz, crate);  // +x (out)
    test::add_quad(s, c, cy, cx, crate);       // -z (out)
    test::add_quad(s, c + cz, cx, cy, crate);  // +z (out)
    PunctualLight spot;                        // a lamp: a narrow cone onto the floor at x = 1.2
    spot.type = PunctualLight::Type::Spot;
    spot.position = {1.2f, 2.3f, 1.0f};
    spot.direction = {0.0f, -1.0f, 0.0f};
    spot.intensity = glm::vec3(20.0f);
    spot.inner_cone = 0.25f;
    spot.outer_cone = 0.35f;
    PunctualLight side = spot;  // a point light near the +x wall: the -x corners get indirect light
    side.type = PunctualLight::Type::Point;
    side.position = {1.7f, 1.2f, -1.0f};
    side.intensity = glm::vec3(4.0f);
    s.lights = {spot, side};
    AtlasOptions options;
    options.resolution = 64;
    prepare_lightmap_atlas(s, options);
    const auto on_floor = [](glm::vec3 p) { return std::abs(p.y) < 1e-3f; };
    f.regions = {
        {"floor at the box's foot",
         [=](glm::vec3 p) {
             const float d = std::max(std::abs(p.x), std::abs(p.z));
             return on_floor(p) && d > 0.4f && d < 0.8f;
         },
         0.06},
        {"the box",
         [](glm::vec3 p) { return std::max(std::abs(p.x), std::abs(p.z)) <= 0.401f && p.y > 1e-3f && p.y <= 0.801f; },
         0.03},
        {"the lamp's pool",
         [=](glm::vec3 p) { return on_floor(p) && glm::length(glm::vec2(p.x - 1.2f, p.z - 1.0f)) < 0.7f; }, 0.03},
        {"ceiling over the pool",
         [](glm::vec3 p) { return p.y > 2.499f && glm::length(glm::vec2(p.x - 1.2f, p.z - 1.0f)) < 0.7f; }, 0.04},
        {"the far corner (indirect light)", [](glm::vec3 p) { return p.x < -1.4f && p.z > 1.4f; }, 0.03},
        {"wall just above the shelf",
         [](glm::vec3 p) {
             return p.x < -1.999f && p.x > -2.001f && std::abs(p.z) < 0.6f && p.y > 1.24f && p.y < 1.5f;
         },
         0.03},
        {"wall just under the shelf",
         [](glm::vec3 p) {
             return p.x < -1.999f && p.x > -2.001f && std::abs(p.z) < 0.6f && p.y < 1.2f && p.y > 0.95f;
         },
         0.05},
        {"the shelf's top", [](glm::vec3 p) { return p.y > 1.2399f && p.y < 1.2401f && p.x > -1.999f; }, 0.045},
    };
    f.sealed = {"inside the crate's lid",
                [](glm::vec3 p) {
                    return std::abs(p.y - 2.1f) < 1e-3f && p.x > -0.95f && p.x < -0.25f && p.z > -1.65f && p.z < -0.95f;
                },
                0.01};
    return f;
}

double region_mean(const BakeResult& r, const std::function<bool(glm::vec3)>& in_region) {
    const auto& g = r.image.at("G");
    double sum = 0.0;
    size_t n = 0;
    for (size_t i = 0; i < r.texels.covered_count(); ++i)
        if (in_region(r.texels.samples[r.texels.first_sample[i]].position)) {
            sum += g[r.texels.texels[i]];
            ++n;
        }
    EXPECT_GT(n, 4u) << "a region with almost no texels";
    return n ? sum / double(n) : 0.0;
}

TEST(RadiosityMap, FailureModesAgainstThePathTracer) {
    const FailureModes f = failure_mode_room();
    RadiosityMapSettings path, final_gather;
    path.scheme = RadiosityScheme::PathTracing;
    final_gather.scheme = RadiosityScheme::FinalGather;
    const BakeResult truth = bake(f.scene, 64, 1024, path);
    const BakeResult epochs = bake(f.scene, 64, 256);
    const BakeResult gathered = bake(f.scene, 64, 256, final_gather);
    for (const FailureModes::Region& region : f.regions) {
        const double t = region_mean(truth, region.contains), e = region_mean(epochs, region.contains);
        const double g = region_mean(gathered, region.contains);
        std::printf("  %-34s path tracer %.4f  epochs %.4f (%+.1f%%)  final-gather %.4f (%+.1f%%)\n", region.name, t, e,
                    100.0 * (e / t - 1.0), g, 100.0 * (g / t - 1.0));
        EXPECT_NEAR(e / t, 1.0, region.bound) << region.name;
        EXPECT_NEAR(g / t, 1.0, region.bound) << region.name << " (final gather)";
    }
    const double room = region_mean(truth, [](glm::vec3) { return true; });
    const double t = region_mean(truth, f.sealed.contains), e = region_mean(epochs, f.sealed.contains);
    const double g = region_mean(gathered, f.sealed.contains);
    std::printf("  %-34s path tracer %.4f  epochs %.4f  final-gather %.4f  (the room's mean %.4f)\n", f.sealed.name, t,
                e, g, room);
    EXPECT_LT(t, 1e-3 * room) << "light inside a closed crate: the test scene leaks";
    EXPECT_LT(e, f.sealed.bound * room) << f.sealed.name;
    EXPECT_LT(g, f.sealed.bound * room) << f.sealed.name << " (final gather)";
}

// The brute-force baseline reads no map: unbiased at any pass count.
TEST(RadiosityMap, PathTracingBaselineConvergesInTheFurnace) {
    const int res = 32;
    const Scene s = furnace(0.8f, 1.0f, res);
    RadiosityMapSettings settings;
    settings.scheme = RadiosityScheme::PathTracing;
    const BakeResult r = bake(s, res, 64, settings);
    EXPECT_NEAR(mean_covered(r, "R"), 5.0, 0.02 * 5.0);
}

// The path tracer (the lightmap's reference) reflects the albedo texture
// where each path lands, not a per-triangle or per-texel average. A floor
// (2x2 m, two triangles, 10 x 10 texels) is white in its middle square
// and black elsewhere; a point light 0.5 m above its centre lights mostly the
// white square. A black ceiling 1 m above receives the light directly and the
// light the floor reflects, the latter known by quadrature of the floor's
// radiosity a(y) E(y) with the texture itself (Texture::sample). The floor's
// mean albedo (0.25) gives 2.5 times less reflected light on the ceiling:
// the test fails any averaging of the texture over a triangle.
TEST(RadiosityMap, PathTracerReflectsTexturesWhereThePathsLand) {
    Scene s;
    Texture pattern;
    pattern.width = pattern.height = 64;
    for (int y = 0; y < 64; ++y)
        for (int x = 0; x < 64; ++x) {
            const bool white = x >= 16 && x < 48 && y >= 16 && y < 48;
            pattern.texels.push_back(glm::vec4(white ? 1.0f : 0.0f, white ? 1.0f : 0.0f, white ? 1.0f : 0.0f, 1.0f));
        }
    s.textures.push_back(pattern);
    const uint32_t floor = test::add_material(s, glm::vec3(1.0f));
    s.materials[floor].base_color_texture = 0;
    const uint32_t black = test::add_material(s, glm::vec3(0.0f));
    const int res = 32;
    test::add_quad(s, {-1, 0, 1}, {2, 0, 0}, {0, 0, -2}, floor, grid_cell(0, 2, res));  // y = 0, facing up
    for (size_t v = 0; v < 4; ++v) s.uv0[v] = glm::vec2(s.positions[v].x + 1.0f, s.positions[v].z + 1.0f) * 0.5f;
    test::add_quad(s, {-1, 1, -1}, {2, 0, 0}, {0, 0, 2}, black, grid_cell(1, 2, res));  // y = 1, facing down
    PunctualLight light;
    light.position = {0.0f, 0.5f, 0.0f};
    light.intensity = glm::vec3(1.0f);  // W/sr
    s.lights.push_back(light);

    // Irradiance/pi at a ceiling point q: direct, and reflected by the floor
    // (radiance a E / pi, cos·cos/r² = 1/r⁴ between planes 1 m apart),
    // by the midpoint rule on 256² floor cells.
    auto ceiling_value = [&](glm::vec3 q, bool mean_albedo) {
        const float h = 0.5f;  // the light's height over the floor, and under the ceiling
        const glm::vec3 to_light = light.position - q;
        const double direct = h / std::pow(double(glm::length(to_light)), 3.0);
        const int n = 256;
        const double cell = 2.0 / n;
        double reflected = 0.0;
        for (int i = 0; i < n; ++i)
            for (int k = 0; k < n; ++k) {
                const double x = -1.0 + (i + 0.5) * cell, z = -1.0 + (k + 0.5) * cell;
                const double a = mean_albedo ? 0.25 : pattern.sample(glm::vec2((x + 1.0) / 2.0, (z + 1.0) / 2.0)).r;
                const double e = h / std::pow(x * x + z * z + h * h, 1.5);
                const double r2 = (x - q.x) * (x - q.x) + (z - q.z) * (z - q.z) + 1.0;
                reflected += a * e / M_PI / (r2 * r2) * cell * cell;
            }
        return std::pair<double, double>(direct / M_PI, reflected / M_PI);
    };

    RadiosityMapSettings settings;
    settings.scheme = RadiosityScheme::PathTracing;
    const BakeResult r = bake(s, res, 256, settings);
    double baked = 0.0, direct = 0.0, reflected = 0.0, reflected_if_averaged = 0.0;
    size_t texels = 0;
    for (size_t i = 0; i < r.texels.covered_count(); ++i) {
        if (r.texels.samples[r.texels.first_sample[i]].position.y < 0.5f) continue;  // the floor's texels
        for (uint32_t k = r.texels.first_sample[i]; k < r.texels.first_sample[i + 1]; ++k) {
            const glm::vec3 q = r.texels.samples[k].position;
            const auto [d, f] = ceiling_value(q, false);
            direct += d / r.texels.sample_count(i);
            reflected += f / r.texels.sample_count(i);
            reflected_if_averaged += ceiling_value(q, true).second / r.texels.sample_count(i);
        }
        baked += r.image.at("R")[r.texels.texels[i]];
        ++texels;
    }
    ASSERT_GT(texels, 10u);
    const double baked_reflected = (baked - direct) / double(texels);
    reflected /= double(texels);
    reflected_if_averaged /= double(texels);
    std::printf("ceiling's reflected light: baked %.5f, quadrature %.5f, with the mean albedo %.5f\n", baked_reflected,
                reflected, reflected_if_averaged);
    ASSERT_GT(reflected / reflected_if_averaged, 2.0) << "the scene must tell texture from mean";
    EXPECT_NEAR(baked_reflected, reflected, 0.03 * reflected);
}

// Texels where the light changes (atlas.light_density): two floors under a
// sun straight down, one half shaded by a roof over it (a shadow's edge
// across it), the other evenly lit, and the roof, lit by nothing directly.
// The shaded floor gets more than the scene's density, the even floor and
// the roof less, as many texels in all (area x scale^2 summed); at least
// four times the even floor's texels per m² once packed, and the texel
// count within 10% of the uniform atlas's. A chart left to its own scale
// (an unlit one) is not measured and keeps 1.
TEST(LightDensity, AShadowsEdgeGetsTexelsThatAnEvenlyLitFloorGivesUp) {
    gpu();
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(0.5f));
    test::add_quad(s, {-3, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);  // floor A, facing up: x in [-3, -1]
    test::add_quad(s, {1, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);   // floor B, facing up: x in [1, 3]
    test::add_quad(s, {-3, 1, -1}, {1, 0, 0}, {0, 0, 2}, m);  // roof over A's x < -2, facing down
    test::add_sun(s, glm::vec3(0.0f, -1.0f, 0.0f), 1.0f);
    const Tracer tracer(s);
    const int res = 128;
    auto texels_per_m2 = [&](const Scene& scene, float x_lo, float x_hi) {
        double texels = 0.0, area = 0.0;
        for (size_t t = 0; t < scene.triangles.size(); ++t) {
            const glm::uvec3 v = scene.triangles[t];
            const float x = (scene.positions[v.x].x + scene.positions[v.y].x + scene.positions[v.z].x) / 3.0f;
            if (x < x_lo || x > x_hi || scene.positions[v.x].y != 0.0f) continue;
            const glm::vec2 a = scene.uv1[v.x], b = scene.uv1[v.y], c = scene.uv1[v.z];
            texels += 0.5 * std::abs((b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y)) * res * res;
            area += scene.triangle_area(t);
        }
        return texels / area;
    };
    auto atlas = [&](bool light_density, LightScales* measured) {
        Scene scene = s;
        AtlasOptions options;
        options.resolution = res;
        if (light_density)
            options.light_scales = [&](const std::vector<uint32_t>& chart, size_t count,
                                       const std::vector<uint8_t>& few, double texel) {
                *measured = light_driven_chart_scales(scene, tracer, chart, count, few, texel, nullptr);
                return measured->scale;
            };
        const AtlasReport report = generate_lightmap_uvs(scene, options);
        const TexelSamples texels = rasterize_texel_samples(scene, res, res, 1);
        return std::make_tuple(report, scene, texels.covered_count());
    };
    LightScales scales;
    const auto [uniform_report, uniform, uniform_texels] = atlas(false, nullptr);
    const auto [report, lit, texels] = atlas(true, &scales);
    // The charts: A, B and the roof, by their first triangle (one chart each).
    const uint32_t a = report.triangle_chart[0], b = report.triangle_chart[2], roof = report.triangle_chart[4];
    std::printf("  scales: shaded floor %.3f, even floor %.3f, roof %.3f (k %.3g, %.3g, %.3g); %zu rays\n",
                scales.scale[a], scales.scale[b], scales.scale[roof], scales.k[a], scales.k[b], scales.k[roof],
                size_t(scales.rays));
    EXPECT_GT(scales.scale[a], 1.0);
    EXPECT_LT(scales.scale[b], 1.0);
    EXPECT_LT(scales.scale[roof], 1.0);
    EXPECT_GT(scales.k[a], 100.0 * scales.k[b]) << "only pairs across the edge differ";
    EXPECT_NEAR(4.0 * (scales.scale[a] * scales.scale[a] + scales.scale[b] * scales.scale[b]) +
                    2.0 * scales.scale[roof] * scales.scale[roof],
                10.0, 1e-6)
        << "as many texels: area x scale^2 summed is the area";
    EXPECT_EQ(report.light_scaled_charts, 3u);
    const double shaded = texels_per_m2(lit, -3.5f, -0.5f), even = texels_per_m2(lit, 0.5f, 3.5f);
    std::printf("  texels per m²: shaded floor %.0f, even floor %.0f; covered texels %zu (uniform: %zu)\n", shaded,
                even, texels, uniform_texels);
    EXPECT_GT(shaded, 4.0 * even);
    EXPECT_NEAR(double(texels), double(uniform_texels), 0.1 * double(uniform_texels));
    EXPECT_NEAR(texels_per_m2(uniform, -3.5f, -0.5f), texels_per_m2(uniform, 0.5f, 3.5f),
                0.05 * texels_per_m2(uniform, 0.5f, 3.5f));

    std::vector<uint8_t> leave(report.charts, 0);
    leave[roof] = 1;
    const LightScales left =
        light_driven_chart_scales(lit, tracer, report.triangle_chart, report.charts, leave, 0.05, nullptr);
    EXPECT_EQ(left.scale[roof], 1.0);
    EXPECT_EQ(left.k[roof], 0.0);
}

// `s`'s atlas at 128² with the light's own density (no sky), and the first
// look's scales.
std::pair<AtlasReport, LightScales> light_driven_atlas(const Scene& s) {
    const Tracer tracer(s);
    Scene scene = s;
    AtlasOptions options;
    options.resolution = 128;
    LightScales scales;
    options.light_scales = [&](const std::vector<uint32_t>& chart, size_t count, const std::vector<uint8_t>& few,
                               double texel) {
        scales = light_driven_chart_scales(scene, tracer, chart, count, few, texel, nullptr);
        return scales.scale;
    };
    const AtlasReport report = generate_lightmap_uvs(scene, options);
    return {report, scales};
}

// The indirect light's first look: two floors lit alike by a sun overhead,
// one with a wall standing on it edge-on to the sun (no shadow: the direct
// light is even on both). Near the wall's foot a point sees the wall where
// the other floor sees open space, so its indirect light changes there
// (openness, light_density.cpp's chart_k): that floor keeps more texels
// than the open one, which is even in every light and gives them up.
TEST(LightDensity, AWallsFootGetsTexelsThatAnOpenFloorGivesUp) {
    gpu();
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(0.5f), glm::vec3(0.0f), true);
    test::add_quad(s, {-3, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);    // floor A, facing up: x in [-3, -1]
    test::add_quad(s, {1, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);     // floor B, facing up: x in [1, 3]
    test::add_quad(s, {-3, 0, 0}, {2, 0, 0}, {0, 0.5f, 0}, m);  // a wall across A, in the sun's plane
    test::add_sun(s, glm::vec3(0.0f, -1.0f, 0.0f), 1.0f);
    const auto [report, scales] = light_driven_atlas(s);
    const uint32_t a = report.triangle_chart[0], b = report.triangle_chart[2];
    std::printf("  scales: floor with a wall %.3f, open floor %.3f (k %.3g, %.3g)\n", scales.scale[a], scales.scale[b],
                scales.k[a], scales.k[b]);
    EXPECT_GT(scales.k[a], 0.0);
    EXPECT_EQ(scales.k[b], 0.0) << "an open floor under a sun: the same light everywhere";
    EXPECT_GT(scales.scale[a], 1.5 * scales.scale[b]);
}

// The first look's shadow rays pass see-through surfaces as the bake's do:
// a sun on two floors, half of one under a clear glass pane (transmission
// 1: it passes all the light), half of the other under an opaque roof. Only
// the roof's shadow has an edge; the glass casts none (before: every
// surface stopped a shadow ray, and the glass's "shadow" drew texels).
TEST(LightDensity, GlassCastsNoEdgeARoofDoes) {
    gpu();
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(0.5f));
    const uint32_t glass = test::add_material(s, glm::vec3(1.0f));
    s.materials[glass].transmission = 1.0f;
    test::add_quad(s, {-3, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);      // floor A, facing up: x in [-3, -1]
    test::add_quad(s, {1, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);       // floor B, facing up: x in [1, 3]
    test::add_quad(s, {-3, 1, -1}, {1, 0, 0}, {0, 0, 2}, glass);  // glass over A's x < -2, facing down
    test::add_quad(s, {1, 1, -1}, {1, 0, 0}, {0, 0, 2}, m);       // a roof over B's x < 2, facing down
    test::add_sun(s, glm::vec3(0.0f, -1.0f, 0.0f), 1.0f);
    const auto [report, scales] = light_driven_atlas(s);
    const uint32_t a = report.triangle_chart[0], b = report.triangle_chart[2];
    std::printf("  scales: floor under glass %.3f, floor under a roof %.3f (k %.3g, %.3g)\n", scales.scale[a],
                scales.scale[b], scales.k[a], scales.k[b]);
    EXPECT_LT(scales.k[a], 1e-3 * scales.k[b]);
    EXPECT_GT(scales.scale[b], 2.0 * scales.scale[a]);
}

// A lit room (six walls facing in, a point light inside) wrapped in a shell
// 0.1 m outside it whose six walls face out, to the void, as a closed
// interior's outer walls do: no light can reach the shell. Its charts are
// found unlit and packed at 1/8 of the density (1/64 of the texels); with a
// sky, or a light outside, they are lit again.
TEST(UnlitCharts, AClosedRoomsOuterWallsGetFewTexels) {
    gpu();
    Scene s = furnace(0.5f, 0.0f, 64);
    test::add_box(s, glm::vec3(-1.1f), glm::vec3(1.1f), test::add_material(s, glm::vec3(0.5f)));
    PunctualLight inside;
    inside.intensity = glm::vec3(1.0f);
    s.lights.push_back(inside);
    const Tracer tracer(s);
    auto atlas = [&](Scene scene, bool sky) {
        AtlasOptions options;
        options.resolution = 128;
        options.find_unlit_charts = [&](const std::vector<uint32_t>& chart, size_t count) {
            return find_unlit_charts(scene, tracer, chart, count, sky).unlit;
        };
        AtlasReport report = generate_lightmap_uvs(scene, options);
        // Texel area of the shell (x beyond 1.05) against the room's, per m².
        double shell = 0.0, room = 0.0;
        for (size_t t = 0; t < scene.triangles.size(); ++t) {
            const glm::uvec3 v = scene.triangles[t];
            const glm::vec2 a = scene.uv1[v.x], b = scene.uv1[v.y], c = scene.uv1[v.z];
            const double texels = 0.5 * std::abs((b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y)) * 128 * 128;
            (std::abs(scene.positions[v.x].x) > 1.05f || std::abs(scene.positions[v.x].y) > 1.05f ||
                     std::abs(scene.positions[v.x].z) > 1.05f
                 ? shell
                 : room) += texels / scene.triangle_area(t);
        }
        return std::make_pair(report, shell / room);
    };
    const auto [dark, dark_ratio] = atlas(s, false);
    EXPECT_EQ(dark.unlit_charts, 6u);
    EXPECT_NEAR(dark.unlit_area_fraction, 6 * 2.2 * 2.2 / (6 * 2.2 * 2.2 + 6 * 2.0 * 2.0), 1e-4);
    EXPECT_NEAR(dark_ratio, 1.0 / 64.0, 0.2 / 64.0);  // whole texels round each chart up a little
    const auto [sky, sky_ratio] = atlas(s, true);
    EXPECT_EQ(sky.unlit_charts, 0u);
    EXPECT_NEAR(sky_ratio, 1.0, 0.1);
    Scene outside_light = s;
    test::add_sun(outside_light, glm::vec3(0.0f, -1.0f, 0.0f), 1.0f);
    const Tracer tracer2(outside_light);
    AtlasOptions options;
    options.resolution = 128;
    options.find_unlit_charts = [&](const std::vector<uint32_t>& chart, size_t count) {
        return find_unlit_charts(outside_light, tracer2, chart, count, false).unlit;
    };
    EXPECT_EQ(generate_lightmap_uvs(outside_light, options).unlit_charts, 5u) << "the sun lights the shell's top";
}

// A double-sided panel lit on one side and baked for the other: its texels
// hold the side facing a large black wall (the side that sees more of the
// scene), while a small receiver on the other side sees the lit side. Where
// the receiver's rays land on the panel's unbaked side, the light is
// gathered there rather than read from the map (which holds the dark side:
// 11% darkness on grey_white_room). The receiver then agrees with the path
// tracer, and the panel's reflection is a sixth of its light, so reading
// the wrong side would fail the bound.
TEST(RadiosityMap, LightOnTheUnbakedSideOfADoubleSidedPanelIsGathered) {
    gpu();
    Scene s;
    const int res = 64;
    const uint32_t panel = test::add_material(s, glm::vec3(0.8f), glm::vec3(0.0f), true);
    const uint32_t black = test::add_material(s, glm::vec3(0.0f));
    test::add_quad(s, {0, -1, -1}, {0, 0, 2}, {0, 2, 0}, panel, grid_cell(0, 3, res));     // x = 0, front -x
    test::add_quad(s, {0.3f, -2, -2}, {0, 4, 0}, {0, 0, 4}, black, grid_cell(1, 3, res));  // x = 0.3, facing -x
    test::add_quad(s, {-1, -0.3f, -0.3f}, {0, 0.6f, 0}, {0, 0, 0.6f}, black, grid_cell(2, 3, res));  // receiver, +x
    PunctualLight light;
    light.position = {-0.5f, 0.0f, 0.0f};
    light.intensity = glm::vec3(1.0f);
    s.lights.push_back(light);
    ASSERT_EQ(face_double_sided_charts_to_the_scene(s, Tracer(s)).charts, 1u) << "baked for the black wall's side";

    auto receiver_mean = [&](const BakeResult& r, double* direct) {
        double sum = 0.0, closed_form = 0.0;
        size_t n = 0;
        for (size_t i = 0; i < r.texels.covered_count(); ++i) {
            const glm::vec3 q = r.texels.samples[r.texels.first_sample[i]].position;
            if (q.x > -0.9f) continue;
            sum += r.image.at("R")[r.texels.texels[i]];
            for (uint32_t k = r.texels.first_sample[i]; k < r.texels.first_sample[i + 1]; ++k) {
                const glm::vec3 d = light.position - r.texels.samples[k].position;
                closed_form += d.x / std::pow(double(glm::length(d)), 3.0) / M_PI / r.texels.sample_count(i);
            }
            ++n;
        }
        if (direct) *direct = closed_form / double(n);
        return sum / double(n);
    };
    RadiosityMapSettings path_tracing;
    path_tracing.scheme = RadiosityScheme::PathTracing;
    double direct = 0.0;
    const double reference = receiver_mean(bake(s, res, 512, path_tracing), &direct);
    const double map = receiver_mean(bake(s, res, 256), nullptr);
    std::printf("receiver: path tracer %.4f (direct %.4f), epochs %.4f\n", reference, direct, map);
    ASSERT_GT((reference - direct) / reference, 0.12) << "the panel's reflection must matter";
    EXPECT_NEAR(map, reference, 0.03 * reference);
}

// Light that reaches a receiver only across two unbaked sides in a row: a
// spot lights the top of a double-sided floor panel B, whose top's light
// reaches the receiver only by way of the unbaked side of a double-sided
// wall A (both baked for their other sides, which face black walls). Where a
// ray gathering at A's unbaked side lands on B's unbaked side, the light is
// gathered there too (radiosity_gather.comp's back_side_radiance); reading
// B's map there would return the dark side's light and the receiver would
// be nearly black (grey_white_room was 2.3% dark for it).
TEST(RadiosityMap, LightAcrossTwoUnbakedSidesInARowIsGathered) {
    gpu();
    Scene s;
    const int res = 64;
    const uint32_t panel = test::add_material(s, glm::vec3(0.8f), glm::vec3(0.0f), true);
    const uint32_t black = test::add_material(s, glm::vec3(0.0f));
    test::add_quad(s, {0, 0, -0.5f}, {0, 1, 0}, {0, 0, 1}, panel, grid_cell(0, 3, res));       // A: x = 0, front +x
    test::add_quad(s, {0.3f, 0, -0.5f}, {0, 0, 1}, {1, 0, 0}, panel, grid_cell(1, 3, res));    // B: y = 0, front +y
    test::add_quad(s, {-0.2f, -1, -1.5f}, {0, 3, 0}, {0, 0, 3}, black, grid_cell(2, 3, res));  // behind A
    test::add_quad(s, {-1, -0.2f, -1.5f}, {0, 0, 3}, {3, 0, 0}, black, grid_cell(3, 3, res));  // below B
    test::add_quad(s, {0.3f, 0.6f, -0.15f}, {0, 0, 0.3f}, {0, 0.3f, 0}, black, grid_cell(4, 3, res));  // receiver, -x
    PunctualLight spot;
    spot.type = PunctualLight::Type::Spot;
    spot.position = {0.8f, 0.6f, 0.0f};
    spot.direction = {0.0f, -1.0f, 0.0f};  // onto B's top alone (A is more than 53 degrees off its axis)
    spot.intensity = glm::vec3(4.0f);
    spot.inner_cone = 0.4f;
    spot.outer_cone = 0.5f;
    s.lights.push_back(spot);
    ASSERT_EQ(face_double_sided_charts_to_the_scene(s, Tracer(s)).charts, 2u) << "A and B baked for their dark sides";

    auto receiver_mean = [&](const BakeResult& r) {
        double sum = 0.0;
        size_t n = 0;
        for (size_t i = 0; i < r.texels.covered_count(); ++i) {
            const glm::vec3 q = r.texels.samples[r.texels.first_sample[i]].position;
            if (std::abs(q.x - 0.3f) > 1e-3f || q.y < 0.59f) continue;
            sum += r.image.at("R")[r.texels.texels[i]];
            ++n;
        }
        return n ? sum / double(n) : 0.0;
    };
    RadiosityMapSettings path_tracing;
    path_tracing.scheme = RadiosityScheme::PathTracing;
    const double reference = receiver_mean(bake(s, res, 512, path_tracing));
    // 1024 passes: at 256 the map's receiver mean spread from -8% to +10% of
    // the path tracer's over seeds 1-5 (the light arrives by rare two-back
    // paths), so the 5% bound held by the seed's luck; at 1024 seeds 1-7 lie
    // within 2.5% of it.
    const double map = receiver_mean(bake(s, res, 1024));
    std::printf("receiver: path tracer %.5f, epochs %.5f\n", reference, map);
    ASSERT_GT(reference, 1e-3) << "light reaches the receiver across A and B";
    EXPECT_NEAR(map, reference, 0.05 * reference);
}

// A room of double-sided walls exported with their fronts facing out (as the
// staircase's back rooms are): baked as given, every wall is black inside
// (its texels face the void); turned to face the scene
// (face_double_sided_charts_to_the_scene), the walls carry the same light as
// the same room built facing in, and a free-standing double-sided panel in
// the room (both sides in the scene) keeps its front.
TEST(RadiosityMap, DoubleSidedWallsFacingOutAreBakedForTheRoom) {
    const int res = 64, passes = 96;
    auto room = [&](bool facing_out) {
        Scene s;
        const uint32_t wall = test::add_material(s, glm::vec3(0.5f), glm::vec3(0.0f), true);
        const uint32_t light = test::add_material(s, glm::vec3(0.0f), glm::vec3(10.0f));
        const glm::vec3 o(-1.0f), X(2, 0, 0), Y(0, 2, 0), Z(0, 0, 2);
        const glm::vec3 walls[6][3] = {{o, Z, X}, {o + Y, X, Z}, {o, X, Y}, {o + Z, Y, X}, {o, Y, Z}, {o + X, Z, Y}};
        int cell = 0;
        for (const auto& w : walls)  // inward: cross(u, v) points into the room
            if (facing_out) test::add_quad(s, w[0], w[2], w[1], wall, grid_cell(cell++, 3, res));
            else test::add_quad(s, w[0], w[1], w[2], wall, grid_cell(cell++, 3, res));
        test::add_quad(s, {-0.25f, 0.95f, -0.25f}, {0.5f, 0, 0}, {0, 0, 0.5f}, light, grid_cell(cell++, 3, res));
        test::add_quad(s, {-0.5f, -1.0f, 0.0f}, {0, 1.2f, 0}, {1.0f, 0, 0}, wall, grid_cell(cell++, 3, res));
        return s;
    };
    auto wall_mean = [](const BakeResult& r) {  // texels on the six walls (|coordinate| = 1)
        double sum = 0.0;
        size_t n = 0;
        for (size_t i = 0; i < r.texels.covered_count(); ++i) {
            const glm::vec3 p = r.texels.samples[r.texels.first_sample[i]].position;
            if (std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)}) < 0.999f) continue;
            sum += r.image.at("R")[r.texels.texels[i]];
            ++n;
        }
        return sum / double(n);
    };
    gpu();
    Scene inward = room(false);
    EXPECT_EQ(face_double_sided_charts_to_the_scene(inward, Tracer(inward)).charts, 0u);
    const double expected = wall_mean(bake(inward, res, passes));
    ASSERT_GT(expected, 0.01);

    Scene outward = room(true);
    EXPECT_LT(wall_mean(bake(outward, res, passes)), 0.01 * expected) << "as given, the walls face the void";
    const TurnedCharts turned = face_double_sided_charts_to_the_scene(outward, Tracer(outward));
    EXPECT_EQ(turned.charts, 6u) << "the six walls, not the panel (both its sides see the room) nor the light";
    EXPECT_EQ(turned.triangles, 12u);
    ASSERT_EQ(outward.triangle_turned.size(), outward.triangles.size());
    EXPECT_EQ(std::count(outward.triangle_turned.begin(), outward.triangle_turned.end(), 1), 12);
    const double turned_mean = wall_mean(bake(outward, res, passes));
    std::printf("  wall mean: built facing in %.4f, facing out and turned %.4f\n", expected, turned_mean);
    EXPECT_NEAR(turned_mean / expected, 1.0, 0.03);
}

// The denoiser (--denoise) on the furnace, where every texel has the same
// answer: the raw map's texel-to-texel spread is noise, and filtering must
// cut it by more than half without moving the mean (a filter that averages
// within charts keeps a flat answer where it was), keeping the raw map.
TEST(LightmapDenoiser, CutsTheFurnacesNoiseAndKeepsItsMean) {
    const int res = 48;
    const Scene s = furnace(0.8f, 1.0f, res);
    BakeResult r = bake(s, res, 64);
    auto spread_and_mean = [&](const char* channel) {
        double sum = 0.0, sq = 0.0;
        for (uint32_t t : r.texels.texels) {
            sum += r.image.at(channel)[t];
            sq += double(r.image.at(channel)[t]) * r.image.at(channel)[t];
        }
        const double n = double(r.texels.covered_count()), mean = sum / n;
        return std::pair{std::sqrt(std::max(0.0, sq / n - mean * mean)) / mean, mean};
    };
    const auto [raw_spread, raw_mean] = spread_and_mean("R");
    LightmapDenoiser(s, r.texels).denoise(r.image);
    const auto [spread, mean] = spread_and_mean("R");
    const auto [kept_spread, kept_mean] = spread_and_mean("raw.R");
    std::printf("  furnace, 64 passes: relative spread raw %.4f, denoised %.4f; mean %.4f -> %.4f\n", raw_spread,
                spread, raw_mean, mean);
    EXPECT_LT(spread, 0.5 * raw_spread);
    EXPECT_NEAR(mean / raw_mean, 1.0, 0.002);
    EXPECT_EQ(kept_spread, raw_spread);
    EXPECT_EQ(kept_mean, raw_mean);
}

// A width x height atlas of texels 0.1 m apart on the plane y = 0, one
// sample point each, filled by value(x, y) with the given standard error,
// each the mean of `passes` samples (the "samples" channel and the
// lightfarm.pass attribute, as a bake writes them), every one of them lit
// where the value is not 0 (the "lit" channel; a value below 0 is a draw
// of noise around a lit one); the left half is
// triangles 0, 1 (chart A), the right half 2, 3 (chart B).
struct FlatAtlas {
    Scene scene;
    TexelSamples texels;
    FloatImage image;
};
template <class Value>
FlatAtlas flat_atlas(int width, int height, float error, Value value, int passes = 16) {
    FlatAtlas a;
    const uint32_t m = test::add_material(a.scene, glm::vec3(0.5f));
    const float side = 0.1f * float(width) / 2.0f;
    test::add_quad(a.scene, {0, 0, 0}, {0, 0, 1.6f}, {side, 0, 0}, m);     // triangles 0, 1: chart A
    test::add_quad(a.scene, {side, 0, 0}, {0, 0, 1.6f}, {side, 0, 0}, m);  // triangles 2, 3: chart B
    a.texels.width = a.image.width = width;
    a.texels.height = a.image.height = height;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            a.texels.texels.push_back(uint32_t(y * width + x));
            a.texels.first_sample.push_back(uint32_t(a.texels.samples.size()));
            a.texels.samples.push_back({glm::vec3(0.1f * float(x), 0.0f, 0.1f * float(y)), glm::vec3(0, 1, 0),
                                        glm::vec3(0, 1, 0), x >= width / 2 ? 2u : 0u, glm::vec2(0.0f)});
            a.texels.texel_world_size.push_back(0.1f);
            for (const char* c : {"R", "G", "B"}) a.image.channel(c)[size_t(y * width + x)] = value(x, y);
            a.image.channel("error")[size_t(y * width + x)] = error;
            a.image.channel("samples")[size_t(y * width + x)] = float(passes);
            a.image.channel("lit")[size_t(y * width + x)] =
                a.image.at("R")[size_t(y * width + x)] != 0.0f ? 1.0f : 0.0f;
        }
    a.texels.first_sample.push_back(uint32_t(a.texels.samples.size()));
    a.image.number_attributes["lightfarm.pass"] = passes;
    return a;
}

// Texels as a short bake leaves them where light is found by few paths: each
// the mean of 16 samples that are 4 with probability 1/4 and 0 otherwise
// (irradiance 1), with the standard error its own samples give. That error
// rises with the texel's value (a texel that saw no light claims none), so
// weighing neighbours by the centre's own sigma kept every dark texel to
// itself and averaged the bright ones away: the mean fell by 2.6% (RMS error
// 0.43 -> 0.12). Weighed by the neighbourhood's sigma (SVGF's filtered
// variance) it fell by 0.65% (RMS error 0.43 -> 0.053); each chart now keeps
// its raw sum exactly (conserve_chart_light), so each half of the atlas, a
// chart of its own, has the raw mean to float precision. (With the
// low-frequency restore, 2026-11-28: RMS error 0.43 -> 0.063, as some of
// the noise's low frequencies come back with what the filter moved.)
TEST(LightmapDenoiser, KeepsTheMeanOfSkewedNoise) {
    gpu();
    const int width = 64, height = 32, samples = 16;
    std::mt19937 rng(9);
    std::bernoulli_distribution found(0.25);
    std::vector<float> value(size_t(width) * height), error(value.size());
    for (size_t t = 0; t < value.size(); ++t) {
        int k = 0;
        for (int s = 0; s < samples; ++s) k += found(rng) ? 1 : 0;
        const double mean = 4.0 * k / samples;
        const double variance = (k * (4.0 - mean) * (4.0 - mean) + (samples - k) * mean * mean) / (samples - 1);
        value[t] = float(mean);
        error[t] = float(std::sqrt(variance / samples));
    }
    FlatAtlas a = flat_atlas(width, height, 0.0f, [&](int x, int y) { return value[size_t(y * width + x)]; });
    a.image.channel("error") = error;
    for (size_t t = 0; t < value.size(); ++t) a.image.channel("lit")[t] = value[t] / 4.0f;  // k of the 16 samples
    LightmapDenoiser(a.scene, a.texels).denoise(a.image);
    double raw[2] = {0.0, 0.0}, denoised[2] = {0.0, 0.0}, raw_sq = 0.0, denoised_sq = 0.0;
    for (size_t t = 0; t < value.size(); ++t) {
        const int chart = int(t % size_t(width)) >= width / 2 ? 1 : 0;
        raw[chart] += a.image.at("raw.R")[t];
        denoised[chart] += a.image.at("R")[t];
        raw_sq += std::pow(a.image.at("raw.R")[t] - 1.0, 2);
        denoised_sq += std::pow(a.image.at("R")[t] - 1.0, 2);
    }
    const double n = double(value.size());
    std::printf("  skewed noise: mean %.4f -> %.4f, RMS error %.4f -> %.4f\n", (raw[0] + raw[1]) / n,
                (denoised[0] + denoised[1]) / n, std::sqrt(raw_sq / n), std::sqrt(denoised_sq / n));
    for (int chart = 0; chart < 2; ++chart) {
        EXPECT_NEAR(denoised[chart] / raw[chart], 1.0, 1e-5) << "chart " << chart;
    }
    EXPECT_LT(denoised_sq, 0.25 * raw_sq);
}

// Two charts side by side in the atlas, on one plane, equally noisy, one at
// 1 and one at 3: the filter's 61-texel footprint spans both, and the
// luminance weight alone would let them mix (exp(-2 / (4 x 0.5)) = 0.37);
// the chart guard keeps each exactly what it was.
TEST(LightmapDenoiser, NeverMixesCharts) {
    gpu();
    const int width = 32, height = 16;
    FlatAtlas a = flat_atlas(width, height, 0.5f, [&](int x, int) { return x >= width / 2 ? 3.0f : 1.0f; });
    LightmapDenoiser(a.scene, a.texels).denoise(a.image);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x)
            ASSERT_NEAR(a.image.at("R")[size_t(y * width + x)], x >= width / 2 ? 3.0f : 1.0f, 1e-5f) << x << ", " << y;
}

// Light that falls across a chart (a wall towards a corner) is a gradient up
// to the chart's border. A kernel that the border cuts off on one side would
// pull the texels there towards the inside (by 0.19 at the border texel of
// this ramp, 9% of its value, before taps needed their mirror image in the
// chart too); one that keeps only taps whose mirror image is in the chart
// is symmetric everywhere and leaves any linear ramp as it was.
TEST(LightmapDenoiser, KeepsALinearRampUpToTheChartsBorder) {
    gpu();
    const int width = 64, height = 32;
    auto ramp = [](int x, int y) { return 2.0f + 0.05f * float(x % 32) + 0.02f * float(y); };
    FlatAtlas a = flat_atlas(width, height, 2.0f, ramp);
    LightmapDenoiser(a.scene, a.texels).denoise(a.image);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x)
            ASSERT_NEAR(a.image.at("R")[size_t(y * width + x)], ramp(x, y), 1e-4f) << x << ", " << y;
}

// A flat wall stays flat (issue #35: the staircase showed a jagged bright
// streak on a flat wall before the filter was on by default). A uniformly
// lit wall with Gaussian noise (sigma 0.2, the error channel saying so), in
// charts 32, 4, 2 and 1 texels wide: a plane fit near a border extrapolates,
// and on a chart a few texels wide every texel is near one, so a streak would
// show there first. Measured (2026-11-28, llvmpipe, with the low-frequency
// restore): RMS error 0.029 at a wide chart's border texels, 0.012 inside
// it, 0.019 to 0.027 in the narrow charts; the worst texel anywhere 0.13. Bounds: a fifth of the raw noise in
// every ring of texels by distance from the border, and no texel past the
// raw sigma (a streak is a line of texels the filter made worse than raw).
TEST(LightmapDenoiser, AFlatWallStaysFlatUpToItsChartsBorders) {
    gpu();
    constexpr float kSigma = 0.2f;
    for (const int width : {64, 8, 4, 2}) {
        SCOPED_TRACE("charts " + std::to_string(width / 2) + " texels wide");
        const int height = 32, chart_width = width / 2;
        std::mt19937 rng(3);
        std::normal_distribution<float> noise(0.0f, kSigma);
        FlatAtlas a = flat_atlas(width, height, kSigma, [&](int, int) { return 1.0f + noise(rng); });
        LightmapDenoiser(a.scene, a.texels).denoise(a.image);
        constexpr int kRings = 4;  // distance from the chart's border: 0, 1, 2, 3 or more texels
        double sq[kRings] = {}, count[kRings] = {}, worst = 0.0;
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                const int cx = x % chart_width;
                const int ring = std::min({cx, chart_width - 1 - cx, y, height - 1 - y, kRings - 1});
                const double e = a.image.at("R")[size_t(y * width + x)] - 1.0;
                sq[ring] += e * e;
                count[ring] += 1.0;
                worst = std::max(worst, std::abs(e));
            }
        for (int ring = 0; ring < kRings; ++ring) {
            if (count[ring] > 0.0) {
                EXPECT_LT(std::sqrt(sq[ring] / count[ring]), 0.2 * kSigma) << "ring " << ring;
            }
        }
        EXPECT_LT(worst, kSigma);
    }
}

// The filter is there to take noise out of the map, not to move light
// within a chart: its weights favour alike neighbours, so it flattens a peak
// it cannot tell from noise and darkens where the noise is skewed more than
// where it is not, and keeping each chart's sum (conserve_chart_light) then
// moves light between the two. Two charts as a bake leaves them: a lamp pool
// (a peak four texels wide on a flat wall) under Gaussian noise, and a wall
// whose top half is lit by few paths (skewed noise, as in
// KeepsTheMeanOfSkewedNoise) and whose bottom half by many (Gaussian noise of
// the same sigma). The filter's bias is the mean of its output over 24 noise
// draws against the truth, in 4x4-texel means (compare --block 4, the
// low-frequency error); it is to be under half the raw map's noise at that
// scale in one draw, so that the denoised map is no worse than the raw one
// there. Measured (2026-11-28, llvmpipe): the lamp pool's bias 4.5% of the
// mean before restore_low_frequencies, 1.4% with it, against a raw noise of
// 5.0% (the bound 2.5%); the skewed wall's 0.8% (raw noise 11.8%); the texels'
// RMS error 0.30 -> 0.050 and 0.43 -> 0.043.
TEST(LightmapDenoiser, MovesNoLightWithinAChart) {
    gpu();
    const int width = 64, height = 32;
    std::mt19937 rng(5);
    std::normal_distribution<float> gaussian(0.0f, 1.0f);
    std::bernoulli_distribution found(0.25);
    auto lamp_pool = [](int x, int y) {
        const float dx = float(x % 32) - 16.0f, dy = float(y) - 16.0f;
        return 1.0f + 3.0f * std::exp(-(dx * dx + dy * dy) / (2.0f * 4.0f * 4.0f));
    };
    const float skew_sigma = std::sqrt(3.0f) / 4.0f;  // of the mean of 16 samples of 4 with probability 1/4
    struct Case {
        const char* name;
        std::function<float(int, int)> truth;
        std::function<std::pair<float, float>(int, int)> sample;  // (value, its standard error)
        std::function<float(int, float)> lit;                     // row, value: the share of lit samples
        int dark_at_least;  // texels whose samples all missed the light, over the draws
    };
    auto all_lit = [](int, float value) { return value != 0.0f ? 1.0f : 0.0f; };  // below 0: noise, lit
    const Case cases[] = {
        {"lamp pool", lamp_pool,
         [&](int x, int y) {
             return std::pair{lamp_pool(x, y) + 0.3f * gaussian(rng), 0.3f};
         },
         all_lit, 0},
        {"skew across the chart", [](int, int) { return 1.0f; },
         [&](int, int y) {
             if (y >= 16) return std::pair{1.0f + skew_sigma * gaussian(rng), skew_sigma};
             int k = 0;
             for (int s = 0; s < 16; ++s) k += found(rng) ? 1 : 0;
             const float mean = 4.0f * float(k) / 16.0f;
             const float variance = (float(k) * (4.0f - mean) * (4.0f - mean) + float(16 - k) * mean * mean) / 15.0f;
             return std::pair{mean, std::sqrt(variance / 16.0f)};
         },
         [&](int y, float value) { return y >= 16 ? all_lit(y, value) : value / 4.0f; },  // k of 16 found it
         100},  // ~1% of the skewed half's 512 texels x 24 draws
    };
    constexpr int kDraws = 24;
    for (const Case& c : cases) {
        SCOPED_TRACE(c.name);
        FloatImage truth, raw_mean, denoised_mean;
        for (FloatImage* im : {&truth, &raw_mean, &denoised_mean}) im->width = width, im->height = height;
        double raw_sq = 0.0, denoised_sq = 0.0;  // the texels' squared error, over all draws
        int dark = 0;                            // texels whose samples all missed the light
        float darkest = 1.0f;                    // the least light the filter gave one of them
        for (int draw = 0; draw < kDraws; ++draw) {
            std::vector<float> error(size_t(width) * height);
            FlatAtlas a = flat_atlas(width, height, 0.0f, [&](int x, int y) {
                const auto [value, sigma] = c.sample(x, y);
                error[size_t(y * width + x)] = sigma;
                return value;
            });
            a.image.channel("error") = error;
            for (int y = 0; y < height; ++y)
                for (int x = 0; x < width; ++x)
                    a.image.channel("lit")[size_t(y * width + x)] = c.lit(y, a.image.at("R")[size_t(y * width + x)]);
            LightmapDenoiser(a.scene, a.texels).denoise(a.image);
            for (int y = 0; y < height; ++y)
                for (int x = 0; x < width; ++x) {
                    const size_t t = size_t(y * width + x);
                    const float r = a.image.at("raw.R")[t], d = a.image.at("R")[t], v = c.truth(x, y);
                    if (r == 0.0f) ++dark, darkest = std::min(darkest, d);
                    raw_sq += double(r - v) * (r - v);
                    denoised_sq += double(d - v) * (d - v);
                    for (const char* ch : {"R", "G", "B"}) {
                        truth.channel(ch)[t] = v;
                        raw_mean.channel(ch)[t] += r / float(kDraws);
                        denoised_mean.channel(ch)[t] += d / float(kDraws);
                    }
                }
        }
        // The mean over the draws: the filter's bias, the raw map's noise / sqrt(kDraws).
        const ReferenceError raw_bias = compare_to_reference(raw_mean, truth, nullptr, 4),
                             denoised_bias = compare_to_reference(denoised_mean, truth, nullptr, 4);
        std::printf("  %s: texels' RMS error %.4f -> %.4f; the mean of %d draws in 4x4 means %.4f -> %.4f\n", c.name,
                    std::sqrt(raw_sq / (kDraws * width * height)), std::sqrt(denoised_sq / (kDraws * width * height)),
                    kDraws, raw_bias.relative_rmse, denoised_bias.relative_rmse);
        EXPECT_LT(denoised_sq, 0.25 * raw_sq);
        EXPECT_LT(denoised_bias.relative_rmse, 0.5 * raw_bias.relative_rmse * std::sqrt(double(kDraws)));
        // A texel whose 16 samples all missed light that a quarter of its
        // neighbours' samples found is noise like the rest (1% of the skewed
        // half's texels), smoothed as they are: sure_darks keeps no such 0,
        // not even where its neighbours found light more often by chance.
        std::printf("  %s: %d texels of 16 dark samples, the darkest %.3f after\n", c.name, dark, darkest);
        EXPECT_GE(dark, c.dark_at_least);
        if (dark > 0) {
            EXPECT_GT(darkest, 0.3f);
        }
    }
}

// A contact shadow: a band three texels wide that no light reaches (0, with
// an error of 0: every sample of it found no light) across a lit, noisy
// wall; light peaks right beside the band (a lamp's pool cut by the
// shadow). The band's middle texels see only dark neighbours in the
// filter's variance, so the edge-aware steps leave them be; the
// low-frequency restore reads further (13x13) and once put its neighbours'
// light into them (monkey.glb's floor under the monkey: 0.02 where the path
// tracer has 0, 11% of the map's mean): it adds no more than twice a
// texel's own standard error, so they stay 0. The band's border texels
// (beside lit ones) are the test of sure_darks:
//  * after 256 passes, where a lit neighbour's sample finds light so often
//    that 256 dark samples cannot be chance, they stay 0 too (before, the
//    filter lent them 0.016 on average and up to 0.063 of their
//    neighbours' 3.6: grey_white_room's texels under other geometry got
//    0.01-0.03 so);
//  * after 2 passes a 0 is no surer than its neighbours' noise, and the
//    filter smooths it as any texel (an early shadow's 0s).
TEST(LightmapDenoiser, AZeroTheBakeIsSureOfStaysAsItIs) {
    gpu();
    const int width = 64, height = 32;
    auto in_band = [](int x, int) { return std::abs((x % 32) - 16) <= 1; };  // in the middle of each chart
    auto lit = [](int x) {
        const float beside = float(std::abs((x % 32) - 16) - 2);  // texels from the band
        return 1.0f + 3.0f * std::exp(-beside * beside / 8.0f);
    };
    for (const int passes : {256, 2}) {
        SCOPED_TRACE(std::to_string(passes) + " passes");
        // The lit texels' standard error: 0.3 at 256 passes (a sample's 4.8),
        // 0.3 x sqrt(128) at 2, the same samples' noise.
        const float sigma = 0.3f * std::sqrt(256.0f / float(passes));
        std::mt19937 rng(11);
        std::normal_distribution<float> noise(0.0f, sigma);
        std::vector<float> error(size_t(width) * height);
        FlatAtlas a = flat_atlas(
            width, height, 0.0f,
            [&](int x, int y) {
                error[size_t(y * width + x)] = in_band(x, y) ? 0.0f : sigma;
                return in_band(x, y) ? 0.0f : std::max(lit(x) + noise(rng), 0.0f);
            },
            passes);
        a.image.channel("error") = error;
        LightmapDenoiser(a.scene, a.texels).denoise(a.image);
        double border_sum = 0.0;
        int middle = 0, border = 0;
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                const float value = a.image.at("R")[size_t(y * width + x)];
                if (!in_band(x, y)) continue;
                if (passes == 256) {
                    EXPECT_LT(value, 1e-4f) << x << ", " << y;
                }
                if (x % 32 == 16) {
                    ++middle;
                } else {
                    ++border;
                    border_sum += value;
                }
            }
        EXPECT_EQ(middle, 2 * height);
        EXPECT_EQ(border, 4 * height);
        std::printf("  %d passes: the band's border texels %.4f on average\n", passes, border_sum / border);
        if (passes == 2) {
            EXPECT_GT(border_sum / border, 0.1);  // smoothed: a tenth of the dimmest light beside
        }
    }
}

// Thin lines (issue #53): a sunlit line through a roof slit, one texel
// wide, on a floor lit by bounce; a dark line (a gap's shadow) on a lit
// wall. Drawn: widths 1-4 texels, orientations (along the atlas's rows,
// columns and diagonals), contrasts 3-30x bright on dark and 1/3-1/30 dark
// on bright, and how the noise goes (the same everywhere, as bounce light's;
// or with the value, as light found by few paths), 24 noise draws each with
// the error channel saying it. The raw bake's error at a texel is its noise;
// the denoiser must make no texel worse: in each ring of texels by distance
// from the line (on it, 1, 2, 3 texels beside), the denoised map's RMS error
// over the rings' texels and the draws is at most the raw map's. Before
// (2026-12-07): the rings beside a bright line were +11% to +19% too bright
// on the review's roof slit, the per-chart rescaling hiding the bias.
TEST(LightmapDenoiser, ThinLinesComeOutNoWorseThanRaw) {
    gpu();
    std::mt19937 rng = test::family_rng(5304);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::normal_distribution<float> gaussian(0.0f, 1.0f);
    const int width = 64, height = 32;
    constexpr int kRings = 5, kDraws = 24;  // rings 0 (on the line) .. 3 beside, 4: the rest
    double worst_ratio = 0.0;
    for (int config = 0; config < 8; ++config) {
        const int line_width = 1 + int(4.0f * u(rng)) % 4, orientation = int(3.0f * u(rng)) % 3;
        const bool bright = config % 2 == 0, noise_with_value = u(rng) < 0.5f;
        const float contrast = 3.0f * std::pow(10.0f, u(rng));  // 3-30
        const float background = bright ? 1.0f : contrast, line = bright ? contrast : 1.0f;
        const float relative_noise = 0.05f + 0.15f * u(rng);
        // Texels from the line (0 on it), within each 32-texel chart.
        const auto distance = [&](int x, int y) {
            const int cx = x % 32;
            const float along = orientation == 0 ? float(cx) : orientation == 1 ? float(y) : float(cx + y) / 1.4142f;
            const float centre = orientation == 2 ? 32.0f / 1.4142f : 16.0f;
            return std::max(0, int(std::floor(std::abs(along - centre) - float(line_width) / 2.0f + 1.0f)));
        };
        const auto truth = [&](int x, int y) { return distance(x, y) == 0 ? line : background; };
        const auto sigma = [&](int x, int y) {
            return relative_noise * (noise_with_value ? truth(x, y) : std::max(background, line) / 3.0f);
        };
        double raw_sq[kRings] = {}, denoised_sq[kRings] = {}, bias[kRings] = {}, count[kRings] = {};
        for (int draw = 0; draw < kDraws; ++draw) {
            std::vector<float> error(size_t(width) * height);
            FlatAtlas a = flat_atlas(width, height, 0.0f, [&](int x, int y) {
                error[size_t(y * width + x)] = sigma(x, y);
                return truth(x, y) + sigma(x, y) * gaussian(rng);  // below 0: a draw of noise, lit
            });
            a.image.channel("error") = error;
            LightmapDenoiser(a.scene, a.texels).denoise(a.image);
            for (int y = 0; y < height; ++y)
                for (int x = 0; x < width; ++x) {
                    const size_t t = size_t(y * width + x);
                    const int ring = std::min(distance(x, y), kRings - 1);
                    raw_sq[ring] += std::pow(double(a.image.at("raw.R")[t]) - truth(x, y), 2);
                    denoised_sq[ring] += std::pow(double(a.image.at("R")[t]) - truth(x, y), 2);
                    bias[ring] += double(a.image.at("R")[t]) - truth(x, y);
                    count[ring] += 1.0;
                }
        }
        std::printf("  %s line, %d wide, %s, contrast %.1f, noise %.2f %s: RMS error raw -> denoised by ring:",
                    bright ? "bright" : "dark", line_width,
                    orientation == 0   ? "columns"
                    : orientation == 1 ? "rows"
                                       : "diagonal",
                    double(contrast), double(relative_noise), noise_with_value ? "of the value" : "flat");
        for (int ring = 0; ring < kRings; ++ring) {
            if (count[ring] == 0.0) continue;
            const double raw = std::sqrt(raw_sq[ring] / count[ring]),
                         denoised = std::sqrt(denoised_sq[ring] / count[ring]);
            std::printf(" %.3f->%.3f (%+.3f)", raw, denoised, bias[ring] / count[ring]);
            worst_ratio = std::max(worst_ratio, denoised / raw);
            EXPECT_LE(denoised, raw) << "config " << config << ", ring " << ring;
        }
        std::printf("\n");
    }
    std::printf("  worst ring: denoised RMS error %.2f of the raw map's\n", worst_ratio);
}

// Irradiance / pi at x for the normal n from a convex polygon of radiance 1
// wholly above n's plane: Lambert's formula, E = (L/2) |sum_i theta_i n . u_i|
// over the edges (theta_i the angle an edge subtends, u_i the unit normal of
// the plane through x and the edge).
double polygon_irradiance_over_pi(glm::dvec3 x, glm::dvec3 n, const std::vector<glm::dvec3>& corners) {
    glm::dvec3 sum(0.0);
    for (size_t k = 0; k < corners.size(); ++k) {
        const glm::dvec3 a = glm::normalize(corners[k] - x), b = glm::normalize(corners[(k + 1) % corners.size()] - x);
        sum += std::acos(std::clamp(glm::dot(a, b), -1.0, 1.0)) * glm::normalize(glm::cross(a, b));
    }
    return std::abs(glm::dot(sum, n)) / (2.0 * M_PI);
}

// Relative RMSE over the covered texels with y < 0.5 (a floor) of the L0 map
// alone (RGB) and of RGB + L1 . (n' - n), shaded with normals tilted 26.6
// degrees four ways (as a normal map would), against `expected(x, n')`
// averaged over each texel's sample points; a tilt it returns < 0 for is left out.
template <class Expected>
std::pair<double, double> tilted_normal_errors(const BakeResult& r, Expected expected, size_t* count) {
    const glm::dvec3 n(0, 1, 0);
    double l0_sq = 0.0, l1_sq = 0.0, ref_sq = 0.0;
    *count = 0;
    for (size_t i = 0; i < r.texels.covered_count(); ++i) {
        if (r.texels.samples[r.texels.first_sample[i]].position.y > 0.5f) continue;
        const uint32_t a = r.texels.texels[i];
        const glm::dvec3 l1(r.image.at("L1x.R")[a], r.image.at("L1y.R")[a], r.image.at("L1z.R")[a]);
        for (int k = 0; k < 4; ++k) {
            const double phi = M_PI / 2.0 * k;
            const glm::dvec3 tilted = glm::normalize(n + 0.5 * glm::dvec3(std::cos(phi), 0.0, std::sin(phi)));
            double e = 0.0;
            for (uint32_t s = r.texels.first_sample[i]; s < r.texels.first_sample[i + 1]; ++s)
                e += expected(glm::dvec3(r.texels.samples[s].position), tilted);
            if (e < 0.0) continue;
            e /= r.texels.sample_count(i);
            const double l0 = r.image.at("R")[a], with_l1 = l0 + glm::dot(l1, tilted - n);
            l0_sq += (l0 - e) * (l0 - e);
            l1_sq += (with_l1 - e) * (with_l1 - e);
            ref_sq += e * e;
            ++*count;
        }
    }
    return {std::sqrt(l0_sq / ref_sq), std::sqrt(l1_sq / ref_sq)};
}

// An environment map lights a lone black plane (nothing bounces) with the
// integral of the map over the plane's hemisphere. For radiance linear in
// the direction, L(ω) = c0 + c·ω per channel, that integral is closed:
// E = ∫ (c0 + c·ω)(n·ω) dω over n·ω > 0 = π c0 + (2π/3) c·n, so the map's
// E/π is c0 + (2/3) c·n, whatever the plane's angle. Planes facing up,
// down, sideways, on a 30° slope and askew, each baked alone; the map is
// 512 x 256 texels, read at the nearest (environment.glsl), which leaves
// well under the noise. 256 passes of one cosine ray and one sample of the
// map (each an R2 sequence per texel, combined by MIS: environment.glsl):
// under 1% a texel, 0.04% over a plane's mean.
TEST(RadiosityMap, AnEnvironmentMapLightsPlanesAtEveryAngleByItsIntegral) {
    const test::LinearSky linear;
    const Environment sky = linear.map(512, 256);
    RadiosityMapSettings settings;
    settings.environment = &sky;
    const glm::dvec3 normals[] = {{0, 1, 0},
                                  {0, -1, 0},
                                  {1, 0, 0},
                                  {0, 0, -1},
                                  {std::sin(M_PI / 6), std::cos(M_PI / 6), 0},
                                  glm::normalize(glm::dvec3(1, 2, -3))};
    for (const glm::dvec3& n : normals) {
        char name[64];
        std::snprintf(name, sizeof name, "n = (%.3f, %.3f, %.3f)", n.x, n.y, n.z);
        SCOPED_TRACE(name);
        const glm::dvec3 t =
            glm::normalize(glm::cross(n, std::abs(n.y) < 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(1, 0, 0)));
        const glm::dvec3 b = glm::cross(n, t);  // cross(t, b) = n: the quad faces n
        Scene s;
        const uint32_t black = test::add_material(s, glm::vec3(0.0f));
        test::add_quad(s, glm::vec3(-t - b), glm::vec3(2.0 * t), glm::vec3(2.0 * b), black, grid_cell(0, 1, 16));
        const BakeResult r = bake(s, 16, 256, settings);
        ASSERT_GT(r.texels.covered_count(), 50u);
        const glm::dvec3 expected = linear.irradiance_over_pi(n);
        glm::dvec3 mean(0.0), worst(0.0);
        for (uint32_t a : r.texels.texels) {
            const glm::dvec3 got(r.image.at("R")[a], r.image.at("G")[a], r.image.at("B")[a]);
            mean += got / double(r.texels.covered_count());
            worst = glm::max(worst, glm::abs(got / expected - 1.0));
        }
        std::printf("  %s: E/pi %.4f %.4f %.4f (closed form %.4f %.4f %.4f), worst texel %.3f\n", name, mean.r, mean.g,
                    mean.b, expected.r, expected.g, expected.b, std::max(worst.r, std::max(worst.g, worst.b)));
        for (int k = 0; k < 3; ++k) {
            EXPECT_NEAR(mean[k] / expected[k], 1.0, 0.003) << "channel " << k;  // measured: 0.04% at most
            EXPECT_LT(worst[k], 0.03) << "channel " << k;                       // measured: 0.9% at most
        }
    }
}

// A sky with a sun (tests/sky_maps.h: a 2 x 2-texel sun about 40° from the
// zenith, 95% of the light a plane facing up receives). A cosine ray finds
// the sun with the probability of its projected solid angle over π
// (~1/2600): a texel's estimate after 64 passes was mostly 0 or ~2600
// times the sun's share (measured with the map's sampling turned off: worst
// texel 38x off, the planes' means -17% and -35%). Each pass now also
// draws one direction from the map in proportion to its light
// (environment.glsl), weighted against the cosine ray (balance heuristic).
// Planes facing the sun's side, tilted 30° towards it, and facing down (the
// sun below the horizon: the 0.05 of the lower half alone), against the
// map's integral over each plane's hemisphere. Measured at 64 passes: means
// within 0.03%, worst texel 3.9%, 4.7%, 4.3% (noise: the bound leaves room
// for another device's rounding of the same samples).
TEST(RadiosityMap, ASunInTheEnvironmentMapIsFoundByEveryPass) {
    const test::SunSky sun;
    const Environment map = sun.map();
    const glm::dvec3 towards_sun = sun.towards_sun();
    RadiosityMapSettings settings;
    settings.environment = &map;
    for (const glm::dvec3& n :
         {glm::dvec3(0, 1, 0), glm::normalize(glm::dvec3(0, std::cos(M_PI / 6), 0) + std::sin(M_PI / 6) * towards_sun),
          glm::dvec3(0, -1, 0)}) {
        char name[64];
        std::snprintf(name, sizeof name, "n = (%.3f, %.3f, %.3f)", n.x, n.y, n.z);
        SCOPED_TRACE(name);
        const glm::dvec3 t =
            glm::normalize(glm::cross(n, std::abs(n.y) < 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(1, 0, 0)));
        const glm::dvec3 b = glm::cross(n, t);
        Scene s;
        test::add_quad(s, glm::vec3(-t - b), glm::vec3(2.0 * t), glm::vec3(2.0 * b),
                       test::add_material(s, glm::vec3(0.0f)), grid_cell(0, 1, 16));
        const BakeResult r = bake(s, 16, 64, settings);
        const double truth = sun.irradiance_over_pi(n);
        double mean = 0.0, worst = 0.0;
        for (uint32_t a : r.texels.texels) {
            const double got = r.image.at("G")[a];
            mean += got / double(r.texels.covered_count());
            worst = std::max(worst, std::abs(got / truth - 1.0));
        }
        std::printf("  %s: E/pi %.4f (closed form %.4f), worst texel %.4f\n", name, mean, truth, worst);
        EXPECT_NEAR(mean / truth, 1.0, 0.01);
        EXPECT_LT(worst, 0.08);
    }
}

// A mesh without a lightmap (lightmap scale 0) still casts and bounces
// light: rays that land on it gather there (map_may_say), with its albedo
// at the hit, where its one texel per chart holds only the chart's mean. A
// sun straight down (2 W/m²) lights a floor (2x2 m, one chart of two
// triangles: albedo 0.1 on the half along the wall, 0.8 on the far one) but
// for the half that a black roof (at 1.5 m) shades; a black wall standing
// on the floor's edge, lit by nothing else, reads the floor's bounce: E/pi
// = 2/pi x the sum over the two triangles' lit parts of albedo x form
// factor (Lambert's, exact), each half of the wall (its lit and shaded
// side) summed over its ~300 texels' samples, at 256 passes (at 64 the
// dark half's noise alone was 3%). With the floor and the roof left out of
// the lightmap, each half is within 3% of that (-0.2% and 0.0%; 1024
// passes: the same). The lightmapped scene is held to 6% (+0.3% and +4.4%,
// +1.2% and +3.1% at 1024 passes: its floor's texels blur the roof's shadow
// edge and the albedos' edge, which a gather at the hit sees sharp).
// Faults, on the same atlas: the triangle flag ignored (the floor's one
// texel read, flat): +104% and +400%; the albedo read from that texel
// instead of the hit's: +219% and +113% (at 64 passes).
TEST(RadiosityMap, AMeshWithoutALightmapStillCastsAndBounces) {
    auto scene = [](float floor_and_roof_scale) {
        Scene s;
        const uint32_t dark = test::add_material(s, glm::vec3(0.1f)), bright = test::add_material(s, glm::vec3(0.8f)),
                       black = test::add_material(s, glm::vec3(0.0f));
        test::add_quad(s, {0, 0, 1}, {2, 0, 0}, {0, 0, -2}, bright);  // floor, facing up
        s.triangle_material[1] = dark;  // corners (0, 0, 1), (2, 0, -1), (0, 0, -1): along the wall
        test::add_quad(s, {0, 1.5f, 0}, {2.5f, 0, 0}, {0, 0, 1.5f}, black);  // roof over z > 0, facing down
        test::add_quad(s, {0, 0, -1}, {0, 1, 0}, {0, 0, 2}, black);          // wall at x = 0, facing +x
        s.instances[0].lightmap_scale = s.instances[1].lightmap_scale = floor_and_roof_scale;
        test::add_sun(s, glm::vec3(0, -1, 0), 2.0f);
        AtlasOptions options;
        options.resolution = 64;
        generate_lightmap_uvs(s, options);
        return s;
    };
    // Baked over expected on the wall's half under the sun (z < 0) and under the roof.
    auto wall_halves = [](const Scene& s) {
        // The two triangles' parts under the sun (z < 0; the diagonal crosses z = 0 at x = 1).
        const std::array<glm::vec3, 3> bright_part = {glm::vec3(2, 0, -1), glm::vec3(2, 0, 0), glm::vec3(1, 0, 0)};
        const std::array<glm::vec3, 4> dark_part = {glm::vec3(0, 0, -1), glm::vec3(2, 0, -1), glm::vec3(1, 0, 0),
                                                    glm::vec3(0, 0, 0)};
        const BakeResult r = bake(s, 64, 256);
        glm::dvec2 baked(0.0), expected(0.0);
        for (size_t i = 0; i < r.texels.covered_count(); ++i) {
            const glm::vec3 p = r.texels.samples[r.texels.first_sample[i]].position;
            if (std::abs(p.x) > 0.01f || p.y < 0.05f || p.y > 1.01f) continue;  // the wall's, off its foot
            const int half = p.z < 0.0f ? 0 : 1;
            double closed_form = 0.0;
            for (uint32_t k = r.texels.first_sample[i]; k < r.texels.first_sample[i + 1]; ++k) {
                const glm::vec3 x = r.texels.samples[k].position, n(1, 0, 0);
                closed_form += 2.0 / M_PI *
                               (0.8 * std::abs(polygon_to_point_form_factor(x, n, bright_part.data(), 3)) +
                                0.1 * std::abs(polygon_to_point_form_factor(x, n, dark_part.data(), 4)));
            }
            baked[half] += r.image.at("R")[r.texels.texels[i]];
            expected[half] += closed_form / r.texels.sample_count(i);
        }
        EXPECT_GT(expected.x, 1.5 * expected.y) << "the lit half of the floor lights its half of the wall most";
        return baked / expected;
    };
    const glm::dvec2 mapped = wall_halves(scene(1.0f));
    for (int half = 0; half < 2; ++half) EXPECT_NEAR(mapped[half], 1.0, 0.06) << "half " << half;
    Scene unmapped = scene(0.0f);
    const glm::dvec2 left_out = wall_halves(unmapped);
    for (int half = 0; half < 2; ++half) EXPECT_NEAR(left_out[half], 1.0, 0.03) << "half " << half;
    unmapped.instances[0].lightmap_scale = unmapped.instances[1].lightmap_scale = 1.0f;  // the fault
    const glm::dvec2 fault = wall_halves(unmapped);
    EXPECT_GT(std::max(std::abs(fault.x - 1.0), std::abs(fault.y - 1.0)), 0.2) << fault.x << " " << fault.y;
}

// --directional under a uniform sky of radiance 1 over a black floor: at a
// normal tilted by a, a point of the floor receives E/pi = (1 + cos a) / 2
// (the sky's part of the tilted hemisphere), which the L1 SH of irradiance
// represents exactly: RGB + L1 . (n' - n) must match it to the noise, where
// the L0 map alone is off by (1 - cos a) / 2 = 5.3%. The noise: an L1
// sample's tangential part is tan(theta) cos(phi) / 2 under cosine sampling
// (variance about 0.6 with the cosine held at 0.05 or more), so 1024 passes
// leave about 1.2% at this tilt.
TEST(RadiosityMap, DirectionalLightmapFollowsTiltedNormalsUnderTheSky) {
    const int res = 32;
    Scene s;
    const uint32_t black = test::add_material(s, glm::vec3(0.0f));
    test::add_quad(s, {-1, 0, 1}, {2, 0, 0}, {0, 0, -2}, black, grid_cell(0, 1, res));
    RadiosityMapSettings settings;
    settings.directional = true;
    Environment sky;
    sky.constant = glm::vec3(1.0f);  // a uniform sky
    settings.environment = &sky;
    const BakeResult r = bake(s, res, 1024, settings);
    size_t count = 0;
    const auto [l0, l1] = tilted_normal_errors(
        r, [](glm::dvec3, glm::dvec3 tilted) { return (1.0 + tilted.y) / 2.0; }, &count);
    std::printf("  uniform sky, %zu texel-tilts: relative RMSE of L0 %.4f, of L0 + L1 %.4f\n", count, l0, l1);
    ASSERT_GT(count, 1000u);
    EXPECT_NEAR(l0, 0.053, 0.01);
    EXPECT_LT(l1, 0.3 * l0);
}

// --directional under a 1x1 m emitter 1 m above: where the emitter lies
// wholly above the tilted plane, E(n') = V . n' is linear in the normal
// (Lambert's formula), with twice the slope the L1 SH of irradiance gives
// it (the SH fit holds for light from the whole hemisphere, as above; a small
// source needs a non-linear reconstruction, as Geomerics' in engines that
// ship L1). So L1 halves L0's error here: measured, and held to that.
TEST(RadiosityMap, DirectionalLightmapUnderASmallEmitter) {
    RadiosityMapSettings settings;
    settings.directional = true;
    settings.light_samples = 4;
    const ParallelPlates p = bake_parallel_plates(settings, 256);
    const std::vector<glm::dvec3> emitter = {{-0.5, 1, -0.5}, {0.5, 1, -0.5}, {0.5, 1, 0.5}, {-0.5, 1, 0.5}};
    size_t count = 0;
    const auto [l0, l1] = tilted_normal_errors(
        p.result,
        [&](glm::dvec3 x, glm::dvec3 tilted) {
            for (const glm::dvec3& c : emitter)
                if (glm::dot(tilted, c - x) <= 0.0) return -1e9;  // the plane cuts the emitter
            return polygon_irradiance_over_pi(x, tilted, emitter);
        },
        &count);
    std::printf("  1x1 m emitter at 1 m, %zu texel-tilts: relative RMSE of L0 %.4f, of L0 + L1 %.4f\n", count, l0, l1);
    ASSERT_GT(count, 1000u);
    EXPECT_LT(l1, 0.6 * l0);
}

// A sealed box with the only light outside: nothing inside may be lit.
TEST(RadiosityMap, SealedBoxWithLightOutsideStaysExactlyBlack) {
    const int res = 48;
    Scene s = furnace(0.8f, 0.0f, res);  // the box, no emission
    for (Material& m : s.materials) m.emission = glm::vec3(0.0f);
    const uint32_t light = test::add_material(s, glm::vec3(0.5f), glm::vec3(10.0f), true);
    test::add_quad(s, {-0.5f, 2.0f, -0.5f}, {1, 0, 0}, {0, 0, 1}, light, grid_cell(6, 3, res));
    test::add_sun(s, glm::vec3(0.3f, -1.0f, 0.2f), 5.0f);
    const BakeResult r = bake(s, res, 64);
    const auto& R = r.image.at("R");
    float inside_max = 0.0f;
    for (size_t i = 0; i < r.texels.covered_count(); ++i) {
        const glm::vec3 p = r.texels.samples[r.texels.first_sample[i]].position;
        if (p.y < 1.5f) inside_max = std::max(inside_max, R[r.texels.texels[i]]);
    }
    EXPECT_EQ(inside_max, 0.0f);
}

// Two rooms under one floor, split by a thin closed wall; the light is in
// room A (x < 0). Room B must stay dark, and A's floor texels at the wall's
// foot (whose sample points partly sit under the wall) must not go black.
TEST(RadiosityMap, ThinWallNeitherLeaksNorBlackensItsFoot) {
    const int res = 128;
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.6f));
    const uint32_t light = test::add_material(s, glm::vec3(0.0f), glm::vec3(20.0f));
    const float w = 0.02f;  // half the wall's thickness
    int cell = 0;
    auto quad = [&](glm::vec3 c, glm::vec3 u, glm::vec3 v, uint32_t m) {
        test::add_quad(s, c, u, v, m, grid_cell(cell++, 4, res));
    };
    // The enclosing room, x in [-2, 2], y in [0, 2], z in [-1, 1], faces inward.
    quad({-2, 0, -1}, {0, 0, 2}, {4, 0, 0}, grey);  // floor, +y, spans under the wall
    quad({-2, 2, -1}, {4, 0, 0}, {0, 0, 2}, grey);  // ceiling, -y
    quad({-2, 0, -1}, {4, 0, 0}, {0, 2, 0}, grey);  // back z=-1, +z
    quad({-2, 0, 1}, {0, 2, 0}, {4, 0, 0}, grey);   // front z=+1, -z
    quad({-2, 0, -1}, {0, 2, 0}, {0, 0, 2}, grey);  // x=-2, +x
    quad({2, 0, -1}, {0, 0, 2}, {0, 2, 0}, grey);   // x=+2, -x
    // The wall: a closed box x in [-w, w], faces outward.
    quad({-w, 0, -1}, {0, 0, 2}, {0, 2, 0}, grey);      // facing -x (room A)
    quad({w, 0, -1}, {0, 2, 0}, {0, 0, 2}, grey);       // facing +x (room B)
    quad({-w, 2, -1}, {0, 0, 2}, {2 * w, 0, 0}, grey);  // top, +y (against the ceiling)
    quad({-w, 0, -1}, {2 * w, 0, 0}, {0, 0, 2}, grey);  // bottom, -y (on the floor)
    // The light, in room A under the ceiling, facing down.
    quad({-1.5f, 1.95f, -0.5f}, {1, 0, 0}, {0, 0, 1}, light);
    const BakeResult r = bake(s, res, 128);
    const auto& R = r.image.at("R");
    const float floor_texel = 4.0f / (float(res) / 4.0f);  // floor chart: 4 m over a quarter of the atlas
    double a_sum = 0.0, b_max = 0.0;
    int a_n = 0;
    std::vector<std::pair<float, float>> foot;  // (x, value) of floor texels in A near the wall
    for (size_t i = 0; i < r.texels.covered_count(); ++i) {
        const glm::vec3 p = r.texels.samples[r.texels.first_sample[i]].position;
        const float v = R[r.texels.texels[i]];
        if (p.x < -w - 2 * floor_texel) {
            a_sum += v;
            ++a_n;
        }
        if (p.x > w + 2 * floor_texel) b_max = std::max(b_max, double(v));
        if (std::abs(p.y) < 1e-4f && p.x < -w && p.x > -w - 3 * floor_texel && std::abs(p.z) < 0.5f)
            foot.push_back({p.x, v});
    }
    const double a_mean = a_sum / a_n;
    ASSERT_GT(a_mean, 0.1);
    EXPECT_LT(b_max, 0.01 * a_mean) << "light leaked under or through the wall into room B";
    ASSERT_FALSE(foot.empty());
    for (const auto& [x, v] : foot)
        EXPECT_GT(v, 0.25 * a_mean) << "floor texel at x = " << x << " went dark at the wall's foot";
    // The output says how many texels the wall touched: the floor's and the
    // ceiling's rows along its foot and top, and the side walls' along its
    // ends (each a texel or two wide, 16-32 long at 0.125 m texels: measured
    // 208 of 7,436), not the rooms' other texels.
    std::printf("thin wall: %zu texels moved out of geometry, %zu cut by geometry, of %zu\n", r.moved_texels,
                r.cut_texels, r.texels.covered_count());
    EXPECT_GT(r.cut_texels, 4u * 16u);
    EXPECT_LT(r.cut_texels, r.texels.covered_count() / 20);
    EXPECT_LE(r.moved_texels, r.cut_texels) << "a moved texel is marked cut too";
}

// Converged texels stop costing rays; the answer stays right.
TEST(RadiosityMap, ConvergedTexelsStopTracing) {
    const int res = 48;
    const Scene s = furnace(0.5f, 1.0f, res);
    RadiosityMapSettings settings;
    settings.converged_texel_error = 0.02;
    gpu();
    const TexelSamples texels = rasterize_texel_samples(s, res, res, 2);
    Tracer tracer(s);
    RadiosityMapBaker baker(s, texels, tracer, settings);
    std::vector<uint64_t> rays_per_pass;
    uint64_t last = 0;
    for (int p = 0; p < 400; ++p) {
        const PassStats st = baker.step();
        rays_per_pass.push_back(st.rays - last);
        last = st.rays;
    }
    EXPECT_LT(rays_per_pass.back(), rays_per_pass.front() / 2) << "late passes should trace for fewer texels";
    const FloatImage image = baker.snapshot();
    double sum = 0.0;
    for (uint32_t t : texels.texels) sum += image.at("R")[t];
    EXPECT_NEAR(sum / double(texels.covered_count()), 2.0, 0.02 * 2.0) << "Le / (1 - rho) with rho = 0.5";
}

// Passes run in a batch (one read-back at its end) are the same passes as
// one at a time: the same pixels, and for every pass the same rays and error
// estimate, read from that pass's own slot of partial sums. The furnace with
// a convergence threshold changes which texels trace from pass to pass, and
// the final gather adds rays that vary per pass, so both counts are exercised.
// With several passes per dispatch, batches that end inside a cell split it
// into two dispatches, which must read the map of the cell's start alike.
TEST(RadiosityMap, BatchedPassesAreThePassesOneAtATime) {
    const int res = 48;
    const Scene s = furnace(0.5f, 1.0f, res);
    gpu();
    const TexelSamples texels = rasterize_texel_samples(s, res, res, 2);
    Tracer tracer(s);
    for (int per_dispatch : {1, 4}) {
        SCOPED_TRACE("passes per dispatch " + std::to_string(per_dispatch));
        RadiosityMapSettings settings;
        settings.converged_texel_error = 0.05;
        settings.scheme = RadiosityScheme::FinalGather;
        settings.passes_per_dispatch = per_dispatch;
        RadiosityMapBaker single(s, texels, tracer, settings), batched(s, texels, tracer, settings);
        ASSERT_GE(batched.max_batch(), 36);
        ASSERT_EQ(batched.passes_per_dispatch(), per_dispatch);
        // To pass 100: cells of 2 passes from 32, of 4 from 64 (cell_end_after).
        std::vector<PassStats> one_at_a_time, in_batches;
        for (int p = 0; p < 100; ++p) one_at_a_time.push_back(single.step());
        for (int count : {1, 3, 16, 7, 1, 32, 5, 35}) {
            const std::vector<PassStats> batch = batched.run_passes(count);
            ASSERT_EQ(batch.size(), size_t(count));
            in_batches.insert(in_batches.end(), batch.begin(), batch.end());
        }
        ASSERT_EQ(in_batches.size(), one_at_a_time.size());
        for (size_t p = 0; p < in_batches.size(); ++p) {
            EXPECT_EQ(in_batches[p].pass, int(p) + 1);
            EXPECT_EQ(in_batches[p].rays, one_at_a_time[p].rays) << "pass " << p + 1;
            EXPECT_EQ(in_batches[p].error_estimate, one_at_a_time[p].error_estimate) << "pass " << p + 1;
            if (p > 0) {
                EXPECT_GE(in_batches[p].seconds, in_batches[p - 1].seconds);
            }
        }
        EXPECT_LT(in_batches.back().rays - in_batches[in_batches.size() - 2].rays,
                  in_batches[1].rays - in_batches[0].rays)
            << "texels converged: the counts must have changed within the batches";
        const FloatImage a = single.snapshot(), b = batched.snapshot();
        for (const auto& [name, data] : a.channels) EXPECT_EQ(data, b.at(name)) << name;
        EXPECT_THROW(batched.run_passes(batched.max_batch() + 1), std::invalid_argument);
    }
}

// Where a cell of passes ends (cell_end_after): at every power of two (the
// epochs' ends), in cells of 1/16 of the passes so far, at most
// passes_per_dispatch; and how many passes a dispatch runs by default.
TEST(RadiosityMap, CellsOfPassesAreShortEarlyAndEndAtEveryDoubling) {
    auto cell_ends = [](int per_dispatch, int passes) {
        std::vector<int> ends;
        for (int p = 0; p < passes; p = cell_end_after(p, per_dispatch))
            ends.push_back(cell_end_after(p, per_dispatch));
        return ends;
    };
    std::vector<int> every_pass(40);
    for (int p = 0; p < 40; ++p) every_pass[size_t(p)] = p + 1;
    EXPECT_EQ(cell_ends(1, 40), every_pass);
    std::vector<int> expected(every_pass.begin(), every_pass.begin() + 32);
    for (int end : {34, 36, 38, 40}) expected.push_back(end);  // 2^5 / 16: cells of 2
    EXPECT_EQ(cell_ends(16, 40), expected);
    EXPECT_EQ(cell_end_after(300, 16), 304);  // 2^8 / 16 = 16: cells of 16
    EXPECT_EQ(cell_end_after(300, 8), 304);   // at most passes_per_dispatch
    EXPECT_EQ(cell_end_after(1000, 16), 1008);
    EXPECT_EQ(cell_end_after(1020, 16), 1024);  // cut at the doubling
    EXPECT_EQ(cell_end_after(1024, 5), 1025);   // a cell need not divide an epoch
    EXPECT_EQ(cell_end_after(1021, 5), 1024);

    EXPECT_EQ(passes_per_dispatch_for(40'000, false), 8);  // 8 x 40,000 >= 2^18
    EXPECT_EQ(passes_per_dispatch_for(300'000, false), 1);
    EXPECT_EQ(passes_per_dispatch_for(100, false), kMaxPassesPerDispatch);
    EXPECT_EQ(passes_per_dispatch_for(100, true), 1) << "llvmpipe: any pass fills its cores";

    // A count outside 0 (auto) to kMaxPassesPerDispatch is refused, saying so.
    gpu();
    const Scene s = furnace(0.5f, 1.0f, 16);
    const TexelSamples texels = rasterize_texel_samples(s, 16, 16, 2);
    const Tracer tracer(s);
    for (int wrong : {-1, kMaxPassesPerDispatch + 1}) {
        RadiosityMapSettings settings;
        settings.passes_per_dispatch = wrong;
        try {
            RadiosityMapBaker baker(s, texels, tracer, settings);
            ADD_FAILURE() << wrong << " passes per dispatch were taken";
        } catch (const std::invalid_argument& e) {
            EXPECT_NE(std::string(e.what()).find("passes per dispatch must be 1 to 16"), std::string::npos) << e.what();
        }
    }
}

// Path tracing reads no map, so how many passes a dispatch runs changes
// nothing but the dispatches: the same bits, L1 layers included. The epochs read the map a few
// passes late in a furnace of albedo 0.8, where most of the light has
// bounced more than ten times: the cells keep it within the same bound.
TEST(RadiosityMap, SeveralPassesPerDispatchAreTheSamePasses) {
    const int res = 48;
    const Scene s = furnace(0.8f, 1.0f, res);
    RadiosityMapSettings pathtrace, pathtrace_in_cells;
    pathtrace.scheme = pathtrace_in_cells.scheme = RadiosityScheme::PathTracing;
    pathtrace.directional = pathtrace_in_cells.directional = true;  // each pass's own L1 sums
    pathtrace.passes_per_dispatch = 1;
    pathtrace_in_cells.passes_per_dispatch = 16;
    const BakeResult a = bake(s, res, 200, pathtrace), b = bake(s, res, 200, pathtrace_in_cells);
    for (const auto& [name, data] : a.image.channels) EXPECT_EQ(data, b.image.at(name)) << name;
    EXPECT_EQ(a.stats.rays, b.stats.rays);
    EXPECT_EQ(a.stats.error_estimate, b.stats.error_estimate);

    RadiosityMapSettings epochs;
    epochs.passes_per_dispatch = 16;
    const BakeResult r = bake(s, res, 256, epochs);
    const double mean = mean_covered(r, "R");
    std::printf("furnace rho=0.8, 16 passes per dispatch, 256 passes: mean %.4f (exact 5)\n", mean);
    EXPECT_NEAR(mean, 5.0, 0.02 * 5.0);
}

// A curved mesh cut into many charts, lit from above: after stitching, the
// two sides of every smooth seam agree to the noise floor, and better than
// without stitching.
TEST(RadiosityMap, StitchedSeamsAgreeToTheNoiseFloor) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.7f));
    test::add_icosphere(s, glm::vec3(0.0f, 1.0f, 0.0f), 0.8f, 3, grey);
    test::add_quad(s, {-3, 0, 3}, {6, 0, 0}, {0, 0, -6}, grey);
    PunctualLight lamp;
    lamp.position = glm::vec3(1.0f, 3.0f, 0.5f);
    lamp.intensity = glm::vec3(20.0f);
    s.lights.push_back(lamp);
    for (PrimitiveInstance& i : s.instances) i.has_uv1 = false;
    AtlasOptions options;
    options.resolution = 256;
    generate_lightmap_uvs(s, options);
    const BakeResult r = bake(s, 256, 64);
    std::vector<SeamEdge> seams;
    for (const SeamEdge& e : find_seams(s))
        if (e.smooth) seams.push_back(e);
    ASSERT_GT(seams.size(), 20u) << "the sphere should be cut into several charts";
    std::vector<glm::vec4> image(size_t(256 * 256));
    double noise = 0.0;
    for (size_t i = 0; i < image.size(); ++i)
        image[i] = glm::vec4(r.image.at("R")[i], r.image.at("G")[i], r.image.at("B")[i], 0.0f);
    for (uint32_t t : r.texels.texels) noise += r.image.at("error")[t];
    noise /= double(r.texels.covered_count());
    const double before = seam_metric(seams, image, 256, 256);
    stitch_seams(seams, image, 256, 256);
    const double after = seam_metric(seams, image, 256, 256);
    std::printf("seam metric over %zu smooth seams: %.5f unstitched, %.5f stitched; mean texel standard error %.5f\n",
                seams.size(), before, after, noise);
    EXPECT_LT(after, 0.5 * before);
    EXPECT_LT(after, noise) << "stitched seams should agree to within the bake's own noise";
}

// The Cornell box at 256² against Blender Cycles (32768 samples per texel,
// examples/SOURCES.md), over the reference's mask.
// Two quads textured with random colours (37 x 23 texels, odd sizes), one
// reflecting, one emitting, their texture coordinates reaching outside
// [0, 1] on both sides (REPEAT).
Scene randomly_textured_quads() {
    Scene s;
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    Texture t;
    t.width = 37;
    t.height = 23;
    for (int i = 0; i < t.width * t.height; ++i) t.texels.push_back(glm::vec4(u(rng), u(rng), u(rng), u(rng)));
    s.textures.push_back(t);
    const uint32_t reflecting = test::add_material(s, glm::vec3(0.9f, 0.5f, 0.7f));
    s.materials[reflecting].base_color_texture = 0;
    const uint32_t emitting = test::add_material(s, glm::vec3(0.5f), glm::vec3(3.0f, 2.0f, 1.0f));
    s.materials[emitting].base_color_texture = 0;
    s.materials[emitting].emissive_texture = 0;
    // See-through: a cut-out, a blend and a tinted glass, each textured.
    const uint32_t cut_out = test::add_material(s, glm::vec3(0.7f));
    s.materials[cut_out].alpha_mode = Material::AlphaMode::Mask;
    s.materials[cut_out].alpha_cutoff = 0.4f;
    const uint32_t blended = test::add_material(s, glm::vec3(0.6f, 0.8f, 1.0f));
    s.materials[blended].alpha_mode = Material::AlphaMode::Blend;
    s.materials[blended].base_color.a = 0.6f;
    const uint32_t glass = test::add_material(s, glm::vec3(0.9f, 0.7f, 0.5f));
    s.materials[glass].transmission = 0.7f;
    for (uint32_t m : {cut_out, blended, glass}) s.materials[m].base_color_texture = 0;
    test::add_quad(s, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, reflecting);
    test::add_quad(s, {0, 0, 1}, {1, 0, 0}, {0, 1, 0}, emitting);
    for (uint32_t m : {cut_out, blended, glass}) test::add_quad(s, {0, 0, 2.0f + float(m)}, {1, 0, 0}, {0, 1, 0}, m);
    for (size_t v = 0; v < s.uv0.size(); ++v) s.uv0[v] = glm::vec2(3.1f * u(rng) - 1.3f, 2.7f * u(rng) - 1.1f);
    return s;
}

// A shading normal packed into 32 bits (pack_unit_vector, the texels'
// sample points) comes back in GLSL within 1e-4 rad (0.006°) of itself,
// and exactly on the axes: random directions, the axes, and the
// octahedron's folds (z = 0, |x| = |y|); a zero or NaN vector comes back
// as +z. The bound is the quantization's: a step of 1/32767 in octahedral
// coordinates, stretched up to about 2x where the octahedron is folded
// (6.4e-5 rad measured on 100,000 directions).
TEST(SamplePoints, PackedNormalsComeBackInGlsl) {
    gpu();
    std::mt19937 rng(11);
    std::normal_distribution<float> g;
    std::vector<glm::vec3> normals = {{1, 0, 0},
                                      {-1, 0, 0},
                                      {0, 1, 0},
                                      {0, -1, 0},
                                      {0, 0, 1},
                                      {0, 0, -1},
                                      glm::normalize(glm::vec3(1, 1, 0)),
                                      glm::normalize(glm::vec3(-1, 1, 0)),
                                      glm::normalize(glm::vec3(1, -1, -1e-7f))};
    for (int i = 0; i < 100000; ++i) normals.push_back(glm::normalize(glm::vec3(g(rng), g(rng), g(rng))));
    std::vector<glm::vec4> cases;
    for (const glm::vec3& n : normals) cases.push_back(glm::vec4(pack_unit_vector(n), 0.0f, 0.0f, 0.0f));
    // No direction (a degenerate triangle's normal) and NaN: +z, not NaN.
    for (const glm::vec3 none : {glm::vec3(0.0f), glm::vec3(std::nanf(""), 0.0f, 1.0f)})
        cases.push_back(glm::vec4(pack_unit_vector(none), 0.0f, 0.0f, 0.0f));
    const auto got = test::run_check_program(ComputeProgram("unit_vector_check.comp"), cases, 1);
    for (size_t i = normals.size(); i < cases.size(); ++i) EXPECT_EQ(glm::vec3(got[i]), glm::vec3(0, 0, 1)) << i;
    double worst = 0.0;
    for (size_t i = 0; i < normals.size(); ++i) {
        const glm::dvec3 a(normals[i]), b(glm::vec3(got[i]));
        const double angle = std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b));
        worst = std::max(worst, angle);
        ASSERT_NEAR(glm::length(b), 1.0, 1e-6) << i;
        if (i < 6) {
            EXPECT_EQ(glm::vec3(got[i]), normals[i]) << i;
        }
    }
    EXPECT_LT(worst, 1e-4);
}

// The solid angle of triangle (a, b, c) from the origin (Van Oosterom and
// Strackee 1983), in double precision.
double solid_angle_of_triangle(glm::dvec3 a, glm::dvec3 b, glm::dvec3 c) {
    a = glm::normalize(a), b = glm::normalize(b), c = glm::normalize(c);
    return 2.0 *
           std::atan2(std::abs(glm::dot(a, glm::cross(b, c))), 1.0 + glm::dot(a, b) + glm::dot(b, c) + glm::dot(c, a));
}

// Solid-angle sampling of an emitter weighs each sample by the solid angle
// the shader computes, so a relative error there is a bias of the same size
// in the direct light. In GLSL: the solid angle, against double precision,
// and the integral of the cosine over the triangle from 128² stratified
// sample_spherical_triangle directions (so the sampler spreads its
// directions uniformly), against polygon_to_point_form_factor. The cases: the Cornell box's light from points of
// its floor, back wall and side wall, up to 4 mm under the light's plane
// (seen nearly edge-on), and random triangles of 0.002 sr or more at 0.3 to
// 30 times their size. When the solid angle was the spherical excess from
// three acos, llvmpipe's was 1-2% off on the Cornell cases (46% on the
// worst random one), and so was the Cornell box's direct light, in smooth
// patches against the closed form and against Cycles. Below 0.001 sr the
// float sampler itself drifts (1% at 3e-4 sr: its cosines of small arcs
// round off), so such triangles are sampled by area, as pbrt-v4 does below
// 3e-4 sr.
TEST(SphericalTriangles, SolidAngleAndSamplerAreExactInGlsl) {
    gpu();
    struct Case {
        glm::dvec3 a, b, c, n;  // seen from the origin
    };
    std::vector<Case> cases;
    const glm::dvec3 light[4] = {
        {0.213, 0.5487, 0.227}, {0.343, 0.5487, 0.227}, {0.343, 0.5487, 0.332}, {0.213, 0.5487, 0.332}};
    for (int i = 0; i <= 10; ++i) {
        for (int j = 0; j <= 10; ++j) {
            const double s = 0.05 + 0.045 * i, t = 0.05 + 0.045 * j, height = std::min(0.545, 0.04 + 0.05 * j);
            for (const auto& [x, n] : {std::pair{glm::dvec3(s, 0, t), glm::dvec3(0, 1, 0)},            // floor
                                       std::pair{glm::dvec3(s, height, 0.559), glm::dvec3(0, 0, -1)},  // back wall
                                       std::pair{glm::dvec3(0, height, t), glm::dvec3(1, 0, 0)}}) {    // side wall
                cases.push_back({light[0] - x, light[1] - x, light[2] - x, n});
                cases.push_back({light[0] - x, light[2] - x, light[3] - x, n});
            }
        }
    }
    const size_t cornell_cases = cases.size();
    std::mt19937 rng(3);
    std::normal_distribution<double> g;
    std::uniform_real_distribution<double> u(0.0, 1.0);
    while (cases.size() < cornell_cases + 300) {
        const glm::dvec3 centre = glm::normalize(glm::dvec3(g(rng), g(rng), g(rng))) * (0.3 + 30.0 * u(rng) * u(rng));
        const Case c{centre + glm::dvec3(g(rng), g(rng), g(rng)), centre + glm::dvec3(g(rng), g(rng), g(rng)),
                     centre + glm::dvec3(g(rng), g(rng), g(rng)), glm::normalize(glm::dvec3(g(rng), g(rng), g(rng)))};
        if (glm::dot(c.n, c.a) <= 0.0 || glm::dot(c.n, c.b) <= 0.0 || glm::dot(c.n, c.c) <= 0.0) continue;
        if (solid_angle_of_triangle(c.a, c.b, c.c) < 0.002) continue;
        cases.push_back(c);
    }
    std::vector<glm::vec4> packed;
    for (const Case& c : cases) {
        packed.push_back(glm::vec4(glm::vec3(c.a), float(c.n.x)));
        packed.push_back(glm::vec4(glm::vec3(c.b), float(c.n.y)));
        packed.push_back(glm::vec4(glm::vec3(c.c), float(c.n.z)));
    }
    const ComputeProgram program("spherical_triangle_check.comp");
    CheckParams params{};
    params.grid = 128;
    const auto got = test::run_check_program(program, packed, 1, 3, params);
    double worst_omega = 0.0, worst_integral = 0.0, worst_cornell_integral = 0.0, worst_atan = 0.0, glsl_atan = 0.0;
    for (size_t i = 0; i < cases.size(); ++i) {
        const Case& c = cases[i];
        const double omega = solid_angle_of_triangle(c.a, c.b, c.c);
        ASSERT_GT(got[i].x, 0.0f) << i << ": sampled by area";
        worst_omega = std::max(worst_omega, std::abs(got[i].x / omega - 1.0));
        // The integral of max(0, n . w) over a triangle wholly above the plane
        // of n is pi times its form factor (Lambert's formula, either winding).
        const glm::vec3 corners[3] = {glm::vec3(c.a), glm::vec3(c.b), glm::vec3(c.c)};
        const double integral =
            M_PI * std::abs(polygon_to_point_form_factor(glm::vec3(0.0f), glm::vec3(c.n), corners, 3));
        const double integral_error = std::abs(got[i].y / integral - 1.0);
        worst_integral = std::max(worst_integral, integral_error);
        if (i < cornell_cases && omega > 0.01)
            worst_cornell_integral = std::max(worst_cornell_integral, integral_error);
        const double angle = std::atan2(double(float(c.a.y)), double(float(c.a.x)));
        worst_atan = std::max(worst_atan, std::abs(got[i].z - angle));
        glsl_atan = std::max(glsl_atan, std::abs(got[i].w - angle));
    }
    std::printf(
        "worst relative error: solid angle %.2e, cosine integral %.2e (Cornell light above 0.01 sr %.2e); "
        "atan2 %.2e rad (GLSL's own %.2e)\n",
        worst_omega, worst_integral, worst_cornell_integral, worst_atan, glsl_atan);
    EXPECT_LT(worst_omega, 1e-5);
    EXPECT_LT(worst_cornell_integral, 1e-4);
    EXPECT_LT(worst_integral, 2e-3);
    EXPECT_LT(worst_atan, 1e-6);
}

// surface_textures.glsl reads albedo and emission as Scene::albedo_at and
// Scene::emission_at do (the CPU's Texture::sample), at random points of
// every triangle of randomly_textured_quads and of the staircase (real
// textures, 262 k triangles), to the half-float texels' precision.
TEST(SurfaceTextures, GlslMatchesTheSceneOnTheCpu) {
    gpu();
    const ComputeProgram program("surface_texture_check.comp");
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    const std::vector<std::pair<std::string, Scene>> scenes = {
        {"random textures", randomly_textured_quads()},
        {"staircase", load_scene(test::example_scene("real/wooden_staircase/wooden_staircase.gltf"))}};
    for (const auto& [name, scene] : scenes) {
        SCOPED_TRACE(name);
        const SurfaceTextures textures(scene);
        size_t textured = 0;
        for (const Material& m : scene.materials) textured += m.base_color_texture >= 0;
        ASSERT_GT(textured, 0u);
        std::vector<glm::vec4> cases;
        for (int i = 0; i < 4096; ++i) {
            const uint32_t t = uint32_t(u(rng) * float(scene.triangle_count())) % uint32_t(scene.triangle_count());
            const float a = u(rng), b = u(rng);
            const glm::vec2 bary = a + b > 1.0f ? glm::vec2(1.0f - a, 1.0f - b) : glm::vec2(a, b);
            cases.push_back(glm::vec4(uint_bits(t), bary, 0.0f));
        }
        textures.bind();
        const auto got = test::run_check_program(program, cases, 3);
        size_t see_through = 0;
        for (size_t i = 0; i < cases.size(); ++i) {
            const size_t t = glm::floatBitsToUint(cases[i].x);
            const glm::vec2 bary(cases[i].y, cases[i].z);
            const glm::vec3 albedo = scene.albedo_at(t, bary), emission = scene.emission_at(t, bary);
            const glm::vec3 passes = scene.transmittance_at(t, bary);
            const Material& m = scene.materials[scene.triangle_material[t]];
            // A cut-out's alpha within the half floats' rounding of its cutoff may fall either way.
            const glm::uvec3 tri = scene.triangles[t];
            const glm::vec2 uv =
                (1 - bary.x - bary.y) * scene.uv0[tri.x] + bary.x * scene.uv0[tri.y] + bary.y * scene.uv0[tri.z];
            const float alpha =
                m.base_color.a *
                (m.base_color_texture >= 0 ? scene.textures[size_t(m.base_color_texture)].sample(uv).a : 1.0f);
            const bool at_cutoff =
                m.alpha_mode == Material::AlphaMode::Mask && std::abs(alpha - m.alpha_cutoff) < 2e-3f;
            see_through += m.is_see_through();
            for (int c = 0; c < 3; ++c) {
                // Half floats: 2^-11 relative, and the bilinear weights' float rounding.
                ASSERT_NEAR(got[3 * i][c], albedo[c], 1e-3f * albedo[c] + 1e-5f) << "triangle " << t;
                ASSERT_NEAR(got[3 * i + 1][c], emission[c], 1e-3f * emission[c] + 1e-5f) << "triangle " << t;
                if (at_cutoff) continue;
                ASSERT_NEAR(got[3 * i + 2][c], passes[c], 1e-3f * passes[c] + 1e-5f) << "triangle " << t;
            }
        }
        if (name == "random textures") {
            EXPECT_GT(see_through, cases.size() / 2) << "cut-outs, blends and glass tried";
        }
    }
}

TEST(RadiosityMap, CornellBoxAgreesWithCyclesReference) {
    const Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    const FloatImage reference = read_exr(test::example_scene("cornell_box.ref256.exr"));
    const FloatImage mask = read_pfm(test::example_scene("cornell_box.mask256.pfm"));
    const int passes = 256;
    const BakeResult r = bake(scene, 256, passes);
    const ReferenceError e = compare_to_reference(r.image, reference, &mask);
    std::printf("cornell 256², %d passes, %.3g rays, %.2f s: relative RMSE %.4f, bias %+.4f over %zu texels\n", passes,
                double(r.stats.rays), r.stats.seconds, e.relative_rmse, e.bias, e.texels);
    EXPECT_EQ(e.texels, 33016u);
    EXPECT_LT(std::abs(e.bias), 0.02);
    EXPECT_LT(e.relative_rmse, kCornellRelativeRmseBound256);
    // The error estimate the bake reports should be honest: within a factor
    // of two of the measured error (the reference's own 0.39% noise aside)
    // below, and of 2.5 above. The estimate takes each texel's samples as
    // independent; they are stratified across passes (R3 emitter samples, R2
    // directions over the whole bake), which makes the true error of their
    // mean smaller than their variance says: 1.94x at 256 passes when the
    // directions restarted with each epoch, 2.1x since they run over the
    // bake (error 2.38% -> 2.18%, estimate unchanged). Over-stating is the
    // safe side for --target-error; the bound says by how much at most.
    EXPECT_GT(r.stats.error_estimate.value_or(0.0), 0.5 * (e.relative_rmse - 0.004));
    EXPECT_LT(r.stats.error_estimate.value_or(0.0), 2.5 * e.relative_rmse);
}

// The path-tracing scheme is the project's reference on scenes without an
// outside one, so it must agree with Cycles where there is one: the Cornell
// box at 256², 64 passes, to its own noise (its error estimate, with the
// reference's 0.39%), and without a bias beyond what that noise allows over
// 33 k texels.
TEST(RadiosityMap, PathTracerAgreesWithCyclesOnTheCornellBox) {
    const Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    const FloatImage reference = read_exr(test::example_scene("cornell_box.ref256.exr"));
    const FloatImage mask = read_pfm(test::example_scene("cornell_box.mask256.pfm"));
    RadiosityMapSettings settings;
    settings.scheme = RadiosityScheme::PathTracing;
    const BakeResult r = bake(scene, 256, 64, settings);
    const ReferenceError e = compare_to_reference(r.image, reference, &mask);
    const double noise = std::hypot(r.stats.error_estimate.value_or(0.0), 0.0039);
    std::printf("cornell 256², path tracer, 64 passes, %.2f s: relative RMSE %.4f (noise %.4f), bias %+.4f\n",
                r.stats.seconds, e.relative_rmse, noise, e.bias);
    EXPECT_LT(std::abs(e.bias), 0.01);
    EXPECT_LT(e.relative_rmse, 1.3 * noise);
}

// A box whose back stands a few millimetres from a wall (grey_white_room's
// panelling stands mm from its walls), all double-sided, under a uniform
// sky: light reaches the gap only through its slits. A texel on the box's
// back gathers along paths that cross the gap over and over, each hop
// closer than a texel to where it left, where the map cannot say
// (radiosity_gather.comp's map_may_say). Ending such a path by reading the
// map after four points read a wall texel deep in the gap, which averages
// the gap's dark with the lit wall beside the box: at 2 mm the back came out
// 40-42% too bright and the wall behind it 5-9% (seeds 1-2). With Russian
// roulette instead, both lie within 3.3% of the path tracer (seeds 1-3).
// The family: 2 mm and 2 cm (about half a texel, where the map is read
// across the gap), the scene axis-aligned and turned (35 degrees about y,
// then 20 about x: the gap and the texels' grid at no axis, the same light
// under a uniform sky), every surface double-sided and every one one-sided
// (front faces out of the box and into the room): 2 mm turned and one-sided
// within 0.6%, 2 cm turned +3.1% (seed 1). Each side is a few hundred
// texels' mean. The path tracer's reference takes 256 passes (it took 512,
// three quarters of the test's time): its means at 256 lay within 1.2% of
// those at 512 (seeds 1 and 2, every case and side), and two seeds differ
// by up to 4% on the wall behind at either count (2026-11-29, llvmpipe).
TEST(RadiosityMap, ABoxMillimetresFromAWallIsAsDarkBehindAsThePathTracerSays) {
    gpu();
    const int res = 128;
    struct Case {
        float gap;
        bool turned, double_sided;
    };
    for (const Case& c : {Case{0.002f, false, true}, Case{0.02f, true, true}, Case{0.002f, true, false}}) {
        const glm::mat3 turn = c.turned
                                   ? glm::mat3(glm::rotate(glm::mat4(1.0f), glm::radians(20.0f), glm::vec3(1, 0, 0)) *
                                               glm::rotate(glm::mat4(1.0f), glm::radians(35.0f), glm::vec3(0, 1, 0)))
                                   : glm::mat3(1.0f);
        Scene s;
        const uint32_t m = test::add_material(s, glm::vec3(0.8f), glm::vec3(0.0f), c.double_sided);
        auto quad = [&](glm::vec3 corner, glm::vec3 u, glm::vec3 v) {
            test::add_quad(s, turn * corner, turn * u, turn * v, m);
        };
        const float zb = -0.5f + c.gap;                        // the box's back
        quad({-1, 0, -1}, {0, 0, 2}, {2, 0, 0});               // floor, facing up
        quad({-1, 0, -0.5f}, {2, 0, 0}, {0, 1, 0});            // wall, facing +z
        quad({-0.3f, 0, zb}, {0, .4f, 0}, {.6f, 0, 0});        // the box's back, facing the wall
        quad({-0.3f, 0, zb + .1f}, {.6f, 0, 0}, {0, .4f, 0});  // front
        quad({-0.3f, .4f, zb}, {0, 0, .1f}, {.6f, 0, 0});      // top
        quad({-0.3f, 0, zb}, {0, 0, .1f}, {0, .4f, 0});        // left
        quad({.3f, 0, zb}, {0, .4f, 0}, {0, 0, .1f});          // right
        AtlasOptions options;
        options.resolution = res;
        generate_lightmap_uvs(s, options);
        face_double_sided_charts_to_the_scene(s, Tracer(s));
        Environment sky;
        sky.constant = glm::vec3(1.0f);
        // The mean of the texels on the box's back (x) and on the wall behind the box (y).
        auto gap_means = [&](const BakeResult& r) {
            glm::dvec2 sum(0.0), n(0.0);
            for (size_t i = 0; i < r.texels.covered_count(); ++i) {
                const glm::vec3 q = glm::transpose(turn) * r.texels.samples[r.texels.first_sample[i]].position;
                if (std::abs(q.x) > 0.3f || q.y > 0.4f) continue;
                const int side = std::abs(q.z - zb) < 1e-4f ? 0 : std::abs(q.z + 0.5f) < 1e-4f ? 1 : -1;
                if (side < 0) continue;
                sum[side] += r.image.at("R")[r.texels.texels[i]];
                n[side] += 1;
            }
            EXPECT_GT(std::min(n.x, n.y), 100.0);
            return sum / n;
        };
        RadiosityMapSettings path_tracing;
        path_tracing.scheme = RadiosityScheme::PathTracing;
        path_tracing.environment = &sky;
        RadiosityMapSettings epochs;
        epochs.environment = &sky;
        const glm::dvec2 reference = gap_means(bake(s, res, 256, path_tracing));
        const glm::dvec2 map = gap_means(bake(s, res, 256, epochs));
        const std::string name = std::to_string(std::lround(c.gap * 1000.0f)) + " mm" + (c.turned ? ", turned" : "") +
                                 (c.double_sided ? ", double-sided" : ", one-sided");
        std::printf("  gap %s: the box's back: path tracer %.4f, epochs %.4f; the wall behind: %.4f, %.4f\n",
                    name.c_str(), reference.x, map.x, reference.y, map.y);
        ASSERT_LT(reference.x, 0.2) << "the gap is dark: the sky alone gives an open surface 1";
        EXPECT_NEAR(map.x, reference.x, 0.08 * reference.x) << name;
        EXPECT_NEAR(map.y, reference.y, 0.08 * reference.y) << name;
    }
}
}  // namespace
}  // namespace lf
