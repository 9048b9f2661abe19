// The lightmap atlas: generated charts, texel samples, dilation, seams and the
// lightmapped glb. Scenes are built in code where a number must be known; the
// shared scenes measure the atlas against the thesis's triangle-pair baseline.
#include "atlas/atlas.h"
#include "atlas/lightmapped_gltf.h"
#include "atlas/seams.h"
#include "atlas/texel_samples.h"
#include "display_tone.h"
#include "util/parallel.h"
#include "scene/gltf_loader.h"
#include "scene_builders.h"
#include "thread_count.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <stb/stb_image.h>
#include <tiny_gltf.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <thread>
#include <unistd.h>

namespace lf {
namespace {

namespace fs = std::filesystem;
const fs::path kScenes = LIGHTFARM_EXAMPLES;

// A scene with flat, curved, thin and tiny parts.
Scene mixed_scene() {
    Scene s;
    const uint32_t white = test::add_material(s, glm::vec3(0.8f));
    test::add_grid(s, {-2, 0, -2}, {4, 0, 0}, {0, 0, 4}, 8, 8, white);                    // floor, one chart
    test::add_box(s, {-0.5f, 0, -0.5f}, {0.5f, 1, 0.5f}, white);                          // 6 charts, touches the floor
    test::add_icosphere(s, {1.2f, 0.5f, 1.2f}, 0.4f, 2, white);                           // curved
    test::add_quad(s, {-1.8f, 0.5f, 1.5f}, {1.5f, 0, 0}, {0, 0.7f, 0}, white);            // wall
    test::add_mesh(s, {{0, 2, 0}, {1.5f, 2, 0}, {1.5f, 2.002f, 0}}, {{0, 1, 2}}, white);  // sliver
    test::add_mesh(s, {{1, 2, 1}, {1.001f, 2, 1}, {1, 2, 1.001f}}, {{0, 2, 1}}, white);   // tiny
    return s;
}

glm::vec2 uv_at(const Scene& s, uint32_t t, glm::vec2 bary) {
    const glm::uvec3& tri = s.triangles[t];
    return (1.0f - bary.x - bary.y) * s.uv1[tri.x] + bary.x * s.uv1[tri.y] + bary.y * s.uv1[tri.z];
}

double uv_pixel_area(const Scene& s, size_t t, int w, int h) {
    const glm::uvec3& tri = s.triangles[t];
    const glm::dvec2 a = glm::dvec2(s.uv1[tri.x]) * glm::dvec2(w, h), b = glm::dvec2(s.uv1[tri.y]) * glm::dvec2(w, h),
                     c = glm::dvec2(s.uv1[tri.z]) * glm::dvec2(w, h);
    return 0.5 * std::abs((b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x));
}

// Chart of every texel (-1 uncovered); fails the test where two charts share a texel.
std::vector<int> chart_per_texel(const Scene& s, const AtlasReport& report, const TexelSamples& texels) {
    std::vector<int> chart(size_t(texels.width) * size_t(texels.height), -1);
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        std::set<uint32_t> charts;
        for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k)
            charts.insert(report.triangle_chart[texels.samples[k].triangle]);
        EXPECT_EQ(charts.size(), 1u) << "texel " << texels.texels[i] << " is claimed by several charts";
        chart[texels.texels[i]] = int(*charts.begin());
    }
    (void)s;
    return chart;
}

// Any two texels of different charts are more than `padding` texels apart
// (Chebyshev distance), i.e. at least `padding` empty texels lie between them.
void expect_charts_apart(const std::vector<int>& chart, int w, int h, int padding) {
    size_t violations = 0;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const int c = chart[size_t(y) * size_t(w) + size_t(x)];
            if (c < 0) continue;
            for (int dy = -padding; dy <= padding; ++dy)
                for (int dx = -padding; dx <= padding; ++dx) {
                    const int xx = x + dx, yy = y + dy;
                    if (xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
                    const int other = chart[size_t(yy) * size_t(w) + size_t(xx)];
                    if (other >= 0 && other != c) ++violations;
                }
        }
    EXPECT_EQ(violations, 0u);
}

// Stitching never invents light: a dark texel between bright ones across
// seams would be pulled below 0 by the unconstrained least squares (measured
// here: 34 texel channels went negative in the solve without the
// constraint); the constrained solve holds them at 0 and still brings both
// sides together (seam metric 1.38 -> 0.068; clamping the unconstrained
// solution instead leaves 0.075).
TEST(Seams, StitchingNeverWritesANegativeTexel) {
    const int w = 16, h = 16;
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<glm::vec4> image(size_t(w) * h);
    for (glm::vec4& p : image) {
        const float v = u(rng) < 0.5f ? 0.0f : 10.0f * u(rng);  // half the texels black
        p = glm::vec4(v, 0.5f * v, 0.0f, 0.0f);
    }
    std::vector<SeamEdge> seams;
    for (int k = 0; k < 60; ++k) {
        const glm::vec2 a0(u(rng), u(rng)), b0(u(rng), u(rng));
        const glm::vec2 d(0.1f * (u(rng) - 0.5f), 0.1f * (u(rng) - 0.5f));
        seams.push_back({a0, a0 + d, b0, b0 - d, true});
    }
    const std::vector<glm::vec4> before = image;
    const double metric_before = seam_metric(seams, image, w, h);
    stitch_seams(seams, image, w, h);
    const double metric_after = seam_metric(seams, image, w, h);
    std::printf("random seams: metric %.4f before stitching, %.4f after\n", metric_before, metric_after);
    for (const glm::vec4& p : image)
        for (int c = 0; c < 4; ++c) ASSERT_GE(p[c], 0.0f);
    EXPECT_LT(metric_after, 0.5 * metric_before);
    size_t changed = 0;
    for (size_t i = 0; i < image.size(); ++i) changed += image[i] != before[i];
    EXPECT_GT(changed, 0u);
}

// Signed data (a directional lightmap's L1 components) is stitched without
// the constraint: a field negative everywhere, whose two sides already agree
// on every seam, comes back unchanged; with the constraint it would be
// clamped to 0 at every texel the seams read.
TEST(Seams, SignedDataIsStitchedWithoutTheNonNegativeConstraint) {
    const int w = 16, h = 16;
    std::vector<glm::vec4> image(size_t(w) * h, glm::vec4(-0.5f, -1.0f, 0.25f, 0.0f));
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<SeamEdge> seams;
    for (int k = 0; k < 20; ++k) {
        const glm::vec2 a0(u(rng), u(rng)), b0(u(rng), u(rng));
        seams.push_back({a0, a0 + glm::vec2(0.05f, 0.0f), b0, b0 + glm::vec2(0.0f, 0.05f), true});
    }
    std::vector<glm::vec4> signed_image = image, clamped = image;
    stitch_seams(seams, signed_image, w, h, 8, 0.1f, 64, false);
    for (const glm::vec4& p : signed_image) {
        ASSERT_NEAR(p.x, -0.5f, 1e-5f);
        ASSERT_NEAR(p.y, -1.0f, 1e-5f);
    }
    stitch_seams(seams, clamped, w, h);
    EXPECT_GT(std::count_if(clamped.begin(), clamped.end(), [](const glm::vec4& p) { return p.x == 0.0f; }), 0)
        << "the default (irradiance) stitch holds negative components at 0";
}

// A bake builds the seam system once and stitches every layer of every
// snapshot with it, the layers on threads of their own: each image comes out
// exactly as a stitch of its own would make it.
TEST(Seams, OneSystemStitchesManyImagesAtOnceAsEachAlone) {
    const int w = 32, h = 32;
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<SeamEdge> seams;
    for (int k = 0; k < 80; ++k) {
        const glm::vec2 a0(u(rng), u(rng)), b0(u(rng), u(rng));
        seams.push_back({a0, a0 + glm::vec2(0.06f, 0.02f), b0, b0 + glm::vec2(-0.02f, 0.06f), true});
    }
    std::vector<std::vector<glm::vec4>> images(6, std::vector<glm::vec4>(size_t(w) * h));
    for (auto& image : images)
        for (glm::vec4& p : image) p = glm::vec4(u(rng), u(rng), u(rng), 0.0f) * 4.0f;
    std::vector<std::vector<glm::vec4>> alone = images;
    for (auto& image : alone) stitch_seams(seams, image, w, h);
    const SeamStitcher stitcher(seams, w, h);
    std::vector<std::thread> threads;
    for (auto& image : images) threads.emplace_back([&stitcher, &image] { stitcher.stitch(image); });
    for (std::thread& t : threads) t.join();
    for (size_t i = 0; i < images.size(); ++i) EXPECT_EQ(images[i], alone[i]) << "image " << i;
    EXPECT_NE(images[0], images[1]);
}

TEST(Atlas, GeneratedChartsNeitherOverlapNorTouch) {
    Scene s = mixed_scene();
    AtlasOptions options;
    options.resolution = 128;
    options.padding = 2;
    const AtlasReport report = generate_lightmap_uvs(s, options);
    ASSERT_TRUE(report.generated);
    EXPECT_EQ(report.width, 128);
    EXPECT_GT(report.charts, 8u);  // floor, 6 box faces, sphere charts, wall, sliver, tiny
    const TexelSamples texels = rasterize_texel_samples(s, report.width, report.height);
    expect_charts_apart(chart_per_texel(s, report, texels), report.width, report.height, options.padding);
    for (const glm::vec2& uv : s.uv1) {
        EXPECT_GE(uv.x, 0.0f);
        EXPECT_LE(uv.x, 1.0f);
        EXPECT_GE(uv.y, 0.0f);
        EXPECT_LE(uv.y, 1.0f);
    }
}

TEST(Atlas, EveryTriangleOwnsATexelIncludingSliversAndTinyOnes) {
    Scene s = mixed_scene();
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 64});
    const TexelSamples texels = rasterize_texel_samples(s, report.width, report.height);
    std::vector<int> samples_of(s.triangles.size(), 0);
    for (const TexelSample& sample : texels.samples) ++samples_of[sample.triangle];
    for (size_t t = 0; t < s.triangles.size(); ++t) EXPECT_GT(samples_of[t], 0) << "triangle " << t;
    // The sliver (1.5 m x 2 mm) and the tiny triangle (1 mm) are the last two.
    EXPECT_GT(samples_of[s.triangles.size() - 2], 0);
    EXPECT_GT(samples_of[s.triangles.size() - 1], 0);
}

TEST(Atlas, TexelDensityIsTheSameForEveryChart) {
    Scene s = mixed_scene();
    const AtlasReport report = generate_lightmap_uvs(s, {.texel_density = 20.0f});
    EXPECT_FLOAT_EQ(report.texel_density, 20.0f);  // fits, so it is kept
    std::vector<double> world(report.charts, 0.0), uv(report.charts, 0.0);
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        world[report.triangle_chart[t]] += s.triangle_area(t);
        uv[report.triangle_chart[t]] += uv_pixel_area(s, t, report.width, report.height);
    }
    for (size_t c = 0; c < report.charts; ++c) {
        if (world[c] * 20.0 * 20.0 < 1.0) continue;  // charts under one texel take the minimum size
        EXPECT_NEAR(std::sqrt(uv[c] / world[c]), 20.0, 0.02) << "chart " << c;
    }
}

