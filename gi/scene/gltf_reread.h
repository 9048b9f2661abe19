// A second read, by tinygltf, of a scene file that load_scene has already
// accepted (its URIs checked there, gltf_files.h): for the writers that
// rebuild a glb from the source's own JSON (lightmapped_gltf.cpp, sh_glb.cpp).
#pragma once

#include <tiny_gltf.h>

#include <filesystem>

namespace lf {

// Only the files the document names are read, each found as load_scene
// finds it (gltf::SceneFiles: no expansion, URIs decoded as RFC 3986 does);
// each image's encoded bytes go to `image_loader` with `user` (nothing is
// decoded here). Throws std::runtime_error naming the file.
tinygltf::Model reread_gltf(const std::filesystem::path& file, tinygltf::LoadImageDataFunction image_loader,
                            void* user);

}  // namespace lf
