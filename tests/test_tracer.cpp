// The one tracer against a CPU brute-force reference, and the properties a
// tracer must have: watertight shared edges, no self-intersection, occlusion
// queries consistent with closest hits.
#include "gpu_fixture.h"
#include "scene_builders.h"
#include "thread_count.h"

#include "gpu/shader.h"
#include "scene/gltf_loader.h"
#include "trace/bvh.h"
#include "trace/ray_reference.h"
#include "trace/tracer.h"
#include "shaders/buffer_bindings.glsl"

#include <gtest/gtest.h>

#include <cstring>
#include <functional>
#include <limits>
#include <random>

namespace lf {
namespace {

using test::gpu;

glm::vec3 random_direction(std::mt19937& rng) {
    std::normal_distribution<float> g;
    glm::vec3 d;
    do d = glm::vec3(g(rng), g(rng), g(rng));
    while (glm::length(d) < 1e-3f);
    return glm::normalize(d);
}

// Random rays from inside the scene's box and from its surfaces.
std::vector<Ray> random_rays(const Scene& scene, size_t count, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::uniform_int_distribution<size_t> pick(0, scene.triangles.size() - 1);
    const float far = 4.0f * glm::length(scene.bounds.extent());
    std::vector<Ray> rays;
    for (size_t i = 0; i < count; ++i) {
        Ray r{};
        if (i % 2 == 0) {
            r.origin = scene.bounds.lo + glm::vec3(u(rng), u(rng), u(rng)) * scene.bounds.extent();
        } else {
            size_t t = pick(rng);
            while (scene.triangle_area(t) <= 0.0f) t = pick(rng);
            const glm::uvec3 tri = scene.triangles[t];
            const float a = u(rng), b = u(rng) * (1.0f - a);
            const glm::vec3 p =
                (1 - a - b) * scene.positions[tri.x] + a * scene.positions[tri.y] + b * scene.positions[tri.z];
            const glm::vec3 n = scene.geometric_normal(t);
            r.origin = offset_ray_origin(p, n);
            r.direction = random_direction(rng);
            if (glm::dot(r.direction, n) < 0.0f) r.direction = -r.direction;
        }
        if (i % 2 == 0) r.direction = random_direction(rng);
        r.t_max = far;
        rays.push_back(r);
    }
    return rays;
}

// How far two correct float32 evaluations of the same hit may differ (the
// GPU's fused multiply-adds against the CPU's separate ones). t = n·(A−o) /
// n·d: each product is off by a few ulps of the magnitudes it multiplies,
// |A−o| (the vertices' distance from the origin, not t) in the numerator and
// |d| in the denominator, and dividing by n·d = cos θ amplifies both for
// grazing rays. The old bound, 1e-5·max(1, t), followed neither: on the H100
// a hit at t = 1.36 differed by 2.2e-5 and failed it.
float hit_distance_tolerance(const Scene& scene, const Ray& ray, const RayHit& hit) {
    constexpr float kUlps = 64.0f * std::numeric_limits<float>::epsilon();
    const glm::uvec3 tri = scene.triangles[hit.triangle];
    float reach = hit.t;
    for (uint32_t v : {tri.x, tri.y, tri.z}) reach = std::max(reach, glm::length(scene.positions[v] - ray.origin));
    const float cos_theta = std::abs(glm::dot(scene.geometric_normal(hit.triangle), glm::normalize(ray.direction)));
    return kUlps * reach / std::max(cos_theta, 1e-3f);
}

void expect_matches_brute_force(const Scene& scene, size_t ray_count) {
    Tracer tracer(scene);
    const std::vector<Ray> rays = random_rays(scene, ray_count, 12345);
    const std::vector<RayHit> gpu_hits = tracer.trace(rays);
    ASSERT_EQ(gpu_hits.size(), rays.size());
    size_t hits = 0, ties = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        const RayHit ref = trace_brute_force(scene, rays[i]);
        const RayHit& got = gpu_hits[i];
        ASSERT_EQ(ref.triangle == kNoHit, got.triangle == kNoHit) << "ray " << i << " (hit vs miss)";
        if (ref.triangle == kNoHit) continue;
        ++hits;
        EXPECT_NEAR(got.t, ref.t, hit_distance_tolerance(scene, rays[i], ref)) << "ray " << i;
        if (got.triangle != ref.triangle) {
            // Only an exact tie (a shared edge, coplanar overlap) may pick another triangle.
            EXPECT_NEAR(got.t, ref.t, 1e-6f * std::max(1.0f, ref.t)) << "ray " << i << " different triangle, not a tie";
            ++ties;
        } else {
            EXPECT_NEAR(got.bary.x, ref.bary.x, 1e-4f);
            EXPECT_NEAR(got.bary.y, ref.bary.y, 1e-4f);
        }
    }
    EXPECT_GT(hits, ray_count / 4) << "too few hits for the comparison to mean anything";
    EXPECT_LT(ties, ray_count / 100 + 1);
}

TEST(Tracer, MatchesBruteForceOnCornellBox) {
    gpu();
    expect_matches_brute_force(load_scene(test::example_scene("cornell_box.gltf")), 20000);
}

TEST(Tracer, MatchesBruteForceOnMonkey) {
    gpu();
    expect_matches_brute_force(load_scene(test::example_scene("monkey.glb")), 4000);
}

TEST(Tracer, MatchesBruteForceOnRealStaircase) {
    gpu();
    expect_matches_brute_force(load_scene(test::example_scene("real/wooden_staircase/wooden_staircase.gltf")), 600);
}

// A tracer that takes a scene's winding after every other triangle was
// turned round (as double-sided charts are before a bake) hits what a tracer
// built from the turned scene hits: the same triangles at the same t, with
// the turned triangles' barycentrics (their 2nd and 3rd vertices swapped).
TEST(Tracer, RewoundTrianglesHitAsARebuiltTree) {
    gpu();
    const Scene scene = load_scene(test::example_scene("monkey.glb"));
    Scene turned = scene;
    for (size_t t = 0; t < turned.triangles.size(); t += 2) std::swap(turned.triangles[t].y, turned.triangles[t].z);
    Tracer rewound(scene);
    rewound.rewind(turned);
    const std::vector<Ray> rays = random_rays(scene, 4000, 7);
    const std::vector<RayHit> got = rewound.trace(rays), want = Tracer(turned).trace(rays);
    const std::vector<RayHit> before = Tracer(scene).trace(rays);
    size_t turned_hits = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        ASSERT_EQ(got[i].triangle, want[i].triangle) << "ray " << i;
        if (got[i].triangle == kNoHit) continue;
        EXPECT_EQ(got[i].t, want[i].t) << "ray " << i;
        EXPECT_EQ(got[i].bary, want[i].bary) << "ray " << i;
        if (got[i].triangle % 2 == 0 && got[i].bary != before[i].bary) ++turned_hits;
    }
    EXPECT_GT(turned_hits, rays.size() / 10) << "the turned triangles' winding was not taken";
}