// A mesh's lightmap scale (glTF extras lightfarm_lightmap_scale) multiplies
// its charts' density, and only theirs: at 20 texels/m, a mesh at 2 gets 40,
// at 0.5 gets 10, the rest 20, each within its chart's rounding.
TEST(Atlas, AMeshsLightmapScaleMultipliesItsChartsDensityAlone) {
    Scene s = mixed_scene();
    ASSERT_GE(s.instances.size(), 3u);
    s.instances[0].lightmap_scale = 2.0f;
    s.instances[1].lightmap_scale = 0.5f;
    const AtlasReport report = generate_lightmap_uvs(s, {.texel_density = 20.0f});
    EXPECT_FLOAT_EQ(report.texel_density, 20.0f);
    std::vector<double> world(report.charts, 0.0), uv(report.charts, 0.0), scale(report.charts, 0.0);
    for (const PrimitiveInstance& inst : s.instances)
        for (uint32_t t = inst.first_triangle; t < inst.first_triangle + inst.triangle_count; ++t) {
            world[report.triangle_chart[t]] += s.triangle_area(t);
            uv[report.triangle_chart[t]] += uv_pixel_area(s, t, report.width, report.height);
            scale[report.triangle_chart[t]] = inst.lightmap_scale;
        }
    size_t scaled = 0;
    for (size_t c = 0; c < report.charts; ++c) {
        const double density = 20.0 * scale[c];
        if (world[c] * density * density < 1.0) continue;  // charts under one texel take the minimum size
        EXPECT_NEAR(std::sqrt(uv[c] / world[c]), density, 0.001 * density + 0.02) << "chart " << c;
        scaled += scale[c] != 1.0;
    }
    EXPECT_GT(scaled, 0u);
    EXPECT_EQ(report.mesh_scaled_charts, scaled);
}

// A mesh at lightmap scale 0 has no lightmap of its own: each of its
// charts lies in one texel (the chart's mean), counted apart from the
// scaled ones, and the other charts keep the asked density. Each kind of
// mesh: flat (the wall), a box's six charts, a curved sphere's many.
TEST(Atlas, AMeshWithoutALightmapHasOneTexelPerChart) {
    for (const size_t excluded : {size_t(1), size_t(2), size_t(3)}) {
        SCOPED_TRACE("instance " + std::to_string(excluded));
        Scene s = mixed_scene();
        s.instances.at(excluded).lightmap_scale = 0.0f;
        EXPECT_FALSE(s.instances[excluded].has_lightmap());
        const AtlasReport report = generate_lightmap_uvs(s, {.texel_density = 20.0f});
        EXPECT_FLOAT_EQ(report.texel_density, 20.0f);
        std::vector<double> world(report.charts, 0.0), uv(report.charts, 0.0);
        std::vector<int> unmapped(report.charts, -1);  // 1: only the excluded mesh's triangles, 0: none of them
        std::vector<glm::dvec2> low(report.charts, glm::dvec2(1e30)), high(report.charts, glm::dvec2(-1e30));
        for (size_t i = 0; i < s.instances.size(); ++i) {
            const PrimitiveInstance& inst = s.instances[i];
            for (uint32_t t = inst.first_triangle; t < inst.first_triangle + inst.triangle_count; ++t) {
                const uint32_t c = report.triangle_chart[t];
                ASSERT_NE(unmapped[c], int(i != excluded)) << "a chart spans the excluded mesh and another";
                unmapped[c] = int(i == excluded);
                world[c] += s.triangle_area(t);
                uv[c] += uv_pixel_area(s, t, report.width, report.height);
                for (int k = 0; k < 3; ++k) {
                    const glm::dvec2 p = glm::dvec2(s.uv1[s.triangles[t][k]]) * glm::dvec2(report.width, report.height);
                    low[c] = glm::min(low[c], p);
                    high[c] = glm::max(high[c], p);
                }
            }
        }
        size_t one_texel = 0;
        for (size_t c = 0; c < report.charts; ++c) {
            if (unmapped[c] == 1) {
                EXPECT_EQ(glm::floor(low[c]), glm::floor(high[c] - 1e-6)) << "chart " << c << " spans texels";
                ++one_texel;
            } else if (world[c] * 400.0 >= 1.0) {  // charts under one texel take the minimum size
                EXPECT_NEAR(std::sqrt(uv[c] / world[c]), 20.0, 0.02) << "chart " << c;
            }
        }
        EXPECT_GT(one_texel, 0u);
        EXPECT_EQ(report.unmapped_charts, one_texel);
        // No seam is stitched to those texels (the box's creases, the sphere's smooth seams).
        std::set<std::pair<int, int>> unmapped_texels;
        for (size_t c = 0; c < report.charts; ++c)
            if (unmapped[c] == 1) unmapped_texels.insert({int(low[c].x), int(low[c].y)});
        for (const SeamEdge& seam : find_seams(s))
            for (const glm::vec2 uv : {seam.a0, seam.a1, seam.b0, seam.b1})
                EXPECT_FALSE(unmapped_texels.count({int(uv.x * report.width), int(uv.y * report.height)}))
                    << "a seam on a mesh without a lightmap";
        EXPECT_EQ(report.mesh_scaled_charts, 0u) << "no lightmap is not a scaled lightmap";
    }
    // Two meshes that meet flat along an edge make one chart, but not where
    // one of them has no lightmap: its texels would be read by no one.
    Scene flat;
    const uint32_t white = test::add_material(flat, glm::vec3(0.8f));
    test::add_quad(flat, {0, 0, 0}, {1, 0, 0}, {0, 0, 1}, white);
    test::add_quad(flat, {1, 0, 0}, {1, 0, 0}, {0, 0, 1}, white);
    Scene joined = flat;
    EXPECT_EQ(generate_lightmap_uvs(joined, {.texel_density = 20.0f}).charts, 1u);
    flat.instances[1].lightmap_scale = 0.0f;
    const AtlasReport apart = generate_lightmap_uvs(flat, {.texel_density = 20.0f});
    EXPECT_EQ(apart.charts, 2u);
    EXPECT_EQ(apart.unmapped_charts, 1u);
}

// Separate triangles (obtuse, standing on their longest edge, all facing
// the same way): one chart each, each filling half its rectangle.
Scene triangles_scene(int count) {
    Scene s;
    const uint32_t white = test::add_material(s, glm::vec3(0.8f));
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int i = 0; i < count; ++i) {
        const float base = 0.3f + 0.7f * u(rng), height = base * (0.3f + 0.4f * u(rng)), apex = 0.3f * base * u(rng);
        const glm::vec3 at(float(i % 20) * 2.0f, 0.0f, float(i / 20) * 2.0f);
        test::add_mesh(s, {at, at + glm::vec3(base, 0, 0), at + glm::vec3(apex, 0, height)}, {{0, 2, 1}}, white);
    }
    return s;
}

// Packed as whole rectangles, charts that each fill half of theirs cover at
// most about half the atlas (these 100 triangles: 42.2% at 256², 92.9
// texels/m at 512², measured before charts were packed by their texels).
// Packed by texel shape and turned to nest they cover well over half, at a
// density where their padded rectangles alone would not fit the atlas.
TEST(Atlas, PackingByTexelShapeFillsMoreThanRectanglesCan) {
    Scene s = triangles_scene(100);
    const int res = 256;
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = res});
    ASSERT_EQ(report.charts, 100u);
    double rectangles = 0.0;          // each chart's bounding rectangle in whole texels, 2 texels of padding added
    std::array<int, 4> directions{};  // of each triangle's base in the atlas: +u, -u, +v, -v
    for (const glm::uvec3& t : s.triangles) {
        glm::vec2 lo(1e9f), hi(-1e9f);
        for (int k = 0; k < 3; ++k) {
            lo = glm::min(lo, s.uv1[t[k]] * float(res));
            hi = glm::max(hi, s.uv1[t[k]] * float(res));
        }
        rectangles += (std::ceil(hi.x - lo.x - 1e-3) + 2.0) * (std::ceil(hi.y - lo.y - 1e-3) + 2.0);
        const glm::vec2 base = s.uv1[t.z] - s.uv1[t.x];  // the mesh's corners 0 and 1 (triangle {0, 2, 1})
        ++directions[std::abs(base.x) > std::abs(base.y) ? (base.x > 0 ? 0 : 1) : (base.y > 0 ? 2 : 3)];
    }
    std::printf(
        "100 triangles at %d²: %.1f texels/m, utilisation %.1f%%, padded rectangles %.2f of the atlas, "
        "bases +u %d, -u %d, +v %d, -v %d\n",
        res, report.texel_density, 100.0 * report.utilisation, rectangles / ((res + 2.0) * (res + 2.0)), directions[0],
        directions[1], directions[2], directions[3]);
    EXPECT_GT(report.utilisation, 0.55);
    EXPECT_GT(rectangles, 1.15 * (res + 2.0) * (res + 2.0));
    // The charts were turned: their bases point more than one way.
    EXPECT_LT(*std::max_element(directions.begin(), directions.end()), 90);

    Scene at512 = triangles_scene(100);
    EXPECT_GT(generate_lightmap_uvs(at512, {.resolution = 512}).texel_density, 1.15f * 92.9f);
}

// Every invariant holds on turned, nested charts, whatever the padding:
// charts apart, every triangle with a texel, one density, UVs in the atlas,
// the same atlas every time.
TEST(Atlas, TurnedChartsKeepEveryInvariant) {
    for (int padding : {1, 2, 3}) {
        Scene s = triangles_scene(100);
        const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 192, .padding = padding});
        const TexelSamples texels = rasterize_texel_samples(s, report.width, report.height);
        expect_charts_apart(chart_per_texel(s, report, texels), report.width, report.height, padding);
        std::vector<int> samples_of(s.triangles.size(), 0);
        for (const TexelSample& sample : texels.samples) ++samples_of[sample.triangle];
        for (size_t t = 0; t < s.triangles.size(); ++t) {
            EXPECT_GT(samples_of[t], 0) << "triangle " << t << ", padding " << padding;
            const double density = std::sqrt(uv_pixel_area(s, t, report.width, report.height) / s.triangle_area(t));
            EXPECT_NEAR(density, report.texel_density, 1e-3 * report.texel_density) << "triangle " << t;
        }
        for (const glm::vec2& uv : s.uv1) {
            EXPECT_GE(std::min(uv.x, uv.y), 0.0f);
            EXPECT_LE(std::max(uv.x, uv.y), 1.0f);
        }
        Scene again = triangles_scene(100);
        generate_lightmap_uvs(again, {.resolution = 192, .padding = padding});
        EXPECT_EQ(again.uv1, s.uv1) << "padding " << padding;
    }
}

