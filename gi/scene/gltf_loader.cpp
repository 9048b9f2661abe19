// load_scene: the steps, in order. Each step refuses what it cannot use with
// a one-line SceneError; see gltf_loader.h for the rules.
#include "scene/gltf_loader.h"

#include "scene/gltf_accessors.h"
#include "scene/gltf_build.h"
#include "scene/gltf_document.h"
#include "scene/gltf_errors.h"
#include "scene/gltf_files.h"
#include "scene/gltf_images.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

namespace lf {

namespace {

using namespace gltf;

// tinygltf's messages end in newlines and may hold several lines; the first says most.
std::string first_line(const std::string& text) {
    std::string line = text.substr(0, text.find('\n'));
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
    return line.empty() ? "unknown error" : line;
}

tinygltf::Model parse_with_tinygltf(const Document& doc, SceneFiles& files, ImageDecoder& images,
                                    const Errors& errors) {
    tinygltf::TinyGLTF parser;
    parser.SetFsCallbacks(files.callbacks());
    parser.SetImageLoader(&ImageDecoder::callback, &images);

    tinygltf::Model model;
    std::string err, warn;
    bool ok = false;
    try {
        // Sizes fit unsigned int: read_document refused 4 GiB and more.
        if (doc.binary) {
            ok = parser.LoadBinaryFromMemory(&model, &err, &warn, doc.bytes.data(), unsigned(doc.bytes.size()),
                                             files.base_dir());
        } else {
            ok = parser.LoadASCIIFromString(&model, &err, &warn, reinterpret_cast<const char*>(doc.bytes.data()),
                                            unsigned(doc.json_size), files.base_dir());
        }
    } catch (const std::exception& e) {
        errors.fail(std::string("glTF parse error: ") + e.what());
    }
    if (!images.deferred_error().empty()) throw SceneError(images.deferred_error());
    if (!ok) errors.fail("glTF parse error: " + first_line(err));
    return model;
}

// The world-space bounds within LoadLimits::max_coordinate of the origin.
void check_extent(const Bounds& b, const LoadLimits& limits, const Errors& errors) {
    if (b.empty()) return;
    float reach = 0.0f;
    for (int a = 0; a < 3; ++a) reach = std::max({reach, std::abs(b.lo[a]), std::abs(b.hi[a])});
    if (reach > limits.max_coordinate) {
        char text[160];
        std::snprintf(text, sizeof text,
                      "the scene reaches %.3g m from the origin, beyond the limit of %.3g m (are its units metres?)",
                      double(reach), double(limits.max_coordinate));
        errors.fail(text);
    }
}

void add_scene_warnings(Scene& scene) {
    if (scene.emissive_triangle_count() == 0 && scene.lights.empty())
        scene.warnings.push_back("no light source: no emissive material on any triangle and no punctual light");
    double area = 0.0;
    for (size_t t = 0; t < scene.triangles.size() && area == 0.0; ++t) area += scene.triangle_area(t);
    if (!(area > 0.0)) scene.warnings.push_back("no geometry with area: nothing to bake into");
    const std::vector<bool> closed = scene.closed_volumes();
    std::vector<bool> used(scene.materials.size(), false);
    for (uint32_t m : scene.triangle_material) used[m] = true;
    for (size_t m = 0; m < scene.materials.size(); ++m)
        if (used[m] && scene.materials[m].has_volume() && !closed[m])
            scene.warnings.push_back(Errors::label("material", int(m), scene.materials[m].name) +
                                     ": KHR_materials_volume on triangles that do not close around a volume: "
                                     "each surface crossed absorbs over thicknessFactor (" +
                                     std::to_string(scene.materials[m].thickness) + " m) instead of the path inside");
}

}  // namespace

Scene load_scene(const std::filesystem::path& file, const LoadLimits& limits) {
    const Errors errors(file.filename().string());

    // Everything the file names is resolved inside this directory.
    std::error_code ec;
    const std::filesystem::path dir = std::filesystem::canonical(std::filesystem::absolute(file, ec).parent_path(), ec);
    if (ec) errors.fail("its directory cannot be opened (" + ec.message() + ")");
    SceneFiles files(dir, limits.max_file_bytes);

    // 1. Container and JSON, checked before tinygltf sees them.
    Document doc = read_document(file, limits, errors, files);

    // 2. tinygltf parses, reading only the files step 1 approved and
    //    decoding only images the materials use, within the size limits.
    ImageDecoder images(errors, limits, doc.used_images);
    tinygltf::Model model = parse_with_tinygltf(doc, files, images, errors);
    std::vector<unsigned char>().swap(doc.bytes);

    // 3. The model, checked as it is converted.
    Scene scene;
    scene.source = file.string();
    scene.warnings = std::move(doc.warnings);
    scene.content_hash = files.content_hash();
    const uint64_t max_elements = std::min<uint64_t>(3 * limits.max_triangles, std::numeric_limits<uint32_t>::max());
    const AccessorReader reader(model, errors, max_elements);
    reader.check_buffer_views();
    const Placement placement = place_nodes(model, errors, &scene.warnings);
    add_materials(model, errors, images, reader, scene, &scene.warnings);
    add_geometry(model, placement.meshes, reader, limits, errors, scene, &scene.warnings);
    add_lights(model, placement.lights, errors, scene, &scene.warnings);
    for (const auto& p : placement.probes) scene.probe_points.emplace_back(p.world[3]);
    check_extent(scene.bounds, limits, errors);
    add_scene_warnings(scene);
    return scene;
}

}  // namespace lf
