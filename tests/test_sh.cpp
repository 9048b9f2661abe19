// SH transfer and environment SH against answers known in closed form, and
// against brute-force ray-traced irradiance (issue 6, "Accuracy and stability").
#include "form_factors.h"
#include "gpu_fixture.h"
#include "scene_builders.h"

#include "atlas/texel_samples.h"
#include "bake/bake_job.h"
#include "bake/sh_transfer_method.h"
#include "io/image_files.h"
#include "bake/sh_transfer_baker.h"
#include "scene/gltf_loader.h"
#include "sh/sh_glb.h"
#include "sh/transfer_file.h"
#include "sh/environment.h"
#include "sh/sh_basis.h"
#include "sh/shading.h"
#include "trace/tracer.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

namespace lf {
namespace {

using test::gpu;
using test::rectangle_form_factor;

const double kSqrtPiOver2 = std::sqrt(M_PI) / 2.0;

ShVertexTransfer bake_transfer(const Scene& scene, int passes, const ShTransferSettings& settings = {},
                               PassStats* stats = nullptr) {
    gpu();
    const Tracer tracer(scene);
    ShTransferBaker baker(scene, tracer, settings);
    PassStats s;
    for (int p = 0; p < passes; ++p) s = baker.step();
    if (stats) *stats = s;
    return baker.snapshot();
}

ShTransferSettings settings(int per_pass = 64, int bounces = 0, float far = 0.0f, std::vector<int> occluders = {},
                            std::vector<int> receivers = {}) {
    ShTransferSettings s;
    s.samples_per_pass = per_pass;
    s.bounces = bounces;
    s.far = far;
    s.occluder_meshes = std::move(occluders);
    s.receiver_meshes = std::move(receivers);
    return s;
}

glm::mat3 rotation_about(glm::vec3 axis, float angle) {
    return glm::mat3(glm::rotate(glm::mat4(1.0f), angle, glm::normalize(axis)));
}

// ---------------------------------------------------------------- basis ----

TEST(ShBasis, IsOrthonormalOnTheSphere) {
    for (int j = 0; j < kShMaxCoefficients; ++j) {
        const Environment env = environment_from_function(
            512, 256, [j](glm::vec3 d) { return glm::vec3(sh_evaluate(d)[j]); }, "y_j");
        const EnvironmentSh sh = project_environment(env);
        for (int i = 0; i < kShMaxCoefficients; ++i)
            EXPECT_NEAR(sh.coefficients[i].r, i == j ? 1.0 : 0.0, 2e-3) << "<y_" << i << ", y_" << j << ">";
    }
}

TEST(ShBasis, UnoccludedTransferHasTheIssuesBandNorms) {
    for (glm::vec3 n : {glm::vec3(0, 1, 0), glm::vec3(1, 0, 0), glm::normalize(glm::vec3(0.3f, -0.5f, 0.8f))}) {
        const ShCoefficients t = unoccluded_transfer(n);
        double band[4] = {};
        for (int i = 0; i < kShMaxCoefficients; ++i) band[sh_band_of(i)] += double(t[i]) * t[i];
        EXPECT_NEAR(t[0], kSqrtPiOver2, 1e-6);
        EXPECT_NEAR(std::sqrt(band[1]), 2.0 * M_PI / 3.0 * std::sqrt(3.0 / (4.0 * M_PI)), 1e-5);
        EXPECT_NEAR(std::sqrt(band[2]), M_PI / 4.0 * std::sqrt(5.0 / (4.0 * M_PI)), 1e-5);
        EXPECT_NEAR(std::sqrt(band[3]), 0.0, 1e-6);
    }
}

// The SH of a rotated environment equals the rotated SH coefficients.
TEST(ShBasis, RotatedEnvironmentHasRotatedCoefficients) {
    const glm::vec3 lobe = glm::normalize(glm::vec3(0.2f, 0.9f, -0.4f));
    auto radiance = [&](glm::vec3 d) {
        return glm::vec3(std::exp(2.0f * (glm::dot(d, lobe) - 1.0f)), 0.5f + 0.5f * d.x * d.z, 1.0f + 0.3f * d.y);
    };
    const glm::mat3 r = rotation_about({1.0f, 2.0f, 3.0f}, 1.1f);
    const EnvironmentSh original = project_environment(environment_from_function(1024, 512, radiance, "f"));
    // f(R^-1 ω): the environment turned by R.
    const EnvironmentSh turned = project_environment(environment_from_function(
        1024, 512, [&](glm::vec3 d) { return radiance(glm::transpose(r) * d); }, "f∘R⁻¹"));
    const EnvironmentSh rotated = rotate(original, r);
    for (int i = 0; i < kShMaxCoefficients; ++i)
        for (int c = 0; c < 3; ++c)
            EXPECT_NEAR(rotated.coefficients[i][c], turned.coefficients[i][c], 2e-3) << "coefficient " << i;
    // Rotation keeps each band's energy.
    for (int l = 0; l < kShMaxBands; ++l) {
        double a = 0, b = 0;
        for (int i = l * l; i < (l + 1) * (l + 1); ++i) {
            a += glm::dot(original.coefficients[i], original.coefficients[i]);
            b += glm::dot(rotated.coefficients[i], rotated.coefficients[i]);
        }
        EXPECT_NEAR(std::sqrt(a), std::sqrt(b), 1e-4 * (1.0 + std::sqrt(a)));
    }
}

TEST(ShBasis, ConstantEnvironmentProjectsToBandZero) {
    const EnvironmentSh sh = project_environment(load_environment("0.5,1,2"));
    EXPECT_NEAR(sh.coefficients[0].g, 2.0 * std::sqrt(M_PI), 1e-5);
    for (int i = 1; i < kShMaxCoefficients; ++i) EXPECT_EQ(sh.coefficients[i], glm::vec3(0.0f));
    // An unoccluded surface under a constant sky of radiance L receives E = pi L.
    EXPECT_NEAR(sh_irradiance(unoccluded_transfer({0, 0, 1}), sh).b, M_PI * 2.0, 1e-4);
    EXPECT_THROW(load_environment("1,2"), std::runtime_error);
    EXPECT_THROW(load_environment("/nonexistent/sky.hdr"), std::runtime_error);
}

// ------------------------------------------------------------- transfer ----

// Every vertex of a convex icosphere is unoccluded: its transfer is the
// clamped-cosine zonal harmonics rotated to its normal, to Monte Carlo noise.
TEST(ShTransfer, UnoccludedVertexIsRotatedClampedCosine) {
    Scene s;
    test::add_icosphere(s, {0.3f, 1.0f, -0.2f}, 0.7f, 1, test::add_material(s, glm::vec3(0.5f)));
    const int passes = 16, per_pass = 64;
    PassStats stats;
    const ShVertexTransfer t = bake_transfer(s, passes, settings(per_pass), &stats);
    ASSERT_EQ(t.coefficients.size(), s.positions.size());
    double worst = 0.0;
    for (size_t v = 0; v < s.positions.size(); ++v) {
        const ShCoefficients expected = unoccluded_transfer(s.normals[v]);
        for (int i = 0; i < kShMaxCoefficients; ++i) {
            // 5 standard errors of the iid estimate (the stratified directions do better).
            const double tolerance = 5.0 * t.standard_error[v][i] + 1e-4;
            EXPECT_NEAR(t.coefficients[v][i], expected[i], tolerance) << "vertex " << v << " coefficient " << i;
            worst = std::max(worst, double(std::abs(t.coefficients[v][i] - expected[i])));
        }
        // T_0 of an unoccluded vertex is exact with cosine-weighted rays: pi y_0 = sqrt(pi)/2 for every ray.
        EXPECT_NEAR(t.coefficients[v][0], kSqrtPiOver2, 1e-5);
    }
    std::printf("  unoccluded: %d samples/vertex, worst coefficient error %.2e, error estimate %.2e\n",
                passes * per_pass, worst, stats.error_estimate.value_or(0.0));
    EXPECT_EQ(stats.rays, uint64_t(passes) * per_pass * s.positions.size());
}

TEST(ShTransfer, FloorUnderParallelRectangleMatchesFormFactor) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    // A 4 x 4 m floor at y = 0 (vertices every 0.5 m), a 1 x 1.5 m rectangle 1 m above it.
    test::add_grid(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, 8, 8, grey);
    const double x0 = -0.5, x1 = 0.5, z0 = -0.25, z1 = 1.25, h = 1.0;
    test::add_quad(s, {float(x0), float(h), float(z0)}, {0, 0, float(z1 - z0)}, {float(x1 - x0), 0, 0}, grey);
    const int passes = 32, per_pass = 64, n = passes * per_pass;
    const ShVertexTransfer t = bake_transfer(s, passes, settings(per_pass));
    int checked = 0;
    for (size_t v = 0; v < 81; ++v) {
        const glm::vec3 p = s.positions[v];
        ASSERT_NEAR(p.y, 0.0f, 0.0f);
        const double f = rectangle_form_factor(p.x, p.z, x0, x1, z0, z1, h);
        const double expected = kSqrtPiOver2 * (1.0 - f);
        // Each ray is blocked with probability F: binomial noise, 4 sigma.
        const double sigma = kSqrtPiOver2 * std::sqrt(f * (1.0 - f) / n);
        EXPECT_NEAR(t.coefficients[v][0], expected, 4.0 * sigma + 2e-3)
            << "floor vertex at " << p.x << ", " << p.z << " (F = " << f << ")";
        ++checked;
    }
    EXPECT_EQ(checked, 81);
}

// The same rectangle see-through (issue #35): a ray through it is blocked
// by the share of it that stops light, so the vertex's DC transfer is
// sqrt(pi)/2 (1 - F (1 - k)), k the mean of its transmittance over the
// channels (the transfer is one channel). Without bounces the shadow ray
// takes the transmittance itself; with one, the ray's drawn choice
// (trace_closest), the sheet being black: no bounce light. Binomial noise
// of a blocked share q = F (1 - k) bounds both, 4 sigma.
TEST(ShTransfer, ASeeThroughRectangleBlocksWhatItStops) {
    struct Case {
        const char* name;
        Material::AlphaMode mode;
        float alpha, transmission;
        glm::vec3 color;
        double k;
        int bounces;
    };
    for (const Case& c :
         {Case{"blended", Material::AlphaMode::Blend, 0.4f, 0.0f, glm::vec3(0.0f), 0.6, 0},
          Case{"tinted glass", Material::AlphaMode::Opaque, 1.0f, 1.0f, glm::vec3(1.0f, 0.5f, 0.25f), 1.75 / 3.0, 0},
          Case{"cut out", Material::AlphaMode::Mask, 0.0f, 0.0f, glm::vec3(0.0f), 1.0, 0},
          Case{"blended, one bounce", Material::AlphaMode::Blend, 0.4f, 0.0f, glm::vec3(0.0f), 0.6, 1}}) {
        SCOPED_TRACE(c.name);
        Scene s;
        const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
        const uint32_t sheet = test::add_material(s, c.color);
        s.materials[sheet].alpha_mode = c.mode;
        s.materials[sheet].base_color.a = c.alpha;
        s.materials[sheet].transmission = c.transmission;
        test::add_grid(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, 8, 8, grey);
        const double x0 = -0.5, x1 = 0.5, z0 = -0.25, z1 = 1.25, h = 1.0;
        test::add_quad(s, {float(x0), float(h), float(z0)}, {0, 0, float(z1 - z0)}, {float(x1 - x0), 0, 0}, sheet);
        const int passes = 32, per_pass = 64, n = passes * per_pass;
        const ShVertexTransfer t = bake_transfer(s, passes, settings(per_pass, c.bounces));
        for (size_t v = 0; v < 81; ++v) {
            const glm::vec3 p = s.positions[v];
            const double q = rectangle_form_factor(p.x, p.z, x0, x1, z0, z1, h) * (1.0 - c.k);
            const double sigma = kSqrtPiOver2 * std::sqrt(q * (1.0 - q) / n);
            EXPECT_NEAR(t.coefficients[v][0], kSqrtPiOver2 * (1.0 - q), 4.0 * sigma + 2e-3)
                << "floor vertex at " << p.x << ", " << p.z;
        }
    }
}

// The seed's Figure 3.1: adjacent triangles of a flat surface must not
// shadow its vertices ("blackout"), far from the origin and tilted too.
TEST(ShTransfer, FinelyTessellatedPlaneDoesNotShadowItself) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    test::add_grid(s, {1000.0f, 3.7f, -2000.0f}, {0, 0, 10}, {10, 0, 0}, 120, 120, grey);
    const glm::vec3 u = glm::normalize(glm::vec3(1.0f, 0.35f, 0.1f)),
                    w = glm::normalize(glm::cross(u, {0.2f, 0.1f, 1.0f}));
    test::add_grid(s, {-3.0f, 7.0f, 5.0f}, 6.0f * glm::normalize(glm::cross(w, u)), 6.0f * u, 120, 120, grey);
    const int passes = 4, per_pass = 64, n = passes * per_pass;
    const ShVertexTransfer t = bake_transfer(s, passes, settings(per_pass));
    double lowest = 1e9, mean = 0.0;
    for (const ShCoefficients& c : t.coefficients) {
        lowest = std::min(lowest, double(c[0]));
        mean += c[0];
    }
    mean /= double(t.coefficients.size());
    std::printf("  plane: %zu vertices, lowest T_0 %.6f, mean %.6f (unoccluded %.6f)\n", t.coefficients.size(), lowest,
                mean, kSqrtPiOver2);
    // One blocked ray would lower T_0 by sqrt(pi)/2 / n.
    EXPECT_GE(lowest, kSqrtPiOver2 * (1.0 - 1.5 / n));
    EXPECT_NEAR(mean, kSqrtPiOver2, 1e-5);
}

