// glTF 2.0 (.gltf with external or data: buffers and images, and .glb) -> Scene.
//
// The loader treats every file as hostile: it reads nothing outside the
// scene's own directory, expands nothing, checks every size and index itself
// before using it, and refuses anything malformed with one line that names the
// file, the glTF object and what is wrong with it, e.g.
//   scene.gltf: accessor 12: byteOffset+length 4096 exceeds bufferView 3 length 2048
// Problems that do not make the file unusable (no light source, skipped
// primitives, ignored extensions) go to Scene::warnings instead.
#pragma once

#include "scene/scene.h"

#include <cstdint>
#include <filesystem>
#include <stdexcept>

namespace lf {

struct LoadLimits {
    // Bytes read from disk for one scene: the .gltf/.glb plus every external
    // buffer and image it references. Checked before anything is read.
    uint64_t max_file_bytes = 1ull << 30;
    // Triangles after node instancing, checked before geometry is allocated.
    uint64_t max_triangles = 20'000'000;
    // Largest width or height of an image, checked from its header before it is decoded.
    int max_texture_dim = 8192;
    // Texels of all decoded textures together (each becomes 16 bytes of
    // linear float RGBA): 2^26 = one 8192² texture, or 1 GiB.
    uint64_t max_total_texels = uint64_t(1) << 26;
    // false: images are checked from their headers (format, sizes, budget)
    // and not decoded; Texture::texels stay empty. What an upload check
    // needs: a 200 KB PNG of 8192² zeros would otherwise cost 1.3 GB.
    bool decode_images = true;
    // Largest |coordinate| of a world-space vertex, in metres. float32 has
    // about a metre of precision at 1e7 m, far past any scene a lightmap can
    // serve, and coordinates near float's limit overflow every derived size
    // (chart grids, atlas texels: found by fuzzing).
    float max_coordinate = 1e7f;
};

// A file lightfarm cannot or will not load. what() is one line:
// "<file name>: <object> <index>: <what is wrong>".
class SceneError : public std::runtime_error {
public:
    using runtime_error::runtime_error;
};

// Loads the default scene (else scene 0, else every root node) of a glTF 2.0
// file into world space. Throws SceneError; never reads outside file's directory.
Scene load_scene(const std::filesystem::path& file, const LoadLimits& limits = {});

}  // namespace lf
