// Light-probe evaluation (issue 11): the polygon-to-point form factor against
// closed forms, the four estimators on synthetic probes captured by ray casting
// simple geometry in C++ (no GPU capture needed), the GLSL include against the
// C++, the probes files' round trip and `lightfarm probe-eval`.
#include "cli_runner.h"
#include "family_errors.h"
#include "gpu_fixture.h"

#include "gpu/shader.h"
#include "io/image_files.h"
#include "probes/probe_eval.h"
#include "probes/probe_set.h"
#include "sh/sh_basis.h"
#include "shaders/buffer_bindings.glsl"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>

namespace lf {
namespace {

namespace fs = std::filesystem;
using test::gpu;

constexpr double kPi = 3.14159265358979323846;

// ------------------------------------------------------ closed forms ----

// Point under a corner of an a × b rectangle parallel to its tangent plane, at height c.
double parallel_corner(double a, double b, double c) {
    const double x = a / c, y = b / c;
    return 1.0 / (2.0 * kPi) *
           (x / std::sqrt(1 + x * x) * std::atan(y / std::sqrt(1 + x * x)) +
            y / std::sqrt(1 + y * y) * std::atan(x / std::sqrt(1 + y * y)));
}

// Parallel rectangle [x0, x1] × [z0, z1] at height c above a point at the
// origin (normal +y), by superposition of corner rectangles (signed extents).
double parallel_rect(double x0, double x1, double z0, double z1, double c) {
    const auto corner = [c](double a, double b) {
        return (a < 0 ? -1.0 : 1.0) * (b < 0 ? -1.0 : 1.0) * parallel_corner(std::abs(a), std::abs(b), c);
    };
    return corner(x1, z1) - corner(x0, z1) - corner(x1, z0) + corner(x0, z0);
}

// Element at the origin, normal +z; rectangle in the plane y = c, x in [0, a],
// z in [0, h] (perpendicular to the element's plane, starting on it).
// (Checked against a 800² midpoint quadrature of cos·cos/(π r²): 0.137228 for a=2, h=1.5, c=0.7.)
double perpendicular_rect(double a, double h, double c) {
    const double x = h / a, y = c / a, s = std::sqrt(x * x + y * y);
    return 1.0 / (2.0 * kPi) * (std::atan(1.0 / y) - y / s * std::atan(1.0 / s));
}

// Corners of a rectangle, wound counter-clockwise about `toward` (the
// direction from the receiver towards it), as the form factor wants.
std::array<glm::vec3, 4> rect(glm::vec3 o, glm::vec3 e1, glm::vec3 e2, glm::vec3 toward) {
    std::array<glm::vec3, 4> c = {o, o + e1, o + e1 + e2, o + e2};
    if (glm::dot(glm::cross(e1, e2), toward) < 0.0f) std::swap(c[1], c[3]);
    return c;
}

TEST(FormFactor, ParallelRectangleOnItsAxis) {
    for (const double c : {5.0, 1.0, 0.3, 0.01, 1e-4}) {
        const double a = 1.0, b = 0.6;
        const auto q = rect({-0.5f, float(c), -0.3f}, {1, 0, 0}, {0, 0, 0.6f}, {0, 1, 0});
        const double expected = 4.0 * parallel_corner(a / 2, b / 2, c);
        EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, q.data(), 4), expected, 2e-6 + 1e-5 * expected)
            << "height " << c;
        EXPECT_NEAR(clipped_polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, q.data(), 4), expected,
                    2e-6 + 1e-5 * expected);
        // The other winding is the negative.
        const std::array<glm::vec3, 4> reversed = {q[0], q[3], q[2], q[1]};
        EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, reversed.data(), 4), -expected,
                    2e-6 + 1e-5 * expected);
    }
    // Almost on the plane, under the middle: the rectangle fills the hemisphere.
    const auto q = rect({-0.5f, 1e-4f, -0.3f}, {1, 0, 0}, {0, 0, 0.6f}, {0, 1, 0});
    EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, q.data(), 4), 1.0, 5e-4);
}

TEST(FormFactor, ParallelRectangleOffAxisByCornerFormula) {
    // The corner formula itself, then a rectangle beside the point (superposition).
    const auto corner = rect({0, 0.7f, 0}, {2, 0, 0}, {0, 0, 1.5f}, {0, 1, 0});
    EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, corner.data(), 4), parallel_corner(2, 1.5, 0.7),
                1e-6);
    for (const double c : {2.0, 0.5, 0.05, 1e-3, 1e-5}) {
        const auto q = rect({1, float(c), 0.5f}, {2, 0, 0}, {0, 0, 1.5f}, {0, 1, 0});
        const double expected = parallel_rect(1, 3, 0.5, 2, c);
        EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, q.data(), 4), expected, 1e-6 + 1e-4 * expected)
            << "height " << c;
    }
    // Almost on the rectangle's plane, beside it: nothing above the horizon.
    const auto q = rect({1, 1e-5f, 0.5f}, {2, 0, 0}, {0, 0, 1.5f}, {0, 1, 0});
    EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 1, 0}, q.data(), 4), 0.0, 1e-5);
}

TEST(FormFactor, PerpendicularRectangle) {
    // Element at the origin with normal +z; the rectangle stands on its tangent plane.
    for (const double c : {2.0, 0.7, 0.1, 1e-3, 1e-5}) {
        const auto q = rect({0, float(c), 0}, {2, 0, 0}, {0, 0, 1.5f}, {0, 1, 0});
        const double expected = perpendicular_rect(2, 1.5, c);
        EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 0, 1}, q.data(), 4), expected, 1e-6 + 1e-4 * expected)
            << "distance " << c;
    }
    // Almost on the rectangle's plane, at its foot: a quarter of the projected disk.
    const auto near = rect({0, 1e-5f, 0}, {2, 0, 0}, {0, 0, 1.5f}, {0, 1, 0});
    EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 0, 1}, near.data(), 4), 0.25, 1e-4);
    // Straddling the tangent plane (z in [-0.8, 1.5]): Lambert's sum integrates the
    // signed cosine (the part below subtracts), clipping gives the exact value.
    const auto straddle = rect({0, 0.7f, -0.8f}, {2, 0, 0}, {0, 0, 2.3f}, {0, 1, 0});
    EXPECT_NEAR(polygon_to_point_form_factor({0, 0, 0}, {0, 0, 1}, straddle.data(), 4),
                perpendicular_rect(2, 1.5, 0.7) - perpendicular_rect(2, 0.8, 0.7), 1e-6);
    EXPECT_NEAR(clipped_polygon_to_point_form_factor({0, 0, 0}, {0, 0, 1}, straddle.data(), 4),
                perpendicular_rect(2, 1.5, 0.7), 1e-6);
}

// ------------------------------------------------------ cube and SH ----

TEST(CubeMap, TexelSolidAnglesCoverTheSphereAndSh9ProjectsTheBasis) {
    for (const int r : {1, 2, 5, 16}) {
        double total = 0.0;
        for (int j = 0; j < r; ++j)
            for (int i = 0; i < r; ++i) total += 6.0 * cube_texel_solid_angle(r, i, j);
        EXPECT_NEAR(total, 4.0 * kPi, 1e-9) << r;
    }
    const int r = 32;
    for (int c = 0; c < 9; ++c) {
        std::vector<glm::vec3> cube(size_t(6) * r * r);
        for (int f = 0; f < 6; ++f)
            for (int j = 0; j < r; ++j)
                for (int i = 0; i < r; ++i)
                    cube[(size_t(f) * r + j) * r + i] =
                        glm::vec3(sh_evaluate(cube_direction(f, (i + 0.5f) / r, (j + 0.5f) / r))[c]);
        const auto sh = project_cube_to_sh9(r, cube);
        for (int k = 0; k < 9; ++k) EXPECT_NEAR(sh[k].r, k == c ? 1.0 : 0.0, 2e-3) << "<y_" << k << ", y_" << c << ">";
    }
    // The convolved SH of a constant is the constant, for any normal.
    std::array<glm::vec3, 9> constant{};
    constant[0] = glm::vec3(0.7f * std::sqrt(4.0f * float(kPi)));
    EXPECT_NEAR(sh9_irradiance_over_pi(constant, glm::normalize(glm::vec3(0.3f, -1, 0.2f))).r, 0.7, 1e-6);
}

TEST(CubeMap, CornerDistancesPutCornersOnTheWallsOfABoxAroundTheProbe) {
    const int m = 3;
    // The mean distances a capture sees from the centre of a cube of half-size 1.5:
    // every corner lands on the cube, its own corners included.
    std::vector<float> depth_one(size_t(6) * m * m, 1.0f), stretch(size_t(6) * m * m);
    for (size_t k = 0; k < stretch.size(); ++k) stretch[k] = 1.0f / cube_texel_depths(m, depth_one)[k];
    std::vector<float> distance(stretch.size());
    for (size_t k = 0; k < distance.size(); ++k) distance[k] = 1.5f * stretch[k];
    const std::vector<float> c = cube_corner_distances(m, distance);
    const auto at = [&](const std::vector<float>& v, int f, int a, int b) {
        return v[(size_t(f) * (m + 1) + b) * (m + 1) + a];
    };
    for (int f = 0; f < 6; ++f)
        for (int b = 0; b <= m; ++b)
            for (int a = 0; a <= m; ++a) {
                const glm::vec3 p = at(c, f, a, b) * cube_direction(f, float(a) / m, float(b) / m);
                EXPECT_NEAR(std::max({std::abs(p.x), std::abs(p.y), std::abs(p.z)}), 1.5f, 1e-5f)
                    << f << " " << a << " " << b;
            }
    // Which texels share a corner: face +X's texel (0, 0) deeper by 3; its
    // corner (0, 0) is a cube corner (3 texels), (1, 0) on a face edge (2 + 2),
    // (1, 1) inside the face (4); the cube corner is the same seen from the 3 faces.
    distance[0] = 4.5f * stretch[0];
    const std::vector<float> d = cube_corner_distances(m, distance);
    const float root3 = std::sqrt(3.0f);
    EXPECT_NEAR(at(d, 0, 0, 0), root3 * (4.5f + 1.5f + 1.5f) / 3, 1e-5f);
    EXPECT_NEAR(at(d, 0, 2, 2) / glm::length(glm::vec3(1, 1.0f / 3, 1.0f / 3)), 1.5f, 1e-5f);
    const float edge = glm::length(glm::vec3(1, 1, 1.0f / 3)), inner = glm::length(glm::vec3(1, 1.0f / 3, 1.0f / 3));
    EXPECT_NEAR(at(d, 0, 1, 0), edge * (4.5f + 1.5f * 3) / 4, 1e-5f);
    EXPECT_NEAR(at(d, 0, 1, 1), inner * (4.5f + 1.5f * 3) / 4, 1e-5f);
    int shared = 0;
    for (int f = 0; f < 6; ++f)
        for (int b = 0; b <= m; ++b)
            for (int a = 0; a <= m; ++a)
                if (glm::length(cube_direction(f, float(a) / m, float(b) / m) - cube_direction(0, 0, 0)) < 1e-5f) {
                    EXPECT_NEAR(at(d, f, a, b), root3 * (4.5f + 1.5f + 1.5f) / 3, 1e-5f) << "face " << f;
                    ++shared;
                }
    EXPECT_EQ(shared, 3);
    // A miss only counts when every texel around the corner missed.
    std::vector<float> misses(size_t(6) * m * m, kMissDistance);
    misses[0] = 3.0f * stretch[0];
    const std::vector<float> cm = cube_corner_distances(m, misses);
    EXPECT_NEAR(cm[0], root3 * 3.0f, 1e-5f);
    EXPECT_FLOAT_EQ(cm[size_t(4) * (m + 1) * (m + 1)], kMissDistance);
}