// The seed's Figure 3.2: a far clip plane lets a vertex deep in a tunnel see
// past walls that are far away. Without one, a closed tunnel is dark.
TEST(ShTransfer, FarEndOfLongTunnelStillOccludes) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    const glm::vec3 along(0, 0, 100);
    test::add_grid(s, {-0.5f, 0, 0}, along, {1, 0, 0}, 100, 2, grey);  // floor, facing up
    test::add_grid(s, {-0.5f, 1, 0}, {1, 0, 0}, along, 2, 100, grey);  // ceiling, facing down
    test::add_grid(s, {-0.5f, 0, 0}, {0, 1, 0}, along, 1, 100, grey);  // walls
    test::add_grid(s, {0.5f, 0, 0}, along, {0, 1, 0}, 100, 1, grey);
    test::add_grid(s, {-0.5f, 0, 0}, {1, 0, 0}, {0, 1, 0}, 2, 1, grey);  // end caps
    test::add_grid(s, {-0.5f, 0, 100}, {0, 1, 0}, {1, 0, 0}, 1, 2, grey);
    size_t middle = s.positions.size();
    for (size_t v = 0; v < s.positions.size(); ++v)
        if (s.positions[v] == glm::vec3(0, 0, 50)) middle = v;
    ASSERT_LT(middle, s.positions.size());
    ASSERT_GT(s.normals[middle].y, 0.99f);

    const ShVertexTransfer closed = bake_transfer(s, 16, settings(64));
    EXPECT_LT(std::abs(closed.coefficients[middle][0]), 1e-6) << "rays escaped a closed tunnel";
    // With the seed's far plane at 2 m, the tunnel's far parts stop occluding.
    const ShVertexTransfer clipped = bake_transfer(s, 16, settings(64, 0, 2.0f));
    EXPECT_GT(clipped.coefficients[middle][0], 0.01);
    std::printf("  tunnel: T_0 = %.2e closed, %.3f with a 2 m far plane\n", closed.coefficients[middle][0],
                clipped.coefficients[middle][0]);
}