// Rays aimed exactly at the vertices and edge midpoints of a closed mesh, from
// inside and from outside, must hit it: no ray slips between two triangles,
// nor past the boxes around them (which the tree quantizes), also far from
// the origin where float spacing is coarse.
TEST(Tracer, WatertightOnSharedEdgesAndVertices) {
    gpu();
    for (float distance : {0.0f, 1000.0f, 100000.0f}) {
        Scene s;
        const uint32_t m = test::add_material(s, glm::vec3(0.5f));
        const glm::vec3 centre = glm::vec3(0.3f, -0.2f, 0.1f) + distance * glm::vec3(1.0f, 0.5f, -1.0f);
        test::add_icosphere(s, centre, 1.0f + distance * 1e-3f, 3, m);
        Tracer tracer(s);
        std::vector<Ray> rays;
        auto aim = [&](glm::vec3 target) {
            rays.push_back(Ray{centre, 10.0f, target - centre, 0});  // from inside, t in units of the offset
            const glm::vec3 outside = centre + 3.0f * (target - centre);
            rays.push_back(Ray{outside, 10.0f, target - outside, 0});
        };
        for (uint32_t v = 0; v < s.positions.size(); ++v) aim(s.positions[v]);
        for (const glm::uvec3& t : s.triangles)
            for (int k = 0; k < 3; ++k) aim(0.5f * (s.positions[t[k]] + s.positions[t[(k + 1) % 3]]));
        const std::vector<RayHit> hits = tracer.trace(rays);
        size_t escaped = 0;
        for (const RayHit& h : hits) escaped += h.triangle == kNoHit;
        EXPECT_EQ(escaped, 0u) << "of " << rays.size() << " rays through edges and vertices, at distance " << distance;
    }
}