// ------------------------------------------------ synthetic captures ----

// Rectangles radiating uniformly (both sides, or only towards `front`).
struct Patch {
    glm::vec3 origin, e1, e2;
    glm::vec3 radiance;
    bool one_sided = false;  // emits only on the side of cross(e1, e2)
};

struct Hit {
    float t = -1.0f;
    glm::vec3 radiance{0.0f};
};

Hit cast(const std::vector<Patch>& scene, glm::vec3 o, glm::vec3 d) {
    Hit best;
    for (const Patch& p : scene) {
        const glm::vec3 n = glm::cross(p.e1, p.e2);
        const float denom = glm::dot(n, d);
        if (std::abs(denom) < 1e-12f) continue;
        const float t = glm::dot(n, p.origin - o) / denom;
        if (t <= 1e-6f || (best.t > 0.0f && t >= best.t)) continue;
        const glm::vec3 q = o + t * d - p.origin;
        const float a = glm::dot(q, p.e1) / glm::dot(p.e1, p.e1), b = glm::dot(q, p.e2) / glm::dot(p.e2, p.e2);
        if (a < 0.0f || a > 1.0f || b < 0.0f || b > 1.0f) continue;
        best.t = t;
        best.radiance = p.one_sided && denom > 0.0f ? glm::vec3(0.0f) : p.radiance;
    }
    return best;
}

// A probe "captured" at R per face with 2 × 2 rays per texel (radiance the
// mean, distance the mean over hits), downsampled to M as the capture does,
// SH9 from the R × R faces.
Probe capture(const std::vector<Patch>& scene, glm::vec3 position, int r, int m) {
    std::vector<glm::vec3> radiance(size_t(6) * r * r);
    std::vector<float> distance(size_t(6) * r * r);
    for (int f = 0; f < 6; ++f)
        for (int j = 0; j < r; ++j)
            for (int i = 0; i < r; ++i) {
                glm::vec3 l(0.0f);
                double sum = 0.0;
                int hits = 0;
                for (int s = 0; s < 4; ++s) {
                    const glm::vec3 d =
                        cube_direction(f, (i + 0.25f + 0.5f * (s % 2)) / r, (j + 0.25f + 0.5f * (s / 2)) / r);
                    const Hit h = cast(scene, position, d);
                    l += h.radiance * 0.25f;
                    if (h.t > 0.0f) {
                        sum += h.t;
                        ++hits;
                    }
                }
                radiance[(size_t(f) * r + j) * r + i] = l;
                distance[(size_t(f) * r + j) * r + i] = hits ? float(sum / hits) : kMissDistance;
            }
    Probe p;
    p.position = position;
    downsample_faces(r, radiance, distance, m, p.radiance, p.distance);
    p.sh9 = project_cube_to_sh9(r, radiance);
    // Each grid corner's own ray, as probe_corners.comp traces it.
    for (int f = 0; f < 6; ++f)
        for (int b = 0; b <= m; ++b)
            for (int a = 0; a <= m; ++a) {
                const Hit h = cast(scene, position, cube_direction(f, float(a) / m, float(b) / m));
                p.corner_distance.push_back(h.t > 0.0f ? h.t : kMissDistance);
            }
    // And each texel's centre ray (probe_corners.comp with LF_TEXEL_CENTRES).
    for (int f = 0; f < 6; ++f)
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                const Hit h = cast(scene, position, cube_direction(f, (i + 0.5f) / m, (j + 0.5f) / m));
                p.centre_distance.push_back(h.t > 0.0f ? h.t : kMissDistance);
            }
    return p;
}

ProbeSet one_probe_set(const Probe& p, int r, int m) {
    ProbeSet set;
    set.m = m;
    set.capture_resolution = r;
    set.probes = {p};
    return set;
}

// The six inner walls of the box [lo, hi], radiance per wall (+X, -X, +Y, -Y, +Z, -Z).
std::vector<Patch> box(glm::vec3 lo, glm::vec3 hi, const std::array<glm::vec3, 6>& l) {
    const glm::vec3 s = hi - lo;
    return {{{hi.x, lo.y, lo.z}, {0, s.y, 0}, {0, 0, s.z}, l[0]}, {{lo.x, lo.y, lo.z}, {0, s.y, 0}, {0, 0, s.z}, l[1]},
            {{lo.x, hi.y, lo.z}, {s.x, 0, 0}, {0, 0, s.z}, l[2]}, {{lo.x, lo.y, lo.z}, {s.x, 0, 0}, {0, 0, s.z}, l[3]},
            {{lo.x, lo.y, hi.z}, {s.x, 0, 0}, {0, s.y, 0}, l[4]}, {{lo.x, lo.y, lo.z}, {s.x, 0, 0}, {0, s.y, 0}, l[5]}};
}

// Exact irradiance / π at (x, n) from uniformly radiating patches that x sees
// unoccluded (a convex room around x): Σ L · F, each patch clipped to the horizon.
glm::vec3 exact_irradiance(const std::vector<Patch>& scene, glm::vec3 x, glm::vec3 n) {
    glm::vec3 e(0.0f);
    for (const Patch& p : scene) {
        const std::array<glm::vec3, 4> c = {p.origin, p.origin + p.e1, p.origin + p.e1 + p.e2, p.origin + p.e2};
        const float f = std::abs(clipped_polygon_to_point_form_factor(x, n, c.data(), 4));
        const bool facing = !p.one_sided || glm::dot(glm::cross(p.e1, p.e2), x - p.origin) > 0.0f;
        if (facing) e += p.radiance * f;
    }
    return e;
}

float relative_error(glm::vec3 estimate, glm::vec3 exact) {
    return glm::length(estimate - exact) / std::max(glm::length(exact), 1e-12f);
}

glm::vec3 random_direction(std::mt19937& rng) {
    std::normal_distribution<float> g;
    return glm::normalize(glm::vec3(g(rng), g(rng), g(rng)));
}

const char* kNames[4] = {"sh9", "point_to_point", "polygon_to_point", "ddgi"};
glm::vec3 pick(const ProbeEvaluation& e, int k) {
    return k == 0 ? e.sh9 : k == 1 ? e.point_to_point : k == 2 ? e.polygon_to_point : e.ddgi;
}

// Furnace: a closed box of uniform radiance L; the exact irradiance / π is L at
// any point and normal inside. Random points at least 0.1 from the walls.
TEST(ProbeEstimators, FurnaceBoxUniformRadiance) {
    const glm::vec3 lo(-1.0f, -0.6f, -0.8f), hi(1.2f, 0.9f, 0.7f), L(0.8f, 0.5f, 0.3f);
    const std::vector<Patch> scene = box(lo, hi, {L, L, L, L, L, L});
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<std::pair<glm::vec3, glm::vec3>> points;
    for (int i = 0; i < 200; ++i)
        points.push_back({lo + 0.1f + (hi - lo - 0.2f) * glm::vec3(u(rng), u(rng), u(rng)), random_direction(rng)});
    std::printf("  furnace box, %zu points >= 0.1 m from the walls: max | mean relative error\n", points.size());
    std::printf("  %3s %18s %18s %18s %18s %18s\n", "M", "sh9", "point_to_point", "polygon_to_point", "(paper's clamp)",
                "ddgi");
    float worst[4][5] = {}, mean_of[4][5] = {};
    for (int mi = 0; mi < 4; ++mi) {
        const int m = 1 << mi;
        const ProbeSet set = one_probe_set(capture(scene, {0.05f, 0.1f, -0.1f}, 32, m), 32, m);
        ProbeEvalOptions paper;
        paper.clip_to_horizon = false;
        const ProbeEvaluator eval(set), clamped(set, paper);
        float max_err[5] = {}, mean_err[5] = {};
        for (const auto& [x, n] : points) {
            const ProbeEvaluation e = eval.evaluate(x, n);
            for (int k = 0; k < 5; ++k) {
                const glm::vec3 v = k < 4 ? pick(e, k) : clamped.evaluate(x, n).polygon_to_point;
                const float err = relative_error(v, L);
                max_err[k] = std::max(max_err[k], err);
                mean_err[k] += err / points.size();
            }
        }
        std::printf("  %3d", m);
        for (int k : {0, 1, 2, 4, 3}) std::printf("   %7.4f | %6.4f", max_err[k], mean_err[k]);
        std::printf("\n");
        for (int k = 0; k < 5; ++k) {
            worst[mi][k] = max_err[k];
            mean_of[mi][k] = mean_err[k];
        }
    }
    for (int mi = 0; mi < 4; ++mi) {
        EXPECT_LT(worst[mi][0], 1e-4) << "sh9 of a constant is exact";
        EXPECT_LT(worst[mi][3], 1e-4) << "the convolved texels of a constant are exact";
    }
    // Measured (max | mean over the points, probe off-centre in a 2.2 x 1.5 x 1.5 box),
    // corners traced, a point beyond a chord polygon moved just inside it
    // (probe_point_inside):
    //   polygon_to_point (clipped, signed):   0.0000|0.0000 at every M;
    //   the paper's clamp:                    M=1 0.63|0.27, 2 0.62|0.15, 4 0.26|0.060, 8 0.19|0.019.
    // (Before points were moved: clamp M=1 0.89|0.31, 2 0.81|0.17, 4
    // 0.48|0.061, 8 0.19|0.019; clipped M=1 1.00|0.17, 2 1.00|0.084, 4
    // 0.48|0.0024, 8 0.0000. A texel whose corners land on two or three walls
    // is a chord across the room's edge or corner, and a point between it and
    // the walls was outside the polygons' polyhedron; with corners from the
    // texels' depths, before corners were traced: clamp M=1 0.73|0.27, 2
    // 0.64|0.15, 4 0.46|0.067, 8 0.21|0.019.) Clipped polygons tile the
    // sphere around a point inside, so they are exact; the clamp loses the
    // above-horizon part of texels whose sum goes negative (random normals
    // here; tangent to a wall a few cm away it loses most).
    // Bounds: the measurements + ~15%.
    const float clamp_max[4] = {0.73f, 0.71f, 0.3f, 0.22f}, clamp_mean[4] = {0.32f, 0.18f, 0.07f, 0.022f};
    for (int mi = 0; mi < 4; ++mi) {
        EXPECT_LT(worst[mi][2], 1e-3f) << "M = " << (1 << mi);
        EXPECT_LT(worst[mi][4], clamp_max[mi]) << "M = " << (1 << mi);
        EXPECT_LT(mean_of[mi][4], clamp_mean[mi]) << "M = " << (1 << mi);
    }
}