TEST(ShTransfer, ReceiverAndOccluderSets) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    test::add_grid(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, 4, 4, grey);  // mesh 0: floor
    test::add_quad(s, {-1, 1, -1}, {0, 0, 2}, {2, 0, 0}, grey);        // mesh 1: roof
    const size_t centre = 12;                                          // floor vertex (0, 0, 0)
    ASSERT_EQ(s.positions[centre], glm::vec3(0.0f));
    const ShVertexTransfer all = bake_transfer(s, 4);
    EXPECT_LT(all.coefficients[centre][0], 0.7 * kSqrtPiOver2);
    // The roof casts no shadow when only the floor occludes.
    const ShVertexTransfer floor_only = bake_transfer(s, 4, settings(64, 0, 0.0f, {0}));
    EXPECT_NEAR(floor_only.coefficients[centre][0], kSqrtPiOver2, 1e-5);
    // Only the roof receives: the floor is not traced and keeps unoccluded transfer.
    const ShVertexTransfer roof_receives = bake_transfer(s, 4, settings(64, 0, 0.0f, {}, {1}));
    EXPECT_FALSE(roof_receives.traced[centre]);
    EXPECT_NEAR(roof_receives.coefficients[centre][0], kSqrtPiOver2, 1e-6);
    EXPECT_TRUE(roof_receives.traced[s.positions.size() - 1]);
}