// A closed box whose faces are grids of quads on a power-of-two lattice, far
// from the origin: the tree's boxes then have planes exactly on their node's
// step grid (BvhNode), and rays through the lattice's vertices pass exactly
// through the corners of leaf boxes, which the traversal must keep. Rays
// through a vertex and a lattice point inside the box, leaving the box there
// or entering it, must hit: they cross the closed surface there (exactly, as
// every coordinate is a lattice point; a ray that only touched the box at
// an edge would be allowed to miss). Every number here is dyadic, so the
// slab test's two terms cancel without rounding: the slack that rounding
// needs is ASharedEdgeBetweenNodesFarApartIsWatertight's to check.
TEST(Tracer, RaysThroughBoxCornersOnAPowerOfTwoLatticeHit) {
    gpu();
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(0.5f));
    const glm::vec3 lo(1024.0f, -2048.0f, 512.0f);
    const float step = 0.125f;
    const int n = 24;  // quads along an edge
    std::vector<glm::vec3> vertices;
    for (int a = 0; a < 3; ++a) {
        const int b = (a + 1) % 3, c = (a + 2) % 3;
        for (int side = 0; side < 2; ++side)
            for (int i = 0; i <= n; ++i)
                for (int j = 0; j <= n; ++j) {
                    glm::vec3 p = lo;
                    p[a] += float(side * n) * step;
                    p[b] += float(i) * step;
                    p[c] += float(j) * step;
                    vertices.push_back(p);
                    if (i == n || j == n) continue;
                    glm::vec3 u(0.0f), v(0.0f);
                    u[b] = step;
                    v[c] = step;
                    test::add_quad(s, p, u, v, m);
                }
    }
    Tracer tracer(s);
    // From lattice points inside the box, far from the target, and from
    // points of a 64 times finer lattice near it.
    std::mt19937 rng(11);
    std::uniform_int_distribution<int> anywhere(1, n - 1), near(1, 2);
    const glm::vec3 hi = lo + float(n) * step;
    std::vector<Ray> rays;
    for (const glm::vec3& target : vertices) {
        for (int k = 0; k < 4; ++k) {
            glm::vec3 p = lo + step * glm::vec3(anywhere(rng), anywhere(rng), anywhere(rng));
            if (k >= 2)
                for (int a = 0; a < 3; ++a) {
                    const float towards = target[a] == lo[a]   ? 1.0f
                                          : target[a] == hi[a] ? -1.0f
                                          : rng() % 2          ? 1.0f
                                                               : -1.0f;
                    p[a] = glm::clamp(target[a] + towards * step / 64.0f * float(near(rng)), lo[a] + step / 64.0f,
                                      hi[a] - step / 64.0f);
                }
            rays.push_back(Ray{p, 2.0f, target - p, 0});                  // leaves the box at the target
            rays.push_back(Ray{2.0f * target - p, 2.0f, p - target, 0});  // enters it there
        }
    }
    size_t escaped = 0;
    for (const RayHit& h : tracer.trace(rays)) escaped += h.triangle == kNoHit;
    EXPECT_EQ(escaped, 0u) << "of " << rays.size() << " rays through the lattice's vertices";
}

