// libFuzzer target: an uploaded scene, as lightfarmd checks it
// (`lightfarm inspect FILE --json`) and as a worker then loads it.
//
// The bytes become a file in a directory of this process's own under /tmp
// (scene.glb when they start with "glTF", else scene.gltf; load_scene reads
// only paths) and go through:
//   1. load_scene with images checked from their headers, not decoded, then
//      summarize, smallest_atlas_resolution and the summary's JSON, dumped and
//      read back with scene_summary_from_json: the upload check;
//   2. for a file that passed, load_scene again decoding images: the worker.
// Limits are small (triangles, texels, bytes) so that no input can make a run
// slow or big; refusing an input for a limit is the loader's documented job.
//
// lf::SceneError is the loader's documented refusal and is caught; any other
// exception escapes and libFuzzer reports it as a crash, as it does an ASan or
// UBSan report.
#include "atlas/atlas.h"
#include "scene/gltf_loader.h"
#include "scene/scene_summary.h"
#include "worker_protocol.h"

#include <nlohmann/json.hpp>

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

namespace {

namespace fs = std::filesystem;

fs::path g_dir;  // this process's own directory under /tmp

void remove_dir() {
    std::error_code ec;
    if (!g_dir.empty()) fs::remove_all(g_dir, ec);
}

lf::LoadLimits small_limits(bool decode_images) {
    lf::LoadLimits limits;
    limits.max_file_bytes = 1u << 20;
    limits.max_triangles = 4096;
    limits.max_texture_dim = 256;
    limits.max_total_texels = 1u << 16;
    limits.decode_images = decode_images;
    return limits;
}

void upload_check(const fs::path& file) {
    const lf::Scene scene = lf::load_scene(file, small_limits(false));
    lf::protocol::SceneSummary summary = lf::summarize(scene);
    if (!summary.has_lightmap_uvs) summary.min_atlas_res = lf::smallest_atlas_resolution(scene);
    (void)lf::format_summary(scene);
    // What inspect prints and the server reads back.
    const std::string text = lf::protocol::to_json(summary).dump(2);
    const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
    if (j.is_discarded()) {
        std::fprintf(stderr, "fuzz_gltf_upload: the scene summary is not JSON:\n%s\n", text.c_str());
        std::abort();
    }
    try {
        (void)lf::protocol::scene_summary_from_json(j);
    } catch (const std::invalid_argument& e) {
        std::fprintf(stderr, "fuzz_gltf_upload: the scene summary is refused (%s):\n%s\n", e.what(), text.c_str());
        std::abort();
    }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
    g_dir = fs::temp_directory_path() / ("lightfarm-fuzz-" + std::to_string(getpid()));
    std::error_code ec;
    fs::remove_all(g_dir, ec);
    fs::create_directories(g_dir);
    std::atexit(remove_dir);
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const bool glb = size >= 4 && std::memcmp(data, "glTF", 4) == 0;
    const fs::path file = g_dir / (glb ? "scene.glb" : "scene.gltf");
    {
        std::ofstream out(file, std::ios::binary | std::ios::trunc);
        out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
        if (!out) {
            std::fprintf(stderr, "fuzz_gltf_upload: cannot write %s\n", file.c_str());
            std::abort();
        }
    }
    bool accepted = false;
    try {
        upload_check(file);
        accepted = true;
    } catch (const lf::SceneError&) {
    }
    if (accepted) {
        try {
            (void)lf::load_scene(file, small_limits(true));
        } catch (const lf::SceneError&) {
        }
    }
    std::error_code ec;
    fs::remove(file, ec);
    return 0;
}