// The furnace at a room's edges and corners (issue #34): the box [-1, 1]³
// of uniform radiance L = 1, so irradiance / π is 1 at every point and normal
// inside. Probes at the centre (its cube's edges point at the room's edges,
// so every texel polygon lies on one wall) and at two points off it (the
// capture test's, and one low in the room), whose texels see the room's edges
// cross them: such a texel's corners land on two or three walls, and its
// polygon is a chord across the edge. Points 1 cm and 10 cm from one, two and
// three walls, near all four of the room's edges they are near, each with the
// normal of every wall within 15 cm (into the room) and its opposite.
struct EdgePoint {
    const char* name;
    glm::vec3 x;
};

std::vector<EdgePoint> room_edge_points() {
    std::vector<EdgePoint> out;
    for (const glm::vec3 s : {glm::vec3(1, -1, 1), glm::vec3(-1, -1, -1), glm::vec3(1, 1, -1), glm::vec3(-1, 1, 1)}) {
        out.push_back({"1 cm from a wall", s * glm::vec3(0.99f, 0.3f, -0.4f)});
        out.push_back(
            {"1 cm above the floor or below the ceiling, 10 cm from two walls", s * glm::vec3(0.9f, 0.99f, 0.9f)});
        out.push_back({"1 cm from two walls", s * glm::vec3(0.99f, 0.99f, 0.2f)});
        out.push_back({"1 cm from three", s * glm::vec3(0.99f)});
        out.push_back({"10 cm from three", s * glm::vec3(0.9f)});
    }
    return out;
}

std::vector<glm::vec3> wall_normals(glm::vec3 x) {
    std::vector<glm::vec3> out;
    for (int a = 0; a < 3; ++a) {
        if (std::abs(x[a]) < 0.85f) continue;
        glm::vec3 n(0.0f);
        n[a] = x[a] > 0.0f ? -1.0f : 1.0f;
        out.push_back(n);
        out.push_back(-n);
    }
    return out;
}

TEST(ProbeEstimators, FurnaceHoldsAtTheRoomsEdgesAndCorners) {
    const glm::vec3 L(1.0f);
    const std::vector<Patch> scene = box(glm::vec3(-1.0f), glm::vec3(1.0f), {L, L, L, L, L, L});
    std::printf("  furnace [-1, 1]³, %zu points 1-10 cm from walls: worst relative error\n", room_edge_points().size());
    std::printf("  %3s %22s %10s %12s %18s %8s\n", "M", "probe", "clipped", "the clamp", "clamp, 1 wall", "moved");
    float clipped_worst = 0, one_wall_worst = 0, clamp_at_centre = 0;
    int moved = 0;
    for (const int m : {4, 8})
        for (const glm::vec3 probe : {glm::vec3(0.0f), glm::vec3(0.5f, 0.2f, -0.3f), glm::vec3(-0.3f, -0.6f, 0.4f)}) {
            const PreparedProbe p = prepare_probe(capture(scene, probe, 4 * m, m), m);
            float clipped = 0, clamp = 0, one_wall = 0;
            int moved_here = 0;
            for (const EdgePoint& e : room_edge_points()) {
                moved_here += probe_point_inside(p, e.x) != e.x;
                for (const glm::vec3& n : wall_normals(e.x)) {
                    clipped = std::max(clipped, relative_error(probe_polygon_to_point(p, e.x, n), L));
                    const float c = relative_error(probe_polygon_to_point(p, e.x, n, false), L);
                    clamp = std::max(clamp, c);
                    if (e.name == std::string("1 cm from a wall")) one_wall = std::max(one_wall, c);
                }
            }
            std::printf("  %3d   (%5.2f %5.2f %5.2f) %10.4f %12.4f %18.4f %5d/%zu\n", m, probe.x, probe.y, probe.z,
                        clipped, clamp, one_wall, moved_here, room_edge_points().size());
            clipped_worst = std::max(clipped_worst, clipped);
            one_wall_worst = std::max(one_wall_worst, one_wall);
            if (probe == glm::vec3(0.0f)) clamp_at_centre = std::max(clamp_at_centre, clamp);
            if (probe != glm::vec3(0.0f)) moved += moved_here;
        }
    // A point between a chord polygon and the room's edge is outside the
    // polygons' polyhedron, where their form factors cancel: before
    // probe_point_inside, the clipped estimate was off by up to 0.76 at the
    // off-centre probes (0.74 1 cm from three walls, 0.72 1 cm above the
    // floor 10 cm from two walls, 0.52 1 cm from two walls; exact at the
    // centre). Measured now: clipped <= 0.0055 everywhere (M 4 and 8).
    EXPECT_GT(moved, 0) << "no point lay beyond a chord: the case is not tried";
    EXPECT_LT(clipped_worst, 0.02f) << "Le / (1 - rho) within 2% as close as 1 cm to a wall";
    // The paper's clamp (max(F, 0) per texel) loses a texel's part above the
    // tangent plane when the part below is larger; a point 1 cm from one wall
    // keeps it (measured <= 0.010), but 1 cm from a second wall, with the
    // first wall's normal, that wall's texels straddle the plane beside x:
    // even at the centre probe, with no chord anywhere, it loses up to 0.53
    // (0.60 at the others). Clipping is exact there.
    EXPECT_LT(one_wall_worst, 0.02f);
    EXPECT_GT(clamp_at_centre, 0.3f) << "the paper's clamp near two walls: if this holds now, say so in BENCHMARKS";
}

// The furnace with things in the room (issue #34): a block on the floor and
// a shelf (two-sided) in the box [-1, 1]³, all of radiance 1, so irradiance /
// π is 1 at every point and normal the probe sees. The probe, low beside the
// block, sees the block's sides and the shelf's underside with the walls
// behind them: texels across their edges join them to the walls behind, and
// from a point beside the block those texels face away. Points: a grid in
// front of the block's face 1 and 5 cm from it (its contact shadow, the
// Cornell sweep's case), each with the normals towards the block, up and
// away, and random points the probe sees with random normals. Measured
// worst, near the block | random, M 4 and 8: lightfarm's signed sum of
// clipped triangles 0.0000 | 0.0000; the same with each texel clamped at 0
// (as before), 0.31 | 0.095 at M 4 (it counts the wall behind the block as
// well as the block); the paper's clamp 0.40 | 0.50 and 0.39 | 0.43.
TEST(ProbeEstimators, FurnaceHoldsBesideThingsInTheRoom) {
    const glm::vec3 L(1.0f), probe(-0.2f, -0.75f, 0.6f);
    std::vector<Patch> scene = box(glm::vec3(-1.0f), glm::vec3(1.0f), {L, L, L, L, L, L});
    const glm::vec3 lo(0.2f, -1.0f, -0.3f), hi(0.6f, -0.5f, 0.1f), s = hi - lo;
    for (const Patch& p : std::vector<Patch>{{{lo.x, hi.y, lo.z}, {s.x, 0, 0}, {0, 0, s.z}, L},       // top
                                             {{lo.x, lo.y, lo.z}, {0, s.y, 0}, {0, 0, s.z}, L},       // -x
                                             {{hi.x, lo.y, lo.z}, {0, s.y, 0}, {0, 0, s.z}, L},       // +x
                                             {{lo.x, lo.y, lo.z}, {s.x, 0, 0}, {0, s.y, 0}, L},       // -z
                                             {{lo.x, lo.y, hi.z}, {s.x, 0, 0}, {0, s.y, 0}, L},       // +z
                                             {{-0.8f, 0.3f, -0.5f}, {0.6f, 0, 0}, {0, 0, 1.0f}, L}})  // the shelf
        scene.push_back(p);
    std::vector<std::pair<glm::vec3, glm::vec3>> points;
    for (const float gap : {0.01f, 0.05f})
        for (const float x : {0.25f, 0.4f, 0.55f})
            for (const float y : {-0.98f, -0.9f, -0.7f})
                for (const glm::vec3 n : {glm::vec3(0, 0, -1), glm::vec3(0, 1, 0), glm::vec3(0, 0, 1)})
                    points.push_back({{x, y, hi.z + gap}, n});
    const size_t near_block = points.size();
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(0.05f, 0.99f);
    while (points.size() < near_block + 200) {
        const glm::vec3 d = random_direction(rng);
        const Hit h = cast(scene, probe, d);
        if (h.t > 0.0f) points.push_back({probe + d * h.t * u(rng), random_direction(rng)});
    }
    std::printf("  furnace with a block and a shelf: worst relative error (near the block | random points)\n");
    for (const int m : {4, 8}) {
        const PreparedProbe p = prepare_probe(capture(scene, probe, 4 * m, m), m);
        float signed_worst[2] = {}, paper_worst[2] = {};
        for (size_t k = 0; k < points.size(); ++k) {
            const auto& [x, n] = points[k];
            const int set = k < near_block ? 0 : 1;
            signed_worst[set] = std::max(signed_worst[set], relative_error(probe_polygon_to_point(p, x, n), L));
            paper_worst[set] = std::max(paper_worst[set], relative_error(probe_polygon_to_point(p, x, n, false), L));
        }
        std::printf("  M %d: signed, clipped %.4f | %.4f   the paper's clamp %.4f | %.4f\n", m, signed_worst[0],
                    signed_worst[1], paper_worst[0], paper_worst[1]);
        EXPECT_LT(std::max(signed_worst[0], signed_worst[1]), 0.02f) << "M = " << m;
    }
}

// probe_point_inside's three cases, in the box [-1, 1]³ from (0.5, 0.2,
// -0.3), M = 4: a point 1 cm above the floor 10 cm from two walls lies
// beyond the chord of the texel that sees that edge, and moves along the line
// from the probe to just inside it (the polygon's plane, so the move is the
// chord's gap); a point 3 m beyond a wall (more than the polygon's diagonal)
// and a point in a probe read without traced corners stay where they are.
TEST(ProbeEstimators, APointBeyondAChordMovesJustInsideIt) {
    const glm::vec3 L(1.0f), probe(0.5f, 0.2f, -0.3f);
    const std::vector<Patch> scene = box(glm::vec3(-1.0f), glm::vec3(1.0f), {L, L, L, L, L, L});
    Probe captured = capture(scene, probe, 16, 4);
    const PreparedProbe p = prepare_probe(captured, 4);
    const glm::vec3 x(0.9f, -0.99f, 0.9f), moved = probe_point_inside(p, x);
    const glm::vec3 along = glm::normalize(x - probe);
    EXPECT_LT(glm::length(glm::cross(moved - probe, along)), 1e-5f) << "on the line from the probe to x";
    const float gap = glm::length(x - moved);
    // Measured 0.20 m: at M = 4 that texel's chord passes 0.2 m short of the edge along this line.
    EXPECT_GT(gap, 0.005f);
    EXPECT_LT(gap, 0.25f);
    for (int a = 0; a < 3; ++a) EXPECT_LT(std::abs(moved[a]), 1.0f) << "inside the room";
    std::printf("  1 cm above the floor 10 cm from two walls: moved %.4f m towards the probe\n", gap);
    // Beyond a wall by more than its polygon's diagonal: behind a surface, left.
    EXPECT_EQ(probe_point_inside(p, glm::vec3(4.0f, 0.2f, -0.3f)), glm::vec3(4.0f, 0.2f, -0.3f));
    // Inside the polygons: left.
    EXPECT_EQ(probe_point_inside(p, glm::vec3(0.2f, 0.1f, 0.1f)), glm::vec3(0.2f, 0.1f, 0.1f));
    // No traced corners (a file from before they were): no polygon is known to lie on the walls.
    captured.corner_distance.clear();
    EXPECT_EQ(probe_point_inside(prepare_probe(captured, 4), x), x);
}

