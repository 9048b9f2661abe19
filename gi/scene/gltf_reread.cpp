#include "scene/gltf_reread.h"

#include "scene/glb.h"

#include <fstream>
#include <stdexcept>
#include <string>

namespace lf {

namespace {

std::string verbatim_path(const std::string& path, void*) { return path; }

}  // namespace

tinygltf::Model reread_gltf(const std::filesystem::path& file, tinygltf::LoadImageDataFunction image_loader,
                            void* user) {
    tinygltf::TinyGLTF gltf;
    gltf.SetFsCallbacks(
        {&tinygltf::FileExists, &verbatim_path, &tinygltf::ReadWholeFile, &tinygltf::WriteWholeFile, nullptr});
    gltf.SetImageLoader(image_loader, user);
    unsigned char magic[4] = {};
    std::ifstream(file, std::ios::binary).read(reinterpret_cast<char*>(magic), 4);
    tinygltf::Model model;
    std::string err, warn;
    const bool ok = glb::read_u32(magic, 0) == glb::kMagic ? gltf.LoadBinaryFromFile(&model, &err, &warn, file.string())
                                                           : gltf.LoadASCIIFromFile(&model, &err, &warn, file.string());
    if (!ok) throw std::runtime_error(file.filename().string() + ": cannot re-read: " + err);
    return model;
}

}  // namespace lf