// Two squares sharing an edge at x = 0, the boxes on one side of it tested
// in nodes whose corners are 512 and more units away (a square far out makes
// them so). A ray from close by that crosses the edge meets such a box's
// plane at t = (corner - org) / dir + q step / dir, two terms of about
// 512 / |dir| that cancel to about 1: their rounding is then thousands of
// ulps of t. Without each axis's slack in intersect_boxes the box could be
// dropped, and the ray miss the surface where the edge falls to that side
// (with dff5986's shader, 84 of these 2,032 rays did).
TEST(Tracer, ASharedEdgeBetweenNodesFarApartIsWatertight) {
    gpu();
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(0.5f));
    auto square = [&](float x0, float x1) { test::add_quad(s, {x0, 0.0f, 0.0f}, {x1 - x0, 0, 0}, {0, 16, 0}, m); };
    // A (scene triangles 0 to 7) and B (8 to 15): 2 x 2 quads each, so the
    // surface area heuristic splits the scene between them.
    for (float x0 : {-16.0f, 0.0f})
        for (float dx : {0.0f, 8.0f})
            for (float y0 : {0.0f, 8.0f}) test::add_quad(s, {x0 + dx, y0, 0.0f}, {8, 0, 0}, {0, 8, 0}, m);
    square(-512.0f, -32.0f);
    square(32.0f, 512.0f);
    square(-2048.0f, -2032.0f);
    square(2032.0f, 2048.0f);
    const Bvh bvh = build_bvh(s);
    // The setup this test needs: a box that ends at the shared edge is
    // tested in a node whose corner is 512 units or more away.
    bool far_box_at_edge = false;
    for (const BvhNode& node : bvh.nodes)
        for (int c = 0; c < kBvhWidth; ++c)
            far_box_at_edge |= node.child_used(c) && node.origin.x <= -512.0f && node.child_box(c).hi.x == 0.0f;
    ASSERT_TRUE(far_box_at_edge);

    Tracer tracer(s);
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> offset(1.0f / 64.0f, 1.0f / 8.0f);
    auto any_sign = [&] { return rng() % 2 ? offset(rng) : -offset(rng); };
    std::vector<Ray> rays;
    for (int k = 1; k < 128; ++k) {  // towards points on the shared edge, from random points close by
        const glm::vec3 target(0.0f, float(k) / 8.0f, 0.0f);
        for (int r = 0; r < 16; ++r) {
            const glm::vec3 org = target + glm::vec3(any_sign(), any_sign(), any_sign());
            rays.push_back(Ray{org, 2.0f, target - org, 0});
        }
    }
    size_t escaped = 0;
    for (const RayHit& h : tracer.trace(rays)) escaped += h.triangle == kNoHit;
    EXPECT_EQ(escaped, 0u) << "of " << rays.size() << " rays across the shared edge";
}

// Rays leaving a convex surface outward, far from the origin where float
// spacing is coarse, must not hit the surface they start on.
TEST(Tracer, OffsetOriginsDoNotSelfIntersect) {
    gpu();
    for (float distance : {0.0f, 1000.0f, 100000.0f}) {
        Scene s;
        const uint32_t m = test::add_material(s, glm::vec3(0.5f));
        test::add_icosphere(s, glm::vec3(distance, distance * 0.5f, -distance), 1.0f + distance * 1e-3f, 2, m);
        Tracer tracer(s);
        std::mt19937 rng(7);
        std::uniform_real_distribution<float> u(0.0f, 1.0f);
        std::vector<Ray> rays;
        for (size_t t = 0; t < s.triangles.size(); ++t) {
            const glm::uvec3 tri = s.triangles[t];
            const float a = u(rng), b = u(rng) * (1.0f - a);
            const glm::vec3 p = (1 - a - b) * s.positions[tri.x] + a * s.positions[tri.y] + b * s.positions[tri.z];
            const glm::vec3 n = s.geometric_normal(t);
            glm::vec3 d = random_direction(rng);
            if (glm::dot(d, n) < 0.0f) d = -d;
            rays.push_back(Ray{offset_ray_origin(p, n), 1e9f, d, 0});
        }
        size_t self_hits = 0;
        for (const RayHit& h : tracer.trace(rays)) self_hits += h.triangle != kNoHit;
        EXPECT_EQ(self_hits, 0u) << "at distance " << distance;
    }
}

