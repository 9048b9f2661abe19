// Shared by the atlas, texel and seam code: which vertices are the same point
// and which triangle edges are the same edge, across meshes.
//
// glTF files split a vertex wherever any attribute changes (normals at a
// crease, UVs at a seam) and separate meshes that touch share no vertices at
// all, so adjacency is decided by position, never by vertex index.
#pragma once

#include "scene/scene.h"
#include "scene/weld.h"

#include <glm/glm.hpp>

#include <cstdint>
#include <vector>

namespace lf::atlas_detail {

// Vertices welded by position: scene/weld.h.
using lf::weld_positions;
using lf::weld_tolerance;

// Edge k of a triangle runs from corner k to corner (k+1) % 3.
struct EdgeRef {
    uint32_t triangle;
    uint32_t edge;
};

// Triangle edges grouped by their welded endpoints, either orientation. Group g
// is edges[group_start[g] .. group_start[g+1]); only groups with two or more
// edges (edges that something else shares) are kept. Edges whose endpoints
// weld together (degenerate) are left out.
struct SharedEdges {
    std::vector<EdgeRef> edges;
    std::vector<uint32_t> group_start;
    size_t group_count() const { return group_start.empty() ? 0 : group_start.size() - 1; }
};
SharedEdges find_shared_edges(const std::vector<glm::uvec3>& triangles, const std::vector<uint32_t>& weld);

}  // namespace lf::atlas_detail