// The paper's experiment: points moving from the reference point to a wall,
// normals facing it, in the furnace box. Polygon-to-point stays bounded;
// point-to-point blows up in front of a virtual light.
TEST(ProbeEstimators, ApproachingAWallPolygonToPointStaysPointToPointBlowsUp) {
    const glm::vec3 lo(-1.0f), hi(1.0f), L(1.0f);
    const std::vector<Patch> scene = box(lo, hi, {L, L, L, L, L, L});
    const int m = 4;
    const ProbeSet set = one_probe_set(capture(scene, glm::vec3(0.0f), 32, m), 32, m);
    const PreparedProbe prepared = prepare_probe(set.probes[0], m);
    // Towards the virtual light of +X's texel (1, 1) (a texel centre, not a corner).
    const glm::vec3 light = prepared.texels[set.texel(0, 1, 1)].centre;
    std::printf("  furnace box, M = 4: x -> the +X wall in front of a virtual light (%.3f, %.3f, %.3f), n = +X\n",
                light.x, light.y, light.z);
    std::printf("  %8s %10s %15s %17s %10s\n", "gap", "sh9", "point_to_point", "polygon_to_point", "ddgi");
    float p2p_far = 0, p2p_near = 0, poly_worst = 0;
    for (const float gap : {0.9f, 0.5f, 0.2f, 0.1f, 0.05f, 0.02f, 0.01f, 0.005f}) {
        const glm::vec3 x(1.0f - gap, light.y, light.z);
        const ProbeEvaluation e = evaluate(set, x, {1, 0, 0});
        std::printf("  %8.3f", gap);
        for (int k = 0; k < 4; ++k)
            std::printf(" %*.4f", k == 0 ? 10 : k == 1 ? 15 : k == 2 ? 17 : 10, relative_error(pick(e, k), L));
        std::printf("\n");
        if (gap == 0.9f) p2p_far = relative_error(e.point_to_point, L);
        if (gap == 0.005f) p2p_near = relative_error(e.point_to_point, L);
        poly_worst = std::max(poly_worst, relative_error(e.polygon_to_point, L));
    }
    EXPECT_LT(p2p_far, 0.1f) << "point-to-point is fine far from the wall";
    // Measured: point-to-point 0.019 at 0.9 m, 1.1 at 0.2 m, 6.7 at 0.1 m, 190 at 2 cm, 3058 at 5 mm
    // (∝ 1/gap²: the virtual light lies on the wall); polygon-to-point <= 0.039 all the way.
    EXPECT_GT(p2p_near, 300.0f) << "point-to-point must blow up in front of a virtual light";
    EXPECT_LT(poly_worst, 0.05f) << "polygon-to-point stays bounded at the wall";
}

// A coloured box: sh9 (irradiance at the reference point only) drifts as x
// moves away from it; polygon-to-point follows.
TEST(ProbeEstimators, ColouredBoxSh9DriftsWithDistanceFromTheProbe) {
    const glm::vec3 lo(-1.0f), hi(1.0f);
    const std::vector<Patch> scene = box(lo, hi,
                                         {glm::vec3(2, 0.1f, 0.1f), glm::vec3(0.1f, 2, 0.1f), glm::vec3(1.5f),
                                          glm::vec3(0.2f), glm::vec3(0.1f, 0.1f, 1.5f), glm::vec3(0.5f)});
    const int m = 4;
    const ProbeSet set = one_probe_set(capture(scene, glm::vec3(0.0f), 64, m), 64, m);
    const ProbeEvaluator eval(set);
    std::mt19937 rng(9);
    std::printf("  coloured box, M = 4: mean relative error over 40 normals at distance s from the probe\n");
    std::printf("  %6s %10s %15s %17s %10s\n", "s", "sh9", "point_to_point", "polygon_to_point", "ddgi");
    float sh_near = 0, sh_far = 0, poly_worst = 0;
    for (const float s : {0.0f, 0.2f, 0.4f, 0.6f, 0.8f}) {
        float err[4] = {};
        for (int i = 0; i < 40; ++i) {
            const glm::vec3 n = random_direction(rng);
            const glm::vec3 x = s * random_direction(rng) * glm::vec3(1.0f);
            const glm::vec3 exact = exact_irradiance(scene, x, n);
            const ProbeEvaluation e = eval.evaluate(x, n);
            for (int k = 0; k < 4; ++k) err[k] += relative_error(pick(e, k), exact) / 40;
        }
        std::printf("  %6.2f %10.4f %15.4f %17.4f %10.4f\n", s, err[0], err[1], err[2], err[3]);
        if (s == 0.0f) sh_near = err[0];
        if (s == 0.8f) sh_far = err[0];
        poly_worst = std::max(poly_worst, err[2]);
    }
    // Measured mean errors, s = 0 .. 0.8: sh9 0.0023 0.067 0.14 0.21 0.28; point_to_point
    // 0.0044 .. 0.060; polygon_to_point 0.013 .. 0.029; ddgi (one probe) as sh9.
    EXPECT_LT(sh_near, 0.01f) << "SH9 is close at the reference point (band-limiting only)";
    EXPECT_GT(sh_far, 0.2f) << "SH9 must drift away from the reference point";
    EXPECT_LT(poly_worst, 0.045f);
}

// A probe between a black floor and a parallel rectangular emitter facing it:
// points on the floor have irradiance / π = L · F(point -> rectangle).
TEST(ProbeEstimators, EmitterOverFloorMatchesTheRectangleFormFactor) {
    const glm::vec3 L(3.0f);
    const float h = 1.0f;
    const std::vector<Patch> scene = {
        {{-10, 0, -10}, {0, 0, 20}, {20, 0, 0}, glm::vec3(0.0f)},  // floor, black
        {{-0.5f, h, -0.75f}, {1, 0, 0}, {0, 0, 1.5f}, L, true},    // emitter, facing down (cross = -y)
    };
    std::vector<glm::vec3> points;
    for (const float px : {0.0f, 0.2f, 0.4f})
        for (const float pz : {0.0f, 0.3f, 0.6f}) points.push_back({px, 0.0f, pz});
    std::printf(
        "  emitter 1 x 1.5 m at 1 m over a black floor, probe at 0.5 m: %zu points on the floor, "
        "max | mean relative error\n",
        points.size());
    std::printf("  %3s %18s %18s %18s %18s\n", "M", "sh9", "point_to_point", "polygon_to_point", "ddgi");
    float poly[4] = {};
    for (int mi = 0; mi < 4; ++mi) {
        const int m = 1 << mi;
        const ProbeSet set = one_probe_set(capture(scene, {0.0f, 0.5f, 0.0f}, 64, m), 64, m);
        const ProbeEvaluator eval(set);
        float max_err[4] = {}, mean_err[4] = {};
        for (const glm::vec3& x : points) {
            const glm::vec3 exact = L * float(parallel_rect(-0.5 - x.x, 0.5 - x.x, -0.75 - x.z, 0.75 - x.z, h));
            const ProbeEvaluation e = eval.evaluate(x, {0, 1, 0});
            for (int k = 0; k < 4; ++k) {
                const float err = relative_error(pick(e, k), exact);
                max_err[k] = std::max(max_err[k], err);
                mean_err[k] += err / points.size();
            }
        }
        std::printf("  %3d", m);
        for (int k = 0; k < 4; ++k) std::printf("   %7.4f | %6.4f", max_err[k], mean_err[k]);
        std::printf("\n");
        poly[mi] = max_err[2];
    }
    // Measured max | mean relative error of polygon_to_point over the points,
    // corners traced, a corner past the emitter's edge on its plane continued
    // (probe_corner_distances), a point beyond a chord moved inside it
    // (probe_point_inside): M=1 0.14|0.12 (0.31|0.18 before that), 2
    // 0.037|0.023, 4 0.21|0.14, 8 0.024|0.011 (8 was 0.071|0.047 with that
    // corner from the texels' depths)
    // (from the texels' depths, before: M=1 0.76|0.49, 2 0.27|0.16, 4
    // 0.16|0.098, 8 0.079|0.051). What is left is the emitter's edges blurred
    // over one texel: edge texels hold the covered fraction of L over the
    // whole texel's polygon, which M = 2 happens to align with here.
    // sh9 and one-probe ddgi are off by up to 2.1x: the probe, halfway up,
    // sees the emitter much larger than the floor does. Bounds: measured + ~15%.
    EXPECT_LT(poly[0], 0.17f);
    EXPECT_LT(poly[1], 0.043f);
    EXPECT_LT(poly[2], 0.24f);
    EXPECT_LT(poly[3], 0.028f);
}

// ----------------------------------------------------------- sets ----

TEST(ProbeSets, GridBlendingUsesValidProbesOnly) {
    const glm::vec3 lo(-2.0f), hi(2.0f), L(0.6f);
    const std::vector<Patch> scene = box(lo, hi, {L, L, L, L, L, L});
    ProbeSet set;
    set.m = 2;
    set.capture_resolution = 16;
    for (int z = 0; z < 2; ++z)
        for (int y = 0; y < 2; ++y)
            for (int x = 0; x < 2; ++x) set.probes.push_back(capture(scene, glm::vec3(x, y, z) - 0.5f, 16, 2));
    // One probe invalid, with nonsense in it: it must not be used.
    set.probes[3].valid = false;
    for (glm::vec3& l : set.probes[3].radiance) l = glm::vec3(100.0f);
    set.probes[3].sh9[0] = glm::vec3(100.0f);
    const ProbeEvaluator eval(set);
    EXPECT_TRUE(eval.is_grid());
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-0.9f, 0.9f);
    for (int i = 0; i < 20; ++i) {
        const glm::vec3 x(u(rng), u(rng), u(rng)), n = random_direction(rng);
        float total = 0.0f;
        for (const auto& [k, w] : eval.weights(x)) {
            EXPECT_NE(k, 3);
            total += w;
        }
        EXPECT_NEAR(total, 1.0f, 1e-5f);
        const ProbeEvaluation e = eval.evaluate(x, n);
        EXPECT_LT(relative_error(e.sh9, L), 1e-4f);
        EXPECT_LT(relative_error(e.ddgi, L), 1e-4f);
        EXPECT_LT(relative_error(e.polygon_to_point, L), 0.35f);
    }
    // At a lattice point, that probe alone.
    const auto at = eval.weights(set.probes[5].position);
    ASSERT_EQ(at.size(), 1u);
    EXPECT_EQ(at[0].first, 5);
    // A moved probe: no lattice; inverse-distance weights over the valid probes.
    set.probes[0].position += glm::vec3(0.1f, 0.05f, 0.0f);
    const ProbeEvaluator moved(set);
    EXPECT_FALSE(moved.is_grid());
    float total = 0.0f;
    for (const auto& [k, w] : moved.weights({0.1f, 0.2f, 0.3f})) {
        EXPECT_NE(k, 3);
        total += w;
    }
    EXPECT_NEAR(total, 1.0f, 1e-5f);
    // No valid probe: refused.
    for (Probe& p : set.probes) p.valid = false;
    EXPECT_THROW(ProbeEvaluator{set}, std::invalid_argument);
}