TEST(Atlas, ResolutionOnlyDerivesADensityThatFills) {
    Scene s = mixed_scene();
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 256});
    EXPECT_EQ(report.width, 256);
    EXPECT_GT(report.texel_density, 0.0f);
    EXPECT_GT(report.utilisation, 0.4);  // 10-odd charts of very different sizes
    std::printf("mixed scene at 256²: %zu charts, density %.1f texels/m, utilisation %.1f%%\n", report.charts,
                report.texel_density, 100.0 * report.utilisation);
}

TEST(Atlas, DensityTooHighForTheResolutionShrinks) {
    Scene s = mixed_scene();
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 64, .texel_density = 1000.0f});
    EXPECT_EQ(report.width, 64);
    EXPECT_LT(report.texel_density, 1000.0f);
    EXPECT_GT(report.texel_density, 1.0f);
}

// ---------------------------------------------------------------------------
// Atlas pages (issue #36): charts that do not fit one page at an asked
// density go on several pages of max_resolution² (LightmapPages).

// The page whose rows hold each triangle, checking that all three corners
// lie on it (a chart never crosses a page or reaches into the rows between).
std::vector<int> triangle_pages(const Scene& s, const LightmapPages& pages, int height) {
    std::vector<int> page(s.triangles.size());
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        const glm::uvec3& tri = s.triangles[t];
        const float centre = (s.uv1[tri.x].y + s.uv1[tri.y].y + s.uv1[tri.z].y) / 3.0f;
        page[t] = pages.page_of(centre);
        const double top = double(page[t]) * pages.stride(), bottom = top + pages.rows;
        for (uint32_t v : {tri.x, tri.y, tri.z}) {
            const double row = double(s.uv1[v].y) * height;
            EXPECT_GE(row, top - 1e-3) << "triangle " << t << " reaches above page " << page[t];
            EXPECT_LE(row, bottom + 1e-3) << "triangle " << t << " reaches below page " << page[t];
        }
    }
    return page;
}

// Each chart's texels per metre over its world area (charts under a texel
// take the minimum size, and are left out).
void expect_density(const Scene& s, const AtlasReport& report, double density) {
    std::vector<double> world(report.charts, 0.0), uv(report.charts, 0.0);
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        world[report.triangle_chart[t]] += s.triangle_area(t);
        uv[report.triangle_chart[t]] += uv_pixel_area(s, t, report.width, report.height);
    }
    for (size_t c = 0; c < report.charts; ++c) {
        if (world[c] * density * density < 1.0) continue;
        EXPECT_NEAR(std::sqrt(uv[c] / world[c]), density, 0.001 * density + 0.02) << "chart " << c;
    }
}

// The mixed scene and six more boxes, 61 m² in all (the floor's 4 m the largest chart).
Scene paged_scene() {
    Scene s = mixed_scene();
    const uint32_t grey = test::add_material(s, glm::vec3(0.5f));
    for (int k = 0; k < 6; ++k) test::add_box(s, {3.0f + 1.5f * float(k), 0, 0}, {4.0f + 1.5f * float(k), 1, 1}, grey);
    return s;
}

// At densities whose charts take one to several 128² pages: the density
// asked is kept; the stacked atlas is the pages `padding` rows apart; every
// triangle lies inside one page; charts keep their padding on the stacked
// atlas (across a page's edge too) and no texel lies between pages; every
// chart has the density; the pages are used (each holds a chart).
TEST(AtlasPages, ChartsThatDoNotFitOnePageGoOnPagesAtTheAskedDensity) {
    int most_pages = 0;
    for (const float density : {8.0f, 20.0f, 31.0f}) {
        SCOPED_TRACE(density);
        Scene s = paged_scene();
        const AtlasOptions options{.texel_density = density, .padding = 2, .max_resolution = 128, .max_pages = 8};
        const AtlasReport report = generate_lightmap_uvs(s, options);
        const LightmapPages& pages = report.pages;
        EXPECT_FLOAT_EQ(report.texel_density, density);
        // One page: the smallest square that holds the charts, as before.
        EXPECT_EQ(report.width, pages.count > 1 ? 128 : report.height);
        EXPECT_LE(report.width, 128);
        EXPECT_EQ(pages.rows, report.width);
        EXPECT_EQ(pages.gap, pages.count > 1 ? options.padding : 0);
        EXPECT_EQ(report.height, pages.count * pages.rows + (pages.count - 1) * pages.gap);
        EXPECT_EQ(s.lightmap_pages.count, pages.count);
        most_pages = std::max(most_pages, pages.count);

        const std::vector<int> page = triangle_pages(s, pages, report.height);
        const TexelSamples texels = rasterize_texel_samples(s, report.width, report.height);
        expect_charts_apart(chart_per_texel(s, report, texels), report.width, report.height, options.padding);
        for (uint32_t t : texels.texels) {
            const int row = int(t / uint32_t(report.width));
            EXPECT_LT(row % pages.stride(), pages.rows) << "a texel between pages, row " << row;
        }
        expect_density(s, report, density);
        std::set<int> used(page.begin(), page.end());
        EXPECT_EQ(int(used.size()), pages.count) << "every page holds a chart";
    }
    EXPECT_GE(most_pages, 3) << "the family reaches several pages";
}

// More pages than max_pages would hold: the density shrinks until the
// charts fill max_pages, to 2% (one: the single atlas as before); a chart
// wider than a page at the density asked sets the density at which it
// spans one.
TEST(AtlasPages, PastMaxPagesOrAPageTheDensityShrinks) {
    for (const int max_pages : {1, 2}) {
        Scene s = paged_scene();
        const AtlasReport report =
            generate_lightmap_uvs(s, {.texel_density = 31.0f, .max_resolution = 128, .max_pages = max_pages});
        EXPECT_EQ(report.pages.count, max_pages);
        EXPECT_LT(report.texel_density, 31.0f);
        expect_density(s, report, report.texel_density);
        // Within 2% of the densest that fits: 2% more takes more pages.
        Scene denser = paged_scene();
        const AtlasReport more = generate_lightmap_uvs(
            denser, {.texel_density = report.texel_density * 1.02f, .max_resolution = 128, .max_pages = 64});
        EXPECT_GT(more.pages.count, max_pages) << report.texel_density << " texels/m";
    }
    // The 4 m floor spans a 128-texel page at 32 texels/m.
    Scene s = mixed_scene();
    const AtlasReport report =
        generate_lightmap_uvs(s, {.texel_density = 100.0f, .max_resolution = 128, .max_pages = 64});
    EXPECT_LE(report.texel_density, 32.0f);
    EXPECT_GT(report.texel_density, 31.5f);
    EXPECT_GT(report.pages.count, 1);
}

// One accessor's values as doubles, `components` per element (float, or the
// unsigned integer types of indices).
std::vector<double> accessor_values(const tinygltf::Model& model, int index) {
    const tinygltf::Accessor& a = model.accessors[size_t(index)];
    const tinygltf::BufferView& view = model.bufferViews[size_t(a.bufferView)];
    const unsigned char* data = model.buffers[size_t(view.buffer)].data.data() + view.byteOffset + a.byteOffset;
    const int components = tinygltf::GetNumComponentsInType(uint32_t(a.type));
    const int size = tinygltf::GetComponentSizeInBytes(uint32_t(a.componentType));
    const size_t stride = view.byteStride ? view.byteStride : size_t(components * size);
    std::vector<double> out;
    for (size_t i = 0; i < a.count; ++i)
        for (int c = 0; c < components; ++c) {
            const unsigned char* p = data + i * stride + size_t(c * size);
            if (a.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT) out.push_back(*reinterpret_cast<const float*>(p));
            else if (size == 4) out.push_back(*reinterpret_cast<const uint32_t*>(p));
            else if (size == 2) out.push_back(*reinterpret_cast<const uint16_t*>(p));
            else out.push_back(*p);
        }
    return out;
}

// The files of a paged atlas: each primitive whose triangles lie on several
// pages is one primitive per page, their triangles together the
// primitive's; each piece's TEXCOORD_1 is its page's v (in [0, 1]), and its
// extras' lightfarm_lightmap_stacked_v maps it back to the stacked atlas's
// uv1 exactly; in scene.lit.glb each piece's material carries its own
// page's lightmap: a lightmap whose page p holds p + 1 everywhere decodes to
// p + 1 on every piece of page p.
TEST(AtlasPages, EveryPrimitiveOfTheGlbsIsOnItsPageAndItsPagesLightmap) {
    const fs::path dir = fs::temp_directory_path() / ("lightfarm_pages_test_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    Scene scene = load_scene(kScenes / "monkey.glb");
    const AtlasReport report =
        generate_lightmap_uvs(scene, {.texel_density = 100.0f, .max_resolution = 256, .max_pages = 8});
    const LightmapPages& pages = report.pages;
    ASSERT_GE(pages.count, 3);
    std::vector<float> rgb(size_t(report.width) * size_t(report.height) * 3, 0.0f);
    for (int row = 0; row < report.height; ++row)
        if (row % pages.stride() < pages.rows)
            std::fill_n(rgb.begin() + std::ptrdiff_t(size_t(row) * size_t(report.width) * 3), report.width * 3,
                        float(row / pages.stride() + 1));
    const protocol::RgbmImage lightmap = protocol::encode_rgbm(rgb, report.width, report.height);
    write_lit_glb(kScenes / "monkey.glb", scene, {&lightmap}, dir / "scene.lit.glb");

    tinygltf::Model model;
    tinygltf::TinyGLTF gltf;
    std::string err, warn;
    ASSERT_TRUE(gltf.LoadBinaryFromFile(&model, &err, &warn, (dir / "scene.lit.glb").string())) << err;
    size_t split = 0;
    std::set<int> pages_seen;
    for (const PrimitiveInstance& inst : scene.instances) {
        const std::vector<tinygltf::Primitive>& primitives =
            model.meshes[size_t(model.nodes[size_t(inst.node)].mesh)].primitives;
        const int uv_accessor = primitives[size_t(inst.primitive)].attributes.at("TEXCOORD_1");
        const std::vector<double> uv = accessor_values(model, uv_accessor);
        size_t triangles = 0, pieces = 0;
        for (const tinygltf::Primitive& piece : primitives) {
            if (piece.attributes.at("TEXCOORD_1") != uv_accessor) continue;
            ++pieces;
            const int page = piece.extras.Get("lightfarm_lightmap_page").GetNumberAsInt();
            pages_seen.insert(page);
            const tinygltf::Value& stacked = piece.extras.Get("lightfarm_lightmap_stacked_v");
            const double offset = stacked.Get(0).GetNumberAsDouble(), scale = stacked.Get(1).GetNumberAsDouble();
            EXPECT_NEAR(offset, double(page) * pages.stride() / report.height, 1e-12);
            const std::vector<double> indices = accessor_values(model, piece.indices);
            triangles += indices.size() / 3;
            for (double k : indices) {
                const glm::vec2 want = scene.uv1[inst.first_vertex + uint32_t(k)];
                const double u = uv[2 * size_t(k)], v = uv[2 * size_t(k) + 1];
                EXPECT_GE(v, -1e-6);
                EXPECT_LE(v, 1.0 + 1e-6);
                EXPECT_FLOAT_EQ(float(u), want.x);
                EXPECT_NEAR(offset + scale * v, want.y, 1e-6) << "vertex " << k << " of page " << page;
            }
            // Its material's lightmap is its page's.
            const tinygltf::Material& material = model.materials[size_t(piece.material)];
            const int texture = material.extensions.at("MOZ_lightmap").Get("index").GetNumberAsInt();
            const tinygltf::Image& image = model.images[size_t(model.textures[size_t(texture)].source)];
            ASSERT_EQ(image.width, pages.rows);
            ASSERT_EQ(image.height, pages.rows);
            for (size_t i = 0; i < image.image.size(); i += 4 * 997) {
                const double value = lightmap.range * image.image[i] / 255.0 * image.image[i + 3] / 255.0;
                ASSERT_NEAR(value, page + 1, 0.02 * (page + 1)) << "page " << page << " shows another page";
            }
        }
        EXPECT_EQ(triangles, inst.triangle_count) << "the pieces hold the primitive's triangles";
        split += pieces > 1;
    }
    EXPECT_EQ(int(pages_seen.size()), pages.count);
    EXPECT_GT(split, 0u) << "a primitive spans pages";
    fs::remove_all(dir);
}

// A unit cube's faces are its six charts (90° apart): 24 m of chart border
// over 6 m², so at d texels per metre the surface within half a texel of a
// border is 24 / (2 · 6 · d) = 2 / d of it.
TEST(Atlas, BorderFractionOfACubeIsTwoOverTheDensity) {
    Scene s;
    test::add_box(s, glm::vec3(0.0f), glm::vec3(1.0f), test::add_material(s, glm::vec3(0.5f)));
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 64});
    ASSERT_EQ(report.charts, 6u);
    EXPECT_NEAR(report.border_fraction, 2.0 / report.texel_density, 1e-6 * report.border_fraction);
    EXPECT_FALSE(report.density_from_scene);
}

