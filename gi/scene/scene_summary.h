// What a loaded Scene holds, for `lightfarm inspect` and the server's answer
// to an upload: counts, lights, textures, lightmap UVs, extent, warnings.
#pragma once

#include "scene/scene.h"
#include "worker_protocol.h"

#include <nlohmann/json.hpp>

#include <string>

namespace lf {

// {
//   "source": "scenes/cornell_box.gltf",
//   "triangles": 32, "vertices": 64,
//   "meshes": 4,                      distinct glTF meshes placed by the scene
//   "primitive_instances": 16,        (node, primitive) pairs baked
//   "materials": 5,
//   "emissive_triangles": 2,
//   "punctual_lights": {"point": 0, "spot": 0, "directional": 0},
//   "textures": 0,
//   "max_texture_size": 0,            pixels, the longest side of any texture
//                                     (the server checks it against its limit)
//   "lightmap_uvs": {"all_primitives": true, "primitives_with_texcoord_1": 16},
//   "bounds": {"lo": [x, y, z], "hi": [x, y, z]},        null for an empty scene
//   "surface_area": 5.57,             m², sum of triangle areas
//   "warnings": ["..."]
// }
protocol::SceneSummary summarize(const Scene& scene);

// The same as a few lines of text, ending in a newline.
std::string format_summary(const Scene& scene);

}  // namespace lf