TEST(ProbeSets, DdgiVisibilityDownweightsAProbeBehindAWall) {
    // Two probes either side of a wall at x = 0; a point on the +x side sees
    // only the +x probe's surfaces. The -x probe's distance towards the point
    // is the wall's, so Chebyshev gives it little weight.
    const glm::vec3 dark(0.1f), bright(1.0f);
    std::vector<Patch> left = box({-2, -1, -1}, {0, 1, 1}, {dark, dark, dark, dark, dark, dark});
    std::vector<Patch> right = box({0, -1, -1}, {2, 1, 1}, {bright, bright, bright, bright, bright, bright});
    ProbeSet set;
    set.m = 4;
    set.capture_resolution = 16;
    set.probes = {capture(left, {-1, 0, 0}, 16, 4), capture(right, {1, 0, 0}, 16, 4)};
    const ProbeEvaluator eval(set);
    const glm::vec3 x(0.3f, 0.0f, 0.0f);
    const PreparedProbe l = prepare_probe(set.probes[0], 4), r = prepare_probe(set.probes[1], 4);
    EXPECT_LT(ddgi_probe_weight(l, x, {0, 1, 0}), 0.01f * ddgi_probe_weight(r, x, {0, 1, 0}));
    const ProbeEvaluation e = eval.evaluate(x, {0, 1, 0});
    EXPECT_LT(relative_error(e.ddgi, bright), 0.02f);
    // The other estimators blend only the probes that see x (probe_sees):
    // the plain blend mixed in the dark room (sh9 0.55 of the truth).
    EXPECT_TRUE(probe_sees(r, x));
    EXPECT_FALSE(probe_sees(l, x));
    EXPECT_LT(relative_error(e.sh9, bright), 1e-4f);
    EXPECT_LT(relative_error(e.polygon_to_point, bright), 1e-4f);
}

// Issue #52's thin wall: a closed lit room x in [-1, w] whose ceiling
// emits 1 and a closed dark room x in [w + t, 1], every other surface black.
struct ThinWall {
    std::vector<Patch> lit, scene;
};
ThinWall thin_wall(float w, float t) {
    const glm::vec3 black(0.0f), light(1.0f);
    ThinWall rooms;
    rooms.lit = box({-1, 0, -0.5f}, {w, 1, 0.5f}, {black, black, light, black, black, black});
    const std::vector<Patch> dark = box({w + t, 0, -0.5f}, {1, 1, 0.5f}, {black, black, black, black, black, black});
    rooms.scene = rooms.lit;
    rooms.scene.insert(rooms.scene.end(), dark.begin(), dark.end());
    return rooms;
}

// The default grid over those rooms' bounds (a quarter of the largest
// extent: 0.5 m, 4 x 2 x 2 cell centres, as ProbesMethod::place puts it).
const glm::ivec3 kThinWallGrid(4, 2, 2);
const glm::vec3 kThinWallOrigin(-0.75f, 0.25f, -0.25f);
constexpr float kThinWallSpacing = 0.5f;
ProbeSet thin_wall_probes(const ThinWall& rooms, int r, int m) {
    ProbeSet set;
    set.m = m;
    set.capture_resolution = r;
    for (int z = 0; z < kThinWallGrid.z; ++z)
        for (int y = 0; y < kThinWallGrid.y; ++y)
            for (int x = 0; x < kThinWallGrid.x; ++x)
                set.probes.push_back(
                    capture(rooms.scene, kThinWallOrigin + kThinWallSpacing * glm::vec3(x, y, z), r, m));
    return set;
}

// A thin wall (issue #52): a closed lit room x in [-1, w], its ceiling
// emitting 1, and a closed dark room x in [w + t, 1] beside it, every other
// surface black, probes on the default grid (a quarter of the largest
// extent: 4 x 2 x 2 cell centres), R 32, M 8. Only direct light, so the
// truth is Lambert's formula of the ceiling on the lit side and exactly 0 on
// the dark side. Drawn over wall positions, thicknesses 1 mm-10 cm, points
// 1 mm-1 m from the wall and 1 mm-1 m above the floor, normals up, towards
// the wall, away from it and at random; the seed is printed. Errors on the
// issue's scale: |estimate - truth| / max(truth, 10% of the brightest truth).
// Before visibility (probes blended whether they saw the point or not) the
// dark side read 11-69% of the lit side; now it reads 0 wherever a probe
// of the dark room sees the point, which at this grid is everywhere.
TEST(ProbeVisibility, NoLightThroughAThinWall) {
    std::mt19937 rng = test::family_rng(52);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    const auto log_uniform = [&](float lo, float hi) { return lo * std::pow(hi / lo, u(rng)); };
    std::vector<double> dark_errors, lit_errors;
    double worst_dark = 0.0;
    for (int config = 0; config < 12; ++config) {
        const float w = -0.2f + 0.3f * u(rng), t = log_uniform(0.001f, 0.1f);
        const ThinWall rooms = thin_wall(w, t);
        const std::vector<Patch>& lit = rooms.lit;
        const ProbeSet set = thin_wall_probes(rooms, 32, 8);
        const ProbeEvaluator eval(set);
        // The brightest truth: under the ceiling's centre, facing up, on the floor.
        const double brightest = exact_irradiance(lit, {(w - 1.0f) / 2.0f, 0.0f, 0.0f}, {0, 1, 0}).g;
        for (int i = 0; i < 40; ++i) {
            const float gap = log_uniform(0.001f, 1.0f), height = log_uniform(0.001f, 0.999f);
            const float z = -0.499f + 0.998f * u(rng);
            const glm::vec3 normals[4] = {{0, 1, 0}, {-1, 0, 0}, {1, 0, 0}, random_direction(rng)};
            const glm::vec3 n = normals[i % 4];
            const glm::vec3 dark_x(std::min(w + t + gap, 0.999f), height, z),
                lit_x(std::max(w - gap, -0.999f), height, z);
            const double dark_reading = eval.evaluate(dark_x, n).polygon_to_point.g;
            dark_errors.push_back(std::abs(dark_reading) / (0.1 * brightest));
            worst_dark = std::max(worst_dark, dark_reading / brightest);
            const double truth = exact_irradiance(lit, lit_x, n).g;
            lit_errors.push_back(std::abs(eval.evaluate(lit_x, n).polygon_to_point.g - truth) /
                                 std::max(truth, 0.1 * brightest));
        }
    }
    const auto p95_and_worst = [](std::vector<double> e) {
        std::sort(e.begin(), e.end());
        return std::pair{e[size_t(0.95 * double(e.size() - 1))], e.back()};
    };
    const auto [dark_p95, dark_worst] = p95_and_worst(dark_errors);
    const auto [lit_p95, lit_worst] = p95_and_worst(lit_errors);
    std::printf("  dark side: p95 %.4f, worst %.4f (of 10%% of the brightest); worst reading %.5f of the brightest\n",
                dark_p95, dark_worst, worst_dark);
    std::printf("  lit side: p95 %.4f, worst %.4f\n", lit_p95, lit_worst);
    // The dark side reads at most 2% of the lit side's brightest at every
    // distance (the issue's bar); measured 0 at every point.
    EXPECT_LE(worst_dark, 0.02);
    EXPECT_LE(dark_p95, 0.05);
    EXPECT_LE(dark_worst, 0.10);
    // The lit side is the estimator's own accuracy, which visibility does not
    // change: measured p95 0.072; its worst (1.9) is a point 1 cm under the
    // emitter beside the wall, the polygons near an emitter's edge (issue #52's
    // other items).
    EXPECT_LE(lit_p95, 0.10);
}

// A 1 x 1 m one-sided emitter of radiance 2 facing down, tilted by `tilt`
// about the horizontal `axis`, centred at `centre`, over a black 4 x 4 m
// floor at y = 0; the emitter is the last patch.
std::vector<Patch> tilted_emitter_over_a_floor(float tilt, glm::vec3 axis, glm::vec3 centre) {
    const glm::mat3 turn = glm::mat3(glm::rotate(glm::mat4(1.0f), tilt, glm::normalize(axis)));
    const glm::vec3 e1 = turn * glm::vec3(1, 0, 0), e2 = turn * glm::vec3(0, 0, 1);
    return {{{-2, 0, -2}, {4, 0, 0}, {0, 0, 4}, glm::vec3(0.0f)},
            {centre - 0.5f * e1 - 0.5f * e2, e1, e2, glm::vec3(2.0f), true}};  // front: cross(e1, e2), down
}

// A tilted emitter (issue #52): a 1 x 1 m one-sided emitter of radiance 2
// facing down, tilted by a drawn angle about a drawn horizontal axis, its
// centre 0.5 m above a black floor (4 x 4 m) at a drawn offset; the probe
// at a drawn point 0.2-0.3 m up (R 32, M 8); points from the floor to 5 cm
// under the emitter's low edge, normal up, against Lambert's formula of the
// emitter clipped to the point's horizon (nothing else is lit or casts a
// shadow). Seed printed; errors on the issue's scale, |estimate - truth| /
// max(truth, 10% of the family's brightest).
test::FamilyErrors tilted_emitter_family(int r, int m) {
    std::mt19937 rng = test::family_rng(5202);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<test::Reading> readings;
    for (int config = 0; config < 12; ++config) {
        const float tilt = glm::radians(75.0f * u(rng)), heading = 6.2831853f * u(rng);
        const glm::vec3 centre(0.2f * (u(rng) - 0.5f), 0.5f, 0.2f * (u(rng) - 0.5f));
        const std::vector<Patch> scene =
            tilted_emitter_over_a_floor(tilt, {std::cos(heading), 0.0f, std::sin(heading)}, centre);
        const Patch& emitter = scene.back();
        const glm::vec3 e1 = emitter.e1, e2 = emitter.e2;
        const glm::vec3 probe(0.3f * (u(rng) - 0.5f), 0.2f + 0.1f * u(rng), 0.3f * (u(rng) - 0.5f));
        const ProbeSet set = one_probe_set(capture(scene, probe, r, m), r, m);
        const ProbeEvaluator eval(set);
        // The emitter's lowest point: no evaluation point within 5 cm under it.
        float low = 1.0f;
        for (const glm::vec3 c : {emitter.origin, emitter.origin + e1, emitter.origin + e2, emitter.origin + e1 + e2})
            low = std::min(low, c.y);
        for (int i = 0; i < 30; ++i) {
            const glm::vec3 x(-0.6f + 1.2f * u(rng), i % 3 == 0 ? 0.0f : std::max(low - 0.05f, 0.0f) * u(rng),
                              -0.6f + 1.2f * u(rng));
            readings.push_back(
                {eval.evaluate(x, {0, 1, 0}).polygon_to_point.g, exact_irradiance({emitter}, x, {0, 1, 0}).g});
        }
    }
    const test::FamilyErrors e = test::family_errors(readings);
    std::printf("  tilted emitter, R %d, M %d: p95 %.4f, worst %.4f over %zu points\n", r, m, e.p95, e.worst,
                readings.size());
    return e;
}

