// A bounding volume hierarchy over the scene's triangles, built on the CPU
// with the binned surface area heuristic and laid out for GPU traversal.
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>

#include <cstdint>
#include <vector>

namespace lf {

// One interior node, 64 bytes: the boxes of BOTH children, so one fetch
// decides which children a ray enters and in which order (Aila & Laine 2009).
// A child is either another node (count 0, index = node) or a leaf
// (count > 0, index = first triangle in Bvh::triangles). An unused slot (the
// root of a tiny or empty scene) has a box at +infinity: no ray enters it.
struct BvhNode {
    glm::vec3 left_lo;
    uint32_t left_index;
    glm::vec3 left_hi;
    uint32_t right_index;
    glm::vec3 right_lo;
    uint32_t left_count;
    glm::vec3 right_hi;
    uint32_t right_count;
};
static_assert(sizeof(BvhNode) == 64);

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
    size_t max_depth = 0;
    size_t bytes = 0;       // nodes + triangles as uploaded
    double sah_cost = 0.0;  // expected cost, traversal step = 1, triangle test = 1
};

struct Bvh {
    std::vector<BvhNode> nodes;          // nodes[0] is the root
    std::vector<BvhTriangle> triangles;  // in leaf order
    BvhStats stats;
};

// The deepest a tree may go; the GLSL traversal stack is sized from it.
constexpr int kBvhMaxDepth = 48;

// Builds over all triangles with non-zero area (degenerate ones can never be
// hit and are left out). Binned SAH, 32 bins, leaves of at most 8 triangles.
Bvh build_bvh(const Scene& scene);

}  // namespace lf
