// A bounding volume hierarchy over the scene's triangles, built on the CPU
// with the binned surface area heuristic and laid out for GPU traversal.
#pragma once

#include "scene/scene.h"
#include "shaders/bvh_layout.glsl"

#include <glm/glm.hpp>

#include <cmath>
#include <cstdint>
#include <vector>

namespace lf {

// One node of the 4-wide tree: the boxes of up to four children, so one
// fetch of 128 bytes decides which children a ray enters and in which order
// (Aila & Laine 2009 for two boxes per node; Wald, Benthin & Boulos 2008 and
// Ylitie, Karras & Laine 2017 for wider nodes: half the node visits of a
// binary tree, and four slab tests that share their loads). The boxes are
// stored as structure of arrays, child c's box being (lo_x[c], lo_y[c],
// lo_z[c]) to (hi_x[c], hi_y[c], hi_z[c]), so the four slab tests are vec4
// arithmetic. A child is either another node (count 0, index = node) or a
// leaf (count > 0, index = first triangle in Bvh::triangles). An unused slot
// has a box at +infinity: no ray enters it.
struct BvhNode {
    glm::vec4 lo_x, hi_x, lo_y, hi_y, lo_z, hi_z;
    glm::uvec4 index;
    glm::uvec4 count;

    Bounds child_box(int c) const { return {{lo_x[c], lo_y[c], lo_z[c]}, {hi_x[c], hi_y[c], hi_z[c]}}; }
    bool child_used(int c) const { return !std::isinf(lo_x[c]); }
};
static_assert(sizeof(BvhNode) == 128);
constexpr int kBvhWidth = LF_BVH_WIDTH;
static_assert(kBvhWidth == 4, "BvhNode holds its children as the components of vec4s");

// A triangle as the traversal reads it: three vertices, 48 bytes; the
// scene's triangle index rides in the first vertex's w.
struct BvhTriangle {
    glm::vec3 v0;
    uint32_t scene_triangle;
    glm::vec3 v1;
    float pad1;
    glm::vec3 v2;
    float pad2;
};
static_assert(sizeof(BvhTriangle) == 48);

struct BvhStats {
    double build_seconds = 0.0;
    size_t nodes = 0;
    size_t leaves = 0;
    size_t max_depth = 0;   // of the 4-wide tree (the root's children: 1)
    size_t bytes = 0;       // nodes + triangles as uploaded
    double sah_cost = 0.0;  // expected cost, traversal step = 1, triangle test = 1
};

struct Bvh {
    std::vector<BvhNode> nodes;          // nodes[0] is the root
    std::vector<BvhTriangle> triangles;  // in leaf order
    BvhStats stats;
};

// The deepest the binary tree may go. The 4-wide tree, collapsed from it, is
// no deeper, and the GLSL traversal's stack is sized from it
// (shaders/bvh_layout.glsl, where both numbers are defined for both languages).
constexpr int kBvhMaxDepth = LF_BVH_MAX_DEPTH;

// Builds over all triangles with non-zero area (degenerate ones can never be
// hit and are left out): a binary tree by binned SAH (32 bins, leaves of at
// most 8 triangles), collapsed into 4-wide nodes by opening, in each node, the
// child of largest surface area until four children fill it.
Bvh build_bvh(const Scene& scene);

}  // namespace lf