TEST(ProbeEstimators, TiltedEmitterFamily) {
    const auto [p95, worst] = tilted_emitter_family(32, 8);
    // Measured p95 0.65, worst 4.4 (the worst at 68° tilts, the probe beside
    // the emitter seeing it edge-on); with the bridges at the texel's mean
    // radiance (before split_bridges) 1.84 and 7.3. Issue #52 asks for 5%
    // and 10%: what is left is the emitter's edges blurred over a texel and
    // seen edge-on, and the signed sum's occlusion (the partition's figure
    // below); this guards what holds.
    EXPECT_LE(p95, 0.8);
    EXPECT_LE(worst, 5.0);
}

// Off centre (issue #52): a closed 2 x 2 x 2 m black room whose ceiling
// holds an emitter of radiance 1 of drawn size 0.3-1.8 m a side at a drawn
// place (its edges on no texel's edge; 1 mm under the ceiling), one probe
// at a drawn point up to 0.6 m off the centre in each axis, points 1 mm-1 m from a
// drawn wall or the floor with drawn normals, against Lambert's formula of
// the emitter clipped to the point's horizon (the room is convex: the point
// sees all of it). Seed printed; errors on the issue's scale.
test::FamilyErrors off_centre_probe_family(int r, int m) {
    std::mt19937 rng = test::family_rng(5205);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    const auto log_uniform = [&](float lo, float hi) { return lo * std::pow(hi / lo, u(rng)); };
    std::vector<test::Reading> readings;
    for (int config = 0; config < 12; ++config) {
        const float sx = 0.3f + 1.5f * u(rng), sz = 0.3f + 1.5f * u(rng);
        // 1 mm under the ceiling: coplanar, the two would each win by rounding.
        const glm::vec3 corner(-1.0f + (2.0f - sx) * u(rng), 1.999f, -1.0f + (2.0f - sz) * u(rng));
        const Patch emitter{corner, {sx, 0, 0}, {0, 0, sz}, glm::vec3(1.0f)};
        std::vector<Patch> scene = {emitter};
        for (const Patch& wall : box({-1, 0, -1}, {1, 2, 1}, {})) scene.push_back(wall);
        const glm::vec3 probe(1.2f * (u(rng) - 0.5f), 1.0f + 1.2f * (u(rng) - 0.5f), 1.2f * (u(rng) - 0.5f));
        const ProbeSet set = one_probe_set(capture(scene, probe, r, m), r, m);
        const ProbeEvaluator eval(set);
        for (int i = 0; i < 25; ++i) {
            // A point `gap` from the floor or from one of the four walls, elsewhere anywhere in the room.
            glm::vec3 x(-0.999f + 1.998f * u(rng), 0.001f + 1.8f * u(rng), -0.999f + 1.998f * u(rng));
            const float gap = log_uniform(0.001f, 1.0f);
            const int wall = i % 5;
            if (wall == 0) x.y = gap;
            else if (wall == 1) x.x = -1.0f + gap;
            else if (wall == 2) x.x = 1.0f - gap;
            else if (wall == 3) x.z = -1.0f + gap;
            else x.z = 1.0f - gap;
            const glm::vec3 n = i % 3 == 0 ? glm::vec3(0, 1, 0) : random_direction(rng);
            readings.push_back({eval.evaluate(x, n).polygon_to_point.g, exact_irradiance({emitter}, x, n).g});
        }
    }
    const test::FamilyErrors e = test::family_errors(readings);
    std::printf("  off-centre probe, R %d, M %d: p95 %.4f, worst %.4f over %zu points\n", r, m, e.p95, e.worst,
                readings.size());
    EXPECT_GT(readings.size(), 250u);
    return e;
}

TEST(ProbeEstimators, OffCentreProbeFamily) {
    const auto [p95, worst] = off_centre_probe_family(32, 8);
    // Measured p95 0.137, worst 0.88 (a point 26 cm under the ceiling beside
    // the emitter, its normal turned away: truth 0, read 9% of the family's
    // brightest). At the probe itself every configuration is within 4.4%
    // (this capture's 2 x 2 rays per fine texel, and the coarse texels'
    // radiance-cosine covariance: issue #52's every-M item). What is left is the
    // emitter's edge blurred over a coarse texel (at M 8 a texel spans
    // about 0.29 m of the ceiling seen from 1.5 m): the part of a texel's
    // polygon beyond the emitter carries the texel's mean radiance, which a
    // point seeing the polygon at a grazing angle reads (issue #52's 5% / 10%
    // are not met; this guards what holds).
    EXPECT_LE(p95, 0.17);
    EXPECT_LE(worst, 1.0);
}

// Issue #52's "error against M": the two families above at the default
// R 32 with M 8, 16 and 32, and at R 64 with M 32 and 64 (docs/BENCHMARKS.md).
//   build/tests/test_probes --gtest_also_run_disabled_tests --gtest_filter='*FiguresFamiliesAgainstM'
TEST(ProbeEstimators, DISABLED_FiguresFamiliesAgainstM) {
    for (const auto& [r, m] : std::vector<std::pair<int, int>>{{32, 8}, {32, 16}, {32, 32}, {64, 32}, {64, 64}}) {
        off_centre_probe_family(r, m);
        tilted_emitter_family(r, m);
    }
}

// A partition under a ceiling light (issue #52): a closed 2 x 2 x 2 m room
// whose ceiling emits 1, the rest black, split by a 1 cm black partition
// across its whole depth, of drawn height 0.3-1.2 m at a drawn x; one probe
// at a drawn point, in the partition's plane above it or beside it (R 32,
// M 8). Points on the floor 1 mm-1 m from the partition, normal up, on
// both sides, against the ceiling's form factor cut by the shadow plane
// through the partition's top edge (the ceiling is lit, nothing else is).
// A figure, not a check (issue #52's open item): measured p95 3.35, worst
// 6.0 (the probe above the partition: a floor point beside its foot reads
// the whole ceiling). The signed sum occludes only where the occluder is as
// bright as what it hides (L1 - L2 + L3 = L3 there): the black partition,
// seen edge-on as a spike of bridges, hides nothing. An estimator that takes
// only the first polygon along each direction from the point would.
//   build/tests/test_probes --gtest_also_run_disabled_tests --gtest_filter='*Partition*'
TEST(ProbeEstimators, DISABLED_FiguresPartitionFamily) {
    std::mt19937 rng = test::family_rng(5203);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    const auto log_uniform = [&](float lo, float hi) { return lo * std::pow(hi / lo, u(rng)); };
    std::vector<test::Reading> readings;
    for (int config = 0; config < 12; ++config) {
        const float px = -0.3f + 0.6f * u(rng), height = 0.3f + 0.9f * u(rng), thick = 0.01f;
        const glm::vec3 black(0.0f);
        std::vector<Patch> scene = box({-1, 0, -1}, {1, 2, 1}, {black, black, glm::vec3(1.0f), black, black, black});
        scene.push_back({{px, 0, -1}, {0, height, 0}, {0, 0, 2}, black});          // its -x face
        scene.push_back({{px + thick, 0, -1}, {0, height, 0}, {0, 0, 2}, black});  // its +x face
        scene.push_back({{px, height, -1}, {thick, 0, 0}, {0, 0, 2}, black});      // its top
        const bool in_plane = config % 2 == 0;
        const glm::vec3 probe(in_plane ? px + thick / 2 : px + (u(rng) < 0.5f ? -1.0f : 1.0f) * (0.1f + 0.4f * u(rng)),
                              height + 0.1f + (1.8f - height) * u(rng), -0.5f + u(rng));
        const PreparedProbe p = prepare_probe(capture(scene, probe, 32, 8), 8);
        for (int i = 0; i < 20; ++i) {
            const float side = i % 2 ? -1.0f : 1.0f, gap = log_uniform(0.001f, 0.7f);
            const float x = side < 0.0f ? px - gap : px + thick + gap;
            const glm::vec3 at(x, 0.0f, -0.9f + 1.8f * u(rng));
            // The shadow plane through the top edge: the ceiling beyond x_cut is hidden.
            const float edge = side < 0.0f ? px : px + thick;
            const float cut = edge + (edge - x) * (2.0f - height) / height;
            const float lo = side < 0.0f ? -1.0f : std::max(-1.0f, cut), hi = side < 0.0f ? std::min(1.0f, cut) : 1.0f;
            const std::vector<Patch> seen = {{{lo, 2, -1}, {hi - lo, 0, 0}, {0, 0, 2}, glm::vec3(1.0f)}};
            readings.push_back(
                {probe_polygon_to_point(p, at, {0, 1, 0}).g, hi > lo ? exact_irradiance(seen, at, {0, 1, 0}).g : 0.0});
        }
    }
    const auto [p95, worst] = test::family_errors(readings);
    std::printf("  partition: p95 %.4f, worst %.4f over %zu points\n", p95, worst, readings.size());
    EXPECT_GT(readings.size(), 200u);
}

// ------------------------------------------------------ GLSL = C++ ----

