#include "scene/scene_summary.h"

#include <algorithm>
#include <filesystem>
#include <cstdio>
#include <set>
#include <sstream>

namespace lf {

protocol::SceneSummary summarize(const Scene& scene) {
    std::set<int> meshes;
    size_t with_uv1 = 0;
    nlohmann::json scales = nlohmann::json::object();  // glTF mesh -> its lightmap scale, where not 1
    for (const PrimitiveInstance& inst : scene.instances) {
        meshes.insert(inst.mesh);
        with_uv1 += inst.has_uv1 ? 1 : 0;
        if (inst.lightmap_scale != 1.0f) scales[std::to_string(inst.mesh)] = inst.lightmap_scale;
    }
    size_t point = 0, spot = 0, directional = 0;
    for (const PunctualLight& light : scene.lights) {
        switch (light.type) {
        case PunctualLight::Type::Point: ++point; break;
        case PunctualLight::Type::Spot: ++spot; break;
        case PunctualLight::Type::Directional: ++directional; break;
        }
    }
    int largest = 0;
    for (const Texture& t : scene.textures) largest = std::max({largest, t.width, t.height});
    double area = 0.0;
    for (size_t t = 0; t < scene.triangles.size(); ++t) area += scene.triangle_area(t);

    nlohmann::json bounds = nullptr;
    if (!scene.bounds.empty()) {
        const Bounds& b = scene.bounds;
        bounds = {{"lo", {b.lo.x, b.lo.y, b.lo.z}}, {"hi", {b.hi.x, b.hi.y, b.hi.z}}};
    }
    protocol::SceneSummary summary;
    // The file's name only: where it lies (a server's data directory) is nobody's business.
    summary.source = std::filesystem::path(scene.source).filename().string();
    summary.triangles = scene.triangles.size();
    summary.emissive_triangles = scene.emissive_triangle_count();
    summary.punctual_lights = scene.lights.size();
    summary.max_texture_size = largest;
    summary.has_lightmap_uvs = scene.all_have_lightmap_uvs();
    summary.details = {
        {"vertices", scene.positions.size()},
        {"meshes", meshes.size()},
        {"primitive_instances", scene.instances.size()},
        {"probe_nodes", scene.probe_points.size()},
        {"materials", scene.materials.size()},
        {"punctual_lights", {{"point", point}, {"spot", spot}, {"directional", directional}}},
        {"textures", scene.textures.size()},
        {"lightmap_uvs", {{"all_primitives", scene.all_have_lightmap_uvs()}, {"primitives_with_texcoord_1", with_uv1}}},
        // The file's extras lightfarm_lightmap_scale (0: no lightmap), by glTF mesh.
        {"lightmap_scales", scales},
        {"bounds", bounds},
        {"surface_area", area},
        {"warnings", scene.warnings},
    };
    return summary;
}

std::string format_summary(const Scene& scene) {
    const nlohmann::json s = to_json(summarize(scene));
    std::ostringstream out;
    char line[256];
    out << "scene:        " << scene.source << "\n";
    out << "geometry:     " << s["triangles"] << " triangles, " << s["vertices"] << " vertices in "
        << s["primitive_instances"] << " primitive instances of " << s["meshes"] << " meshes\n";
    out << "materials:    " << s["materials"] << " (" << s["emissive_triangles"] << " emissive triangles)\n";
    const nlohmann::json& lights = s["punctual_lights"];
    out << "lights:       " << lights["point"] << " point, " << lights["spot"] << " spot, " << lights["directional"]
        << " directional\n";
    out << "textures:     " << s["textures"];
    if (s["textures"].get<size_t>() > 0) out << ", largest " << s["max_texture_size"] << " px";
    out << "\n";
    const nlohmann::json& uvs = s["lightmap_uvs"];
    out << "lightmap UVs: TEXCOORD_1 on " << uvs["primitives_with_texcoord_1"] << " of " << s["primitive_instances"]
        << " primitive instances" << (uvs["all_primitives"].get<bool>() ? " (all: kept)" : " (atlas will be generated)")
        << "\n";
    if (!s["lightmap_scales"].empty()) {
        out << "lightmap scale:";
        for (const auto& [mesh, scale] : s["lightmap_scales"].items()) {
            const double v = scale.get<double>();
            std::snprintf(line, sizeof line,
                          v == 0.0 ? " mesh %s no lightmap (casts and bounces light);" : " mesh %s x%g;", mesh.c_str(),
                          v);
            out << line;
        }
        out << "\n";
    }
    if (!scene.bounds.empty()) {
        const Bounds& b = scene.bounds;
        const glm::vec3 e = b.extent();
        std::snprintf(line, sizeof line,
                      "bounds:       (%.3g, %.3g, %.3g) .. (%.3g, %.3g, %.3g) m, size %.3g x %.3g x %.3g m\n", b.lo.x,
                      b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z, e.x, e.y, e.z);
        out << line;
    }
    std::snprintf(line, sizeof line, "surface area: %.4g m²\n", s["surface_area"].get<double>());
    out << line;
    if (scene.warnings.empty()) {
        out << "warnings:     none\n";
    } else {
        out << "warnings:\n";
        for (const std::string& w : scene.warnings) out << "  - " << w << "\n";
    }
    return out.str();
}

}  // namespace lf