// Interreflection: a floor under a white roof receives, beyond its shadowed
// transfer, light reflected by the roof's underside. That underside faces
// down and is lit only by the floor, so with bounces the floor gains.
TEST(ShTransfer, BouncesAddLightFromSurfacesTheRaysHit) {
    Scene s;
    const uint32_t white = test::add_material(s, glm::vec3(0.8f));
    test::add_grid(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, 4, 4, white);
    test::add_grid(s, {-2, 1, -2}, {4, 0, 0}, {0, 0, 4}, 4, 4, white);  // roof facing down
    const size_t centre = 12;
    const ShVertexTransfer shadowed = bake_transfer(s, 16);
    const ShVertexTransfer bounced = bake_transfer(s, 16, settings(64, 2));
    // Under a uniform sky of radiance 1 the floor centre's irradiance grows.
    EXPECT_GT(bounced.coefficients[centre][0], shadowed.coefficients[centre][0] * 1.05);
    // …and never beyond what an albedo-0.8 enclosure could give: a geometric series bound.
    EXPECT_LT(bounced.coefficients[centre][0], kSqrtPiOver2);
    std::printf("  bounces: floor centre T_0 %.4f shadowed, %.4f with 2 bounces\n", shadowed.coefficients[centre][0],
                bounced.coefficients[centre][0]);
}

// Interreflection against a closed form: a tiny upward patch under a
// downward-facing rectangle of albedo rho, nothing else. The rectangle's
// underside sees an open sky below (the patch is negligible), so its shadowed
// transfer is exactly unoccluded, T_0 = sqrt(pi)/2; a ray from the patch that
// hits it brings back rho·sqrt(pi)/2 instead of sqrt(pi)/2, and the second
// bounce brings back (nearly) nothing: the rectangle sees only the patch.
//   T_0 = sqrt(pi)/2 · (1 − F) + rho · sqrt(pi)/2 · F = sqrt(pi)/2 · (1 − (1 − rho) F)
// with F the point-to-rectangle form factor.
TEST(ShTransfer, BounceOffAnOpenRectangleMatchesClosedForm) {
    Scene s;
    const float rho = 0.6f;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    const uint32_t wall = test::add_material(s, glm::vec3(rho));
    test::add_quad(s, {-0.005f, 0, 0.005f}, {0.01f, 0, 0}, {0, 0, -0.01f}, grey);  // patch, facing up
    const double x0 = -0.5, x1 = 0.5, z0 = -0.25, z1 = 1.25, h = 1.0;
    test::add_quad(s, {float(x0), float(h), float(z0)}, {float(x1 - x0), 0, 0}, {0, 0, float(z1 - z0)},
                   wall);  // facing down
    ASSERT_LT(s.normals[4].y, -0.99f);
    const int passes = 32, per_pass = 64;
    const ShVertexTransfer shadowed = bake_transfer(s, passes, settings(per_pass));
    const ShVertexTransfer bounced = bake_transfer(s, passes, settings(per_pass, 2));
    for (size_t v = 0; v < 4; ++v) {
        const glm::vec3 p = s.positions[v];
        const double f = rectangle_form_factor(p.x, p.z, x0, x1, z0, z1, h);
        ASSERT_GT(f, 0.1);
        // Bounce 1 starts a pass late: (passes − 1) · per_pass of its rays.
        const double n = double(passes - 1) * per_pass;
        const double sigma = kSqrtPiOver2 * std::sqrt(f * (1.0 - f) / n);
        EXPECT_NEAR(shadowed.coefficients[v][0], kSqrtPiOver2 * (1.0 - f), 4.0 * sigma + 2e-3) << "vertex " << v;
        EXPECT_NEAR(bounced.coefficients[v][0], kSqrtPiOver2 * (1.0 - (1.0 - rho) * f),
                    4.0 * (1.0 + rho) * sigma + 2e-3)
            << "vertex " << v << " (F = " << f << ")";
        if (v == 0)
            std::printf(
                "  open rectangle: F = %.4f, T_0 %.4f shadowed (exact %.4f), %.4f with 2 bounces (exact %.4f)\n", f,
                shadowed.coefficients[v][0], kSqrtPiOver2 * (1.0 - f), bounced.coefficients[v][0],
                kSqrtPiOver2 * (1.0 - (1.0 - rho) * f));
    }
    // The rectangle's own vertices: an open sky below, so unoccluded (exact for T_0).
    for (size_t v = 4; v < 8; ++v) EXPECT_NEAR(bounced.coefficients[v][0], kSqrtPiOver2, 1e-3);
}

// ------------------------------------------------------------ per texel ----

struct TexelBake {
    TexelSamples texels;
    ShTexelReceivers receivers;
    ShVertexTransfer transfer;
    FloatImage image;
};

TexelBake bake_texels(const Scene& s, int width, int height, int passes, const ShTransferSettings& st) {
    TexelBake b;
    b.texels = rasterize_texel_samples(s, width, height, 1);
    b.receivers = sh_texel_receivers(s, b.texels, st.receiver_meshes);
    gpu();
    const Tracer tracer(s);
    ShTransferBaker baker(s, tracer, st, b.receivers.points);
    for (int p = 0; p < passes; ++p) baker.step();
    b.transfer = baker.snapshot();
    b.image = sh_texel_image(b.texels, b.receivers, b.transfer.point_coefficients, kShMaxBands);
    return b;
}