TEST(Tracer, OcclusionAgreesWithClosestHit) {
    gpu();
    const Scene scene = load_scene(test::example_scene("monkey.glb"));
    Tracer tracer(scene);
    std::vector<Ray> rays = random_rays(scene, 4000, 99);
    std::vector<Ray> shadow = rays;
    for (size_t i = 0; i < rays.size(); ++i) {
        shadow[i].any_hit = 1;
        shadow[i].t_max = (i % 3 == 0) ? 0.05f : rays[i].t_max;  // short rays too
    }
    const auto closest = tracer.trace(rays);
    const auto occluded = tracer.trace(shadow);
    for (size_t i = 0; i < rays.size(); ++i) {
        const bool blocked = closest[i].triangle != kNoHit && closest[i].t < shadow[i].t_max;
        // Allow a hit within float rounding of t_max to go either way.
        if (closest[i].triangle != kNoHit && std::abs(closest[i].t - shadow[i].t_max) < 1e-5f) continue;
        EXPECT_EQ(occluded[i].triangle != kNoHit, blocked) << "ray " << i;
    }
}

// A scene of one quad has a single-leaf root whose other child slots are
// unused. No ray may enter them: an unused slot's index leads back to the
// root (the traversal would loop), and its planes decode to a box like any
// other, so it is the traversal's check of index and count that skips it.
TEST(Bvh, UnusedChildSlotsAreUnreachable) {
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(0.5f));
    test::add_quad(s, {-1, 0, 1}, {2, 0, 0}, {0, 0, -2}, m);
    const Bvh bvh = build_bvh(s);
    ASSERT_EQ(bvh.nodes.size(), 1u);
    ASSERT_TRUE(bvh.nodes[0].child_used(0));
    for (int c = 1; c < kBvhWidth; ++c) {
        ASSERT_FALSE(bvh.nodes[0].child_used(c));
        EXPECT_EQ(bvh.nodes[0].index[c], 0u);
        EXPECT_EQ(bvh.nodes[0].count(c), 0u);
    }
    gpu();
    Tracer tracer(s);
    // The upward ray starts inside the unused slots' boxes (at the corner).
    const auto hits = tracer.trace({Ray{glm::vec3(0.2f, 0.5f, 0.1f), 10.0f, glm::vec3(0, -1, 0), 0},
                                    Ray{glm::vec3(0.2f, 0.5f, 0.1f), 10.0f, glm::vec3(0, 1, 0), 0},
                                    Ray{glm::vec3(-1.0f, 0.0f, -1.0f), 10.0f, glm::vec3(0, 1, 0), 0}});
    EXPECT_EQ(hits[0].triangle != kNoHit, true);
    EXPECT_NEAR(hits[0].t, 0.5f, 1e-6f);
    EXPECT_EQ(hits[1].triangle, kNoHit);
    EXPECT_EQ(hits[2].triangle, kNoHit);
}

TEST(Tracer, EmptySceneMissesEverything) {
    gpu();
    Scene s;
    Tracer tracer(s);
    const auto hits = tracer.trace({Ray{glm::vec3(0), 100.0f, glm::vec3(0, 0, 1), 0}});
    ASSERT_EQ(hits.size(), 1u);
    EXPECT_EQ(hits[0].triangle, kNoHit);
}

TEST(Bvh, BoundsContainTheirTrianglesAndEveryTriangleIsInOneLeaf) {
    const Scene scene = load_scene(test::example_scene("monkey.glb"));
    const Bvh bvh = build_bvh(scene);
    std::vector<int> seen(scene.triangles.size(), 0);
    auto check_leaf = [&](glm::vec3 lo, glm::vec3 hi, uint32_t first, uint32_t count) {
        for (uint32_t i = first; i < first + count; ++i) {
            const BvhTriangle& t = bvh.triangles[i];
            for (glm::vec3 v : {t.v0, t.v1, t.v2}) {
                EXPECT_TRUE(glm::all(glm::greaterThanEqual(v, lo)) && glm::all(glm::lessThanEqual(v, hi)));
            }
            ++seen[t.scene_triangle];
        }
    };
    for (const BvhNode& n : bvh.nodes) {
        for (int c = 0; c < kBvhWidth; ++c)
            if (n.count(c)) check_leaf(n.child_box(c).lo, n.child_box(c).hi, n.index[c], n.count(c));
    }
    for (size_t t = 0; t < seen.size(); ++t) EXPECT_EQ(seen[t], scene.triangle_area(t) > 0.0f ? 1 : 0) << t;
    EXPECT_LE(bvh.stats.max_depth, size_t(kBvhMaxDepth));
}