// With neither a resolution nor a density, the density follows the scene:
// the one at which the border fraction is the one asked for (the cube: 2 /
// 0.05 = 40 texels/m), twice as fine for half the fraction, but never
// coarser than the default atlas filled; a given resolution or density still
// wins, and the cap holds (the fraction then reported as it is, above the
// one asked for).
TEST(Atlas, DensityFromTheSceneMeetsTheBorderFraction) {
    Scene cube;
    test::add_box(cube, glm::vec3(0.0f), glm::vec3(1.0f), test::add_material(cube, glm::vec3(0.5f)));
    Scene a = cube;
    const AtlasReport r = generate_lightmap_uvs(a, {.max_border_fraction = 0.002f});
    EXPECT_TRUE(r.density_from_scene);
    EXPECT_NEAR(r.texel_density, 1000.0f, 1e-2f);
    EXPECT_NEAR(r.border_fraction, 0.002, 1e-8);
    EXPECT_GT(r.width, kDefaultAtlasResolution);

    Scene m1 = mixed_scene(), m2 = mixed_scene();
    const AtlasReport coarse = generate_lightmap_uvs(m1, {.max_border_fraction = 0.01f});
    const AtlasReport fine = generate_lightmap_uvs(m2, {.max_border_fraction = 0.005f});
    ASSERT_TRUE(coarse.density_from_scene);
    EXPECT_NEAR(coarse.border_fraction, 0.01, 1e-7);
    EXPECT_NEAR(fine.texel_density / coarse.texel_density, 2.0f, 1e-4f);
    EXPECT_GT(fine.width, coarse.width);

    // A fraction the default atlas already meets: the default atlas, filled.
    Scene lax = cube, plain = cube;
    const AtlasReport at_default = generate_lightmap_uvs(lax, {.max_border_fraction = 0.5f});
    const AtlasReport reference = generate_lightmap_uvs(plain, {});
    EXPECT_FALSE(at_default.density_from_scene);
    EXPECT_EQ(at_default.width, kDefaultAtlasResolution);
    EXPECT_EQ(at_default.texel_density, reference.texel_density);
    EXPECT_LT(at_default.border_fraction, 0.5);

    Scene given = cube;
    const AtlasReport fixed = generate_lightmap_uvs(given, {.resolution = 64, .max_border_fraction = 0.002f});
    EXPECT_FALSE(fixed.density_from_scene);
    EXPECT_EQ(fixed.width, 64);

    Scene capped = mixed_scene();
    const AtlasReport cap = generate_lightmap_uvs(capped, {.max_border_fraction = 1e-5f, .auto_max_resolution = 512});
    EXPECT_EQ(cap.width, 512);
    EXPECT_GT(cap.border_fraction, 1e-5);

    // A file's own TEXCOORD_1: its islands are the charts.
    const Scene cornell = load_scene(kScenes / "cornell_box.gltf");
    const AtlasReport own = use_existing_lightmap_uvs(cornell, {.max_border_fraction = 0.005f});
    EXPECT_TRUE(own.density_from_scene);
    EXPECT_GT(own.width, kDefaultAtlasResolution);
    EXPECT_NEAR(own.border_fraction, 0.005, 0.02 * 0.005);  // the side rounds up to whole texels
}

// The smallest resolution an upload's generated atlas fits: every smaller
// one is refused by the atlas itself, that one is not. A triangle 1e30 m wide
// (finite, so the loader takes it) packs nowhere and is answered with 0, not
// an int overflow (found by fuzzing; this suite also runs under UBSan).
TEST(Atlas, SmallestResolutionIsTheSmallestThatPacks) {
    Scene s = mixed_scene();
    const int smallest = smallest_atlas_resolution(s);
    ASSERT_GT(smallest, 1);
    Scene fits = s, too_small = s;
    EXPECT_NO_THROW(generate_lightmap_uvs(fits, {.resolution = smallest}));
    EXPECT_THROW(generate_lightmap_uvs(too_small, {.resolution = smallest - 1}), AtlasDoesNotFit);
    // Any other failure during the atlas is not "does not fit" (the bake
    // answers that one with a hint to raise the resolution; a GL error while
    // finding unlit charts once got the hint, and was called bad input).
    Scene failing = s;
    AtlasOptions options{.resolution = smallest};
    options.find_unlit_charts = [](const std::vector<uint32_t>&, size_t) -> std::vector<uint8_t> {
        throw std::runtime_error("the tracer failed");
    };
    try {
        generate_lightmap_uvs(failing, options);
        ADD_FAILURE() << "the callback's error was swallowed";
    } catch (const AtlasDoesNotFit&) {
        ADD_FAILURE() << "another error was reported as charts that do not fit";
    } catch (const std::runtime_error& e) {
        EXPECT_STREQ(e.what(), "the tracer failed");
    }

    Scene huge;
    test::add_mesh(huge, {{0, 0, 0}, {1e30f, 0, 0}, {0, 0, 1e30f}}, {{0, 1, 2}},
                   test::add_material(huge, glm::vec3(0.5f)));
    EXPECT_EQ(smallest_atlas_resolution(huge, {.max_resolution = 512}), 0);
    EXPECT_THROW(generate_lightmap_uvs(huge, {.resolution = 256}), AtlasDoesNotFit);
}

TEST(Atlas, SplitVerticesKeepPositionsAndMapBack) {
    Scene original = mixed_scene();
    Scene s = original;
    generate_lightmap_uvs(s, {.resolution = 128});
    ASSERT_EQ(s.triangles.size(), original.triangles.size());
    ASSERT_EQ(s.source_vertex.size(), s.positions.size());
    EXPECT_GT(s.positions.size(), original.positions.size());  // the box's corners were split
    for (size_t i = 0; i < s.instances.size(); ++i) {
        const PrimitiveInstance& a = original.instances[i];
        const PrimitiveInstance& b = s.instances[i];
        EXPECT_TRUE(b.has_uv1);
        for (uint32_t v = b.first_vertex; v < b.first_vertex + b.vertex_count; ++v) {
            ASSERT_LT(s.source_vertex[v], a.vertex_count);
            EXPECT_EQ(s.positions[v], original.positions[a.first_vertex + s.source_vertex[v]]);
        }
        for (uint32_t t = b.first_triangle; t < b.first_triangle + b.triangle_count; ++t)
            for (int k = 0; k < 3; ++k) {
                EXPECT_GE(s.triangles[t][k], b.first_vertex);
                EXPECT_LT(s.triangles[t][k], b.first_vertex + b.vertex_count);
                EXPECT_EQ(s.positions[s.triangles[t][k]], original.positions[original.triangles[t][k]]);
            }
    }
}

TEST(TexelSamples, SamplesLieOnTheirTriangleAndInsideTheirTexel) {
    Scene s = mixed_scene();
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 96});
    for (int n : {1, 2, 3}) {
        const TexelSamples texels = rasterize_texel_samples(s, report.width, report.height, n);
        ASSERT_EQ(texels.first_sample.size(), texels.covered_count() + 1);
        for (size_t i = 0; i < texels.covered_count(); ++i) {
            const int x = int(texels.texels[i] % uint32_t(texels.width)),
                      y = int(texels.texels[i] / uint32_t(texels.width));
            ASSERT_GT(texels.sample_count(i), 0u);
            EXPECT_GT(texels.texel_world_size[i], 0.0f);
            for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k) {
                const TexelSample& sample = texels.samples[k];
                ASSERT_GE(sample.bary.x, 0.0f);
                ASSERT_GE(sample.bary.y, 0.0f);
                ASSERT_LE(sample.bary.x + sample.bary.y, 1.0f + 1e-6f);
                const glm::vec2 pixel = uv_at(s, sample.triangle, sample.bary) * glm::vec2(texels.width, texels.height);
                const float eps = 1e-3f;
                EXPECT_GE(pixel.x, float(x) - eps);
                EXPECT_LE(pixel.x, float(x + 1) + eps);
                EXPECT_GE(pixel.y, float(y) - eps);
                EXPECT_LE(pixel.y, float(y + 1) + eps);
                EXPECT_NEAR(glm::length(sample.normal), 1.0f, 1e-4f);
                const glm::uvec3& tri = s.triangles[sample.triangle];
                const glm::vec3 p = (1 - sample.bary.x - sample.bary.y) * s.positions[tri.x] +
                                    sample.bary.x * s.positions[tri.y] + sample.bary.y * s.positions[tri.z];
                EXPECT_LT(glm::length(p - sample.position), 1e-5f);
            }
        }
    }
}

