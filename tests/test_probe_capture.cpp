// The probes through the whole pipeline: the GPU capture (ProbesMethod),
// downsampling, the files, and the evaluation, against closed forms.
#include "family_errors.h"
#include "form_factors.h"
#include "gpu_fixture.h"
#include "scene_builders.h"
#include "sky_maps.h"

#include "bake/bake_job.h"
#include "bake/prepared_scene.h"
#include "bake/probe_bench.h"
#include "scene/gltf_loader.h"
#include "bake/probes_method.h"
#include "bake/radiosity_map_baker.h"
#include "atlas/atlas.h"
#include "atlas/texel_samples.h"
#include "trace/tracer.h"
#include "probes/probe_eval.h"
#include "probes/probe_set.h"
#include "io/image_files.h"
#include "sh/environment.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <random>

namespace lf {
namespace {

using test::gpu;

// A closed box [-1, 1]³ whose inward-facing walls have albedo rho and emit
// Le: the radiance is Le / (1 - rho) everywhere, so is irradiance / pi at any
// point and normal inside, and a probe sees it through every texel.
Scene furnace(float rho, float le) {
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(rho), glm::vec3(le));
    const glm::vec3 o(-1.0f), X(2, 0, 0), Y(0, 2, 0), Z(0, 0, 2);
    test::add_quad(s, o, Z, X, m);      // floor y=-1, normal +y
    test::add_quad(s, o + Y, X, Z, m);  // ceiling, normal -y
    test::add_quad(s, o, X, Y, m);      // z=-1, normal +z
    test::add_quad(s, o + Z, Y, X, m);  // z=+1, normal -z
    test::add_quad(s, o, Y, Z, m);      // x=-1, normal +x
    test::add_quad(s, o + X, Z, Y, m);  // x=+1, normal -x
    return s;
}

void expect_inside(const std::vector<glm::vec3>& points) {
    for (const glm::vec3& p : points)
        for (int a = 0; a < 3; ++a) EXPECT_LT(std::abs(p[a]), 1.0f);
}

// Captures probes at `points` of `scene` for `passes` passes, under the
// environment `env` (none: black), and reads back the written set (the
// files are part of what is tested).
ProbeSet capture(const Scene& scene, const std::vector<glm::vec3>& points, int r, int m, int passes,
                 const protocol::EnvironmentSetting& env = {}) {
    gpu();
    PreparedScene prepared;
    prepared.file = "test.glb";
    prepared.scene = scene;
    prepared.tracer = std::make_unique<Tracer>(prepared.scene);
    protocol::BakeSettings settings = probes_at(points, r, m);
    settings.env = env;
    prepared.environment = read_environment(env);
    ProbesMethod method(prepared, settings);
    PassStats stats;
    for (int p = 0; p < passes; ++p) stats = method.step();
    const std::filesystem::path dir =
        std::filesystem::temp_directory_path() / ("lf-probes-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    method.finish(dir, stats);
    ProbeSet set = read_probe_set(dir / "probes.json");
    std::filesystem::remove_all(dir);
    return set;
}

// Distance from p along d to the inside of the box [-1, 1]³.
float box_distance(glm::vec3 p, glm::vec3 d) {
    float t = 1e30f;
    for (int a = 0; a < 3; ++a)
        if (d[a] != 0.0f) t = std::min(t, ((d[a] > 0.0f ? 1.0f : -1.0f) - p[a]) / d[a]);
    return t;
}

TEST(ProbeCapture, FurnaceRadianceDistancesAndIrradianceAreExact) {
    const float rho = 0.5f, le = 1.0f, expected = le / (1.0f - rho);
    const glm::vec3 centre(0.0f), off(0.5f, 0.2f, -0.3f);
    const ProbeSet set = capture(furnace(rho, le), {centre, off}, 16, 4, 48);
    ASSERT_EQ(set.probes.size(), 2u);
    for (const Probe& p : set.probes) {
        ASSERT_TRUE(p.valid) << p.why;
        EXPECT_EQ(p.backface_fraction, 0.0f);
        double mean = 0.0, worst_distance = 0.0;
        for (int face = 0; face < 6; ++face)
            for (int j = 0; j < set.m; ++j)
                for (int i = 0; i < set.m; ++i) {
                    const size_t t = set.texel(face, i, j);
                    mean += (p.radiance[t].r + p.radiance[t].g + p.radiance[t].b) / 3.0;
                    // The mean distance over the texel's rays against the
                    // distance through its centre: they differ by the box's
                    // curvature in angle across a texel, a few percent at M = 4.
                    const float d =
                        box_distance(p.position, cube_direction(face, (i + 0.5f) / set.m, (j + 0.5f) / set.m));
                    worst_distance = std::max(worst_distance, std::abs(double(p.distance[t]) / d - 1.0));
                }
        mean /= 6.0 * set.m * set.m;
        // Path tracing with Russian roulette is unbiased: 48 passes of 256
        // fine texels per coarse one leave well under 1% noise in the mean.
        EXPECT_NEAR(mean, expected, 0.01 * expected);
        EXPECT_LT(worst_distance, 0.08);
        // SH9 of a constant environment: only the constant band, L·sqrt(4π).
        EXPECT_NEAR(p.sh9[0].g, expected * std::sqrt(4.0 * M_PI), 0.02 * expected * std::sqrt(4.0 * M_PI));
        for (int c = 1; c < 9; ++c) EXPECT_LT(std::abs(p.sh9[size_t(c)].g), 0.03 * expected) << "coefficient " << c;
    }
    // Irradiance/pi is L everywhere inside, whatever the normal: the
    // polygon-to-point estimate holds it from the probe out to 1 cm from a
    // wall facing it, and at the room's edges and corners below (issue #34:
    // within 2% as close as 1 cm to a wall). The estimator is exact for
    // uniform radiance (tests/test_probes.cpp, by ray casting); what is left
    // here is the capture's noise at 48 passes of 16 x 16 texels, measured
    // at most 1.45% over these ten points.
    const ProbeEvaluator eval(set);
    for (const auto& [x, n] : std::vector<std::pair<glm::vec3, glm::vec3>>{{centre, {0, 1, 0}},
                                                                           {{0.3f, -0.4f, 0.2f}, {1, 0, 0}},
                                                                           {{0.95f, 0.0f, 0.0f}, {1, 0, 0}},
                                                                           {{0.99f, 0.3f, -0.5f}, {1, 0, 0}},
                                                                           {{0.4f, 0.5f, -0.99f}, {0, 0, -1}},
                                                                           {{0, -0.9f, 0}, {0, -1, 0}}}) {
        const ProbeEvaluation e = eval.evaluate(x, n);
        std::printf("  furnace at (%.2f, %.2f, %.2f): polygon_to_point %+.4f\n", x.x, x.y, x.z,
                    e.polygon_to_point.g / expected - 1.0f);
        EXPECT_NEAR(e.polygon_to_point.g, expected, 0.02 * expected) << x.x << "," << x.y << "," << x.z;
    }
    // At the room's edges and corners (issue #34), each point with the
    // normal of every wall near it: a texel that sees
    // an edge has corners on two walls and its polygon cuts across the edge;
    // a point in the cut, beyond the polygon, is evaluated just inside it
    // (probe_point_inside). Before, -26% at (0.9, -0.99, 0.9), n = +y; the
    // paper's clamp still loses there (tests/test_probes.cpp says why).
    double worst = 0.0;
    for (const glm::vec3& x : {glm::vec3(0.9f, -0.99f, 0.9f), glm::vec3(0.99f, -0.99f, 0.2f),
                               glm::vec3(-0.99f, 0.99f, -0.99f), glm::vec3(0.9f, 0.9f, -0.9f)})
        for (int a = 0; a < 3; ++a) {
            glm::vec3 n(0.0f);
            n[a] = x[a] > 0.0f ? -1.0f : 1.0f;
            const float g = eval.evaluate(x, n).polygon_to_point.g;
            worst = std::max(worst, std::abs(g / expected - 1.0));
            EXPECT_NEAR(g, expected, 0.02 * expected) << x.x << "," << x.y << "," << x.z << " n " << a;
        }
    std::printf("  furnace at the room's edges: worst relative error %.4f\n", worst);
}

// A probe under a sheet 1 m above it, 200 m wide, under a uniform sky of
// radiance 1 (issue #35): every texel of the face looking up sees the sky
// through the sheet, its transmittance times 1; the face looking down, the
// open sky. Clear and tinted glass and a cut-out pass every ray, so those
// texels are exact; a blend draws per ray, so its face's mean is within its
// noise (64 x 64 fine texels per face and 16 passes: 0.4%); a solid cut-out
// stops everything (its black underside reflects nothing).
TEST(ProbeCapture, AProbeSeesTheSkyThroughASheetTimesItsTransmittance) {
    struct Case {
        const char* name;
        Material::AlphaMode mode;
        float alpha, transmission;
        glm::vec3 color, passes;
        bool drawn;
    };
    const glm::vec3 tint(1.0f, 0.5f, 0.25f);
    for (const Case& c :
         {Case{"tinted glass", Material::AlphaMode::Opaque, 1.0f, 1.0f, tint, tint, false},
          Case{"cut out", Material::AlphaMode::Mask, 0.0f, 0.0f, glm::vec3(0.0f), glm::vec3(1.0f), false},
          Case{"solid cut-out", Material::AlphaMode::Mask, 1.0f, 0.0f, glm::vec3(0.0f), glm::vec3(0.0f), false},
          Case{"blended", Material::AlphaMode::Blend, 0.3f, 0.0f, glm::vec3(0.0f), glm::vec3(0.7f), true}}) {
        SCOPED_TRACE(c.name);
        Scene s;
        const uint32_t sheet = test::add_material(s, c.color);
        s.materials[sheet].alpha_mode = c.mode;
        s.materials[sheet].base_color.a = c.alpha;
        s.materials[sheet].transmission = c.transmission;
        test::add_quad(s, {-100, 1, -100}, {200, 0, 0}, {0, 0, 200}, sheet);  // facing down
        const ProbeSet set = capture(s, {glm::vec3(0.0f)}, 64, 4, 16, {std::array<float, 3>{1, 1, 1}, ""});
        ASSERT_EQ(set.probes.size(), 1u);
        const Probe& p = set.probes[0];
        ASSERT_TRUE(p.valid) << p.why;
        // Faces in cube_direction's order: +x, -x, +y, -y, +z, -z.
        glm::dvec3 up(0.0), down(0.0);
        for (int j = 0; j < set.m; ++j)
            for (int i = 0; i < set.m; ++i) {
                up += glm::dvec3(p.radiance[set.texel(2, i, j)]) / double(set.m * set.m);
                down += glm::dvec3(p.radiance[set.texel(3, i, j)]) / double(set.m * set.m);
            }
        for (int k = 0; k < 3; ++k) {
            EXPECT_NEAR(up[k], c.passes[k], c.drawn ? 0.02 : 1e-5) << "looking up, channel " << k;
            EXPECT_NEAR(down[k], 1.0, 1e-5) << "looking down, channel " << k;
        }
    }
}

// The same under a closed glass slab (KHR_materials_volume, issue #53): 200 m
// wide, y from 1 to 1 + d, drawn thickness, colour and absorption. A ray
// looking up at angle theta from the vertical crosses it over d / cos theta,
// so the sky arrives times base² exp(-attenuation d / cos theta). Each texel
// of the face looking up (R = M = 64) is the mean of its rays, each that at
// its direction: so it lies between that function's least and greatest over
// the texel (which it spans monotonically: its corners and edges' 7 x 7
// points); and the face's mean is the function's mean over the face (the
// rays spread evenly in the face's coordinates) within 0.1% (the within-texel
// draws' noise, 4 passes: 0.002% measured).
TEST(ProbeCapture, AProbeSeesTheSkyThroughAClosedSlabByBeerLambert) {
    std::mt19937 rng = test::family_rng(5303);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int config = 0; config < 3; ++config) {
        const float d = 0.02f + 0.5f * u(rng);
        const glm::vec3 base = glm::vec3(0.6f) + 0.4f * glm::vec3(u(rng), u(rng), u(rng));
        const glm::vec3 attenuation = 2.0f * glm::vec3(u(rng), u(rng), u(rng));
        SCOPED_TRACE("config " + std::to_string(config));
        Scene s;
        const uint32_t glass = test::add_material(s, base);
        s.materials[glass].transmission = 1.0f;
        s.materials[glass].attenuation = attenuation;
        s.materials[glass].thickness = 1.0f;
        test::add_box(s, {-100, 1, -100}, {100, 1 + d, 100}, glass);
        const int r = 64;
        const ProbeSet set = capture(s, {glm::vec3(0.0f)}, r, r, 4, {std::array<float, 3>{1, 1, 1}, ""});
        ASSERT_TRUE(set.probes[0].valid) << set.probes[0].why;
        const PreparedProbe p = prepare_probe(set.probes[0], r);
        const auto through_slab = [&](glm::dvec3 on_face) {  // a point of the cube's face y = 1
            const double cos = 1.0 / glm::length(on_face);
            return glm::dvec3(base * base) * glm::exp(-glm::dvec3(attenuation) * double(d) / cos);
        };
        glm::dvec3 face(0.0), expected_face(0.0);
        int outside = 0;
        for (int j = 0; j < r; ++j)
            for (int i = 0; i < r; ++i) {
                const PreparedProbe::Texel& t = p.texels[size_t(set.texel(2, i, j))];  // +y: looking up
                glm::dvec3 lo(1e30), hi(0.0), mean(0.0);
                constexpr int kSub = 7;
                for (int b = 0; b < kSub; ++b)
                    for (int a = 0; a < kSub; ++a) {
                        // Bilinear between the texel's corners on the face.
                        const double sa = a / (kSub - 1.0), sb = b / (kSub - 1.0);
                        const double w[4] = {(1 - sa) * (1 - sb), sa * (1 - sb), sa * sb, (1 - sa) * sb};
                        glm::dvec3 on_face(0.0);
                        for (int c = 0; c < 4; ++c)
                            on_face += w[c] * glm::dvec3(t.corner_directions[c]) / double(t.corner_directions[c].y);
                        const glm::dvec3 passes = through_slab(on_face);
                        lo = glm::min(lo, passes);
                        hi = glm::max(hi, passes);
                        mean += passes / double(kSub * kSub);
                    }
                const glm::dvec3 got(t.radiance);
                for (int c = 0; c < 3; ++c)
                    outside += got[c] < lo[c] * (1 - 1e-4) || got[c] > hi[c] * (1 + 1e-4) ? 1 : 0;
                face += got;
                expected_face += mean;
            }
        const glm::dvec3 ratio = face / expected_face;
        std::printf("  slab d %.3f: face %.5f %.5f %.5f of Beer-Lambert's; %d texel channels outside their range\n", d,
                    ratio.r, ratio.g, ratio.b, outside);
        EXPECT_EQ(outside, 0);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(ratio[c], 1.0, 1e-3) << "channel " << c;
    }
}

// Irradiance/pi at (x, y, z) on a plane parallel to the 1 x 1 m emitter
// [-0.5, 0.5]² at height h above the plane.
double emitter_form_factor(double x, double z, double h) {
    return test::rectangle_form_factor(x, z, -0.5, 0.5, -0.5, 0.5, h);
}

// Points with the normal n around a probe of `set` against `truth` (irradiance
// / pi): the worst relative error of polygon_to_point, point_to_point and sh9
// over the points.
struct WorstErrors {
    double polygon = 0.0, point = 0.0, sh9 = 0.0;
};
WorstErrors worst_errors(const ProbeSet& set, const std::vector<glm::vec3>& points, glm::vec3 n,
                         const std::function<double(glm::vec3)>& truth) {
    const ProbeEvaluator eval(set);
    WorstErrors w;
    for (const glm::vec3& p : points) {
        const double t = truth(p);
        const ProbeEvaluation e = eval.evaluate(p, n);
        w.polygon = std::max(w.polygon, std::abs(e.polygon_to_point.g / t - 1.0));
        w.point = std::max(w.point, std::abs(e.point_to_point.g / t - 1.0));
        w.sh9 = std::max(w.sh9, std::abs(e.sh9.g / t - 1.0));
    }
    return w;
}

// The same set as a file without traced corners reads it: corners from the texels' depths.
ProbeSet without_traced_corners(ProbeSet set) {
    for (Probe& p : set.probes) p.corner_distance.clear();
    return set;
}

// An environment written as the .exr file a job names.
std::filesystem::path write_map(const Environment& sky) {
    FloatImage image;
    image.width = sky.width;
    image.height = sky.height;
    for (const char* ch : {"R", "G", "B"}) image.channels[ch].resize(sky.texels.size());
    for (size_t t = 0; t < sky.texels.size(); ++t)
        for (int k = 0; k < 3; ++k) image.channels[std::string(1, "RGB"[k])][t] = sky.texels[t][k];
    const std::filesystem::path map =
        std::filesystem::temp_directory_path() / ("lf-sky-" + std::to_string(getpid()) + ".exr");
    write_exr(map, image);
    return map;
}

// A probe in the open under an environment map (an .exr file, as a job
// gives it): what it captures is the map, so each estimator at the probe,
// and at points up to 2.4 m from it (the map is at infinity), returns the
// map's irradiance. For radiance linear in the direction,
// L(ω) = c0 + c·ω per channel, E/π for a normal n is c0 + (2/3) c·n
// (tests/test_radiosity.cpp's closed form), at every angle. The only
// geometry is a 1 cm speck 100 m below. Measured: polygon-to-point, ddgi
// and sh9 within 0.4% at every point (M = 8, R = 32, 8 passes).
TEST(ProbeCapture, AProbeInTheOpenSeesTheEnvironmentMap) {
    const test::LinearSky linear;
    const std::filesystem::path map = write_map(linear.map(256, 128));
    Scene s;
    test::add_quad(s, {0, -100, 0}, {0.01f, 0, 0}, {0, 0, -0.01f}, test::add_material(s, glm::vec3(0.0f)));
    const ProbeSet set = capture(s, {glm::vec3(0.0f)}, 32, 8, 8, {std::nullopt, map.string()});
    std::filesystem::remove(map);
    ASSERT_EQ(set.probes.size(), 1u);
    const ProbeEvaluator eval(set);
    // The sky is at infinity: the same irradiance at the probe and at points
    // away from it (its missed texels' polygons lie at kMissDistance).
    for (const glm::vec3& x :
         {glm::vec3(0.0f), glm::vec3(0.5f, 0.0f, 0.0f), glm::vec3(0.0f, -0.7f, 0.3f), glm::vec3(-1.0f, 1.0f, 2.0f)})
        for (const glm::dvec3& n : {glm::dvec3(0, 1, 0), glm::dvec3(0, -1, 0), glm::dvec3(1, 0, 0),
                                    glm::dvec3(0, 0, -1), glm::normalize(glm::dvec3(1, 2, -3))}) {
            SCOPED_TRACE("x (" + std::to_string(x.x) + ", " + std::to_string(x.y) + ", " + std::to_string(x.z) + ")");
            const glm::dvec3 expected = linear.irradiance_over_pi(n);
            const ProbeEvaluation e = eval.evaluate(x, glm::vec3(n));
            std::printf(
                "  x = (%.1f, %.1f, %.1f), n = (%.2f, %.2f, %.2f): polygon-to-point %.4f %.4f %.4f, ddgi "
                "%.4f %.4f %.4f (closed form %.4f %.4f %.4f)\n",
                x.x, x.y, x.z, n.x, n.y, n.z, e.polygon_to_point.r, e.polygon_to_point.g, e.polygon_to_point.b,
                e.ddgi.r, e.ddgi.g, e.ddgi.b, expected.r, expected.g, expected.b);
            for (int k = 0; k < 3; ++k) {
                EXPECT_NEAR(e.polygon_to_point[k] / expected[k], 1.0, 0.01) << "channel " << k << ", n.y " << n.y;
                EXPECT_NEAR(e.ddgi[k] / expected[k], 1.0, 0.01) << "channel " << k << ", n.y " << n.y;
                EXPECT_NEAR(e.sh9[k] / expected[k], 1.0, 0.01) << "channel " << k << ", n.y " << n.y;
            }
        }
}

// A probe 1 m above a grey floor (albedo 0.5, 400 m wide) under a sky
// with a sun (a 256 x 128 map of 0.05, a 2 x 2-texel sun of 2,500 about
// 40° from the zenith): the floor's radiance, which the probe's face
// looking down sees, is 0.5 x E/π = 0.5 x 0.998 (the map's integral over
// the floor's hemisphere; nothing else bounces). Its paths find the sun by
// the map's own sample at each hit (environment.glsl), not by the cosine
// ray's luck. Measured (R 16, 16 passes, M 4): the face's mean within
// 0.14%, its worst texel 4.7%; with the map's sampling turned off, the
// mean 9.7% low and the worst texel 5.9 times too bright.
TEST(ProbeCapture, AFloorUnderASunInTheMapIsLitByEveryPath) {
    const test::SunSky sun;
    const std::filesystem::path map = write_map(sun.map());
    Scene s;
    test::add_quad(s, {-200, 0, 200}, {400, 0, 0}, {0, 0, -400}, test::add_material(s, glm::vec3(0.5f)));
    const ProbeSet set = capture(s, {glm::vec3(0.0f, 1.0f, 0.0f)}, 16, 4, 16, {std::nullopt, map.string()});
    std::filesystem::remove(map);
    ASSERT_EQ(set.probes.size(), 1u);
    const double expected = 0.5 * sun.irradiance_over_pi({0, 1, 0});
    double mean = 0.0, worst = 0.0;
    for (int j = 0; j < set.m; ++j)
        for (int i = 0; i < set.m; ++i) {
            const double g = set.probes[0].radiance[set.texel(3, i, j)].g;  // -Y: the floor
            mean += g / (set.m * set.m);
            worst = std::max(worst, std::abs(g / expected - 1.0));
        }
    std::printf("  the floor seen from 1 m: radiance %.4f (closed form %.4f), worst texel %.4f\n", mean, expected,
                worst);
    EXPECT_NEAR(mean / expected, 1.0, 0.03);
    EXPECT_LT(worst, 0.1);
}

// The issue's plates (#34): a black floor, a parallel 1 x 1 m emitter of
// radiance 2 0.5 m above it, a probe 0.25 m up under its centre; points
// with the floor's normal under the emitter (|x|, |z| <= 0.45) at the
// probe's height, between it and the floor, on the floor, and 10 and 5 cm
// under the emitter, against L x F(point -> emitter). The emitter is seen
// through the side faces as a plane at right angles to them: with the
// corners traced, every polygon corner lies on it and the emitter's edges on
// texel edges, so polygon_to_point is exact to float rounding at M = 4 and
// 8 (measured 0.0000); with corners from the texels' depths (the files
// before them) it was off by up to 77% (M 4) and 58% (M 8). The paper's
// findings stay: point_to_point fails near the emitter (95% at 5 cm, M 4),
// and sh9 drifts away from the reference point (136% over the points at the
// probe's own height: it ignores x).
TEST(ProbeCapture, PlatesPolygonToPointHoldsAwayFromTheProbe) {
    Scene s;
    const uint32_t black = test::add_material(s, glm::vec3(0.0f));
    const uint32_t light = test::add_material(s, glm::vec3(0.0f), glm::vec3(2.0f));
    test::add_quad(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, black);
    test::add_quad(s, {-0.5f, 0.5f, -0.5f}, {1, 0, 0}, {0, 0, 1}, light);
    const auto truth = [](glm::vec3 p) { return 2.0 * emitter_form_factor(p.x, p.z, 0.5 - p.y); };
    for (int m : {4, 8}) {
        SCOPED_TRACE("M " + std::to_string(m));
        const ProbeSet set = capture(s, {glm::vec3(0, 0.25f, 0)}, 64, m, 16);
        for (float y : {0.25f, 0.125f, 0.0f, 0.4f, 0.45f}) {
            SCOPED_TRACE("y " + std::to_string(y));
            std::vector<glm::vec3> points;
            for (int i = 0; i < 7; ++i)
                for (int k = 0; k < 7; ++k) points.push_back({-0.45f + 0.15f * i, y, -0.45f + 0.15f * k});
            const WorstErrors traced = worst_errors(set, points, {0, 1, 0}, truth);
            EXPECT_LT(traced.polygon, 0.03);
            EXPECT_GT(worst_errors(without_traced_corners(set), points, {0, 1, 0}, truth).polygon, 0.3);
            if (y == 0.45f) {
                EXPECT_GT(traced.point, 0.5) << "point_to_point near the emitter";
            }
            if (y == 0.25f) {
                EXPECT_GT(traced.sh9, 0.5) << "sh9 away from the reference point";
            }
        }
        const ProbeEvaluation at_probe = ProbeEvaluator(set).evaluate({0, 0.25f, 0}, {0, 1, 0});
        EXPECT_NEAR(at_probe.sh9.g, truth({0, 0.25f, 0}), 0.05 * truth({0, 0.25f, 0})) << "sh9 at its reference point";
    }
    // The probe off the centre, (0.13, 0.25, -0.07), so the emitter's edges
    // cross texels: an edge texel's corners beyond the edge continue the
    // emitter's plane (probe_corner_distances). Measured worst at M 8 over
    // the 49 points of each height: 9.3% at the probe's height, 19.5%
    // halfway down, 22.8% on the floor (the grid's corners, 0.6 m from the
    // probe); before the plane was continued there, 46% at the probe's height and 30%
    // on the floor.
    const ProbeSet off = capture(s, {glm::vec3(0.13f, 0.25f, -0.07f)}, 64, 8, 16);
    for (const auto& [y, bound] : {std::pair{0.25f, 0.12}, std::pair{0.125f, 0.24}, std::pair{0.0f, 0.27}}) {
        std::vector<glm::vec3> points;
        for (int i = 0; i < 7; ++i)
            for (int k = 0; k < 7; ++k) points.push_back({-0.45f + 0.15f * i, y, -0.45f + 0.15f * k});
        const double worst = worst_errors(off, points, {0, 1, 0}, truth).polygon;
        std::printf("  plates, off-centre probe, M 8, y %.3f: polygon_to_point worst %.4f\n", y, worst);
        EXPECT_LT(worst, bound) << "off-centre probe, y " << y;
    }
}

// A see-through sheet between the plates' probe and their emitter (issue
// #52): a 4 x 4 m sheet at a drawn height between the probe (0.25 m) and
// the emitter (0.5 m), a black blend of drawn alpha or clear glass of drawn
// transmission, the probe at the defaults (R 32, M 8, 64 passes). Below the
// sheet the truth is the sheet's transmittance times the plates' closed
// form. The capture's distances and the corner and centre rays pass the
// sheet, so the polygons lie on the emitter with its radiance times the
// transmittance; before, a blend's rays stopped on the sheet at random and
// its polygons lay between: -39% on the floor, -55% 0.3 m aside (the
// issue's measure). Seed printed; errors on the issue's scale,
// |estimate - truth| / max(truth, 10% of the family's brightest).
TEST(ProbeCapture, ASheetBetweenTheProbeAndTheEmitterDoesNotMoveItsPolygons) {
    std::mt19937 rng = test::family_rng(5201);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<test::Reading> readings;
    for (int config = 0; config < 6; ++config) {
        const bool blend = config % 2 == 0;
        const float amount = blend ? 0.9f * u(rng) : 0.05f + 0.95f * u(rng);  // alpha, or transmission
        const float height = 0.3f + 0.15f * u(rng);
        const double passes = blend ? 1.0 - amount : amount;
        std::printf("  %s %.3f at %.3f m\n", blend ? "blend, alpha" : "glass, transmission", amount, height);
        Scene s;
        const uint32_t black = test::add_material(s, glm::vec3(0.0f));
        const uint32_t light = test::add_material(s, glm::vec3(0.0f), glm::vec3(2.0f));
        const uint32_t sheet = test::add_material(s, glm::vec3(blend ? 0.0f : 1.0f), glm::vec3(0.0f), true);
        s.materials[sheet].alpha_mode = blend ? Material::AlphaMode::Blend : Material::AlphaMode::Opaque;
        s.materials[sheet].base_color.a = blend ? amount : 1.0f;
        s.materials[sheet].transmission = blend ? 0.0f : amount;
        test::add_quad(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, black);
        test::add_quad(s, {-0.5f, 0.5f, -0.5f}, {1, 0, 0}, {0, 0, 1}, light);
        test::add_quad(s, {-2, height, -2}, {4, 0, 0}, {0, 0, 4}, sheet);  // facing the probe
        const ProbeSet set = capture(s, {glm::vec3(0, 0.25f, 0)}, 32, 8, 64);
        ASSERT_TRUE(set.probes[0].valid) << set.probes[0].why;
        const ProbeEvaluator eval(set);
        for (int i = 0; i < 30; ++i) {
            const glm::vec3 x(-0.45f + 0.9f * u(rng), i % 3 == 0 ? 0.0f : (height - 0.01f) * u(rng),
                              -0.45f + 0.9f * u(rng));
            readings.push_back({eval.evaluate(x, {0, 1, 0}).polygon_to_point.g,
                                passes * 2.0 * emitter_form_factor(x.x, x.z, 0.5 - x.y)});
        }
    }
    const auto [p95, worst] = test::family_errors(readings);
    std::printf("  under the sheet: p95 %.4f, worst %.4f over %zu points\n", p95, worst, readings.size());
    EXPECT_LE(p95, 0.05);
    EXPECT_LE(worst, 0.10);
}

// A closed room turned about (1, 1, 0) by 0, 30 and 60 degrees, so that its
// walls meet the cube's faces at those angles; its ceiling emits 2, the rest
// is black. Points throughout the room with the ceiling's normal, against L
// x F(point -> ceiling) (Lambert's polygon formula). Traced corners lie on
// the walls at any angle; corners from the texels' depths only on walls
// parallel to the faces. What is left is the emitter's edges within texels
// and the texels' size near a wall (the same at every angle). Measured at
// M 8, worst over 125 points, traced / from depths: 0°: 11% / 13%, 30°: 18%
// / 35%, 60°: 29% / 98% (with the paper's clamp, before triangles were
// clipped and summed signed: 11% / 13%, 18% / 38%, 32% / 64%).
TEST(ProbeCapture, CornersLieOnWallsAtEveryAngleToTheFaces) {
    for (float degrees : {0.0f, 30.0f, 60.0f}) {
        SCOPED_TRACE(std::to_string(degrees) + " degrees");
        const glm::mat3 turn =
            glm::mat3(glm::rotate(glm::mat4(1.0f), glm::radians(degrees), glm::normalize(glm::vec3(1, 1, 0))));
        Scene s;
        const uint32_t black = test::add_material(s, glm::vec3(0.0f));
        const uint32_t light = test::add_material(s, glm::vec3(0.0f), glm::vec3(2.0f));
        const glm::vec3 o(-1.0f), X(2, 0, 0), Y(0, 2, 0), Z(0, 0, 2);
        auto quad = [&](glm::vec3 c, glm::vec3 u, glm::vec3 v, uint32_t m) {
            test::add_quad(s, turn * c, turn * u, turn * v, m);
        };
        quad(o, Z, X, black);
        quad(o + Y, X, Z, light);  // the ceiling, facing down
        quad(o, X, Y, black);
        quad(o + Z, Y, X, black);
        quad(o, Y, Z, black);
        quad(o + X, Z, Y, black);
        const glm::vec3 ceiling[4] = {turn * (o + Y), turn * (o + Y + Z), turn * (o + Y + X + Z), turn * (o + Y + X)};
        const glm::vec3 n = turn * glm::vec3(0, 1, 0);
        std::vector<glm::vec3> points;
        for (int i = 0; i < 5; ++i)
            for (int j = 0; j < 5; ++j)
                for (int k = 0; k < 5; ++k)
                    points.push_back(turn * glm::vec3(-0.8f + 0.4f * i, -0.9f + 0.425f * j, -0.8f + 0.4f * k));
        const auto truth = [&](glm::vec3 p) { return 2.0 * std::abs(polygon_to_point_form_factor(p, n, ceiling, 4)); };
        const ProbeSet set = capture(s, {turn * glm::vec3(0.1f, -0.2f, 0.15f)}, 64, 8, 8);
        const double traced = worst_errors(set, points, n, truth).polygon;
        const double depths = worst_errors(without_traced_corners(set), points, n, truth).polygon;
        std::printf("  room turned %.0f°: polygon_to_point worst %.4f traced, %.4f from depths\n", degrees, traced,
                    depths);
        EXPECT_LT(traced, 0.35);
        if (degrees > 0.0f) {
            EXPECT_LT(traced, 0.6 * depths) << "traced corners against corners from depths";
        }
    }
}

// Directional lightmaps on real scenes (issue #36), beside the synthetic
// cases of tests/test_radiosity.cpp: each chosen texel's L0 alone, and
// L0 + L1 · (n′ − n), at its normal tilted 26.6° four ways (as a normal map
// tilts it), against the irradiance there from a probe captured at the
// texel's point, 5 mm above its surface, not downsampled (path traced: every
// bounce, the textures where paths land). The light from below the texel's
// surface is left out, as the lightmap leaves it out: E/π(n′) = Σ L Ω
// max(0, n′·ω) / π over the probe's texels above the surface. Texels whose
// samples all lie on one triangle, evenly over the covered ones.
struct DirectionalErrors {
    double l0 = 0.0, l1 = 0.0;  // relative RMSE over texel-tilts
    size_t count = 0;
};

DirectionalErrors directional_against_probes(const std::string& file, int res, int passes, size_t texel_count,
                                             int probe_res, int probe_passes) {
    gpu();
    Scene scene = load_scene(test::example_scene(file));
    AtlasOptions atlas;
    atlas.resolution = res;
    prepare_lightmap_atlas(scene, atlas);
    const TexelSamples texels = rasterize_texel_samples(scene, res, res, 2);
    const Tracer tracer(scene);
    RadiosityMapSettings settings;
    settings.directional = true;
    RadiosityMapBaker baker(scene, texels, tracer, settings);
    for (int done = 0; done < passes;) {
        const int count = std::min(baker.max_batch(), passes - done);
        baker.run_passes(count);
        done += count;
    }
    const FloatImage image = baker.snapshot();
    std::vector<size_t> chosen;
    std::vector<glm::vec3> points;
    const size_t stride = std::max<size_t>(1, texels.covered_count() / texel_count);
    for (size_t i = 0; i < texels.covered_count() && chosen.size() < texel_count; i += stride) {
        const TexelSample& s = texels.samples[texels.first_sample[i]];
        bool one_triangle = glm::length(s.geometric_normal) > 0.5f;
        for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k)
            one_triangle = one_triangle && texels.samples[k].triangle == s.triangle;
        if (!one_triangle) continue;
        chosen.push_back(i);
        points.push_back(s.position + 0.005f * s.geometric_normal);
    }
    const ProbeSet set = capture(scene, points, probe_res, probe_res, probe_passes);
    DirectionalErrors e;
    double l0_sq = 0.0, l1_sq = 0.0, truth_sq = 0.0;
    for (size_t k = 0; k < chosen.size(); ++k) {
        if (!set.probes[k].valid) continue;
        const PreparedProbe probe = prepare_probe(set.probes[k], set.m);
        const TexelSample& s = texels.samples[texels.first_sample[chosen[k]]];
        const size_t a = texels.texels[chosen[k]];
        const glm::dvec3 n(s.normal), ng(s.geometric_normal);
        const double l0 = image.at("G")[a];
        const glm::dvec3 l1(image.at("L1x.G")[a], image.at("L1y.G")[a], image.at("L1z.G")[a]);
        const glm::dvec3 t =
            glm::normalize(glm::cross(n, std::abs(n.y) < 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(1, 0, 0)));
        const glm::dvec3 b = glm::cross(n, t);
        for (const glm::dvec3& tilt : {t, -t, b, -b}) {
            const glm::dvec3 bumped = glm::normalize(n + 0.5 * tilt);
            double truth = 0.0;
            for (const PreparedProbe::Texel& texel : probe.texels) {
                const glm::dvec3 w(texel.direction);
                if (glm::dot(w, ng) > 0.0)
                    truth += texel.radiance.g * double(texel.solid_angle) * std::max(0.0, glm::dot(bumped, w)) / M_PI;
            }
            l0_sq += (l0 - truth) * (l0 - truth);
            l1_sq += (l0 + glm::dot(l1, bumped - n) - truth) * (l0 + glm::dot(l1, bumped - n) - truth);
            truth_sq += truth * truth;
            ++e.count;
        }
    }
    e.l0 = std::sqrt(l0_sq / truth_sq);
    e.l1 = std::sqrt(l1_sq / truth_sq);
    return e;
}