// The 4-wide tree is a tree (every node but the root is one child of one
// node) and its nodes are full: a node has fewer
// than four children only where none of them could be opened (all leaves).
// That is what halves the node visits against the binary tree it came from.
// The tree is built on several threads near its root (each half into a
// node list of its own) and comes out the same, node for node, as on one:
// the breakfast room (269,538 triangles) on one thread and on four.
TEST(Bvh, TheSameTreeOnOneThreadAsOnFour) {
    const Scene scene = load_scene(test::example_scene("real/breakfast_room/breakfast_room.gltf"));
    auto build = [&](const char* threads) {
        const test::ThreadCount count(threads);
        return build_bvh(scene);
    };
    const Bvh one = build("1"), four = build("4");
    ASSERT_EQ(one.nodes.size(), four.nodes.size());
    ASSERT_EQ(one.triangles.size(), four.triangles.size());
    EXPECT_EQ(0, std::memcmp(one.nodes.data(), four.nodes.data(), one.nodes.size() * sizeof(BvhNode)));
    EXPECT_EQ(0, std::memcmp(one.triangles.data(), four.triangles.data(), one.triangles.size() * sizeof(BvhTriangle)));
    EXPECT_EQ(one.stats.sah_cost, four.stats.sah_cost);
}

TEST(Bvh, FourWideNodesAreFullAndFormOneTree) {
    const Scene scene = load_scene(test::example_scene("real/wooden_staircase/wooden_staircase.gltf"));
    const Bvh bvh = build_bvh(scene);
    std::vector<int> parents(bvh.nodes.size(), 0);
    size_t interior_children = 0;
    for (const BvhNode& n : bvh.nodes) {
        int used = 0, leaves = 0;
        for (int c = 0; c < kBvhWidth; ++c) {
            if (!n.child_used(c)) continue;
            ++used;
            if (n.count(c) > 0) {
                ++leaves;
                continue;
            }
            ++interior_children;
            ASSERT_LT(n.index[c], bvh.nodes.size());
            ++parents[n.index[c]];
        }
        EXPECT_TRUE(used == kBvhWidth || used == leaves) << used << " children, " << leaves << " leaves";
    }
    EXPECT_EQ(parents[0], 0);
    for (size_t i = 1; i < parents.size(); ++i) EXPECT_EQ(parents[i], 1) << "node " << i;
    EXPECT_EQ(interior_children, bvh.nodes.size() - 1);
    EXPECT_GT(bvh.stats.leaves, 2 * bvh.nodes.size()) << "a 4-wide tree has over two leaves per node";
}