TEST(TexelSamples, FullyCoveredTexelGetsStratifiedSubsamplesAndMaterial) {
    Scene s;
    const uint32_t red = test::add_material(s, glm::vec3(0.7f, 0.1f, 0.1f), glm::vec3(2.0f));
    test::add_quad(s, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, red);  // UV1 covers the whole square
    const TexelSamples texels = rasterize_texel_samples(s, 4, 4, 2);
    ASSERT_EQ(texels.covered_count(), 16u);
    EXPECT_TRUE(texels.dilation.empty());
    for (size_t i = 0; i < 16; ++i) {
        // Texels on the quad's diagonal hold samples from both triangles; every
        // sub-position is taken exactly once, except exactly on the diagonal.
        EXPECT_GE(texels.sample_count(i), 4u);
        EXPECT_NEAR(texels.albedo[i].x, 0.7f, 1e-6f);
        EXPECT_NEAR(texels.emission[i].y, 2.0f, 1e-6f);
        EXPECT_NEAR(texels.texel_world_size[i], 0.25f, 1e-5f);
    }
}

TEST(TexelSamples, DilationFillsARingAroundEachChart) {
    Scene s;
    const uint32_t white = test::add_material(s, glm::vec3(1.0f));
    // A 8x8-texel chart in the middle of a 32² atlas.
    test::add_quad(s, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, white, {12.0f / 32, 12.0f / 32, 20.0f / 32, 20.0f / 32});
    const TexelSamples texels = rasterize_texel_samples(s, 32, 32, 2, 3);
    ASSERT_EQ(texels.covered_count(), 64u);
    std::vector<glm::vec4> image(32 * 32, glm::vec4(0.0f));
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        const uint32_t p = texels.texels[i];
        image[p] = glm::vec4(float(p % 32), float(p / 32), 1.0f, 1.0f);  // each texel says where it is
    }
    dilate(texels, image);
    for (int y = 0; y < 32; ++y)
        for (int x = 0; x < 32; ++x) {
            const glm::vec4 v = image[size_t(y) * 32 + size_t(x)];
            const int cx = std::clamp(x, 12, 19), cy = std::clamp(y, 12, 19);  // nearest covered texel
            const int d2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
            if (d2 <= 9) {
                EXPECT_EQ(v.z, 1.0f) << x << "," << y;
                EXPECT_EQ(v.x, float(cx));
                EXPECT_EQ(v.y, float(cy));
            } else {
                EXPECT_EQ(v.z, 0.0f) << x << "," << y;
            }
        }
}

TEST(TexelSamples, CoverageMaskMatchesTheCoveredTexels) {
    Scene s = mixed_scene();
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 64});
    const TexelSamples texels = rasterize_texel_samples(s, 64, 64);
    const std::vector<uint8_t> mask = coverage_mask(s, 64, 64);
    size_t covered = 0;
    for (uint8_t m : mask) covered += m;
    EXPECT_EQ(covered, texels.covered_count());
    for (uint32_t p : texels.texels) EXPECT_EQ(mask[p], 1);
    EXPECT_NEAR(report.utilisation, double(covered) / (64.0 * 64.0), 1e-12);
}

// ---------------------------------------------------------------------------
// Seams.

TEST(Seams, ABoxWithOneChartPerFaceHasTwelveSeams) {
    Scene s;
    test::add_box(s, {0, 0, 0}, {1, 1, 1}, test::add_material(s, glm::vec3(1.0f)));
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 64});
    EXPECT_EQ(report.charts, 6u);
    const std::vector<SeamEdge> seams = find_seams(s);
    EXPECT_EQ(seams.size(), 12u);
}

TEST(Seams, AFlatGridIsOneChartWithoutSeams) {
    Scene s;
    test::add_grid(s, {0, 0, 0}, {2, 0, 0}, {0, 0, 1}, 6, 3, test::add_material(s, glm::vec3(1.0f)));
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 64});
    EXPECT_EQ(report.charts, 1u);
    EXPECT_TRUE(find_seams(s).empty());
}

// A 2 x 2 m plane of 2 x 2 quads, cut along x = 1 into two UV islands.
void add_cut_plane(Scene& s, uint32_t material, bool as_two_meshes) {
    std::vector<glm::vec3> p;
    std::vector<glm::vec2> uv;
    std::vector<glm::uvec3> left, right;
    for (int half = 0; half < 2; ++half) {
        const auto base = uint32_t(p.size());
        for (int j = 0; j <= 2; ++j)
            for (int i = 0; i <= 1; ++i) {
                p.push_back({float(half + i), 0.0f, float(j)});
                uv.push_back({0.05f + 0.5f * half + 0.2f * i, 0.05f + 0.2f * j});
            }
        auto at = [&](int i, int j) { return base + uint32_t(j * 2 + i); };
        auto& tris = half == 0 ? left : right;
        for (int j = 0; j < 2; ++j) {
            tris.push_back({at(0, j), at(1, j + 1), at(1, j)});
            tris.push_back({at(0, j), at(0, j + 1), at(1, j + 1)});
        }
    }
    if (as_two_meshes) {
        auto sub = [&](size_t from) {
            return std::vector<glm::vec3>(p.begin() + long(from), p.begin() + long(from) + 6);
        };
        auto sub_uv = [&](size_t from) {
            return std::vector<glm::vec2>(uv.begin() + long(from), uv.begin() + long(from) + 6);
        };
        std::vector<glm::uvec3> right_local;
        for (auto t : right) right_local.push_back(t - glm::uvec3(6));
        test::add_mesh(s, sub(0), left, material, sub_uv(0));
        test::add_mesh(s, sub(6), right_local, material, sub_uv(6));
    } else {
        std::vector<glm::uvec3> all = left;
        all.insert(all.end(), right.begin(), right.end());
        test::add_mesh(s, p, all, material, uv);
    }
}

TEST(Seams, APlaneCutInTwoHasSeamsAlongTheCutWithinAndBetweenMeshes) {
    for (bool two_meshes : {false, true}) {
        Scene s;
        add_cut_plane(s, test::add_material(s, glm::vec3(1.0f)), two_meshes);
        const std::vector<SeamEdge> seams = find_seams(s);
        ASSERT_EQ(seams.size(), 2u) << (two_meshes ? "two meshes" : "one mesh");
        for (const SeamEdge& seam : seams) {
            EXPECT_TRUE(seam.smooth);
            // Side A and side B are the same points of the cut: x = 1 is u = 0.25 on the
            // left island and u = 0.55 on the right one, v equal.
            EXPECT_NEAR(std::abs(seam.a0.x - seam.b0.x), 0.3f, 1e-6f);
            EXPECT_NEAR(seam.a0.y, seam.b0.y, 1e-6f);
            EXPECT_NEAR(seam.a1.y, seam.b1.y, 1e-6f);
        }
    }
}

TEST(Seams, MetricIsZeroForAgreeingSidesAndMeasuresTheDifference) {
    Scene s;
    add_cut_plane(s, test::add_material(s, glm::vec3(1.0f)), false);
    const std::vector<SeamEdge> seams = find_seams(s);
    const int w = 40, h = 40;
    std::vector<glm::vec4> image(w * h, glm::vec4(0.5f));
    EXPECT_NEAR(seam_metric(seams, image, w, h), 0.0, 1e-9);
    // Left island (u < 0.5) at 1, right at 0: the sides differ by exactly 1.
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) image[size_t(y * w + x)] = glm::vec4(x < w / 2 ? 1.0f : 0.0f);
    EXPECT_NEAR(seam_metric(seams, image, w, h), 1.0, 1e-6);
    EXPECT_EQ(sample_bilinear(image, w, h, {0.0f, 0.0f}), glm::vec4(1.0f));  // clamped at the border
}

TEST(Seams, StitchingMakesBothSidesAgree) {
    Scene s;
    test::add_icosphere(s, {0, 0, 0}, 1.0f, 2, test::add_material(s, glm::vec3(1.0f)));
    const AtlasReport report = generate_lightmap_uvs(s, {.resolution = 128});
    std::vector<SeamEdge> seams = find_seams(s);
    ASSERT_FALSE(seams.empty());
    std::erase_if(seams, [](const SeamEdge& e) { return !e.smooth; });
    ASSERT_FALSE(seams.empty());
    // A smooth "lighting" (a function of position) plus texel noise, dilated.
    const TexelSamples texels = rasterize_texel_samples(s, report.width, report.height);
    std::vector<glm::vec4> image(size_t(report.width) * report.height, glm::vec4(0.0f));
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> noise(-0.1f, 0.1f);
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        const glm::vec3 p = texels.samples[texels.first_sample[i]].position;
        image[texels.texels[i]] = glm::vec4(glm::vec3(1.0f + 0.5f * p.y + noise(rng)), 1.0f);
    }
    dilate(texels, image);
    const double before = seam_metric(seams, image, report.width, report.height);
    stitch_seams(seams, image, report.width, report.height);
    const double after = seam_metric(seams, image, report.width, report.height);
    std::printf("icosphere: %zu smooth seams, metric %.4f before stitching, %.4f after\n", seams.size(), before, after);
    EXPECT_GT(before, 0.01);
    EXPECT_LT(after, 0.25 * before);
}

// ---------------------------------------------------------------------------
// Against the thesis's triangle-pair atlas, on the shared scenes.

struct AtlasFigures {
    AtlasReport report;
    size_t seams = 0;
    double density_spread = 0.0;  // 90th / 10th percentile of the triangles' texel densities
};

AtlasFigures measure(Scene s, bool baseline, int resolution) {
    AtlasFigures f;
    AtlasOptions options;
    options.resolution = resolution;
    f.report = baseline ? generate_triangle_pair_uvs(s, options) : generate_lightmap_uvs(s, options);
    f.seams = find_seams(s).size();
    std::vector<double> density;
    for (size_t t = 0; t < s.triangles.size(); ++t)
        if (s.triangle_area(t) > 0.0f)
            density.push_back(std::sqrt(uv_pixel_area(s, t, resolution, resolution) / s.triangle_area(t)));
    std::sort(density.begin(), density.end());
    f.density_spread = density[density.size() * 9 / 10] / density[density.size() / 10];
    return f;
}

TEST(AtlasVsTrianglePairs, FewerSeamsOnTheSharedScenes) {
    for (const char* name : {"cornell_box.gltf", "monkey.glb", "packuv.glb"}) {
        const fs::path file = kScenes / name;
        ASSERT_TRUE(fs::exists(file)) << file << " missing (the shared scenes are part of the test input)";
        const Scene scene = load_scene(file);  // cornell_box's own TEXCOORD_1 is ignored: both atlases are generated
        for (int resolution : {256, 1024}) {
            const AtlasFigures charts = measure(scene, false, resolution);
            const AtlasFigures pairs = measure(scene, true, resolution);
            std::printf(
                "%-17s %4d² %5zu tris | charts: %4zu charts, %5zu seam edges, utilisation %5.1f%%, "
                "%6.1f texels/m, density p90/p10 %.2f | triangle pairs: %4zu pairs, %5zu seam edges, "
                "utilisation %5.1f%%, %6.1f texels/m, density p90/p10 %.2f\n",
                name, resolution, scene.triangles.size(), charts.report.charts, charts.seams,
                100.0 * charts.report.utilisation, charts.report.texel_density, charts.density_spread,
                pairs.report.charts, pairs.seams, 100.0 * pairs.report.utilisation, pairs.report.texel_density,
                pairs.density_spread);
            EXPECT_LT(charts.seams, pairs.seams) << name;
            EXPECT_LT(charts.report.charts, pairs.report.charts) << name;
        }
    }
}