// An unoccluded plane's texels (open sky: with bounces too, since no ray
// hits anything) have the unoccluded transfer; the chart is dilated by its
// border ring and nothing beyond.
TEST(ShPerTexel, UnoccludedPlaneTexelsAreUnoccluded) {
    Scene s;
    // 2 x 2 m, facing up, in the middle half of a 16 x 16 atlas: texels 4 .. 11.
    // (Away from the cube [-1, 1]³: with two triangles the BVH root is one leaf
    // and its "empty" second child, lo = (1,1,1) > hi = (-1,-1,-1), is entered
    // by rays that cross that cube, since the slab test swaps lo and hi; it
    // points back at the root and traversal loops (gi/trace/bvh.cpp, reported).)
    test::add_quad(s, {2, 3.7f, 1}, {2, 0, 0}, {0, 0, -2}, test::add_material(s, glm::vec3(0.5f)),
                   glm::vec4(0.25f, 0.25f, 0.75f, 0.75f));
    ASSERT_GT(s.normals[0].y, 0.99f);
    for (int bounces : {0, 2}) {
        const TexelBake b = bake_texels(s, 16, 16, 4, settings(64, bounces));
        ASSERT_EQ(b.texels.covered_count(), 64u);
        ASSERT_EQ(b.transfer.point_coefficients.size(), b.texels.samples.size());
        EXPECT_EQ(b.transfer.coefficients.size(), s.positions.size());
        const ShCoefficients expected = unoccluded_transfer({0, 1, 0});
        for (size_t k = 0; k < b.transfer.point_coefficients.size(); ++k)
            for (int i = 0; i < kShMaxCoefficients; ++i)
                EXPECT_NEAR(b.transfer.point_coefficients[k][i], expected[i],
                            5.0 * b.transfer.point_standard_error[k][i] + 1e-4)
                    << "point " << k << " coefficient " << i << " bounces " << bounces;
        const std::vector<float>& t0 = b.image.at("sh.0");
        const std::vector<float>& coverage = b.image.at("coverage");
        for (uint32_t pixel : b.texels.texels) {
            EXPECT_NEAR(t0[pixel], kSqrtPiOver2, 1e-5) << "texel " << pixel << " bounces " << bounces;
            EXPECT_EQ(coverage[pixel], 1.0f);
        }
        // Dilated: the ring just outside the chart copies it; far corners stay empty.
        EXPECT_NEAR(t0[8 * 16 + 3], kSqrtPiOver2, 1e-5);
        EXPECT_EQ(coverage[8 * 16 + 3], 0.0f);
        EXPECT_EQ(t0[0], 0.0f);
    }
}

// The vertex test's floor under a parallel rectangle, per texel: each texel
// is the mean of its sample points' sqrt(pi)/2 · (1 − F).
TEST(ShPerTexel, FloorUnderParallelRectangleMatchesFormFactor) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    // 4 x 4 m floor in the left half of a 32 x 16 atlas (0.25 m texels), the
    // 1 x 1.5 m rectangle 1 m above it in the right half.
    test::add_quad(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, grey, glm::vec4(0.0f, 0.0f, 0.5f, 1.0f));
    const double x0 = -0.5, x1 = 0.5, z0 = -0.25, z1 = 1.25, h = 1.0;
    test::add_quad(s, {float(x0), float(h), float(z0)}, {0, 0, float(z1 - z0)}, {float(x1 - x0), 0, 0}, grey,
                   glm::vec4(0.5f, 0.0f, 1.0f, 1.0f));
    const int passes = 16, per_pass = 64, n = passes * per_pass;
    const TexelBake b = bake_texels(s, 32, 16, passes, settings(per_pass));
    const std::vector<float>& t0 = b.image.at("sh.0");
    int checked = 0, shadowed = 0;
    double worst_sigmas = 0.0;
    for (size_t i = 0; i < b.texels.covered_count(); ++i) {
        double expected = 0.0, f_mean = 0.0;
        bool floor = true;
        const uint32_t first = b.texels.first_sample[i], count = b.texels.sample_count(i);
        for (uint32_t k = first; k < first + count; ++k) {
            const TexelSample& sample = b.texels.samples[k];
            floor = floor && sample.triangle < 2;
            const double f = rectangle_form_factor(sample.position.x, sample.position.z, x0, x1, z0, z1, h);
            expected += kSqrtPiOver2 * (1.0 - f) / count;
            f_mean += f / count;
        }
        if (!floor) continue;
        const double sigma = kSqrtPiOver2 * std::sqrt(f_mean * (1.0 - f_mean) / n);
        EXPECT_NEAR(t0[b.texels.texels[i]], expected, 4.0 * sigma + 2e-3)
            << "floor texel " << b.texels.texels[i] << " (F = " << f_mean << ")";
        ++checked;
        shadowed += f_mean > 0.1;
        if (sigma > 0.0) worst_sigmas = std::max(worst_sigmas, std::abs(t0[b.texels.texels[i]] - expected) / sigma);
    }
    std::printf("  per texel: %d floor texels (%d with F > 0.1), %zu sample points, worst error %.2f sigma\n", checked,
                shadowed, b.texels.samples.size(), worst_sigmas);
    EXPECT_EQ(checked, 256);
    EXPECT_GT(shadowed, 20);
}

// -------------------------------------------------------------- shading ----

double relative_rms(const std::vector<glm::vec3>& a, const std::vector<glm::vec3>& reference) {
    double d = 0, r = 0;
    for (size_t i = 0; i < a.size(); ++i) {
        d += glm::dot(a[i] - reference[i], a[i] - reference[i]);
        r += glm::dot(reference[i], reference[i]);
    }
    return std::sqrt(d / r);
}