// The Cornell box (its own lightmap UVs, 64², 256 passes; 24 texels, probes
// of 16² a face at 32 passes). Measured: relative RMSE over 88 texel-tilts
// of L0 alone 19.5%, of L0 + L1 10.8% (at 512 passes and probes of 64
// passes: 19.5% and 10.3%; what is left is mostly the probes' noise and L1's
// linear fit to light from a small emitter, tests/test_radiosity.cpp).
TEST(DirectionalLightmap, BumpedNormalsOnTheCornellBoxAgainstProbes) {
    const DirectionalErrors e = directional_against_probes("cornell_box.gltf", 64, 256, 24, 16, 32);
    std::printf("  Cornell box, %zu texel-tilts: relative RMSE of L0 %.4f, of L0 + L1 %.4f\n", e.count, e.l0, e.l1);
    ASSERT_GT(e.count, 60u);
    EXPECT_LT(e.l1, 0.7 * e.l0) << "L1 follows the bumped normals";
}

// The same on the staircase (a real interior: 2 emissive triangles, 9,121
// charts at 433², 256 passes; 100 texels chosen, probes of 16² a face at
// 128 passes): a figure for docs/BENCHMARKS.md (11 minutes on llvmpipe),
// disabled in ctest like the scale-out figures; run it with
// --gtest_also_run_disabled_tests --gtest_filter='*Staircase*'. Measured
// 2026-11-28: 60 of the 100 texels' probes valid (the others 5 mm above a
// surface in a crease, where most rays meet backs), 240 texel-tilts: L0
// alone 24.8%, L0 + L1 13.2%.
TEST(DirectionalLightmap, DISABLED_FiguresBumpedNormalsOnTheStaircaseAgainstProbes) {
    const DirectionalErrors e =
        directional_against_probes("real/wooden_staircase/wooden_staircase.gltf", 433, 256, 100, 16, 128);
    std::printf("  staircase, %zu texel-tilts: relative RMSE of L0 %.4f, of L0 + L1 %.4f\n", e.count, e.l0, e.l1);
    ASSERT_GT(e.count, 200u);
    EXPECT_LT(e.l1, e.l0);
}