TEST(Atlas, ExistingLightmapUVsDecideTheSizeFromTheDensity) {
    const fs::path file = kScenes / "cornell_box.gltf";
    ASSERT_TRUE(fs::exists(file)) << file << " missing (the shared scenes are part of the test input)";
    const Scene scene = load_scene(file);
    ASSERT_TRUE(scene.all_have_lightmap_uvs());
    const AtlasReport at256 = use_existing_lightmap_uvs(scene, {.resolution = 256});
    EXPECT_FALSE(at256.generated);
    EXPECT_EQ(at256.width, 256);
    EXPECT_EQ(at256.charts, 16u);  // one rectangle per quad (SOURCES.md)
    EXPECT_GT(at256.utilisation, 0.3);
    // Asking for that density back gives that resolution back.
    const AtlasReport back = use_existing_lightmap_uvs(scene, {.texel_density = at256.texel_density * 0.999f});
    EXPECT_NEAR(back.width, 256, 1);
    std::printf("cornell_box TEXCOORD_1 at 256²: %.1f texels/m, utilisation %.1f%%\n", at256.texel_density,
                100.0 * at256.utilisation);
}

// ---------------------------------------------------------------------------
// scene.lightmapped.glb.

// Loads `file`, generates an atlas, writes the lightmapped glb and loads that
// back: same triangles at the same world positions, every primitive with the
// generated TEXCOORD_1.
// With `turn`, every third triangle is turned round as the bake turns
// double-sided ones (Scene::triangle_turned): the file keeps its own winding.
void expect_round_trip(const fs::path& file, const fs::path& out, bool turn = false) {
    const Scene original = load_scene(file);
    Scene atlas = original;
    generate_lightmap_uvs(atlas, {.resolution = 256});
    Scene written = atlas;
    if (turn) {
        written.triangle_turned.assign(written.triangles.size(), 0);
        for (size_t t = 0; t < written.triangles.size(); t += 3) {
            std::swap(written.triangles[t].y, written.triangles[t].z);
            written.triangle_turned[t] = 1;
        }
    }
    write_lightmapped_glb(file, written, out, false);
    const Scene back = load_scene(out);

    ASSERT_EQ(back.instances.size(), original.instances.size()) << file;
    ASSERT_EQ(back.triangles.size(), original.triangles.size()) << file;
    EXPECT_TRUE(back.all_have_lightmap_uvs());
    size_t position_mismatches = 0, uv_mismatches = 0;
    for (size_t t = 0; t < back.triangles.size(); ++t)
        for (int k = 0; k < 3; ++k) {
            if (back.positions[back.triangles[t][k]] != original.positions[original.triangles[t][k]])
                ++position_mismatches;
            if (back.uv1[back.triangles[t][k]] != atlas.uv1[atlas.triangles[t][k]]) ++uv_mismatches;
        }
    EXPECT_EQ(position_mismatches, 0u) << file;
    EXPECT_EQ(uv_mismatches, 0u) << file;
    for (size_t i = 0; i < back.instances.size(); ++i) EXPECT_TRUE(back.instances[i].has_uv1);
}

TEST(LightmappedGlb, RoundTripsTheSharedScenes) {
    const fs::path dir = fs::temp_directory_path() / ("lightfarm_atlas_test_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    for (const char* name : {"packuv.glb", "monkey.glb", "cornell_box.gltf"}) {
        const fs::path file = kScenes / name;
        ASSERT_TRUE(fs::exists(file)) << file << " missing (the shared scenes are part of the test input)";
        expect_round_trip(file, dir / "scene.lightmapped.glb");
        expect_round_trip(file, dir / "scene.lightmapped.glb", true);
        // Nothing but the result is left behind.
        size_t files = 0;
        for (const auto& entry : fs::directory_iterator(dir)) files += entry.is_regular_file();
        EXPECT_EQ(files, 1u);
    }
    fs::remove_all(dir);
}