TEST(ShShading, SmoothEnvironmentErrorFallsWithBands) {
    Scene s;
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    test::add_grid(s, {-2, 0, 2}, {4, 0, 0}, {0, 0, -4}, 8, 8, grey);
    test::add_box(s, {-0.5f, 0.0f, -0.5f}, {0.5f, 1.0f, 0.5f}, grey);
    test::add_icosphere(s, {1.2f, 0.5f, 1.0f}, 0.4f, 1, grey);
    const glm::vec3 sun = glm::normalize(glm::vec3(0.5f, 1.0f, 0.3f));
    const Environment env = environment_from_function(
        256, 128,
        [&](glm::vec3 d) {
            return glm::vec3(0.3f, 0.4f, 0.6f) +
                   glm::vec3(2.0f, 1.6f, 1.2f) * std::exp(3.0f * (glm::dot(d, sun) - 1.0f));
        },
        "smooth sky");
    gpu();
    const Tracer tracer(s);
    ShTransferBaker baker(s, tracer, settings(128));
    for (int p = 0; p < 16; ++p) baker.step();
    const ShVertexTransfer t = baker.snapshot();
    const std::vector<glm::vec3> reference = reference_irradiance(s, tracer, env, 8192);
    const EnvironmentSh sh = project_environment(env);
    double error[5] = {};
    for (int bands = 1; bands <= 4; ++bands) {
        std::vector<glm::vec3> shaded;
        for (const ShCoefficients& c : t.coefficients) shaded.push_back(sh_irradiance(c, sh, bands));
        error[bands] = relative_rms(shaded, reference);
    }
    std::printf("  smooth sky, relative RMS error vs ray-traced: 1 band %.4f, 2 %.4f, 3 %.4f, 4 %.4f\n", error[1],
                error[2], error[3], error[4]);
    EXPECT_GT(error[1], error[2]);
    EXPECT_GT(error[2], error[4]);
    EXPECT_LT(error[4], 0.05);
    // Auto band choice: a loose target needs fewer bands than a tight one.
    EXPECT_LE(choose_band_count(t.coefficients, sh, 0.2), choose_band_count(t.coefficients, sh, 0.001));
}

// A small bright light: 4-band shading rings (negative irradiance facing
// away, overshoot facing it); windowing trades ringing for blur.
TEST(ShShading, SmallBrightEnvironmentRingingWithAndWithoutWindowing) {
    Scene s;
    test::add_icosphere(s, {0, 0, 0}, 1.0f, 2, test::add_material(s, glm::vec3(0.5f)));
    const glm::vec3 sun = glm::normalize(glm::vec3(-0.3f, 0.8f, 0.5f));
    const float cos_radius = std::cos(glm::radians(5.0f));
    const Environment env = environment_from_function(
        1024, 512, [&](glm::vec3 d) { return glm::vec3(glm::dot(d, sun) > cos_radius ? 500.0f : 0.05f); }, "small sun");
    const ShVertexTransfer t = bake_transfer(s, 16, settings(64));
    // Brute force for a convex shape: nothing occludes, so E = Σ_texels L max(0, n·d) dΩ.
    std::vector<glm::vec3> reference(s.positions.size(), glm::vec3(0.0f));
    for (int y = 0; y < env.height; ++y) {
        const double d_omega =
            2.0 * M_PI / env.width * (std::cos(M_PI * y / env.height) - std::cos(M_PI * (y + 1) / env.height));
        for (int x = 0; x < env.width; ++x) {
            const glm::vec3 d = equirect_direction((x + 0.5f) / env.width, (y + 0.5f) / env.height);
            const glm::vec3 l = env.texels[size_t(y) * env.width + x];
            for (size_t v = 0; v < s.positions.size(); ++v)
                reference[v] += l * float(std::max(0.0f, glm::dot(s.normals[v], d)) * d_omega);
        }
    }
    double peak = 0.0;
    for (const glm::vec3& e : reference) peak = std::max(peak, double(e.r));
    double lowest_unwindowed = 0.0, lowest_hanning = 0.0;
    for (ShWindow window : {ShWindow::None, ShWindow::Hanning, ShWindow::Lanczos}) {
        const EnvironmentSh sh = project_environment(env, window);
        double lowest = 1e30, highest = -1e30, worst = 0.0;
        int negative = 0;
        std::vector<glm::vec3> shaded;
        for (size_t v = 0; v < s.positions.size(); ++v) {
            const glm::vec3 e = sh_irradiance(t.coefficients[v], sh);
            shaded.push_back(e);
            lowest = std::min(lowest, double(e.r));
            highest = std::max(highest, double(e.r));
            worst = std::max(worst, double(std::abs(e.r - reference[v].r)));
            negative += e.r < 0.0f;
        }
        std::printf(
            "  small sun, window %-7s: %3d of %zu vertices negative, lowest %+.3f of peak, overshoot %+.3f, "
            "max error %.3f of peak, relative RMS %.3f\n",
            to_string(window), negative, s.positions.size(), lowest / peak, highest / peak - 1.0, worst / peak,
            relative_rms(shaded, reference));
        if (window == ShWindow::None) {
            lowest_unwindowed = lowest;
            EXPECT_LT(worst / peak, 0.15);  // 3 bands of the clamped cosine: Ramamoorthi & Hanrahan's ~10%
        }
        if (window == ShWindow::Hanning) lowest_hanning = lowest;
    }
    EXPECT_LT(lowest_unwindowed, 0.0) << "a 4-band small light should ring below zero";
    EXPECT_GT(lowest_hanning, lowest_unwindowed) << "windowing should reduce the ringing";
}

// ---------------------------------------------------------------- files ----