// The quantized child boxes (BvhNode) as the traversal decodes them: each
// contains every triangle below it, and is larger than those triangles'
// bounds by less than one step on each side, a step being under 2/255 of
// its node's extent (or the smallest normal float, for a flat axis).
TEST(Bvh, QuantizedBoxesContainTheirTrianglesWithinAStep) {
    const Scene scene = load_scene(test::example_scene("real/wooden_staircase/wooden_staircase.gltf"));
    const Bvh bvh = build_bvh(scene);
    auto triangle_bounds = [&](uint32_t first, uint32_t count) {
        Bounds b;
        for (uint32_t i = first; i < first + count; ++i)
            for (glm::vec3 v : {bvh.triangles[i].v0, bvh.triangles[i].v1, bvh.triangles[i].v2}) b.extend(v);
        return b;
    };
    // The exact bounds of node n's triangles, checking its children's boxes on the way.
    size_t boxes = 0, failures = 0;
    std::function<Bounds(uint32_t)> check = [&](uint32_t n) {
        const BvhNode& node = bvh.nodes[n];
        Bounds exact[kBvhWidth], all;
        for (int c = 0; c < kBvhWidth; ++c) {
            if (!node.child_used(c)) continue;
            exact[c] = node.count(c) ? triangle_bounds(node.index[c], node.count(c)) : check(node.index[c]);
            all.extend(exact[c]);
        }
        for (int c = 0; c < kBvhWidth; ++c) {
            if (!node.child_used(c)) continue;
            const Bounds box = node.child_box(c);
            for (int a = 0; a < 3; ++a) {
                const double extent = double(all.hi[a]) - double(all.lo[a]);
                const double step = std::max(2.0 * extent / 255.0, std::ldexp(1.0, -126));
                const float magnitude = std::max(std::abs(all.lo[a]), std::abs(all.hi[a]));
                const double ulp = double(std::nextafter(magnitude, INFINITY)) - double(magnitude);
                const double slack = step + ulp;  // child_box rounds the decoded planes outwards to floats
                const bool contains = box.lo[a] <= exact[c].lo[a] && box.hi[a] >= exact[c].hi[a];
                const bool tight = exact[c].lo[a] - box.lo[a] <= slack && box.hi[a] - exact[c].hi[a] <= slack;
                if (!contains || !tight) {
                    if (++failures <= 5)
                        ADD_FAILURE() << "node " << n << " child " << c << " axis " << a << ": box [" << box.lo[a]
                                      << ", " << box.hi[a] << "], triangles [" << exact[c].lo[a] << ", "
                                      << exact[c].hi[a] << "], step under " << step;
                }
            }
            ++boxes;
        }
        return all;
    };
    check(0);
    EXPECT_EQ(failures, 0u);
    EXPECT_EQ(boxes, bvh.nodes.size() - 1 + bvh.stats.leaves);
}

TEST(GpuContext, ReportsDeviceAndRefusesAMissingGpu) {
    const DeviceInfo& info = gpu().info();
    EXPECT_FALSE(info.renderer.empty());
    EXPECT_NE(info.version.find("4.5"), std::string::npos) << info.version;
    EXPECT_THROW(parse_device_choice("tpu"), std::invalid_argument);
    EXPECT_THROW(parse_device_choice("gpu:x"), std::invalid_argument);
    EXPECT_EQ(parse_device_choice("gpu:2").kind, DeviceChoice::Gpu);
    EXPECT_EQ(parse_device_choice("gpu:2").gpu_index, 2);
    // The devices listed match what the context found: software iff no GPU was usable here.
    size_t gpus = 0;
    for (const EglDeviceInfo& d : list_egl_devices()) gpus += d.software ? 0 : 1;
    if (gpus == 0) {
        EXPECT_TRUE(info.is_software);
    }
    if (info.is_software) {
        // Auto fell back to software: there is no GPU, so asking for one must fail clearly.
        try {
            GpuContext second(DeviceChoice::Gpu);
            FAIL() << "--device gpu succeeded on a machine whose auto choice was software";
        } catch (const GpuError& e) {
            EXPECT_NE(std::string(e.what()).find("no GPU"), std::string::npos) << e.what();
        }
    }
}

TEST(Shaders, CompileErrorsNameTheFileAndCarryTheLog) {
    gpu();
    try {
        ComputeProgram p("no_such_shader.comp");
        FAIL();
    } catch (const GpuError& e) {
        EXPECT_NE(std::string(e.what()).find("no_such_shader.comp"), std::string::npos);
    }
    // A program that traces, built without the Tracer, is told to be.
    try {
        ComputeProgram p("trace_rays.comp");
        FAIL();
    } catch (const GpuError& e) {
        EXPECT_NE(std::string(e.what()).find("Tracer::program"), std::string::npos) << e.what();
    }
    // Includes are resolved once each and carry #line markers.
    auto [source, files] = assemble_shader_source("raybench.comp", {{"EXTRA", "1"}});
    ASSERT_EQ(files.front(), "raybench.comp");
    EXPECT_NE(std::find(files.begin(), files.end(), "trace.glsl"), files.end());
    EXPECT_EQ(source.rfind("#version 450", 0), 0u);
    EXPECT_NE(source.find("#define EXTRA 1"), std::string::npos);
}

