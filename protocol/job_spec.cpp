#include "job_spec.h"

#include "spec_text.h"

#include <algorithm>
#include <cmath>

namespace lf::protocol {

using nlohmann::json;

namespace {

// The shortest deadline an attempt may have: a worker takes longer than
// this to start, so a shorter one could only fail (three times).
constexpr double kMinMaxSeconds = 1.0;

// A job limit: a number in [1, cap] seconds (max_seconds) or an integer in [1, cap] (max_attempts).
double check_limit(const json& v, bool integer, const SpecLimits& limits, const std::string& key) {
    const std::string field = "limits." + key;
    if (!v.is_number() || (integer && !(v.is_number_integer() || v.is_number_unsigned())))
        throw SpecError(field,
                        std::string("must be ") + (integer ? "an integer" : "a number") + ", not " + json_type_name(v));
    const double x = v.get<double>();
    if (!(integer ? x >= 1.0 : x >= kMinMaxSeconds))
        throw SpecError(field, std::string("must be at least 1") +
                                   (integer ? "" : " (seconds: a worker takes longer than that to start)"));
    if (x > limits.cap(key))
        throw SpecError(field, number_text(x) + " exceeds this server's limit " + number_text(limits.cap(key)));
    if (integer && x > 1e6) throw SpecError(field, number_text(x) + " exceeds the maximum 1000000");
    return x;
}

}  // namespace

JobSpec parse_job_spec(const json& j, const SpecLimits& limits) {
    if (!j.is_object()) throw SpecError("", "a job spec must be a JSON object, not " + json_type_name(j));
    // The spec's own fields, then the job's settings from the catalog (seed, env, ...).
    std::vector<std::string> known = {"scene", "outputs", "atlas", "limits"};
    for (const Setting& s : setting_catalog())
        if (s.group.empty()) known.push_back(s.name);
    for (auto it = j.begin(); it != j.end(); ++it)
        if (std::find(known.begin(), known.end(), it.key()) == known.end()) {
            std::string list;
            for (const std::string& k : known) list += (list.empty() ? "" : ", ") + k;
            throw SpecError(it.key(), "unknown field (known: " + list + ")");
        }
    JobSpec spec;
    if (!j.contains("scene")) throw SpecError("scene", "is required");
    if (!j["scene"].is_string()) throw SpecError("scene", "must be a string, not " + json_type_name(j["scene"]));
    spec.scene = j["scene"].get<std::string>();
    if (spec.scene.empty()) throw SpecError("scene", "must not be empty");

    spec.bake = parse_bake_settings(j, limits);

    if (j.contains("limits")) {
        const json& l = j["limits"];
        if (!l.is_object()) throw SpecError("limits", "must be an object, not " + json_type_name(l));
        for (auto it = l.begin(); it != l.end(); ++it)
            if (it.key() != "max_seconds" && it.key() != "max_attempts")
                throw SpecError("limits." + it.key(), "unknown field (known: max_seconds, max_attempts)");
        if (l.contains("max_seconds"))
            spec.limits.max_seconds = check_limit(l["max_seconds"], false, limits, "max_seconds");
        if (l.contains("max_attempts"))
            spec.limits.max_attempts = int(check_limit(l["max_attempts"], true, limits, "max_attempts"));
    }
    return spec;
}

json to_json(const JobSpec& spec) {
    json j = to_json(spec.bake);
    j["scene"] = spec.scene;
    json limits = json::object();
    if (spec.limits.max_seconds) limits["max_seconds"] = *spec.limits.max_seconds;
    if (spec.limits.max_attempts) limits["max_attempts"] = *spec.limits.max_attempts;
    if (!limits.empty()) j["limits"] = limits;
    return j;
}

namespace {

// "lightmap and probes": the requested outputs that need a light.
std::string lit_outputs(const BakeSettings& bake) {
    std::string out;
    for (const OutputKind& o : output_registry())
        if (o.needs_light && bake.output(o.name)) out += (out.empty() ? "" : " and ") + o.name;
    return out;
}

}  // namespace

std::array<uint64_t, 3> probe_grid_counts(const std::array<double, 3>& extent, double spacing) {
    std::array<uint64_t, 3> counts{1, 1, 1};
    for (int a = 0; a < 3; ++a) {
        const double n = std::floor(extent[a] / spacing);
        counts[a] = n >= 1.0 ? (n < 1e9 ? uint64_t(n) : uint64_t(1e9)) : 1;
    }
    return counts;
}

namespace {

// Mesh indices the scene does not draw (its summary's "meshes": drawn
// meshes), in the SH lists and the atlas's per-mesh scales.
void check_mesh_indices(const BakeSettings& bake, const SceneSummary& scene, const std::string& name) {
    if (!scene.details.contains("meshes")) return;
    const int64_t meshes = scene.details["meshes"].get<int64_t>();
    auto check = [&](const std::string& field, int64_t mesh) {
        if (mesh >= meshes)
            throw SpecError(field, "mesh " + std::to_string(mesh) + " is not drawn by " + name + " (it has " +
                                       std::to_string(meshes) + " meshes: 0 to " + std::to_string(meshes - 1) + ")");
    };
    if (const OutputSettings* sh = bake.output("sh"))
        for (const char* list : {"sh_occluders", "sh_receivers"})
            for (const json& m : sh->values.at(list)) check(std::string("sh.") + list, m.get<int64_t>());
    for (const auto& [mesh, scale] : bake.atlas.mesh_scale) check("atlas.mesh_scale", mesh);
    // Every mesh at scale 0 leaves the atlas no texel: the worker would fail
    // after preparing (issue #55), so it is said here.
    const bool none_scaled = meshes > 0 && std::all_of(bake.atlas.mesh_scale.begin(), bake.atlas.mesh_scale.end(),
                                                       [](const auto& m) { return m.second == 0.0; });
    if (bake.uses_atlas() && none_scaled && int64_t(bake.atlas.mesh_scale.size()) == meshes)
        throw SpecError("atlas.mesh_scale", "every mesh of " + name + " (0 to " + std::to_string(meshes - 1) +
                                                ") has scale 0: no texel is left to bake (give one a scale above 0)");
}

// The probes a job would place: its own points, else (a file without probe
// nodes) the grid over the scene's bounds; 0 when the summary cannot tell.
uint64_t probe_count(const OutputSettings& probes, const SceneSummary& scene, std::string* grid) {
    const size_t given = probes.values.at("probe_positions").size();
    if (given > 0) return given;
    const json& d = scene.details;
    if (!d.contains("probe_nodes") || !d.contains("bounds") || !d["bounds"].is_object()) return 0;
    if (d["probe_nodes"].get<uint64_t>() > 0) return d["probe_nodes"].get<uint64_t>();
    std::array<double, 3> extent{};
    for (int a = 0; a < 3; ++a) extent[a] = d["bounds"]["hi"][a].get<double>() - d["bounds"]["lo"][a].get<double>();
    const double spacing =
        probes.number_or_auto("probe_spacing").value_or(std::max({extent[0], extent[1], extent[2]}) / 4.0);
    if (!(spacing > 0.0)) return 0;
    const std::array<uint64_t, 3> n = probe_grid_counts(extent, spacing);
    *grid = std::to_string(n[0]) + " x " + std::to_string(n[1]) + " x " + std::to_string(n[2]);
    return n[0] * n[1] * n[2];
}

void check_probes(const OutputSettings& probes, const SceneSummary& scene, const std::string& name) {
    std::string grid;
    const uint64_t count = probe_count(probes, scene, &grid);
    if (count > kMaxProbes)
        throw SpecError("probes.probe_spacing", "a grid of " + grid + " = " + std::to_string(count) + " probes over " +
                                                    name + " exceeds the maximum " + std::to_string(kMaxProbes) +
                                                    "; raise probe_spacing (or leave it auto)");
    const uint64_t r = uint64_t(probes.integer("probe_res"));
    if (count * 6 * r * r > kMaxCaptureTexels) {
        uint64_t fits = 16;
        while ((fits * 2) * (fits * 2) * 6 * count <= kMaxCaptureTexels) fits *= 2;
        throw SpecError("probes.probe_res", std::to_string(count) + " probes at probe_res " + std::to_string(r) +
                                                " are " + std::to_string(count * 6 * r * r) +
                                                " capture texels, more than " + std::to_string(kMaxCaptureTexels) +
                                                "; lower probe_res (" + std::to_string(fits) +
                                                " fits) or place fewer probes");
    }
}

}  // namespace

void check_spec_against_scene(const BakeSettings& bake, const SceneSummary& scene) {
    const std::string name = scene.source.empty() ? "the scene" : scene.source;
    if (bake.needs_light() && !scene.has_light() && !bake.env.given())
        throw SpecError("env", name + " has no emissive surface and no punctual light, so its " + lit_outputs(bake) +
                                   " would be black; give a sky with \"env\": [R, G, B] (--env R,G,B)");
    if (bake.uses_atlas() && !scene.has_lightmap_uvs && scene.min_atlas_res > 0 && bake.atlas.res &&
        *bake.atlas.res < scene.min_atlas_res)
        throw SpecError("atlas.res", std::to_string(*bake.atlas.res) + " is too small for " + name + "'s " +
                                         "generated atlas; the smallest that fits is " +
                                         std::to_string(scene.min_atlas_res) + " (or leave res auto)");
    if (bake.uses_atlas() && !scene.has_lightmap_uvs && scene.min_atlas_res > 0 && !bake.atlas.res &&
        bake.atlas.max_res && *bake.atlas.max_res < scene.min_atlas_res)
        throw SpecError("atlas.max_res", std::to_string(*bake.atlas.max_res) + " is too small for " + name +
                                             "'s generated atlas; the smallest that fits is " +
                                             std::to_string(scene.min_atlas_res));
    check_mesh_indices(bake, scene, name);
    if (const OutputSettings* probes = bake.output("probes")) check_probes(*probes, scene, name);
}

std::string bake_identity(const JobSpec& spec) {
    // nlohmann::json objects keep keys sorted, so dump() is canonical.
    json j = to_json(spec);
    j.erase("limits");
    j.erase("keep_snapshots");  // which files stay, not what they hold
    return j.dump();
}

}  // namespace lf::protocol