TEST(ShFiles, TransferFileRoundTripsAndHalfFloatsStayClose) {
    ShTransferFile file;
    file.bands = 3;
    file.bounces = 2;
    for (int p = 0; p < 3; ++p) {
        ShTransferFile::Primitive prim{p, 10 + p, p % 2, {}};
        for (int v = 0; v < 5 + p; ++v) {
            ShCoefficients c = unoccluded_transfer(glm::normalize(glm::vec3(float(v) - 2.0f, 1.0f, float(p))));
            std::fill(c.begin() + 9, c.end(), 0.0f);
            c[4] += 1e-6f * float(v);  // something half floats cannot hold exactly
            prim.vertices.push_back(c);
        }
        file.primitives.push_back(prim);
    }
    const std::string bytes = encode_sh_transfer(file, ShEncoding::Float32);
    EXPECT_EQ(bytes.size(), 32u + 3 * 16 + (5 + 6 + 7) * 9 * 4);
    const ShTransferFile back = decode_sh_transfer(bytes, "test");
    EXPECT_EQ(back.bands, 3);
    EXPECT_EQ(back.bounces, 2);
    ASSERT_EQ(back.primitives.size(), 3u);
    for (size_t p = 0; p < 3; ++p) {
        EXPECT_EQ(back.primitives[p].node, file.primitives[p].node);
        EXPECT_EQ(back.primitives[p].mesh, file.primitives[p].mesh);
        EXPECT_EQ(back.primitives[p].primitive, file.primitives[p].primitive);
        EXPECT_EQ(back.primitives[p].vertices, file.primitives[p].vertices);
    }
    const std::string half = encode_sh_transfer(file, ShEncoding::Float16);
    EXPECT_EQ(half.size(), 32u + 3 * 16 + (5 + 6 + 7) * 9 * 2);
    const ShTransferFile compact = decode_sh_transfer(half, "test");
    for (size_t p = 0; p < 3; ++p)
        for (size_t v = 0; v < file.primitives[p].vertices.size(); ++v)
            for (int i = 0; i < 9; ++i)  // half: 11 significant bits
                EXPECT_NEAR(compact.primitives[p].vertices[v][i], file.primitives[p].vertices[v][i],
                            std::abs(file.primitives[p].vertices[v][i]) / 1024.0 + 1e-7);
    // Damage is reported, not read.
    EXPECT_THROW(decode_sh_transfer(bytes.substr(0, bytes.size() - 1), "cut"), std::runtime_error);
    std::string wrong = bytes;
    wrong[0] = 'X';
    EXPECT_THROW(decode_sh_transfer(wrong, "magic"), std::runtime_error);
    EXPECT_EQ(half_to_float(float_to_half(1.0f)), 1.0f);
    EXPECT_EQ(half_to_float(float_to_half(-0.000061035156f)), -0.000061035156f);  // smallest normal
    EXPECT_EQ(half_to_float(float_to_half(5.9604645e-8f)), 5.9604645e-8f);        // smallest subnormal
}

// The whole bake on a real file: every output written, scene.sh.glb reloads
// with the same positions and carries the transfer of sh_transfer.bin, and
// sh-shade turns it into vertex colours.
TEST(ShBake, WritesFilesThatReloadAndShade) {
    const std::filesystem::path out =
        std::filesystem::temp_directory_path() / ("lightfarm_sh_" + std::to_string(::getpid()));
    std::filesystem::remove_all(out);
    gpu();
    BakeJob job;
    job.scene = test::example_scene("monkey.glb");
    job.out = out;
    job.settings = protocol::parse_bake_settings(
        {{"outputs", {{"sh", {{"sh_bands", "auto"}, {"sh_passes", 3}}}}}, {"env", {0.2, 0.4, 1.0}}});
    std::vector<std::string> events;
    const protocol::DoneEvent done = run_bake_job(job, [&](const protocol::WorkerEvent& e) {
        const nlohmann::json j = protocol::to_json(e);  // a line said again while it ran long: "… again"
        events.push_back(j["event"].get<std::string>() + (j.value("again", false) ? " again" : ""));
    });
    // The stages of preparation first, then the start event, once.
    const auto start = std::find(events.begin(), events.end(), "start");
    ASSERT_NE(start, events.end());
    EXPECT_TRUE(std::all_of(events.begin(), start, [](const std::string& e) { return e.rfind("prepare", 0) == 0; }));
    EXPECT_GT(start - events.begin(), 0) << "preparation's stages are said";
    EXPECT_EQ(std::count(events.begin(), events.end(), "start"), 1);
    EXPECT_EQ(events.back(), "done");
    EXPECT_EQ(std::count(events.begin(), events.end(), "progress"), 3);
    EXPECT_EQ(std::count(events.begin(), events.end(), "snapshot"), 2);  // passes 1 and 2
    EXPECT_EQ(done.final_files.at("sh"), "sh_transfer.bin");
    for (const char* f : {"scene.sh.glb", "sh_transfer.bin", "sh_transfer.half.bin", "env_sh.json", "manifest.json",
                          "sh_transfer.pass-0001.bin"})
        EXPECT_TRUE(std::filesystem::exists(out / f)) << f;
    std::ifstream manifest_in(out / "manifest.json");
    const int bands = nlohmann::json::parse(manifest_in)["sh"]["bands"];
    EXPECT_GE(bands, 1);
    EXPECT_LE(bands, 4);

    const Scene original = load_scene(job.scene);
    const Scene reloaded = load_scene(out / "scene.sh.glb");
    ASSERT_EQ(reloaded.positions.size(), original.positions.size());
    for (size_t v = 0; v < original.positions.size(); ++v) ASSERT_EQ(reloaded.positions[v], original.positions[v]);
    const std::vector<ShCoefficients> from_glb = read_sh_glb_transfer(out / "scene.sh.glb", reloaded);
    const ShTransferFile from_bin = read_sh_transfer(out / "sh_transfer.bin");
    EXPECT_EQ(from_bin.bands, bands);
    ASSERT_EQ(from_bin.primitives.size(), reloaded.instances.size());
    for (size_t i = 0; i < reloaded.instances.size(); ++i) {
        const PrimitiveInstance& inst = reloaded.instances[i];
        ASSERT_EQ(from_bin.primitives[i].vertices.size(), inst.vertex_count);
        for (uint32_t v = 0; v < inst.vertex_count; ++v)
            ASSERT_EQ(from_bin.primitives[i].vertices[v], from_glb[inst.first_vertex + v]);
    }

    const nlohmann::json shaded =
        shade_sh_glb(out / "scene.sh.glb", (out / "env_sh.json").string(), out / "shaded.glb");
    EXPECT_GT(shaded["max_e_over_pi"].get<double>(), 0.0);
    const Scene shaded_scene = load_scene(out / "shaded.glb");
    EXPECT_EQ(shaded_scene.positions, original.positions);
    ShShadeOptions from_bin_options;
    from_bin_options.scene = job.scene;
    const nlohmann::json shaded_bin =
        shade_sh_glb(out / "sh_transfer.bin", "1,1,1", out / "shaded_bin.glb", from_bin_options);
    // Under a white sky E/pi is the unoccluded fraction: at most 1.
    EXPECT_LE(shaded_bin["max_e_over_pi"].get<double>(), 1.0 + 1e-3);
    std::filesystem::remove_all(out);
}