// A program's parameters are one block, set whole (ComputeProgram::use):
// a uniform outside it refuses to build, and a C++ struct of another size
// than the block (a field added on one side only) is refused at use, both
// naming the program.
TEST(Shaders, ParametersAreOneBlockOfTheCppStructsSize) {
    gpu();
    try {
        ComputeProgram p("dispatch_check.comp", {{"LF_CHECK_STRAY_UNIFORM", "1"}});
        FAIL() << "a uniform outside the parameter block was accepted";
    } catch (const GpuError& e) {
        EXPECT_NE(std::string(e.what()).find("dispatch_check.comp: uniform 'stray'"), std::string::npos) << e.what();
    }
    const ComputeProgram program("dispatch_check.comp");
    struct Larger {
        CheckParams params;
        uint32_t extra[4];
    };
    try {
        program.use(Larger{});
        FAIL() << "a struct 16 bytes larger than the block was accepted";
    } catch (const GpuError& e) {
        EXPECT_NE(std::string(e.what()).find("dispatch_check.comp: its parameter block is"), std::string::npos)
            << e.what();
    }
    static_assert(sizeof(CheckParams) % 16 != 0, "the next check needs a struct std140 pads");
    EXPECT_NO_THROW(program.use(CheckParams{})) << "std140 rounds the block up to 16 bytes";
}

// dispatch_1d past GL's 65,535 groups per dimension (4.2 M items of 64): every
// item is visited once, and a per-group buffer sized by groups_1d holds every
// group that runs (the spill into y rounds the count up to whole rows; a
// buffer sized ceil(n / 64) was overrun by real atlases of 4096²).
TEST(GpuDispatch, CoversEveryItemOnceBeyond65535Groups) {
    gpu();
    const ComputeProgram program("dispatch_check.comp");
    for (const size_t n : {size_t(1), size_t(65535) * 64, size_t(65535) * 64 + 1, size_t(65535) * 64 * 2 + 777}) {
        const size_t groups = program.groups_1d(n);
        EXPECT_GE(groups * 64, n);
        // One extra slot past the end: nothing may write it.
        GpuBuffer visits(std::vector<uint32_t>(n, 0u)), slots(std::vector<uint32_t>(groups + 1, 0u));
        CheckParams params{};
        params.item_count = uint32_t(n);
        program.use(params);
        visits.bind(LF_BINDING_ITEM_VISITS);
        slots.bind(LF_BINDING_GROUP_SLOTS);
        program.dispatch_1d(n);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
        const std::vector<uint32_t> v = visits.read<uint32_t>();
        size_t wrong = 0;
        for (uint32_t count : v) wrong += count != 1u;
        EXPECT_EQ(wrong, 0u) << n << " items";
        const std::vector<uint32_t> s = slots.read<uint32_t>();
        for (size_t g = 0; g < groups; ++g) ASSERT_EQ(s[g], uint32_t(g + 1)) << "group " << g << " of " << groups;
        EXPECT_EQ(s[groups], 0u) << "a group beyond groups_1d(" << n << ") ran";
    }
}

// A buffer larger than a shader can address is refused before GL allocates
// it, with its size in the message (the 4096² staircase's 2.26 GB of sample
// points crashed llvmpipe's worker instead).
TEST(GpuBuffer, RefusesMoreThanAShaderCanAddress) {
    gpu();
    try {
        GpuBuffer too_large(kMaxGpuBufferBytes + 1);
        FAIL() << "a buffer of " << too_large.bytes() << " bytes was made";
    } catch (const GpuBufferTooLarge& e) {
        EXPECT_NE(std::string(e.what()).find("2.15 GB"), std::string::npos) << e.what();
    }
    EXPECT_LT(kMaxGpuBufferBytes, size_t(1) << 31);
}

}  // namespace
}  // namespace lf
