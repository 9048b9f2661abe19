// A bounding volume hierarchy over the scene's triangles, built on the CPU
// with the binned surface area heuristic and laid out for GPU traversal.
#pragma once

#include "scene/scene.h"
#include "shaders/bvh_layout.glsl"

#include <glm/glm.hpp>

#include <cstdint>
#include <vector>

namespace lf {

// One node of the 4-wide tree: the boxes of up to four children, so one
// fetch decides which children a ray enters and in which order (Aila &
// Laine 2009 for two boxes per node; Wald, Benthin & Boulos 2008 and Ylitie,
// Karras & Laine 2017 for wider nodes: half the node visits of a binary
// tree, and four slab tests that share their loads).
//
// The child boxes are quantized as in Ylitie et al.'s compressed wide BVH:
// each is given in steps of a power of two from the low corner of the
// node's own box, one byte per plane, the step of each axis the smallest
// with which 255 of them span the node. Low planes are rounded down and
// high planes up, so a decoded box always contains its child. A node is 64
// bytes instead of 128 with float boxes: half the memory each visit reads.
// The byte of child c in a plane word is byte c (bits 8c to 8c + 7), so the
// four slab tests stay vec4 arithmetic.
//
// A child is either another node (count 0, index = node) or a leaf
// (count > 0, index = first triangle in Bvh::triangles). An unused slot has
// index 0 and count 0 (index 0 is the root, never a child): the traversal
// skips it, since no box is empty under a min/max slab test.
struct BvhNode {
    glm::vec3 origin{0.0f};       // the low corner of the node's box
    uint32_t step_exponents = 0;  // bits 8a to 8a + 7: axis a's step as a float's biased exponent
    uint32_t planes[6] = {};      // lo_x, hi_x, lo_y, hi_y, lo_z, hi_z: byte c is child c's, in steps
    uint32_t counts[2] = {};      // child c's triangle count in bits 16 (c % 2) to 16 (c % 2) + 15 of counts[c / 2]
    glm::uvec4 index{0};

    uint32_t count(int c) const { return (counts[c / 2] >> (16 * (c % 2))) & 0xffffu; }
    bool child_used(int c) const { return index[c] != 0 || count(c) != 0; }
    // Child c's box as the traversal decodes it, rounded outwards to floats.
    Bounds child_box(int c) const;
};
static_assert(sizeof(BvhNode) == 16 * LF_BVH_NODE_UVEC4S);
constexpr int kBvhWidth = LF_BVH_WIDTH;
static_assert(kBvhWidth == 4, "BvhNode holds its children as the components of vec4s");
// A leaf's count has 16 bits; the binary tree's leaves hold at most 8
// triangles, except where the depth limit ends a subtree early.
constexpr uint32_t kBvhMaxLeafTriangles = 0xffff;

// A triangle as the traversal reads it: three vertices, 48 bytes; the
// scene's triangle index rides in the first vertex's w.
struct BvhTriangle {
    glm::vec3 v0;
    uint32_t scene_triangle;
    glm::vec3 v1;
    float pad1;  // the Tracer's: uint bits 1 for a see-through triangle
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