TEST(ProbeGlsl, IncludeMatchesTheCpp) {
    gpu();
    const ComputeProgram program("probe_eval_check.comp");
    std::mt19937 rng(17);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    CheckParams params{};  // the probe and the grid, set by the cases below
    const auto run = [&](unsigned mode, const std::vector<glm::vec4>& cases, size_t items) {
        GpuBuffer in(cases), out(items * sizeof(glm::vec4));
        params.item_count = uint32_t(items);
        params.mode = mode;
        program.use(params);
        in.bind(LF_BINDING_CHECK_CASES);
        out.bind(LF_BINDING_CHECK_RESULTS);
        program.dispatch_1d(items);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        return out.read<glm::vec4>();
    };
    // The lattice mode 3 blends over.
    const auto use_grid = [&](glm::ivec3 counts, glm::vec3 origin, glm::vec3 spacing) {
        params.grid_counts_x = counts.x;
        params.grid_counts_y = counts.y;
        params.grid_counts_z = counts.z;
        params.grid_origin_x = origin.x;
        params.grid_origin_y = origin.y;
        params.grid_origin_z = origin.z;
        params.grid_spacing_x = spacing.x;
        params.grid_spacing_y = spacing.y;
        params.grid_spacing_z = spacing.z;
    };
    // Cube directions.
    {
        std::vector<glm::vec4> cases;
        for (int i = 0; i < 600; ++i) cases.push_back({float(i % 6), 0.5f + 0.5f * u(rng), 0.5f + 0.5f * u(rng), 0});
        GpuBuffer dummy(std::vector<glm::vec4>(1));
        dummy.bind(LF_BINDING_PROBE_SET);
        const auto got = run(2, cases, cases.size());
        for (size_t i = 0; i < cases.size(); ++i) {
            const glm::vec3 want = cube_direction(int(cases[i].x), cases[i].y, cases[i].z);
            ASSERT_LT(glm::length(glm::vec3(got[i]) - want), 1e-6f) << "face " << cases[i].x;
        }
    }
    // Form factors of random quads (either winding, anywhere around x).
    {
        std::vector<glm::vec4> cases;
        const size_t count = 2000;
        for (size_t i = 0; i < count; ++i) {
            const glm::vec3 x(u(rng), u(rng), u(rng)), n = random_direction(rng);
            const glm::vec3 o = x + 2.0f * glm::vec3(u(rng), u(rng), u(rng));
            const glm::vec3 e1 = glm::vec3(u(rng), u(rng), u(rng)), e2 = glm::vec3(u(rng), u(rng), u(rng));
            for (glm::vec3 v : {x, n, o, o + e1, o + e1 + e2 + 0.1f * glm::vec3(u(rng)), o + e2})
                cases.push_back(glm::vec4(v, 0));
        }
        GpuBuffer dummy(std::vector<glm::vec4>(1));
        dummy.bind(LF_BINDING_PROBE_SET);
        const auto got = run(0, cases, count);
        double worst = 0.0;
        for (size_t i = 0; i < count; ++i) {
            glm::vec3 c[4];
            for (int k = 0; k < 4; ++k) c[k] = glm::vec3(cases[6 * i + 2 + k]);
            const float want = polygon_to_point_form_factor(glm::vec3(cases[6 * i]), glm::vec3(cases[6 * i + 1]), c, 4);
            worst = std::max(worst, double(std::abs(got[i].x - want)));
        }
        std::printf("  GLSL form factor vs C++: max |difference| %.2e over %zu random quads\n", worst, count);
        EXPECT_LT(worst, 2e-5);
    }
    // A probe's polygon-to-point irradiance (the coloured box, two probes in the buffer).
    {
        const std::vector<Patch> scene = box(glm::vec3(-1.0f), glm::vec3(1.0f),
                                             {glm::vec3(2, 0.1f, 0.1f), glm::vec3(0.1f, 2, 0.1f), glm::vec3(1.5f),
                                              glm::vec3(0.2f), glm::vec3(0.1f, 0.1f, 1.5f), glm::vec3(0.5f)});
        ProbeSet set;
        set.m = 4;
        set.probes = {capture(scene, {0.3f, 0, 0}, 16, 4), capture(scene, {-0.2f, 0.1f, 0.2f}, 16, 4)};
        GpuBuffer probes(pack_probe_buffer(set));
        probes.bind(LF_BINDING_PROBE_SET);
        std::vector<glm::vec4> cases;
        for (int i = 0; i < 300; ++i) {
            cases.push_back(glm::vec4(0.95f * glm::vec3(u(rng), u(rng), u(rng)), 0));
            cases.push_back(glm::vec4(random_direction(rng), 0));
        }
        // And points beyond the chords across the room's edges, which
        // evaluation moves back inside (probe_point_inside).
        int moved = 0;
        const PreparedProbe p = prepare_probe(set.probes[1], 4);
        for (const EdgePoint& e : room_edge_points())
            for (const glm::vec3& n : wall_normals(e.x)) {
                cases.push_back(glm::vec4(e.x, 0));
                cases.push_back(glm::vec4(n, 0));
                moved += probe_point_inside(p, e.x) != e.x;
            }
        EXPECT_GT(moved, 10);
        const size_t count = cases.size() / 2;
        params.m = 4;
        params.probe = 1;
        params.probe_position_x = set.probes[1].position.x;
        params.probe_position_y = set.probes[1].position.y;
        params.probe_position_z = set.probes[1].position.z;
        const auto got = run(1, cases, count);
        double worst = 0.0;
        for (size_t i = 0; i < count; ++i) {
            const glm::vec3 want = probe_polygon_to_point(p, glm::vec3(cases[2 * i]), glm::vec3(cases[2 * i + 1]));
            worst = std::max(worst, double(relative_error(glm::vec3(got[i]), want)));
        }
        std::printf("  GLSL probe polygon-to-point vs C++: max relative difference %.2e over %zu points\n", worst,
                    count);
        EXPECT_LT(worst, 1e-4);
        // The same probe's SH9 irradiance (its coefficients after the corners).
        std::vector<glm::vec4> normals;
        for (size_t i = 0; i < count; ++i) normals.push_back(glm::vec4(random_direction(rng), 0));
        const auto sh = run(4, normals, count);
        double worst_sh = 0.0;
        for (size_t i = 0; i < count; ++i)
            worst_sh =
                std::max(worst_sh, double(relative_error(glm::vec3(sh[i]), probe_sh9(p, glm::vec3(normals[i])))));
        std::printf("  GLSL probe SH9 vs C++: max relative difference %.2e over %zu normals\n", worst_sh, count);
        EXPECT_LT(worst_sh, 1e-4);
    }
    // A grid, blended: a 3 x 2 x 2 lattice in the coloured box whose probes
    // at x = -0.6 and 0 are invalid, so that points in the first cell fall
    // back to the nearest valid probes and those in the second blend its two
    // valid corners' faces only; points also outside the lattice.
    {
        const std::vector<Patch> scene = box(glm::vec3(-1.0f), glm::vec3(1.0f),
                                             {glm::vec3(2, 0.1f, 0.1f), glm::vec3(0.1f, 2, 0.1f), glm::vec3(1.5f),
                                              glm::vec3(0.2f), glm::vec3(0.1f, 0.1f, 1.5f), glm::vec3(0.5f)});
        const glm::ivec3 counts(3, 2, 2);
        const glm::vec3 origin(-0.6f, -0.4f, -0.4f), spacing(0.6f, 0.8f, 0.8f);
        ProbeSet set;
        set.m = 2;
        for (int z = 0; z < counts.z; ++z)
            for (int y = 0; y < counts.y; ++y)
                for (int x = 0; x < counts.x; ++x) {
                    set.probes.push_back(capture(scene, origin + glm::vec3(x, y, z) * spacing, 8, 2));
                    set.probes.back().valid = x == 2;
                }
        const ProbeEvaluator cpu(set);
        ASSERT_TRUE(cpu.is_grid());
        GpuBuffer probes(pack_probe_buffer(set));
        probes.bind(LF_BINDING_PROBE_SET);
        std::vector<glm::vec4> cases;
        const size_t count = 400;
        for (size_t i = 0; i < count; ++i) {
            cases.push_back(glm::vec4(0.95f * glm::vec3(u(rng), u(rng), u(rng)), 0));
            cases.push_back(glm::vec4(random_direction(rng), 0));
        }
        params.m = set.m;
        use_grid(counts, origin, spacing);
        const auto got = run(3, cases, count);
        double worst = 0.0;
        for (size_t i = 0; i < count; ++i) {
            const glm::vec3 want = cpu.evaluate(glm::vec3(cases[2 * i]), glm::vec3(cases[2 * i + 1])).polygon_to_point;
            worst = std::max(worst, double(relative_error(glm::vec3(got[i]), want)));
        }
        std::printf("  GLSL grid polygon-to-point vs C++: max relative difference %.2e over %zu points\n", worst,
                    count);
        EXPECT_LT(worst, 1e-4);
    }
    // Split texels (split_bridges): a probe beside a tilted emitter over a
    // floor, whose texels across the emitter's edges bridge it to the floor.
    {
        const std::vector<Patch> scene =
            tilted_emitter_over_a_floor(glm::radians(40.0f), {0.6f, 0.0f, 0.8f}, {0.05f, 0.5f, -0.03f});
        ProbeSet set = one_probe_set(capture(scene, {0.02f, 0.25f, 0.04f}, 32, 8), 32, 8);
        const PreparedProbe p = prepare_probe(set.probes[0], set.m);
        int splits = 0;
        for (const PreparedProbe::Texel& t : p.texels) splits += t.split;
        EXPECT_GT(splits, 4);
        GpuBuffer probes(pack_probe_buffer(set));
        probes.bind(LF_BINDING_PROBE_SET);
        std::uniform_real_distribution<float> unit(0.0f, 1.0f);
        std::vector<glm::vec4> cases;
        for (int i = 0; i < 300; ++i) {
            cases.push_back(glm::vec4(-0.6f + 1.2f * unit(rng), 0.3f * unit(rng), -0.6f + 1.2f * unit(rng), 0));
            cases.push_back(glm::vec4(random_direction(rng), 0));
        }
        params.m = set.m;
        params.probe = 0;
        params.probe_position_x = p.position.x;
        params.probe_position_y = p.position.y;
        params.probe_position_z = p.position.z;
        const auto got = run(1, cases, cases.size() / 2);
        double worst = 0.0;
        for (size_t i = 0; i < cases.size() / 2; ++i) {
            const glm::vec3 want = probe_polygon_to_point(p, glm::vec3(cases[2 * i]), glm::vec3(cases[2 * i + 1]));
            worst = std::max(worst, double(glm::length(glm::vec3(got[i]) - want)));
        }
        // Against the emitter's radiance (2): a split texel's two polygons
        // cancel in part, so the float rounding is of the terms, not the sum.
        std::printf("  GLSL probe with %d split texels vs C++: max |difference| %.2e over %zu points\n", splits, worst,
                    cases.size() / 2);
        EXPECT_LT(worst / 2.0, 2e-5);
    }
    // Visibility: the thin wall's grid (issue #52), points on both sides of
    // the wall, near the floor, the ceiling and the wall: whether each probe
    // sees each point, and the blend of the probes that do.
    {
        const ThinWall rooms = thin_wall(-0.05f, 0.01f);
        ProbeSet set = thin_wall_probes(rooms, 16, 4);
        // One probe moved off its lattice point, as the bake moves one near a
        // surface: blended at its lattice point, its light from where it is.
        const glm::vec3 lattice = set.probes[5].position;
        set.probes[5] = capture(rooms.scene, lattice + glm::vec3(0.03f, -0.05f, 0.04f), 16, 4);
        set.probes[5].moved_from = lattice;
        const ProbeEvaluator cpu(set);
        ASSERT_TRUE(cpu.is_grid());
        GpuBuffer probes(pack_probe_buffer(set));
        probes.bind(LF_BINDING_PROBE_SET);
        std::uniform_real_distribution<float> unit(0.0f, 1.0f);
        std::vector<glm::vec4> points, cases;
        for (int i = 0; i < 300; ++i) {
            const float side = i % 2 ? -0.05f - 0.3f * unit(rng) * unit(rng) : -0.04f + 0.3f * unit(rng) * unit(rng);
            const glm::vec3 x(side, i % 3 ? unit(rng) : 0.002f, 0.98f * u(rng) / 2.0f);
            points.push_back(glm::vec4(x, 0));
            cases.push_back(glm::vec4(x, 0));
            cases.push_back(glm::vec4(random_direction(rng), 0));
        }
        params.m = set.m;
        use_grid(kThinWallGrid, kThinWallOrigin, glm::vec3(kThinWallSpacing));
        size_t differ = 0, unseen = 0;
        for (size_t k = 0; k < set.probes.size(); ++k) {
            const PreparedProbe p = prepare_probe(set.probes[k], set.m);
            params.probe = uint32_t(k);
            params.probe_position_x = p.position.x;
            params.probe_position_y = p.position.y;
            params.probe_position_z = p.position.z;
            const auto got = run(5, points, points.size());
            for (size_t i = 0; i < points.size(); ++i) {
                const bool want = probe_sees(p, glm::vec3(points[i]));
                differ += (got[i].x > 0.5f) != want;
                unseen += !want;
            }
        }
        std::printf("  GLSL probe_sees vs C++: %zu of %zu differ (%zu not seen)\n", differ,
                    points.size() * set.probes.size(), unseen);
        EXPECT_EQ(differ, 0u);
        EXPECT_GT(unseen, points.size() * set.probes.size() / 4) << "points behind the wall";
        const auto got = run(3, cases, points.size());
        double worst = 0.0;
        for (size_t i = 0; i < points.size(); ++i) {
            const glm::vec3 want = cpu.evaluate(glm::vec3(cases[2 * i]), glm::vec3(cases[2 * i + 1])).polygon_to_point;
            worst = std::max(worst, double(glm::length(glm::vec3(got[i]) - want)));
        }
        std::printf("  GLSL grid behind a wall vs C++: max |difference| %.2e over %zu points\n", worst, points.size());
        EXPECT_LT(worst, 1e-5);
    }
}