// The whole bake with --sh-per-texel: sh_transfer.exr with the documented
// channels and the atlas's size, its snapshots, the manifest and done event.
// (In the ShBake suite, after every test that uses the shared GL context:
// bake_sh makes its own context, and the shared one is not current after it.)
TEST(ShBake, PerTexelWritesTheTransferExr) {
    const std::filesystem::path out =
        std::filesystem::temp_directory_path() / ("lightfarm_sh_texel_" + std::to_string(::getpid()));
    std::filesystem::remove_all(out);
    gpu();
    BakeJob job;
    job.scene = test::example_scene("monkey.glb");
    job.out = out;
    job.settings = protocol::parse_bake_settings(
        {{"outputs", {{"sh", {{"sh_bands", 2}, {"sh_per_texel", true}, {"sh_passes", 2}}}}},
         {"atlas", {{"res", 128}, {"subsamples", 1}}}});
    const protocol::DoneEvent done = run_bake_job(job, [](const protocol::WorkerEvent&) {});
    const std::vector<std::string>& files = done.files;
    // The first pass's snapshot is always taken; the second's only if the
    // writer has finished the first by then (SnapshotSchedule), which a
    // loaded machine may not have: not asked for.
    for (const char* f : {"sh_transfer.exr", "sh_transfer.pass-0001.exr", "sh_transfer.bin"})
        EXPECT_NE(std::find(files.begin(), files.end(), f), files.end()) << f;
    const FloatImage image = read_exr(out / "sh_transfer.exr");
    EXPECT_EQ(image.width, 128);
    EXPECT_EQ(image.height, 128);
    std::vector<std::string> channels;
    for (const auto& [name, values] : image.channels) channels.push_back(name);
    EXPECT_EQ(channels, (std::vector<std::string>{"coverage", "sh.0", "sh.1", "sh.2", "sh.3"}));
    const std::vector<float>& coverage = image.at("coverage");
    const std::vector<float>& t0 = image.at("sh.0");
    size_t covered = 0;
    for (size_t p = 0; p < coverage.size(); ++p)
        if (coverage[p] == 1.0f) {
            ++covered;
            EXPECT_GE(t0[p], 0.0f);
            EXPECT_LE(t0[p], kSqrtPiOver2 + 1e-3);
        }
    EXPECT_GT(covered, 50u);
    std::ifstream in(out / "manifest.json");
    const nlohmann::json manifest = nlohmann::json::parse(in);
    EXPECT_EQ(manifest["sh"]["per_texel"]["file"], "sh_transfer.exr");
    EXPECT_EQ(manifest["sh"]["per_texel"]["covered_texels"], covered);
    EXPECT_EQ(manifest["sh"]["per_texel"]["channels"].size(), 5u);
    EXPECT_TRUE(manifest["files"].contains("sh_transfer.exr"));
    if (manifest["sh"]["per_texel"]["atlas"]["generated"].get<bool>()) {
        EXPECT_TRUE(std::filesystem::exists(out / "scene.lightmapped.glb"));
    }
    std::filesystem::remove_all(out);
}

// Speed on whatever device runs the tests (not part of the suite):
//   LIGHTFARM_SH_BENCH="monkey.glb:4:64,real/breakfast_room/breakfast_room.gltf:1:32"
//     test_sh --gtest_also_run_disabled_tests --gtest_filter=ShBench.*
// Each entry is scene:passes:samples_per_pass.
TEST(ShBench, DISABLED_VerticesAndRaysPerSecond) {
    const char* spec = std::getenv("LIGHTFARM_SH_BENCH");
    std::string list = spec ? spec : "monkey.glb:4:64";
    gpu();
    std::printf("  device: %s\n", gpu().info().renderer.c_str());
    size_t at = 0;
    while (at < list.size()) {
        size_t end = list.find(',', at);
        if (end == std::string::npos) end = list.size();
        const std::string entry = list.substr(at, end - at);
        at = end + 1;
        const size_t c1 = entry.find(':'), c2 = entry.rfind(':');
        const std::string name = entry.substr(0, c1);
        const int passes = std::stoi(entry.substr(c1 + 1, c2 - c1 - 1)), per_pass = std::stoi(entry.substr(c2 + 1));
        const auto t0 = std::chrono::steady_clock::now();
        const Scene scene = load_scene(test::example_scene(name));
        const auto t1 = std::chrono::steady_clock::now();
        const Tracer tracer(scene);
        ShTransferBaker baker(scene, tracer, settings(per_pass));
        const auto t2 = std::chrono::steady_clock::now();
        PassStats stats;
        for (int p = 0; p < passes; ++p) stats = baker.step();
        const ShVertexTransfer t = baker.snapshot();
        const auto t3 = std::chrono::steady_clock::now();
        auto sec = [](auto a, auto b) { return std::chrono::duration<double>(b - a).count(); };
        std::printf(
            "  %s: %zu triangles, %zu vertices (%zu unique); load %.2f s, BVH+setup %.2f s; %d x %d samples: "
            "%.2f s tracing: %.3g vertices/s at %d samples, %.3g rays/s; "
            "error estimate %.3g; snapshot %.2f s\n",
            name.c_str(), scene.triangle_count(), scene.positions.size(), baker.unique_vertices(), sec(t0, t1),
            sec(t1, t2), passes, per_pass, stats.seconds, double(baker.unique_vertices()) / stats.seconds,
            passes * per_pass, double(stats.rays) / stats.seconds, stats.error_estimate.value_or(0.0),
            sec(t2, t3) - stats.seconds);
        EXPECT_EQ(t.coefficients.size(), scene.positions.size());
    }
}

}  // namespace
}  // namespace lf