// Where probes go: the job's points win; else the file's nodes marked
// lightfarm_probe; else a grid of cell centres over the bounds, a quarter of
// the largest extent apart by default.
TEST(ProbePlacement, ExplicitThenTheFilesNodesThenAGrid) {
    Scene s = furnace(0.5f, 1.0f);  // [-1, 1]³
    ProbesSettings settings;
    float spacing = 0.0f;
    std::vector<glm::vec3> grid = ProbesMethod::place(s, settings, &spacing);
    EXPECT_FLOAT_EQ(spacing, 0.5f);
    ASSERT_EQ(grid.size(), 64u);
    expect_inside(grid);
    s.probe_points = {{0.1f, 0.2f, 0.3f}};
    EXPECT_EQ(ProbesMethod::place(s, settings, &spacing), s.probe_points);
    EXPECT_EQ(spacing, 0.0f);
    settings.positions = {{0.0f, 0.0f, 0.0f}, {0.5f, 0.5f, 0.5f}};
    EXPECT_EQ(ProbesMethod::place(s, settings, &spacing).size(), 2u);
}

// A grid probe 1 cm under a shelf (a double-sided slab over a quarter of
// the furnace's cells) is moved away from it first, to the clearance (10 cm
// here, a quarter spacing being 12.5 cm), straight down: the shelf is met
// nearest by the ray up. probes.json keeps where the grid put it
// (moved_from), so the set is still a grid, blended on the lattice, each
// probe's light from where it was captured; the others stay on the lattice.
TEST(ProbePlacement, AGridProbeBesideASurfaceIsMovedAwayFromIt) {
    Scene s = furnace(0.5f, 1.0f);
    test::add_quad(s, {0, 0.26f, 0}, {0, 0, 0.5f}, {0.5f, 0, 0},
                   test::add_material(s, glm::vec3(0.5f), glm::vec3(1.0f), true));
    gpu();
    PreparedScene prepared;
    prepared.file = "shelf.glb";
    prepared.scene = s;
    prepared.tracer = std::make_unique<Tracer>(prepared.scene);
    const protocol::BakeSettings settings =
        protocol::parse_bake_settings({{"outputs", {{"probes", {{"probe_res", 16}, {"probe_m", 4}}}}}, {"seed", 1}});
    ProbesMethod method(prepared, settings);
    PassStats stats = method.step();
    const std::filesystem::path dir =
        std::filesystem::temp_directory_path() / ("lf-probes-moved-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    method.finish(dir, stats);
    const ProbeSet set = read_probe_set(dir / "probes.json");
    std::filesystem::remove_all(dir);
    ASSERT_EQ(set.probes.size(), 64u);
    int moved = 0;
    for (const Probe& p : set.probes) {
        if (!p.moved_from) continue;
        ++moved;
        EXPECT_EQ(*p.moved_from, glm::vec3(0.25f, 0.25f, 0.25f));
        EXPECT_NEAR(p.position.x, 0.25f, 1e-5f);
        EXPECT_NEAR(p.position.y, 0.16f, 1e-4f) << "0.1 m under the shelf";
        EXPECT_NEAR(p.position.z, 0.25f, 1e-5f);
        EXPECT_TRUE(p.valid) << p.why;
    }
    EXPECT_EQ(moved, 1);
    EXPECT_TRUE(ProbeEvaluator(set).is_grid());
}

// A probe inside a solid box sees the backs of its one-sided faces: it is
// dropped, and says why.
TEST(ProbeCapture, AProbeInsideGeometryIsDropped) {
    Scene s;
    const uint32_t light = test::add_material(s, glm::vec3(0.5f), glm::vec3(1.0f), true);
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    test::add_quad(s, {-3, 2, -3}, {6, 0, 0}, {0, 0, 6}, light);
    test::add_box(s, {-0.5f, -0.5f, -0.5f}, {0.5f, 0.5f, 0.5f}, grey);
    const ProbeSet set = capture(s, {{0, 0, 0}, {0, 1.2f, 0}}, 16, 2, 2);
    ASSERT_EQ(set.probes.size(), 2u);
    EXPECT_FALSE(set.probes[0].valid);
    EXPECT_EQ(set.probes[0].why, "inside geometry");
    EXPECT_GT(set.probes[0].backface_fraction, 0.99f);
    EXPECT_TRUE(set.probes[1].valid) << set.probes[1].why;
}

// The paper's experiment (its Figures 4-5) in the Cornell box: one probe at
// the room's centre, points moving from it towards the red wall with normals
// facing the wall. Ground truth at each point: a probe captured there
// (R = 32, not downsampled), whose cosine-weighted integral at its own
// reference point has no parallax error. The polygon-to-point estimate stays
// close all the way; the point-to-point one fails next to the wall (its
// failure is the paper's, reproduced); the SH9 environment ignores where the
// point is and drifts.
TEST(ProbeCapture, CornellBoxPolygonToPointHoldsNearAWall) {
    const Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    const glm::vec3 centre = scene.bounds.centre() + glm::vec3(0.0f, 0.08f, 0.0f);  // above the blocks
    const glm::vec3 wall_normal(-1.0f, 0.0f, 0.0f);                                 // the red wall at x = bounds.lo.x
    const float to_wall = centre.x - scene.bounds.lo.x;
    std::vector<glm::vec3> points;
    for (float gap : {1.0f, 0.5f, 0.2f, 0.08f, 0.03f})
        points.push_back(centre + wall_normal * (to_wall * (1.0f - gap)));
    const int r = 32, passes = 24;
    const ProbeSet reference = capture(scene, {centre}, r, 8, passes);
    const ProbeSet truth = capture(scene, points, r, r, passes);
    ASSERT_TRUE(reference.probes[0].valid);
    const PreparedProbe probe = prepare_probe(reference.probes[0], reference.m);
    std::printf("  gap/room  truth    sh9      p2p      poly     ddgi   (irradiance/pi, green)\n");
    std::vector<double> poly_error, p2p_error, sh9_error;
    for (size_t k = 0; k < points.size(); ++k) {
        const float expected = probe_convolved_irradiance(prepare_probe(truth.probes[k], truth.m), wall_normal).g;
        const ProbeEvaluation e = evaluate_probe(probe, points[k], wall_normal);
        std::printf("  %.3f    %.4f   %.4f   %.4f   %.4f   %.4f\n", double((points[k].x - scene.bounds.lo.x) / to_wall),
                    expected, e.sh9.g, e.point_to_point.g, e.polygon_to_point.g, e.ddgi.g);
        poly_error.push_back(std::abs(e.polygon_to_point.g / expected - 1.0f));
        p2p_error.push_back(std::abs(e.point_to_point.g / expected - 1.0f));
        sh9_error.push_back(std::abs(e.sh9.g / expected - 1.0f));
    }
    // Measured on llvmpipe (24 passes, M = 8): polygon-to-point within 3.9%
    // at every point, point-to-point 93% low at 3% of the way from the wall,
    // SH9 21% off at the reference point (a bright emitter at its normal's
    // horizon, where nine coefficients cannot follow the clamped cosine) and
    // 80% at the wall. The bounds are twice, or half, those.
    for (size_t k = 0; k < points.size(); ++k) EXPECT_LT(poly_error[k], 0.08) << "point " << k;
    EXPECT_GT(p2p_error.back(), 0.45) << "point-to-point should fail next to the wall";
    EXPECT_GT(sh9_error.back(), 0.4) << "the SH9 environment ignores where the point is";
    EXPECT_GT(sh9_error.back(), 2.0 * sh9_error.front()) << "and drifts with distance from the probe";
}

// Downsampling conserves what the capture saw. With each coarse texel's
// radiance the solid-angle-weighted mean of its fine texels, the radiance
// integrated over the sphere is the capture's for every M, and at the
// probe's own reference point the irradiance an exact estimator returns
// (the cosine convolution; polygon-to-point with its polygons clipped at
// the horizon; DDGI) differs from the captured irradiance by exactly the
// within-texel covariance of radiance and cosine,
//   E_M - E_R = -sum_k sum_{f in k} Omega_f (L_f - L_k)(g_f - g_k),
// g = the fine texel's form factor over its solid angle (the mean cosine/pi)
// and g_k its Omega-weighted mean: the identity holds only because
// sum_f Omega_f (L_f - L_k) = 0, which a plain mean breaks. Under the
// Cornell box's small emitter, 5 mm above its floor (R = 32), the plain
// mean was -14.5%, -22%, +6%, -2.5% off at M = 1, 2, 4, 8; what remains
// with the weights is the covariance term alone (+1.9%, -5.3%, +1.5%, -0.6%):
// a coarse texel cannot follow the cosine across itself.
TEST(ProbeCapture, EveryMConservesTheCaptureAtTheReferencePoint) {
    const Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    const glm::vec3 at(0.1f, scene.bounds.lo.y + 0.005f, 0.45f);  // open floor, beside the tall block
    const glm::vec3 up(0.0f, 1.0f, 0.0f);
    const int r = 32;
    const ProbeSet full = capture(scene, {at}, r, r, 64);
    ASSERT_TRUE(full.probes[0].valid) << full.probes[0].why;
    const PreparedProbe fine = prepare_probe(full.probes[0], r);
    const glm::dvec3 truth(probe_convolved_irradiance(fine, up));
    ASSERT_GT(truth.y, 0.05);
    // Per fine texel: solid angle and mean cosine / pi (its clipped form factor over its solid angle).
    std::vector<double> omega(fine.texels.size()), g(fine.texels.size());
    glm::dvec3 integral_r(0.0);
    for (size_t k = 0; k < fine.texels.size(); ++k) {
        const PreparedProbe::Texel& t = fine.texels[k];
        omega[k] = t.solid_angle;
        g[k] = clipped_polygon_to_point_form_factor(glm::vec3(0.0f), up, t.corner_directions.data(), 4) / omega[k];
        integral_r += glm::dvec3(t.radiance) * omega[k];
    }
    std::printf("  M    convolved  predicted  poly(clip)  ddgi     (green; captured %.4f)\n", truth.y);
    for (int m : {1, 2, 4, 8, 16, 32}) {
        SCOPED_TRACE("M = " + std::to_string(m));
        Probe p = full.probes[0];
        downsample_faces(r, full.probes[0].radiance, full.probes[0].distance, m, p.radiance, p.distance);
        const PreparedProbe coarse = prepare_probe(p, m);
        // The radiance over the sphere is conserved.
        glm::dvec3 integral_m(0.0);
        for (const PreparedProbe::Texel& t : coarse.texels)
            integral_m += glm::dvec3(t.radiance) * double(t.solid_angle);
        // The covariance within each coarse texel.
        const int block = r / m;
        glm::dvec3 covariance(0.0);
        for (int face = 0; face < 6; ++face)
            for (int j = 0; j < m; ++j)
                for (int i = 0; i < m; ++i) {
                    const glm::dvec3 mean(p.radiance[(size_t(face) * m + size_t(j)) * m + size_t(i)]);
                    double w = 0.0, wg = 0.0;
                    for (int y = j * block; y < (j + 1) * block; ++y)
                        for (int x = i * block; x < (i + 1) * block; ++x) {
                            const size_t f = (size_t(face) * r + size_t(y)) * r + size_t(x);
                            w += omega[f];
                            wg += omega[f] * g[f];
                        }
                    const double g_mean = wg / w;
                    for (int y = j * block; y < (j + 1) * block; ++y)
                        for (int x = i * block; x < (i + 1) * block; ++x) {
                            const size_t f = (size_t(face) * r + size_t(y)) * r + size_t(x);
                            covariance += omega[f] * (glm::dvec3(full.probes[0].radiance[f]) - mean) * (g[f] - g_mean);
                        }
                }
        const glm::dvec3 predicted = truth - covariance;
        const ProbeEvaluation e = evaluate_probe(coarse, at, up);
        const glm::dvec3 convolved(probe_convolved_irradiance(coarse, up));
        std::printf("  %-4d %.4f     %.4f     %.4f      %.4f\n", m, convolved.y, predicted.y,
                    double(e.polygon_to_point.g), double(e.ddgi.g));
        for (int c = 0; c < 3; ++c) {
            EXPECT_NEAR(integral_m[c], integral_r[c], 1e-5 * integral_r[c]) << "channel " << c;
            EXPECT_NEAR(convolved[c], predicted[c], 1e-4 * truth[c]) << "channel " << c;
            EXPECT_NEAR(e.polygon_to_point[c], convolved[c], 1e-4 * truth[c]) << "channel " << c;
            EXPECT_NEAR(e.ddgi[c], convolved[c], 1e-4 * truth[c]) << "channel " << c;
        }
    }
}

// `lightfarm probebench` (docs/BENCHMARKS.md's probe figures): every row it
// promises, measured, and the paper's finding in its wall sweep.
TEST(ProbeBench, ReportsCaptureThroughputAndErrorRows) {
    gpu();
    const Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    ProbeBenchOptions options;
    options.at = scene.bounds.centre() + glm::vec3(0.0f, 0.08f, 0.0f);
    options.capture_resolutions = {16};
    options.ms = {2, 4};
    options.passes = 2;
    options.truth_resolution = 16;
    options.truth_passes = 4;
    options.random_points = 4;
    options.min_seconds = 0.01;
    const nlohmann::json bench = run_probe_bench(scene, options);
    ASSERT_EQ(bench["capture"].size(), 1u);
    EXPECT_GT(bench["capture"][0]["rays"].get<double>(), 2.0 * 6 * 16 * 16);  // a path per texel per pass, or more
    EXPECT_GT(bench["capture"][0]["seconds"].get<double>(), 0.0);
    ASSERT_EQ(bench["throughput"].size(), 2u * 5u);
    for (const auto& t : bench["throughput"]) {
        EXPECT_GT(t["cpu_points_per_second"].get<double>(), 0.0) << t.dump();
        if (t["estimator"] == "polygon_to_point") {
            EXPECT_GT(t["gpu_points_per_second"].get<double>(), 0.0);
        }
    }
    ASSERT_EQ(bench["error"].size(), 2u * 5u);
    const auto row = [&](int m, const std::string& estimator) {
        for (const auto& e : bench["error"])
            if (e["m"] == m && e["estimator"] == estimator) return e;
        ADD_FAILURE() << "no row for M = " << m << " " << estimator;
        return nlohmann::json();
    };
    // 1% of the way from the red wall (M = 4): point-to-point's virtual
    // lights lie in the point's plane (measured 0.996 at R = 32), polygon-to-point
    // holds (0.15).
    EXPECT_GT(row(4, "point_to_point")["wall"].back().get<double>(), 0.5);
    EXPECT_LT(row(4, "polygon_to_point")["wall"].back().get<double>(), 0.3);
    options.ms = {3};
    EXPECT_THROW(run_probe_bench(scene, options), std::invalid_argument);
}

}  // namespace
}  // namespace lf