// --------------------------------------------------------- files ----

fs::path fresh_dir(const std::string& name) {
    const fs::path d = fs::temp_directory_path() / ("lightfarm-probes-" + name + "-" + std::to_string(getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
}

ProbeSet small_set() {
    const glm::vec3 L(0.8f, 0.5f, 0.3f);
    const std::vector<Patch> scene =
        box(glm::vec3(-1.0f), glm::vec3(1.0f), {L, 0.5f * L, 2.0f * L, L, glm::vec3(0.1f), glm::vec3(1.0f)});
    ProbeSet set;
    set.m = 2;
    set.capture_resolution = 16;
    set.settings = {{"probe_m", 2}};
    set.probes = {capture(scene, {-0.3f, 0, 0}, 16, 2), capture(scene, {0.3f, 0.1f, 0}, 16, 2),
                  capture(scene, {0.0f, 0.5f, 0.5f}, 16, 2)};
    set.probes[1].corner_distance.clear();                     // as in a file written before corners were traced
    set.probes[1].centre_distance.clear();                     // and before centres were
    set.probes[0].moved_from = glm::vec3(-0.3f, 0.05f, 0.0f);  // moved away from a surface by the bake
    set.probes[2].valid = false;
    set.probes[2].why = "inside geometry";
    set.probes[2].backface_fraction = 0.75f;
    set.probes[2].corner_distance.clear();
    return set;
}

TEST(ProbeFiles, WriteThenReadRoundTrips) {
    const ProbeSet set = small_set();
    const fs::path dir = fresh_dir("roundtrip");
    write_probe_set(dir, set);
    const ProbeSet back = read_probe_set(dir / "probes.json");
    EXPECT_EQ(back.m, set.m);
    EXPECT_EQ(back.capture_resolution, set.capture_resolution);
    EXPECT_EQ(back.settings, set.settings);
    ASSERT_EQ(back.probes.size(), set.probes.size());
    for (size_t k = 0; k < set.probes.size(); ++k) {
        const Probe &a = set.probes[k], &b = back.probes[k];
        EXPECT_EQ(a.position, b.position);
        EXPECT_EQ(a.moved_from, b.moved_from);
        EXPECT_EQ(a.valid, b.valid);
        EXPECT_EQ(a.why, b.why);
        EXPECT_FLOAT_EQ(a.backface_fraction, b.backface_fraction);
        for (int c = 0; c < 9; ++c) EXPECT_EQ(a.sh9[c], b.sh9[c]);
        if (!a.valid) continue;
        // Traced corners come back as written (full floats); a probe without
        // them comes back with misses, which evaluation reads from the texels.
        ASSERT_EQ(b.corner_distance.size(), size_t(6) * (set.m + 1) * (set.m + 1));
        for (size_t c = 0; c < b.corner_distance.size(); ++c)
            EXPECT_EQ(b.corner_distance[c], a.corner_distance.empty() ? kMissDistance : a.corner_distance[c]);
        EXPECT_EQ(probe_corner_distances(b, set.m), probe_corner_distances(a, set.m));
        // Centres likewise; a probe without them comes back without them.
        EXPECT_EQ(b.centre_distance, a.centre_distance);
        for (size_t t = 0; t < a.radiance.size(); ++t) {
            // probes.exr may store half floats; allow their precision.
            EXPECT_NEAR(a.distance[t], b.distance[t], 1e-3f * a.distance[t]);
            EXPECT_LT(relative_error(b.radiance[t], a.radiance[t]), 1e-3f);
        }
    }
    fs::remove_all(dir);
}

// A probes file that says more than it holds is refused naming the file and
// what is missing: a version-3 set whose image lacks the centres' channel D,
// a version this build does not know, a malformed moved_from.
TEST(ProbeFiles, AFileThatDoesNotHoldWhatItSaysIsRefusedNamingIt) {
    const fs::path dir = fresh_dir("bad-files");
    write_probe_set(dir, small_set());
    const nlohmann::json good = nlohmann::json::parse(std::ifstream(dir / "probes.json"));
    const auto refused = [&](const nlohmann::json& doc, const std::string& says) {
        std::ofstream(dir / "probes.json") << doc.dump();
        try {
            read_probe_set(dir / "probes.json");
            ADD_FAILURE() << "accepted: " << says;
        } catch (const std::runtime_error& e) {
            EXPECT_NE(std::string(e.what()).find("probes.json"), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
        }
    };
    nlohmann::json future = good;
    future["version"] = 4;
    refused(future, "version 4 is not 1, 2 or 3");
    nlohmann::json moved = good;
    moved["probes"][0]["moved_from"] = {1, 2};
    refused(moved, "moved_from must be [x, y, z]");
    FloatImage image = read_exr(dir / "probes.exr");
    image.channels.erase("D");
    write_exr(dir / "probes.exr", image);
    refused(good, "probes.exr has no channel D");
    fs::remove_all(dir);
}

using test::CliRun;
using test::run_lightfarm;

// probe-eval's points file, every kind of mistake in it: each refused with
// the file, the point and what is wrong; a good one read with its normals
// made unit.
TEST(ProbeCli, ShadingPointsAreReadOrRefusedNamingThePoint) {
    const std::filesystem::path file =
        std::filesystem::temp_directory_path() / ("lightfarm_points_" + std::to_string(::getpid()) + ".json");
    auto refused = [&](const std::string& text) {
        std::ofstream(file) << text;
        try {
            read_shading_points(file);
        } catch (const std::runtime_error& e) {
            return std::string(e.what());
        }
        return std::string("accepted");
    };
    const std::string shape = R"(must be [{"position": [x,y,z], "normal": [x,y,z]}, ...])";
    EXPECT_NE(refused(R"({"position": [0, 0, 0]})").find(shape), std::string::npos) << "not an array";
    EXPECT_NE(refused("[1, 2").find(shape), std::string::npos) << "not JSON";
    EXPECT_NE(refused(R"([{"normal": [0, 1, 0]}])").find("point 0: position"), std::string::npos);
    EXPECT_NE(refused(R"([{"position": [0, 0, 0]}])").find("point 0: normal"), std::string::npos);
    EXPECT_NE(
        refused(R"([{"position": [0, 0, 0], "normal": [0, 1, 0]}, {"position": [0, "a", 0], "normal": [0, 1, 0]}])")
            .find("point 1: position"),
        std::string::npos);
    EXPECT_NE(refused(R"([{"position": [0, 0, 1e39], "normal": [0, 1, 0]}])").find("point 0: position is not finite"),
              std::string::npos);
    EXPECT_NE(refused(R"([{"position": [0, 0, 0], "normal": [0, 0, 0]}])").find("point 0: normal is zero"),
              std::string::npos);
    EXPECT_NE(refused("[]").find("accepted"), std::string::npos) << "no point: nothing to evaluate";
    std::ofstream(file) << R"([{"position": [1, 2, 3], "normal": [0, 2, 0]}])";
    const std::vector<ShadingPoint> points = read_shading_points(file);
    ASSERT_EQ(points.size(), 1u);
    EXPECT_EQ(points[0].position, glm::vec3(1, 2, 3));
    EXPECT_EQ(points[0].normal, glm::vec3(0, 1, 0));
    std::filesystem::remove(file);
    try {
        read_shading_points(file);
        ADD_FAILURE() << "a missing file was read";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find(file.string() + ": cannot be read"), std::string::npos) << e.what();
    }
}

TEST(ProbeCli, ProbeEvalPrintsTheFourEstimatorsInInputOrder) {
    const ProbeSet set = small_set();
    const fs::path dir = fresh_dir("cli");
    write_probe_set(dir, set);
    const std::vector<std::pair<glm::vec3, glm::vec3>> points = {
        {{0, 0, 0}, {0, 1, 0}}, {{0.5f, -0.2f, 0.1f}, {1, 0, 0}}, {{-0.8f, 0.3f, -0.4f}, {0, 0, -1}}};
    nlohmann::json doc = nlohmann::json::array();
    for (const auto& [p, n] : points) doc.push_back({{"position", {p.x, p.y, p.z}}, {"normal", {n.x, n.y, n.z}}});
    std::ofstream(dir / "points.json") << doc.dump();
    const CliRun r =
        run_lightfarm("probe-eval " + (dir / "probes.json").string() + " " + (dir / "points.json").string());
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const nlohmann::json out = nlohmann::json::parse(r.out);
    ASSERT_EQ(out["points"].size(), points.size());
    const ProbeEvaluator eval(read_probe_set(dir / "probes.json"));
    for (size_t i = 0; i < points.size(); ++i) {
        const ProbeEvaluation e = eval.evaluate(points[i].first, points[i].second);
        for (int k = 0; k < 4; ++k) {
            const nlohmann::json& v = out["points"][i][kNames[k]];
            ASSERT_EQ(v.size(), 3u) << kNames[k];
            for (int c = 0; c < 3; ++c) EXPECT_NEAR(v[c].get<float>(), pick(e, k)[c], 1e-5f * (1 + pick(e, k)[c]));
        }
    }
    // Bad input: usage 2, unreadable or malformed files 3, with one line.
    EXPECT_EQ(run_lightfarm("probe-eval " + (dir / "probes.json").string()).exit_code, 2);
    const CliRun missing =
        run_lightfarm("probe-eval " + (dir / "nope.json").string() + " " + (dir / "points.json").string());
    EXPECT_EQ(missing.exit_code, 3);
    EXPECT_NE(missing.err.find("nope.json"), std::string::npos) << missing.err;
    std::ofstream(dir / "bad_points.json") << R"([{"position": [0, 0], "normal": [0, 1, 0]}])";
    const CliRun bad =
        run_lightfarm("probe-eval " + (dir / "probes.json").string() + " " + (dir / "bad_points.json").string());
    EXPECT_EQ(bad.exit_code, 3);
    EXPECT_NE(bad.err.find("point 0: position"), std::string::npos) << bad.err;
    EXPECT_EQ(std::count(bad.err.begin(), bad.err.end(), '\n'), 1) << bad.err;
    std::ofstream(dir / "garbage.json") << "{not json";
    EXPECT_EQ(
        run_lightfarm("probe-eval " + (dir / "garbage.json").string() + " " + (dir / "points.json").string()).exit_code,
        3);
    fs::remove_all(dir);
}

}  // namespace
}  // namespace lf