// A perspective camera without zfar (an infinite projection, as the
// staircase's) is written without zfar: tinygltf writes "zfar": 0, which the
// glTF schema forbids (the Khronos validator's one error on those files).
TEST(LightmappedGlb, AnInfiniteCameraKeepsNoZfar) {
    const fs::path dir = fs::temp_directory_path() / ("lightfarm_camera_test_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    nlohmann::json doc = nlohmann::json::parse(std::ifstream(kScenes / "cornell_box.gltf"));
    doc["cameras"] = {{{"type", "perspective"}, {"perspective", {{"yfov", 1.0}, {"znear", 0.01}}}}};
    doc["nodes"].push_back({{"camera", 0}, {"translation", {0.3, 0.3, -1.0}}});
    doc["scenes"][0]["nodes"].push_back(doc["nodes"].size() - 1);
    std::ofstream(dir / "camera.gltf") << doc.dump();
    expect_round_trip(dir / "camera.gltf", dir / "scene.lightmapped.glb");
    std::ifstream in(dir / "scene.lightmapped.glb", std::ios::binary);
    const std::string glb((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ASSERT_GT(glb.size(), 20u);
    uint32_t total = 0, json_length = 0;
    std::memcpy(&total, glb.data() + 8, 4);
    std::memcpy(&json_length, glb.data() + 12, 4);
    EXPECT_EQ(total, glb.size());
    EXPECT_EQ(json_length % 4, 0u);
    const nlohmann::json written = nlohmann::json::parse(glb.substr(20, json_length));
    ASSERT_EQ(written["cameras"].size(), 1u);
    EXPECT_FALSE(written["cameras"][0]["perspective"].contains("zfar")) << written["cameras"][0].dump();
    EXPECT_DOUBLE_EQ(written["cameras"][0]["perspective"]["znear"].get<double>(), 0.01);
    fs::remove_all(dir);
}

// encode_png: decoded (by stb_image, as viewers and tinygltf do) to the
// bytes it was given, RGB and RGBA, over several strips of rows and a width
// that is no multiple of anything; the same bytes however its strips run.
TEST(Png, DecodesToItsPixelsAndDoesNotDependOnHowItsStripsRun) {
    const int width = 203, height = 2 * protocol::kPngStripRows + 22;
    std::mt19937 random(7);
    for (int channels : {3, 4}) {
        std::vector<uint8_t> pixels(size_t(width) * height * size_t(channels));
        for (size_t i = 0; i < pixels.size(); ++i)  // gradients, and noise in the lower half
            pixels[i] =
                uint8_t(i < pixels.size() / 2 ? (i / size_t(channels)) % 251 + i % size_t(channels) : random() & 0xff);
        const std::string png = protocol::encode_png(pixels.data(), width, height, channels);
        int w = 0, h = 0, n = 0;
        stbi_uc* decoded =
            stbi_load_from_memory(reinterpret_cast<const stbi_uc*>(png.data()), int(png.size()), &w, &h, &n, channels);
        ASSERT_NE(decoded, nullptr) << stbi_failure_reason();
        EXPECT_EQ(w, width);
        EXPECT_EQ(h, height);
        EXPECT_EQ(n, channels);
        EXPECT_EQ(std::memcmp(decoded, pixels.data(), pixels.size()), 0) << channels << " channels";
        stbi_image_free(decoded);

        const protocol::PngStripRunner backwards_on_threads = [](size_t count, const std::function<void(size_t)>& f) {
            std::vector<std::thread> threads;
            for (size_t i = count; i-- > 0;) threads.emplace_back(f, i);
            for (std::thread& t : threads) t.join();
        };
        EXPECT_EQ(protocol::encode_png(pixels.data(), width, height, channels, backwards_on_threads), png);
    }
    const uint8_t pixel[4] = {};
    EXPECT_THROW(protocol::encode_png(pixel, 1, 1, 2), std::invalid_argument);
    EXPECT_THROW(protocol::encode_png(pixel, 0, 1, 4), std::invalid_argument);
    protocol::RgbmImage short_of_pixels;
    short_of_pixels.width = short_of_pixels.height = 2;
    short_of_pixels.rgba.resize(3 * 4);
    EXPECT_THROW(protocol::rgbm_png(short_of_pixels), std::invalid_argument);
}

// scene.unlit.glb (issue #36), for any glTF viewer: each texel holds the
// light leaving it (emission + albedo x E/pi) as lightfarm's 3D view shows
// it, at the lightmap's automatic exposure through the view's filmic curve
// (protocol/display_tone.h, tested against three.js's constants in
// test_protocol.cpp); charts dilated as the lightmap is, black beyond. Every
// material becomes unlit with that texture on TEXCOORD_1 and nothing of its
// own that a viewer would light or add (textures, emission, extensions),
// its alpha kept.
TEST(UnlitGlb, ShowsTheLightLeavingEachTexelAsTheViewDoes) {
    const fs::path dir = fs::temp_directory_path() / ("lightfarm_unlit_test_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    // The Cornell box (its light has KHR_materials_emissive_strength) with a
    // half-transparent material that has it too.
    nlohmann::json doc = nlohmann::json::parse(std::ifstream(kScenes / "cornell_box.gltf"));
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {0.7, 0.6, 0.5, 0.5};
    doc["materials"][0]["alphaMode"] = "BLEND";
    doc["materials"][0]["extensions"]["KHR_materials_emissive_strength"] = {{"emissiveStrength", 2.0}};
    doc["materials"][0]["name"] = "half glass";
    std::ofstream(dir / "box.gltf") << doc.dump();  // its buffer is a data: URI

    Scene scene = load_scene(dir / "box.gltf");
    generate_lightmap_uvs(scene, {.resolution = 64});
    const TexelSamples texels = rasterize_texel_samples(scene, 64, 64);
    std::vector<float> rgb(64 * 64 * 3, 0.0f);
    for (size_t i = 0; i < texels.covered_count(); ++i)
        for (size_t c = 0; c < 3; ++c) rgb[3 * texels.texels[i] + c] = 0.02f + 0.01f * float((i * 7 + c * 3) % 50);
    const ColourImage look = unlit_look(texels, rgb);
    ASSERT_EQ(look.width, 64);
    ASSERT_EQ(look.rgb.size(), rgb.size());
    const float exposure = float(protocol::automatic_exposure(rgb));
    const auto shown = [&](glm::vec3 radiance) {
        const std::array<float, 3> c = protocol::aces_filmic({radiance.r, radiance.g, radiance.b}, exposure);
        return std::array<uint8_t, 3>{protocol::encode_srgb8(c[0]), protocol::encode_srgb8(c[1]),
                                      protocol::encode_srgb8(c[2])};
    };
    size_t emitting = 0;
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        const size_t t = texels.texels[i];
        const glm::vec3 e(rgb[3 * t], rgb[3 * t + 1], rgb[3 * t + 2]);
        const std::array<uint8_t, 3> want = shown(texels.emission[i] + texels.albedo[i] * e);
        for (size_t c = 0; c < 3; ++c) ASSERT_EQ(look.rgb[3 * t + c], want[c]) << "texel " << t << " channel " << c;
        emitting += texels.emission[i] != glm::vec3(0.0f);
    }
    EXPECT_GT(emitting, 0u) << "the light's texels show its emission";
    std::vector<bool> covered(64 * 64, false);
    for (uint32_t t : texels.texels) covered[t] = true;
    std::vector<bool> dilated(64 * 64, false);
    for (const auto& [to, from] : texels.dilation) {
        dilated[to] = true;
        for (size_t c = 0; c < 3; ++c) EXPECT_EQ(look.rgb[3 * to + c], look.rgb[3 * from + c]) << "dilated " << to;
    }
    for (size_t t = 0; t < covered.size(); ++t) {
        if (!covered[t] && !dilated[t]) {
            EXPECT_EQ(look.rgb[3 * t] + look.rgb[3 * t + 1] + look.rgb[3 * t + 2], 0) << "beyond the charts: " << t;
        }
    }

    const fs::path out = dir / "scene.unlit.glb";
    write_unlit_glb(dir / "box.gltf", scene, look, out);
    tinygltf::Model model;
    tinygltf::TinyGLTF gltf;
    std::string err, warn;
    ASSERT_TRUE(gltf.LoadBinaryFromFile(&model, &err, &warn, out.string())) << err;
    int half_glass_primitives = 0;
    EXPECT_EQ(model.extensionsUsed, std::vector<std::string>{"KHR_materials_unlit"})
        << "emissive strength went with the emission";
    for (const tinygltf::Mesh& mesh : model.meshes)
        for (const tinygltf::Primitive& primitive : mesh.primitives) {
            EXPECT_TRUE(primitive.attributes.count("TEXCOORD_1"));
            ASSERT_GE(primitive.material, 0);
            const tinygltf::Material& m = model.materials[size_t(primitive.material)];
            EXPECT_TRUE(m.extensions.count("KHR_materials_unlit")) << m.name;
            EXPECT_EQ(m.extensions.size(), 1u) << m.name;
            const tinygltf::TextureInfo& base = m.pbrMetallicRoughness.baseColorTexture;
            ASSERT_GE(base.index, 0) << m.name;
            EXPECT_EQ(base.texCoord, 1);
            const tinygltf::Image& image = model.images[size_t(model.textures[size_t(base.index)].source)];
            ASSERT_EQ(size_t(image.width) * size_t(image.height) * 3, look.rgb.size());
            std::vector<uint8_t> decoded_rgb;  // tinygltf decodes to image.component channels
            for (size_t p = 0; p < look.rgb.size() / 3; ++p)
                for (size_t c = 0; c < 3; ++c) decoded_rgb.push_back(image.image[p * size_t(image.component) + c]);
            EXPECT_EQ(decoded_rgb, look.rgb) << "the PNG holds the look exactly";
            EXPECT_EQ(m.emissiveFactor, (std::vector<double>{0.0, 0.0, 0.0})) << m.name;
            EXPECT_LT(m.emissiveTexture.index, 0);
            EXPECT_LT(m.normalTexture.index, 0);
            EXPECT_LT(m.occlusionTexture.index, 0);
            EXPECT_LT(m.pbrMetallicRoughness.metallicRoughnessTexture.index, 0);
            const std::vector<double>& factor = m.pbrMetallicRoughness.baseColorFactor;
            EXPECT_EQ(std::vector<double>(factor.begin(), factor.begin() + 3), (std::vector<double>{1.0, 1.0, 1.0}));
            if (m.name == "half glass") {
                ++half_glass_primitives;
                EXPECT_EQ(factor[3], 0.5) << "alpha kept";
                EXPECT_EQ(m.alphaMode, "BLEND");
            }
        }
    EXPECT_GT(half_glass_primitives, 0) << "the half-transparent material reached the file";
    fs::remove_all(dir);
}

// scene.lit.glb: every baked primitive's material carries the lightmap with
// MOZ_lightmap (texCoord 1, intensity pi, RGBM with its range), primitives
// without a material get a white Lambertian one, and the embedded PNG decodes
// to the lightmap it was given, within RGBM's half step.
TEST(LitGlb, CarriesTheLightmapOnEveryBakedMaterial) {
    const fs::path dir = fs::temp_directory_path() / ("lightfarm_lit_test_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    for (const char* name : {"monkey.glb", "cornell_box.gltf"}) {  // no materials; materials and its own UVs
        Scene scene = load_scene(kScenes / name);
        generate_lightmap_uvs(scene, {.resolution = 64});
        std::vector<float> rgb(64 * 32 * 3);
        for (size_t i = 0; i < rgb.size(); ++i) rgb[i] = 0.001f + float(i % 97) * 0.05f * float(1 + i % 3);
        const protocol::RgbmImage lightmap = protocol::encode_rgbm(rgb, 64, 32);
        const fs::path out = dir / "scene.lit.glb";
        write_lit_glb(kScenes / name, scene, {&lightmap}, out);

        tinygltf::Model model;
        tinygltf::TinyGLTF gltf;
        std::string err, warn;
        ASSERT_TRUE(gltf.LoadBinaryFromFile(&model, &err, &warn, out.string())) << err;
        EXPECT_NE(std::find(model.extensionsUsed.begin(), model.extensionsUsed.end(), "MOZ_lightmap"),
                  model.extensionsUsed.end());
        int texture = -1;
        for (const tinygltf::Mesh& mesh : model.meshes)
            for (const tinygltf::Primitive& primitive : mesh.primitives) {
                ASSERT_GE(primitive.material, 0) << name;
                const tinygltf::Material& material = model.materials[size_t(primitive.material)];
                ASSERT_TRUE(material.extensions.count("MOZ_lightmap")) << name << " " << material.name;
                const tinygltf::Value& ext = material.extensions.at("MOZ_lightmap");
                EXPECT_EQ(ext.Get("texCoord").GetNumberAsInt(), 1);
                EXPECT_NEAR(ext.Get("intensity").GetNumberAsDouble(), M_PI, 1e-9);
                EXPECT_EQ(ext.Get("extras").Get("encoding").Get<std::string>(), "RGBM");
                EXPECT_FLOAT_EQ(float(ext.Get("extras").Get("rgbm_range").GetNumberAsDouble()), lightmap.range);
                texture = ext.Get("index").GetNumberAsInt();
                EXPECT_TRUE(primitive.attributes.count("TEXCOORD_1"));
                if (std::string(name) == "monkey.glb") {
                    EXPECT_EQ(material.pbrMetallicRoughness.metallicFactor, 0.0) << "white Lambertian, not metal";
                }
            }
        ASSERT_GE(texture, 0);
        const tinygltf::Image& image = model.images[size_t(model.textures[size_t(texture)].source)];
        ASSERT_EQ(image.width, 64);
        ASSERT_EQ(image.height, 32);
        ASSERT_EQ(image.component, 4);
        EXPECT_EQ(image.image, lightmap.rgba) << "the PNG holds the RGBM bytes exactly";
        EXPECT_EQ(model.samplers[size_t(model.textures[size_t(texture)].sampler)].magFilter,
                  TINYGLTF_TEXTURE_FILTER_LINEAR);
    }
    fs::remove_all(dir);
}

// A glTF with one box mesh (24 vertices, faces split as exporters do) placed
// by two nodes, one of them mirrored.
void write_instanced_box(const fs::path& file) {
    tinygltf::Model model;
    std::vector<float> positions;
    std::vector<uint16_t> indices;
    for (int axis = 0; axis < 3; ++axis)
        for (int side = 0; side < 2; ++side) {
            const auto base = uint16_t(positions.size() / 3);
            for (int corner = 0; corner < 4; ++corner) {
                float p[3];
                p[axis] = side ? 0.5f : -0.5f;
                p[(axis + 1) % 3] = (corner == 1 || corner == 2) ? 0.5f : -0.5f;
                p[(axis + 2) % 3] = corner >= 2 ? 0.5f : -0.5f;
                positions.insert(positions.end(), p, p + 3);
            }
            const bool flip = side == 0;
            indices.insert(indices.end(), {base, uint16_t(base + (flip ? 2 : 1)), uint16_t(base + (flip ? 1 : 2)), base,
                                           uint16_t(base + (flip ? 3 : 2)), uint16_t(base + (flip ? 2 : 3))});
        }
    tinygltf::Buffer buffer;
    buffer.data.resize(positions.size() * 4 + indices.size() * 2);
    std::memcpy(buffer.data.data(), positions.data(), positions.size() * 4);
    std::memcpy(buffer.data.data() + positions.size() * 4, indices.data(), indices.size() * 2);
    model.buffers.push_back(buffer);
    tinygltf::BufferView pv, iv;
    pv.buffer = iv.buffer = 0;
    pv.byteLength = positions.size() * 4;
    iv.byteOffset = pv.byteLength;
    iv.byteLength = indices.size() * 2;
    model.bufferViews = {pv, iv};
    tinygltf::Accessor pa, ia;
    pa.bufferView = 0;
    pa.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
    pa.type = TINYGLTF_TYPE_VEC3;
    pa.count = positions.size() / 3;
    pa.minValues = {-0.5, -0.5, -0.5};
    pa.maxValues = {0.5, 0.5, 0.5};
    ia.bufferView = 1;
    ia.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT;
    ia.type = TINYGLTF_TYPE_SCALAR;
    ia.count = indices.size();
    model.accessors = {pa, ia};
    tinygltf::Primitive prim;
    prim.attributes["POSITION"] = 0;
    prim.indices = 1;
    prim.mode = TINYGLTF_MODE_TRIANGLES;
    tinygltf::Mesh mesh;
    mesh.primitives.push_back(prim);
    model.meshes.push_back(mesh);
    tinygltf::Node a, b;
    a.mesh = b.mesh = 0;
    a.translation = {-1.0, 0.0, 0.0};
    b.translation = {1.0, 0.0, 0.0};
    b.scale = {-1.0, 1.0, 1.0};  // mirrored
    model.nodes = {a, b};
    tinygltf::Scene scene;
    scene.nodes = {0, 1};
    model.scenes.push_back(scene);
    model.defaultScene = 0;
    model.asset.version = "2.0";
    tinygltf::TinyGLTF gltf;
    ASSERT_TRUE(gltf.WriteGltfSceneToFile(&model, file.string(), true, true, true, false));
}

TEST(LightmappedGlb, InstancedAndMirroredMeshesGetTheirOwnUVs) {
    const fs::path dir = fs::temp_directory_path() / ("lightfarm_atlas_box_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    write_instanced_box(dir / "boxes.gltf");
    const Scene original = load_scene(dir / "boxes.gltf");
    ASSERT_EQ(original.instances.size(), 2u);
    // Both boxes face outwards in the Scene (the loader undid the mirroring).
    for (size_t t = 0; t < original.triangles.size(); ++t) {
        const PrimitiveInstance& inst = original.instances[t < original.instances[1].first_triangle ? 0 : 1];
        const glm::vec3 centre(inst.node == 0 ? -1.0f : 1.0f, 0.0f, 0.0f);
        const glm::uvec3& tri = original.triangles[t];
        const glm::vec3 mid =
            (original.positions[tri.x] + original.positions[tri.y] + original.positions[tri.z]) / 3.0f;
        EXPECT_GT(glm::dot(original.geometric_normal(t), mid - centre), 0.0f) << t;
    }
    expect_round_trip(dir / "boxes.gltf", dir / "boxes.lightmapped.glb");

    // Each node placement got its own mesh.
    tinygltf::Model written;
    tinygltf::TinyGLTF gltf;
    std::string err, warn;
    ASSERT_TRUE(gltf.LoadBinaryFromFile(&written, &err, &warn, (dir / "boxes.lightmapped.glb").string())) << err;
    ASSERT_EQ(written.nodes.size(), 2u);
    EXPECT_NE(written.nodes[0].mesh, written.nodes[1].mesh);
    fs::remove_all(dir);
}

// ---------------------------------------------------------------------------
// Preparation on every core (util/parallel.h).

TEST(Parallel, EveryIndexOnceAndTheFirstErrorRethrown) {
    const test::ThreadCount four("4");
    EXPECT_EQ(preparation_threads(), 4u);
    for (const size_t count : {size_t(0), size_t(1), size_t(999), size_t(100003)}) {
        std::vector<std::atomic<int>> visits(count);
        parallel_for(count, 7, [&](size_t i) { ++visits[i]; });
        EXPECT_TRUE(std::all_of(visits.begin(), visits.end(), [](const auto& v) { return v == 1; })) << count;
    }
    for (const char* bad : {"0", "-2", "two", "4x", "", "100000"}) {
        const test::ThreadCount count(bad);
        try {
            preparation_threads();
            ADD_FAILURE() << "LIGHTFARM_THREADS=" << bad << " was taken";
        } catch (const std::invalid_argument& e) {
            EXPECT_NE(std::string(e.what()).find("LIGHTFARM_THREADS="), std::string::npos) << e.what();
        }
    }
    EXPECT_THROW(parallel_for(1000, 1,
                              [](size_t i) {
                                  if (i == 500) throw std::runtime_error("index 500");
                              }),
                 std::runtime_error);
}

// The atlas and the texel samples do not depend on the thread count: 450
// boxes of random sizes and 20 spheres (2,700+ charts: two blocks of
// chart_masks; small enough for the sanitizer build) at 512², on one thread
// and on four, give the same UVs, density and samples bit for bit.
TEST(Parallel, TheAtlasAndTexelSamplesAreTheSameOnOneThreadAsOnFour) {
    Scene loaded;
    const uint32_t white = test::add_material(loaded, glm::vec3(0.8f));
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int i = 0; i < 450; ++i) {
        const glm::vec3 lo(20.0f * u(rng), 20.0f * u(rng), 20.0f * u(rng));
        test::add_box(loaded, lo, lo + glm::vec3(0.05f + u(rng), 0.05f + u(rng), 0.05f + 2.0f * u(rng)), white);
    }
    for (int i = 0; i < 20; ++i)
        test::add_icosphere(loaded, {20.0f * u(rng), 20.0f * u(rng), -2.0f}, 0.2f + u(rng), 2, white);
    struct Result {
        Scene scene;
        AtlasReport report;
        TexelSamples texels;
    };
    auto prepare = [&](const char* threads) {
        const test::ThreadCount count(threads);
        Result r{loaded, {}, {}};
        r.report = generate_lightmap_uvs(r.scene, {.resolution = 512});
        r.texels = rasterize_texel_samples(r.scene, r.report.width, r.report.height);
        return r;
    };
    const Result one = prepare("1"), four = prepare("4");
    ASSERT_GT(one.report.charts, 2048u);
    EXPECT_EQ(one.report.texel_density, four.report.texel_density);
    EXPECT_EQ(one.report.triangle_chart, four.report.triangle_chart);
    ASSERT_EQ(one.scene.uv1.size(), four.scene.uv1.size());
    EXPECT_EQ(0, std::memcmp(one.scene.uv1.data(), four.scene.uv1.data(), one.scene.uv1.size() * sizeof(glm::vec2)));
    EXPECT_EQ(one.texels.texels, four.texels.texels);
    EXPECT_EQ(one.texels.first_sample, four.texels.first_sample);
    ASSERT_EQ(one.texels.samples.size(), four.texels.samples.size());
    EXPECT_EQ(0, std::memcmp(one.texels.samples.data(), four.texels.samples.data(),
                             one.texels.samples.size() * sizeof(TexelSample)));
    EXPECT_EQ(one.texels.albedo, four.texels.albedo);
    EXPECT_EQ(one.texels.texel_world_size, four.texels.texel_world_size);
    EXPECT_EQ(one.texels.dilation, four.texels.dilation);
}

// ---------------------------------------------------------------------------
// Speed on the big scenes (figures printed; bounds loose for shared machines).

TEST(AtlasSpeed, BigScenesAt1024) {
    for (const fs::path& file : {kScenes / "real/wooden_staircase/wooden_staircase.gltf", kScenes / "spheres.glb"}) {
        ASSERT_TRUE(fs::exists(file)) << file << " missing (the shared scenes are part of the test input)";
        Scene scene = load_scene(file);
        using clock = std::chrono::steady_clock;
        const auto t0 = clock::now();
        const AtlasReport report = generate_lightmap_uvs(scene, {.resolution = 1024});
        const auto t1 = clock::now();
        const TexelSamples texels = rasterize_texel_samples(scene, 1024, 1024);
        const auto t2 = clock::now();
        const size_t seams = find_seams(scene).size();
        const auto t3 = clock::now();
        auto seconds = [](auto a, auto b) { return std::chrono::duration<double>(b - a).count(); };
        std::printf(
            "%s: %zu triangles, %zu charts, %.1f texels/m, utilisation %.1f%%, %zu covered texels, "
            "%zu samples, %zu seam edges | atlas %.2f s, texel samples %.2f s, seams %.2f s\n",
            file.filename().c_str(), scene.triangles.size(), report.charts, report.texel_density,
            100.0 * report.utilisation, texels.covered_count(), texels.samples.size(), seams, seconds(t0, t1),
            seconds(t1, t2), seconds(t2, t3));
        for (size_t t = 0; t < scene.triangles.size(); ++t) ASSERT_NE(report.triangle_chart[t], UINT32_MAX);
        EXPECT_LT(seconds(t0, t2), 60.0);
    }
}

// What a bake's stitch costs (docs/BENCHMARKS.md, "Read-backs in batches,
// the seam system built once"): the staircase's smooth seams at 512², three
// layers of random texels (a noisy lightmap), stitched as the bake did before
// (the system built for each layer, one layer after another) and as it does
// now (SeamStitcher built once, a thread per layer); the same texels both ways.
TEST(SeamsSpeed, DISABLED_OneSystemLayersInParallel) {
    Scene scene = load_scene(kScenes / "real/wooden_staircase/wooden_staircase.gltf");
    const int res = 512;
    generate_lightmap_uvs(scene, {.resolution = res});
    std::vector<SeamEdge> seams;
    for (const SeamEdge& e : find_seams(scene))
        if (e.smooth) seams.push_back(e);
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<std::vector<glm::vec4>> layers(3, std::vector<glm::vec4>(size_t(res) * res));
    for (auto& layer : layers)
        for (glm::vec4& t : layer) t = glm::vec4(u(rng), u(rng), u(rng), 0.0f);
    using clock = std::chrono::steady_clock;
    auto seconds = [](auto a, auto b) { return std::chrono::duration<double>(b - a).count(); };
    std::vector<std::vector<glm::vec4>> before = layers, after = layers;
    const auto t0 = clock::now();
    for (auto& layer : before) stitch_seams(seams, layer, res, res);
    const auto t1 = clock::now();
    const SeamStitcher stitcher(seams, res, res);
    const auto t2 = clock::now();
    std::vector<std::thread> threads;
    for (auto& layer : after) threads.emplace_back([&stitcher, &layer] { stitcher.stitch(layer); });
    for (std::thread& t : threads) t.join();
    const auto t3 = clock::now();
    std::printf(
        "%zu smooth seams at %d²: system per layer, layers in turn %.3f s; system once %.3f s, "
        "three layers in parallel %.3f s\n",
        seams.size(), res, seconds(t0, t1), seconds(t1, t2), seconds(t2, t3));
    EXPECT_EQ(before, after);
}

// The figures of docs/BENCHMARKS.md's "Packing by texel shape" (run with
// --gtest_also_run_disabled_tests): per scene, the auto atlas (a border
// fraction of 0.5, gi/bake/bake_job.cpp's default; the fastest of 3) and
// the density a 512² atlas reaches. The Cornell box's own TEXCOORD_1 is
// ignored: every atlas here is generated.
TEST(AtlasSpeed, DISABLED_AutoAndFixedResolution) {
    for (const char* name :
         {"cornell_box.gltf", "monkey.glb", "spheres.glb", "real/wooden_staircase/wooden_staircase.gltf",
          "real/grey_white_room/grey_white_room.gltf", "real/breakfast_room/breakfast_room.gltf"}) {
        const Scene scene = load_scene(kScenes / name);
        AtlasReport automatic;
        double seconds = 1e30;
        for (int run = 0; run < 3; ++run) {
            Scene s = scene;
            const auto t0 = std::chrono::steady_clock::now();
            automatic = generate_lightmap_uvs(s, {.max_border_fraction = 0.5f});
            seconds = std::min(seconds, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        }
        Scene s = scene;
        const AtlasReport fixed = generate_lightmap_uvs(s, {.resolution = 512});
        std::printf(
            "%-44s %5zu charts | auto %4d², %6.2f texels/m, utilisation %5.1f%%, %.2f s | 512²: %7.2f texels/m, "
            "utilisation %5.1f%%\n",
            name, automatic.charts, automatic.width, automatic.texel_density, 100.0 * automatic.utilisation, seconds,
            fixed.texel_density, 100.0 * fixed.utilisation);
    }
}

}  // namespace
}  // namespace lf
