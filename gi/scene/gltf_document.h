// The glTF container and JSON, checked before tinygltf sees them (internal to gi/scene).
//
// tinygltf trusts its input in ways a service cannot: it reads a GLB BIN chunk
// 8 bytes past a length it checked, silently turns a negative byteOffset into
// 0, truncates a 64-bit index to int, recurses into "extras" as deep as the
// JSON nests, and resolves URIs with the shell's wordexp. So the loader reads
// the file itself, checks the GLB container, parses the JSON once with
// nlohmann::json and checks everything tinygltf would misread or trip over
// (asset version, required extensions, buffers and their URIs, bufferView and
// accessor fields, image URIs), approving each external file tinygltf may
// then read. What is left (ranges of views and accessors against the real
// buffer sizes, indices, node graph) is checked on tinygltf's Model.
#pragma once

#include "scene/gltf_errors.h"
#include "scene/gltf_files.h"

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace lf::gltf {

// Extensions the loader implements; a file requiring any other is refused.
bool is_implemented_extension(std::string_view name);

struct Document {
    std::vector<unsigned char> bytes;  // the whole .gltf or .glb file
    bool binary = false;               // GLB container
    size_t json_offset = 0;            // the JSON text within bytes
    size_t json_size = 0;
    std::vector<bool> used_images;  // images behind a base colour or emissive texture
    std::vector<std::string> warnings;
};

// Reads `file` (charging its size to files' budget) and checks container and
// JSON as described above. Throws SceneError.
Document read_document(const fs::path& file, const LoadLimits& limits, const Errors& errors, SceneFiles& files);

}  // namespace lf::gltf
