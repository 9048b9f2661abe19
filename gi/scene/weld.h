// Which vertices are the same point: glTF files split a vertex wherever any
// attribute changes (normals at a crease, UVs at a seam), and separate meshes
// that touch share no vertices at all, so sameness is decided by position,
// never by vertex index. The atlas's topology (atlas/mesh_topology.h) and the
// scene's closed volumes (Scene::closed_volumes) both weld so.
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>

#include <cstdint>
#include <vector>

namespace lf {

// Distance under which two vertices count as one point: 1e-5 of the scene's
// bounding-box diagonal (a 10 m room: 0.1 mm).
float weld_tolerance(const Scene& scene);

// weld[v] is the representative of v: the first vertex (in index order)
// within `tolerance` of it. Vertices closer than the tolerance get one representative.
std::vector<uint32_t> weld_positions(const std::vector<glm::vec3>& positions, float tolerance);

}  // namespace lf
