#include "scene/gltf_reread.h"

#include "scene/glb.h"
#include "scene/gltf_files.h"

#include <nlohmann/json.hpp>

#include <fstream>
#include <iterator>
#include <limits>
#include <stdexcept>
#include <string>

namespace lf {

namespace {

// The document's JSON: the file, or a glb's first chunk.
nlohmann::json document_json(const std::vector<unsigned char>& bytes, bool binary) {
    if (!binary) return nlohmann::json::parse(bytes.begin(), bytes.end(), nullptr, false);
    if (bytes.size() < 20) return nlohmann::json();
    const uint32_t length = glb::read_u32(bytes.data(), 12);
    if (uint64_t(length) + 20 > bytes.size()) return nlohmann::json();
    return nlohmann::json::parse(bytes.begin() + 20, bytes.begin() + 20 + length, nullptr, false);
}

}  // namespace

tinygltf::Model reread_gltf(const std::filesystem::path& file, tinygltf::LoadImageDataFunction image_loader,
                            void* user) {
    const std::string name = file.filename().string();
    std::ifstream in(file, std::ios::binary);
    const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (!in.good() && !in.eof()) throw std::runtime_error(name + ": cannot re-read");
    const bool binary = bytes.size() >= 4 && glb::read_u32(bytes.data(), 0) == glb::kMagic;

    // The files it names, each approved under the path tinygltf will ask for
    // (gltf::SceneFiles): tinygltf decodes a URI as a form does ('+' becomes a
    // space), glTF's URIs are RFC 3986's ('+' is a plus), so its own reads
    // missed "a+b.bin" (issue #53: a scene that baked failed at its glbs).
    // load_scene accepted every one of them already.
    std::error_code ec;
    const std::filesystem::path dir = std::filesystem::canonical(std::filesystem::absolute(file).parent_path(), ec);
    gltf::SceneFiles files(dir, std::numeric_limits<uint64_t>::max());
    const nlohmann::json doc = document_json(bytes, binary);
    for (const char* list : {"buffers", "images"}) {
        if (!doc.is_object() || !doc.contains(list) || !doc[list].is_array()) continue;
        for (const nlohmann::json& entry : doc[list]) {
            if (!entry.is_object() || !entry.contains("uri") || !entry["uri"].is_string()) continue;
            const std::string uri = entry["uri"];
            if (gltf::is_data_uri(uri)) continue;
            std::string why;
            const std::filesystem::path resolved = gltf::resolve_scene_file(dir, uri, &why);
            if (resolved.empty()) throw std::runtime_error(name + ": cannot re-read: uri \"" + uri + "\": " + why);
            files.approve(uri, resolved);
        }
    }

    tinygltf::TinyGLTF gltf;
    gltf.SetFsCallbacks(files.callbacks());
    gltf.SetImageLoader(image_loader, user);
    tinygltf::Model model;
    std::string err, warn;
    const bool ok =
        binary ? gltf.LoadBinaryFromMemory(&model, &err, &warn, bytes.data(), unsigned(bytes.size()), files.base_dir())
               : gltf.LoadASCIIFromString(&model, &err, &warn, reinterpret_cast<const char*>(bytes.data()),
                                          unsigned(bytes.size()), files.base_dir());
    if (!ok) throw std::runtime_error(name + ": cannot re-read: " + err);
    return model;
}

}  // namespace lf
