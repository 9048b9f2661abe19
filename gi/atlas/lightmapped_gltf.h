// scene.lightmapped.glb: the input glTF with the generated lightmap UVs added
// as TEXCOORD_1 (DESIGN.md "Outputs"), so an engine can apply the lightmap.
#pragma once

#include "scene/scene.h"

#include <filesystem>

namespace lf {

// Re-reads `source_gltf` (the file `scene` was loaded from, already
// validated by lf::load_scene) and writes `out_glb`: every primitive that
// `scene` instances gets TEXCOORD_1 from Scene::uv1. Where the atlas split
// vertices (Scene::source_vertex), the primitive gets new vertex attributes
// (every attribute and morph target gathered through source_vertex, so
// positions are bit-for-bit the originals) and a new TRIANGLES index buffer.
// A mesh placed by several nodes is copied for each extra node, since each
// placement has its own atlas region. Buffers are merged into the GLB's
// binary chunk and external images embedded. The write is atomic (temporary
// file in the same directory, then rename). Throws std::runtime_error.
void write_lightmapped_glb(const std::filesystem::path& source_gltf, const Scene& scene,
                           const std::filesystem::path& out_glb);

}  // namespace lf
