// The probes through the whole pipeline: the GPU capture (ProbesMethod),
// downsampling, the files, and the evaluation, against closed forms.
#include "gpu_fixture.h"
#include "scene_builders.h"

#include "bake/prepared_scene.h"
#include "bake/probes_method.h"
#include "probes/probe_eval.h"
#include "probes/probe_set.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>

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

// Captures probes at `points` of `scene` for `passes` passes and reads back
// the written set (the files are part of what is tested).
ProbeSet capture(const Scene& scene, const std::vector<glm::vec3>& points, int r, int m, int passes) {
    gpu();
    PreparedScene prepared;
    prepared.file = "test.glb";
    prepared.scene = scene;
    prepared.tracer = std::make_unique<Tracer>(prepared.scene);
    protocol::BakeSettings settings;
    protocol::ProbesSettings probes;
    for (const glm::vec3& p : points) probes.positions.push_back({p.x, p.y, p.z});
    probes.res = r;
    probes.m = m;
    settings.probes = probes;
    ProbesMethod method(prepared, settings);
    PassStats stats;
    for (int p = 0; p < passes; ++p) stats = method.step();
    const std::filesystem::path dir = std::filesystem::temp_directory_path() / ("lf-probes-" + std::to_string(getpid()));
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
                    const float d = box_distance(p.position, cube_direction(face, (i + 0.5f) / set.m, (j + 0.5f) / set.m));
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
    // polygon-to-point estimate holds it from the probe out to 5 cm from a
    // wall facing it, where texels are large in the point's hemisphere.
    const ProbeEvaluator eval(set);
    for (const auto& [x, n] : std::vector<std::pair<glm::vec3, glm::vec3>>{
             {centre, {0, 1, 0}}, {{0.3f, -0.4f, 0.2f}, {1, 0, 0}}, {{0.95f, 0.0f, 0.0f}, {1, 0, 0}}, {{0, -0.9f, 0}, {0, -1, 0}}}) {
        const ProbeEvaluation e = eval.evaluate(x, n);
        EXPECT_NEAR(e.polygon_to_point.g, expected, 0.05 * expected) << x.x << "," << x.y << "," << x.z;
    }
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

}  // namespace
}  // namespace lf
