#include "sh/sh_glb.h"

#include "atlas/lightmapped_gltf.h"
#include "scene/gltf_loader.h"
#include "scene/gltf_reread.h"
#include "sh/shading.h"
#include "sh/transfer_file.h"

#include <tiny_gltf.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <stdexcept>
#include <tuple>

namespace lf {

namespace fs = std::filesystem;

int sh_attribute_count(int bands) { return (bands * bands + 3) / 4; }

void write_sh_glb(const fs::path& source_gltf, const Scene& scene, const std::vector<ShCoefficients>& per_vertex,
                  int bands, const fs::path& out_glb) {
    if (per_vertex.size() != scene.positions.size())
        throw std::invalid_argument("write_sh_glb: transfer for " + std::to_string(per_vertex.size()) +
                                    " vertices, the scene has " + std::to_string(scene.positions.size()));
    std::vector<std::vector<VertexAttribute>> attributes(scene.instances.size());
    for (size_t i = 0; i < scene.instances.size(); ++i) {
        const PrimitiveInstance& inst = scene.instances[i];
        for (int k = 0; k < sh_attribute_count(bands); ++k) {
            VertexAttribute a{"_SH_TRANSFER_" + std::to_string(k), 4, {}};
            a.values.reserve(size_t(inst.vertex_count) * 4);
            for (uint32_t v = 0; v < inst.vertex_count; ++v)
                for (int c = 4 * k; c < 4 * k + 4; ++c)
                    a.values.push_back(c < bands * bands ? per_vertex[inst.first_vertex + v][c] : 0.0f);
            attributes[i].push_back(std::move(a));
        }
    }
    write_glb_with_vertex_attributes(source_gltf, scene, attributes, out_glb);
}

namespace {

// Images left encoded: only the attributes are read here.
bool skip_image(tinygltf::Image*, const int, std::string*, std::string*, int, int, const unsigned char*, int, void*) {
    return true;
}

// A float VEC4 accessor's elements.
std::vector<glm::vec4> read_vec4(const tinygltf::Model& model, int index, const std::string& what) {
    if (index < 0 || size_t(index) >= model.accessors.size()) throw std::runtime_error(what + ": bad accessor");
    const tinygltf::Accessor& a = model.accessors[size_t(index)];
    if (a.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT || a.type != TINYGLTF_TYPE_VEC4 || a.bufferView < 0 ||
        a.sparse.isSparse)
        throw std::runtime_error(what + ": must be a dense float VEC4 accessor");
    const tinygltf::BufferView& view = model.bufferViews[size_t(a.bufferView)];
    const auto& data = model.buffers[size_t(view.buffer)].data;
    const size_t stride = view.byteStride ? view.byteStride : sizeof(glm::vec4);
    std::vector<glm::vec4> out(a.count);
    for (size_t i = 0; i < a.count; ++i) {
        const size_t at = view.byteOffset + a.byteOffset + i * stride;
        if (at + sizeof(glm::vec4) > data.size()) throw std::runtime_error(what + ": accessor outside its buffer");
        std::memcpy(&out[i], &data[at], sizeof(glm::vec4));
    }
    return out;
}

}  // namespace

std::vector<ShCoefficients> read_sh_glb_transfer(const fs::path& sh_glb, const Scene& scene, int* bands_out) {
    const tinygltf::Model model = reread_gltf(sh_glb, &skip_image, nullptr);
    std::vector<ShCoefficients> per_vertex(scene.positions.size(), ShCoefficients{});
    int attributes = -1;
    for (const PrimitiveInstance& inst : scene.instances) {
        const std::string where = sh_glb.filename().string() + ": node " + std::to_string(inst.node);
        const int mesh = model.nodes.at(size_t(inst.node)).mesh;
        const tinygltf::Primitive& primitive = model.meshes.at(size_t(mesh)).primitives.at(size_t(inst.primitive));
        int count = 0;
        while (primitive.attributes.count("_SH_TRANSFER_" + std::to_string(count))) ++count;
        if (count == 0 || count > 4)
            throw std::runtime_error(where + ": no _SH_TRANSFER_0 attribute (not a scene.sh.glb?)");
        if (attributes >= 0 && count != attributes)
            throw std::runtime_error(where + ": primitives differ in their number of _SH_TRANSFER attributes");
        attributes = count;
        for (int k = 0; k < count; ++k) {
            const std::string name = "_SH_TRANSFER_" + std::to_string(k);
            const std::vector<glm::vec4> values = read_vec4(model, primitive.attributes.at(name), where + " " + name);
            if (values.size() < inst.vertex_count)
                throw std::runtime_error(where + ": " + name + " has too few vertices");
            for (uint32_t v = 0; v < inst.vertex_count; ++v) {
                const uint32_t src = scene.source_vertex.empty() ? v : scene.source_vertex[inst.first_vertex + v];
                for (int c = 0; c < 4; ++c) per_vertex[inst.first_vertex + v][4 * k + c] = values.at(src)[c];
            }
        }
    }
    // 1 attribute: 1 or 2 bands (4 coefficients hold band 1 entirely); report the most the data can hold.
    if (bands_out) *bands_out = attributes <= 1 ? 2 : attributes <= 3 ? 3 : 4;
    return per_vertex;
}

nlohmann::json shade_sh_glb(const fs::path& transfer, const std::string& env, const fs::path& out_glb,
                            const ShShadeOptions& options) {
    std::string ext = transfer.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    const bool from_gltf = ext == ".glb" || ext == ".gltf";
    const fs::path scene_file = from_gltf ? transfer : options.scene;
    if (scene_file.empty())
        throw std::runtime_error(transfer.string() + ": a .bin transfer needs the scene it was baked for (--scene)");
    const Scene scene = load_scene(scene_file);

    int bands = kShMaxBands;
    std::vector<ShCoefficients> per_vertex;
    if (from_gltf) {
        per_vertex = read_sh_glb_transfer(transfer, scene, &bands);
    } else {
        const ShTransferFile file = read_sh_transfer(transfer);
        bands = file.bands;
        per_vertex.assign(scene.positions.size(), ShCoefficients{});
        std::map<std::tuple<int, int, int>, const ShTransferFile::Primitive*> by_key;
        for (const auto& p : file.primitives) by_key[{p.node, p.mesh, p.primitive}] = &p;
        for (const PrimitiveInstance& inst : scene.instances) {
            auto it = by_key.find({inst.node, inst.mesh, inst.primitive});
            if (it == by_key.end())
                throw std::runtime_error(transfer.string() + ": no transfer for node " + std::to_string(inst.node) +
                                         " mesh " + std::to_string(inst.mesh) + " of " + scene_file.string() +
                                         " (baked for another scene?)");
            for (uint32_t v = 0; v < inst.vertex_count; ++v) {
                const uint32_t src = scene.source_vertex.empty() ? v : scene.source_vertex[inst.first_vertex + v];
                if (src >= it->second->vertices.size())
                    throw std::runtime_error(transfer.string() + ": node " + std::to_string(inst.node) +
                                             " has fewer vertices than " + scene_file.string());
                per_vertex[inst.first_vertex + v] = it->second->vertices[src];
            }
        }
    }
    if (options.bands > 0) bands = std::min(bands, options.bands);
    const EnvironmentSh sh = load_environment_sh(env, options.window);

    std::vector<std::vector<VertexAttribute>> colours(scene.instances.size());
    double lowest = 1e300, highest = -1e300;
    size_t negative = 0, saturated = 0;
    for (size_t i = 0; i < scene.instances.size(); ++i) {
        const PrimitiveInstance& inst = scene.instances[i];
        VertexAttribute colour{"COLOR_0", 3, {}}, radiance{"_E_OVER_PI", 3, {}};
        for (uint32_t v = 0; v < inst.vertex_count; ++v) {
            const glm::vec3 e = sh_irradiance(per_vertex[inst.first_vertex + v], sh, bands) / float(M_PI);
            const float mean = (e.r + e.g + e.b) / 3.0f;
            lowest = std::min(lowest, double(mean));
            highest = std::max(highest, double(mean));
            negative += mean < 0.0f;
            saturated += std::max({e.r, e.g, e.b}) > 1.0f;
            // Ringing can make E negative, and a float COLOR_0 must lie in
            // [0, 1] (glTF 2.0 §3.7.2.1): the colour is what a display shows,
            // _E_OVER_PI keeps the values.
            for (int c = 0; c < 3; ++c) {
                colour.values.push_back(std::clamp(e[c], 0.0f, 1.0f));
                radiance.values.push_back(e[c]);
            }
        }
        colours[i].push_back(std::move(colour));
        colours[i].push_back(std::move(radiance));
    }
    write_glb_with_vertex_attributes(scene_file, scene, colours, out_glb, true);
    return {{"vertices", scene.positions.size()}, {"bands", bands},
            {"window", to_string(sh.window)},     {"min_e_over_pi", lowest},
            {"max_e_over_pi", highest},           {"negative_vertices", negative},
            {"saturated_vertices", saturated},    {"out", out_glb.string()}};
}

}  // namespace lf
