#include "bake_settings.h"

#include "spec_text.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <limits>

namespace lf::protocol {

using nlohmann::json;

namespace {

constexpr double kMaxPasses = 1 << 24;

Setting integer(std::string group, std::string name, json def, double min, double max, std::string limit,
                std::string help) {
    Setting s;
    s.group = std::move(group);
    s.name = std::move(name);
    s.type = SettingType::Integer;
    s.default_value = std::move(def);
    s.min = min;
    s.max = max;
    s.limit = std::move(limit);
    s.help = std::move(help);
    return s;
}

Setting number(std::string group, std::string name, json def, double min, bool min_exclusive, double max,
               std::string limit, std::string help) {
    Setting s = integer(std::move(group), std::move(name), std::move(def), min, max, std::move(limit), std::move(help));
    s.type = SettingType::Number;
    s.min_exclusive = min_exclusive;
    return s;
}

Setting choice(std::string group, std::string name, std::vector<std::string> choices, std::string help) {
    Setting s;
    s.group = std::move(group);
    s.name = std::move(name);
    s.type = SettingType::Choice;
    s.default_value = choices.front();
    s.choices = std::move(choices);
    s.help = std::move(help);
    return s;
}

Setting typed(std::string group, std::string name, SettingType type, json def, std::string help) {
    Setting s;
    s.group = std::move(group);
    s.name = std::move(name);
    s.type = type;
    s.default_value = std::move(def);
    s.help = std::move(help);
    return s;
}

Setting with_auto(Setting s) {
    s.accepts_auto = true;
    s.default_value = "auto";
    return s;
}

std::vector<Setting> build_catalog() {
    using T = SettingType;
    return {
        integer("lightmap", "passes", 256, 1, kMaxPasses, "passes", "stop after this many passes"),
        number("lightmap", "target_error", 0, 0, false, 1e3, "",
               "stop when the relative standard error falls below this (0: no target)"),
        number("lightmap", "time_limit", 0, 0, false, 1e7, "time_limit",
               "stop after this many seconds of passes (0: none)"),
        choice("lightmap", "scheme", {"epochs", "final-gather", "thesis", "pathtrace"},
               "indirect light: doubling epochs reading the map, the same with a final gather (the first bounce "
               "at the hit point), the thesis's running average, or brute-force path tracing"),
        integer("lightmap", "light_samples", 1, 1, 1024, "", "emitter samples per texel per pass"),
        choice("lightmap", "light_sampling", {"mis", "area", "solid-angle"},
               "emitter sampling: MIS of solid angle and cosine rays, area alone, solid angle alone"),
        typed("lightmap", "stitch", T::Flag, true, "least-squares stitch of UV seams"),
        typed("lightmap", "directional", T::Flag, false,
              "L1 SH per texel too: layers L1x, L1y, L1z for normal-mapped shading"),
        typed("lightmap", "denoise", T::Flag, true,
              "edge-aware filter of the final lightmap, each chart keeping its raw light (RGB; the raw result "
              "stays in layer raw.)"),
        with_auto(integer("lightmap", "passes_per_dispatch", 1, 1, 16, "",
                          "the most passes one GPU dispatch runs; the passes of a cell read the map published at its "
                          "start (auto: enough for 262,144 texel passes)")),

        with_auto(integer("sh", "sh_bands", 4, 1, 4, "", "SH bands (auto: fewest within 2% of 4 bands)")),
        integer("sh", "sh_bounces", 0, 0, 4, "", "interreflection bounces (0: shadowed transfer)"),
        choice("sh", "sh_window", {"none", "hanning", "lanczos"}, "windowing of env_sh.json against ringing"),
        integer("sh", "sh_passes", 256, 1, kMaxPasses, "passes", "stop after this many passes of 64 rays per vertex"),
        number("sh", "sh_target_error", 0, 0, false, 1e3, "",
               "stop when the transfer's relative standard error falls below this (0: no target)"),
        number("sh", "sh_time_limit", 0, 0, false, 1e7, "time_limit",
               "stop after this many seconds of passes (0: none)"),
        typed("sh", "sh_occluders", T::MeshList, json::array(), "glTF meshes that cast shadows (empty: all)"),
        typed("sh", "sh_receivers", T::MeshList, json::array(), "glTF meshes that get transfer (empty: all)"),
        typed("sh", "sh_per_texel", T::Flag, false,
              "transfer per lightmap texel too (sh_transfer.exr, the atlas below)"),

        typed("probes", "probe_positions", T::Positions, json::array(),
              "probe reference points [{\"position\": [x, y, z]}, …] (CLI: a JSON file); empty: a grid"),
        with_auto(number("probes", "probe_spacing", 0, 0, true, 1e4, "",
                         "grid spacing in metres (auto: a quarter of the scene's largest extent)")),
        integer("probes", "probe_res", 32, 16, 256, "", "capture texels per cube face side (R)"),
        integer("probes", "probe_m", 8, 1, 256, "",
                "texels per face side after downsampling (M, divides R; M = R: not downsampled)"),
        integer("probes", "probe_passes", 64, 1, kMaxPasses, "passes",
                "stop after this many passes of one path per texel"),
        number("probes", "probe_target_error", 0, 0, false, 1e3, "",
               "stop when the radiance's relative standard error falls below this (0: no target)"),
        number("probes", "probe_time_limit", 0, 0, false, 1e7, "time_limit",
               "stop after this many seconds of passes (0: none)"),

        with_auto(number("ao", "ao_distance", 0, 0, true, 1e6, "",
                         "how far a surface occludes, in metres (auto: a tenth of the scene's largest extent)")),
        integer("ao", "ao_passes", 256, 1, kMaxPasses, "passes",
                "stop after this many passes of one ray per sample point"),
        number("ao", "ao_target_error", 0, 0, false, 1e3, "",
               "stop when the occlusion's relative standard error falls below this (0: no target)"),
        number("ao", "ao_time_limit", 0, 0, false, 1e7, "time_limit",
               "stop after this many seconds of passes (0: none)"),

        with_auto(
            integer("atlas", "res", 0, 1, 16384, "res",
                    "atlas width and height in texels (auto: from texel_density, or from the scene's charts and the "
                    "lightmap's target error, at least 256)")),
        with_auto(
            number("atlas", "texel_density", 0, 0, true, 1e4, "", "texels per metre of surface (auto: from res)")),
        integer("atlas", "subsamples", 2, 1, 8, "", "sample points per texel along each axis"),
        with_auto(integer("atlas", "max_res", 0, 256, 16384, "res",
                          "the largest atlas side when res is auto or follows texel_density (a chosen density shrinks "
                          "to fit, an asked one goes on pages: max_pages; auto: 4096, or the server's res limit where "
                          "lower)")),
        integer("atlas", "max_pages", 8, 1, 64, "pages",
                "where the charts at an asked texel_density do not fit one max_res atlas, up to this many pages of "
                "max_res texels square (one lightmap file per page); past this, the density shrinks"),
        typed("atlas", "mesh_scale", T::MeshScales, json::object(),
              "per glTF mesh, its charts' texel density over the atlas's, 0 <= S <= 64 (2: twice the resolution; "
              "0.25: a quarter; 0: no lightmap, while it still casts and bounces light); over the file's extras "
              "lightfarm_lightmap_scale"),
        typed("atlas", "glass_texels", T::Flag, false,
              "glass (KHR_materials_transmission) gets texels at the scene's density; off: 1/8 of it, as charts no "
              "light reaches (light passes glass, which reflects little)"),
        typed("atlas", "light_density", T::Flag, false,
              "charts get texels where their light changes (a first look at it, triplets of points a texel apart: "
              "direct light through glass and cut-outs, and how open each point is): more at shadow edges, lamp "
              "pools and a wall's foot, fewer where it is even, 0.5 to 2 times the scene's density, as many texels "
              "in all"),

        integer("", "seed", 1, 0, 4294967295.0, "", "random seed: the same seed bakes the same pixels"),
        integer("", "keep_snapshots", 0, 0, 1e6, "",
                "keep the intermediate snapshots of each output's newest N passes, removing older ones as newer "
                "ones are written (0: keep all)"),
        typed("", "env", T::Environment, nullptr,
              "environment: a uniform sky R,G,B (W/(sr m^2)), or an .exr/.hdr equirectangular map (CLI only)"),
    };
}

std::string joined(const std::vector<std::string>& items, const std::string& sep) {
    std::string out;
    for (const std::string& s : items) out += (out.empty() ? "" : sep) + s;
    return out;
}

json check_range(const Setting& s, const json& v, const SpecLimits& limits, const std::string& field) {
    if (!v.is_number()) throw SpecError(field, "must be a number, not " + json_type_name(v));
    const double x = v.get<double>();
    if (!std::isfinite(x)) throw SpecError(field, "must be finite");
    const bool is_int = v.is_number_integer() || v.is_number_unsigned();
    if (s.type == SettingType::Integer && !is_int) throw SpecError(field, "must be an integer, not " + number_text(x));
    if (s.min_exclusive ? !(x > s.min) : !(x >= s.min))
        throw SpecError(field, number_text(x) + " is below the minimum " + (s.min_exclusive ? "(exclusive) " : "") +
                                   number_text(s.min));
    if (x > s.max) throw SpecError(field, number_text(x) + " exceeds the maximum " + number_text(s.max));
    if (!s.limit.empty() && x > limits.cap(s.limit))
        throw SpecError(field, number_text(x) + " exceeds this server's limit " + number_text(limits.cap(s.limit)));
    if (s.type == SettingType::Integer)
        return v.is_number_unsigned() ? json(v.get<uint64_t>()) : json(v.get<int64_t>());
    return json(x);
}

json check_environment(const json& v, const SpecLimits& limits, const std::string& field) {
    if (v.is_array()) {
        if (v.size() != 3)
            throw SpecError(field, "a uniform sky is [R, G, B], not " + std::to_string(v.size()) + " values");
        json out = json::array();
        for (const json& c : v) {
            // Stored as float32: a value that overflows it would come back as
            // null and make an accepted spec invalid (found by fuzzing).
            if (!c.is_number() || !(c.get<double>() >= 0.0) || c.get<double>() > std::numeric_limits<float>::max())
                throw SpecError(field, "sky radiance components must be numbers from 0 to 3.4e38");
            out.push_back(c.get<double>());
        }
        return out;
    }
    if (v.is_string()) {
        const std::string file = v.get<std::string>();
        if (file.empty()) throw SpecError(field, "must not be empty");
        if (!limits.allow_local_files)
            throw SpecError(field,
                            "an environment map file cannot be given to the service; give a uniform sky [R, G, B]");
        return file;
    }
    throw SpecError(field, "must be [R, G, B] or an environment map file, not " + json_type_name(v));
}

// Points as [{"position": [x, y, z]}, …], each coordinate a finite float.
json check_positions(const json& v, const std::string& field) {
    constexpr size_t kMaxPoints = 4096;
    if (!v.is_array())
        throw SpecError(field, "must be an array of {\"position\": [x, y, z]}, not " + json_type_name(v));
    if (v.size() > kMaxPoints) throw SpecError(field, std::to_string(v.size()) + " points exceed the maximum 4096");
    for (size_t k = 0; k < v.size(); ++k) {
        const std::string point = "point " + std::to_string(k);
        if (!v[k].is_object() || v[k].size() != 1 || !v[k].contains("position"))
            throw SpecError(field, point + " must be {\"position\": [x, y, z]}");
        const json& p = v[k]["position"];
        bool ok = p.is_array() && p.size() == 3;
        for (size_t c = 0; ok && c < 3; ++c)
            ok = p[c].is_number() && std::abs(p[c].get<double>()) <= std::numeric_limits<float>::max();
        if (!ok) throw SpecError(field, point + ": position must be [x, y, z], finite float32 numbers");
    }
    return v;
}

// {"MESH": SCALE, ...}: mesh indices as decimal keys, scales in [0, 64].
json check_mesh_scales(const json& v, const std::string& field) {
    if (!v.is_object())
        throw SpecError(field, "must be an object of glTF mesh index to scale ({\"3\": 2}), not " + json_type_name(v));
    if (v.size() > kMaxMeshList)
        throw SpecError(field, std::to_string(v.size()) + " meshes exceed the maximum " + std::to_string(kMaxMeshList));
    json out = json::object();
    for (const auto& [key, scale] : v.items()) {
        if (key.empty() || key.size() > 9 || key.find_first_not_of("0123456789") != std::string::npos ||
            (key.size() > 1 && key[0] == '0'))
            throw SpecError(field, "keys are glTF mesh indices (\"0\", \"3\"), not \"" + key + "\"");
        if (!scale.is_number() || !(scale.get<double>() >= 0.0) || scale.get<double>() > kMaxLightmapScale)
            throw SpecError(field + "." + key, "a scale is a number from 0 (no lightmap) to 64, not " + scale.dump());
        out[key] = scale;
    }
    return out;
}

// One value against its setting: returns it in canonical form.
json check_setting(const Setting& s, const json& v, const SpecLimits& limits) {
    const std::string field = s.field();
    if (s.accepts_auto && v.is_string() && v.get<std::string>() == "auto") return "auto";
    switch (s.type) {
    case SettingType::Integer:
    case SettingType::Number:
        if (v.is_string() && !s.accepts_auto) throw SpecError(field, "must be a number, not a string");
        if (v.is_string()) throw SpecError(field, "must be a number or \"auto\", not \"" + v.get<std::string>() + "\"");
        return check_range(s, v, limits, field);
    case SettingType::Choice:
        if (v.is_string())
            for (const std::string& c : s.choices)
                if (v.get<std::string>() == c) return v;
        throw SpecError(field, "must be one of " + joined(s.choices, ", ") + ", not " + v.dump());
    case SettingType::Flag:
        if (!v.is_boolean()) throw SpecError(field, "must be true or false, not " + json_type_name(v));
        return v;
    case SettingType::MeshList: {
        if (!v.is_array()) throw SpecError(field, "must be an array of glTF mesh indices, not " + json_type_name(v));
        if (v.size() > kMaxMeshList)
            throw SpecError(
                field, std::to_string(v.size()) + " mesh indices exceed the maximum " + std::to_string(kMaxMeshList));
        json out = json::array();
        for (const json& m : v) {
            if (!(m.is_number_integer() || m.is_number_unsigned()) || m.get<int64_t>() < 0 ||
                m.get<int64_t>() > 1 << 30)
                throw SpecError(field, "mesh indices are integers >= 0, not " + m.dump());
            out.push_back(m.get<int64_t>());
        }
        return out;
    }
    case SettingType::MeshScales: return check_mesh_scales(v, field);
    case SettingType::Environment: return check_environment(v, limits, field);
    case SettingType::Positions: return check_positions(v, field);
    }
    return v;
}

void require_object(const json& j, const std::string& field) {
    if (!j.is_object()) throw SpecError(field, "must be an object, not " + json_type_name(j));
}

// Every key of group `group` in `j` must be a setting of that group.
void reject_unknown(const json& j, const std::string& group, const std::string& prefix) {
    std::vector<std::string> known;
    for (const Setting& s : setting_catalog())
        if (s.group == group) known.push_back(s.name);
    for (auto it = j.begin(); it != j.end(); ++it)
        if (!find_setting(group, it.key()))
            throw SpecError(prefix + it.key(), "unknown setting (known: " + joined(known, ", ") + ")");
}

// The group's settings, each validated or defaulted, as canonical JSON.
json settings_of_group(const std::string& group, const json& given, const SpecLimits& limits) {
    json out = json::object();
    for (const Setting& s : setting_catalog()) {
        if (s.group != group) continue;
        if (given.contains(s.name)) out[s.name] = check_setting(s, given[s.name], limits);
        else if (s.type == SettingType::Number && s.default_value.is_number())
            out[s.name] = s.default_value.get<double>();  // canonical as a given value is: 0.0, not 0
        else if (!s.default_value.is_null()) out[s.name] = s.default_value;
    }
    return out;
}

std::optional<int> int_or_auto(const json& v) {
    if (v.is_string()) return std::nullopt;
    return v.get<int>();
}

StopSettings stop_from(const json& j, const std::string& prefix) {
    return {j.at(prefix + "passes").get<int>(), j.at(prefix + "target_error").get<double>(),
            j.at(prefix + "time_limit").get<double>()};
}

// Rules between settings; each names the field to change.
void check_combination(const BakeSettings& b) {
    if (b.atlas.res && b.atlas.texel_density)
        throw SpecError("atlas.texel_density", "cannot be given together with atlas.res (give one; the other follows)");
    if (const OutputSettings* probes = b.output("probes"))
        if (probes->integer("probe_res") % probes->integer("probe_m") != 0)
            throw SpecError("probes.probe_m", std::to_string(probes->integer("probe_m")) +
                                                  " does not divide probe_res " +
                                                  std::to_string(probes->integer("probe_res")) + " (M must divide R)");
}

}  // namespace

double SpecLimits::cap(const std::string& key) const {
    auto it = caps.find(key);
    return it == caps.end() ? std::numeric_limits<double>::infinity() : it->second;
}

std::string Setting::flag() const {
    std::string f = name;
    for (char& c : f)
        if (c == '_') c = '-';
    if (type == SettingType::Flag && default_value == true) return "--no-" + f;
    return "--" + f;
}

std::string Setting::field() const { return group.empty() ? name : group + "." + name; }

std::string Setting::value_syntax() const {
    switch (type) {
    case SettingType::Integer:
        return (max - min <= 8 ? number_text(min) + ".." + number_text(max) : std::string("N")) +
               (accepts_auto ? "|auto" : "");
    case SettingType::Number: return std::string("X") + (accepts_auto ? "|auto" : "");
    case SettingType::Choice: return joined(choices, "|");
    case SettingType::Flag: return "";
    case SettingType::MeshList: return "MESHES";
    case SettingType::MeshScales: return "MESH=S,...";
    case SettingType::Environment: return "R,G,B|FILE";
    case SettingType::Positions: return "FILE.json";
    }
    return "";
}

const std::vector<Setting>& setting_catalog() {
    static const std::vector<Setting> catalog = build_catalog();
    return catalog;
}

StopSettings OutputSettings::stop() const { return stop_from(values, find_output(output)->stop_prefix); }

std::optional<int> OutputSettings::integer_or_auto(const std::string& name) const {
    const json& v = values.at(name);
    if (v.is_string()) return std::nullopt;
    return v.get<int>();
}

std::optional<double> OutputSettings::number_or_auto(const std::string& name) const {
    const json& v = values.at(name);
    if (v.is_string()) return std::nullopt;
    return v.get<double>();
}

const OutputSettings* BakeSettings::output(const std::string& name) const {
    const auto it = outputs.find(name);
    return it == outputs.end() ? nullptr : &it->second;
}

OutputSettings* BakeSettings::output(const std::string& name) {
    const auto it = outputs.find(name);
    return it == outputs.end() ? nullptr : &it->second;
}

namespace {

bool on_atlas(const OutputKind& kind, const OutputSettings& settings) {
    return kind.domain == OutputDomain::Texel ||
           (!kind.per_texel_setting.empty() && settings.flag(kind.per_texel_setting));
}

}  // namespace

bool BakeSettings::uses_atlas() const {
    for (const auto& [name, settings] : outputs)
        if (on_atlas(*find_output(name), settings)) return true;
    return false;
}

bool BakeSettings::atlas_needs_light() const {
    bool any = false;
    for (const auto& [name, settings] : outputs) {
        const OutputKind& kind = *find_output(name);
        if (!on_atlas(kind, settings)) continue;
        if (!kind.needs_light) return false;
        any = true;
    }
    return any;
}

bool BakeSettings::needs_light() const {
    for (const auto& [name, settings] : outputs)
        if (find_output(name)->needs_light) return true;
    return false;
}

const Setting* find_setting(const std::string& group, const std::string& name) {
    for (const Setting& s : setting_catalog())
        if (s.group == group && s.name == name) return &s;
    return nullptr;
}

const Setting* find_setting_by_flag(const std::string& flag) {
    for (const Setting& s : setting_catalog())
        if (s.flag() == flag) return &s;
    return nullptr;
}

namespace {

// A flag that is on unless turned off (`--no-denoise`) still takes its
// positive form (`--denoise`, from when it was off by default): it states the
// default, and the scripts written then keep running.
std::optional<std::string> positive_form(const Setting& s) {
    if (s.type != SettingType::Flag || s.default_value != true) return std::nullopt;
    return "--" + s.flag().substr(std::string("--no-").size());
}

const Setting* find_on_by_default_flag(const std::string& flag) {
    for (const Setting& s : setting_catalog())
        if (positive_form(s) == flag) return &s;
    return nullptr;
}

}  // namespace

BakeSettings parse_bake_settings(const json& j, const SpecLimits& limits) {
    require_object(j, "");
    if (!j.contains("outputs")) throw SpecError("outputs", "is required");
    const json& outputs = j["outputs"];
    require_object(outputs, "outputs");
    if (outputs.empty())
        throw SpecError("outputs", "must ask for at least one output (" + joined(output_names(), ", ") + ")");
    for (auto it = outputs.begin(); it != outputs.end(); ++it) {
        bool known = false;
        for (const std::string& o : output_names()) known = known || o == it.key();
        if (!known)
            throw SpecError("outputs." + it.key(), "unknown output (known: " + joined(output_names(), ", ") + ")");
        require_object(it.value(), "outputs." + it.key());
        reject_unknown(it.value(), it.key(), it.key() + ".");
    }
    const json atlas_given = j.value("atlas", json::object());
    require_object(atlas_given, "atlas");
    reject_unknown(atlas_given, "atlas", "atlas.");

    BakeSettings b;
    const json job = settings_of_group("", j, limits);
    b.seed = job.at("seed").get<uint32_t>();
    b.keep_snapshots = job.at("keep_snapshots").get<int>();
    if (job.contains("env")) {
        const json& e = job["env"];
        if (e.is_array()) b.env.sky = std::array<float, 3>{e[0].get<float>(), e[1].get<float>(), e[2].get<float>()};
        else b.env.map_file = e.get<std::string>();
    }
    const json atlas = settings_of_group("atlas", atlas_given, limits);
    b.atlas.res = int_or_auto(atlas["res"]);
    if (!atlas["texel_density"].is_string()) b.atlas.texel_density = atlas["texel_density"].get<double>();
    b.atlas.subsamples = atlas["subsamples"].get<int>();
    b.atlas.max_res = int_or_auto(atlas["max_res"]);
    b.atlas.max_pages = atlas["max_pages"].get<int>();
    if (!atlas_given.contains("max_pages"))  // the default within this server's limit, as max_res's
        b.atlas.max_pages = int(std::clamp(limits.cap("pages"), 1.0, double(b.atlas.max_pages)));
    b.atlas.glass_texels = atlas["glass_texels"].get<bool>();
    b.atlas.light_density = atlas["light_density"].get<bool>();
    for (const auto& [mesh, scale] : atlas["mesh_scale"].items()) b.atlas.mesh_scale[std::stoi(mesh)] = scale;
    if (!b.atlas.max_res && limits.cap("res") < kAutoMaxAtlasRes)
        b.atlas.max_res = int(std::max(256.0, limits.cap("res")));  // the smallest max_res: the default atlas
    for (const OutputKind& kind : output_registry()) {
        if (!outputs.contains(kind.name)) continue;
        OutputSettings& o = b.outputs[kind.name];
        o.output = kind.name;
        o.values = settings_of_group(kind.name, outputs[kind.name], limits);
    }
    check_combination(b);
    return b;
}

json to_json(const BakeSettings& b) {
    auto or_auto = [](const auto& v) { return v ? json(*v) : json("auto"); };
    json j = {{"outputs", json::object()}, {"seed", b.seed}};
    j["keep_snapshots"] = b.keep_snapshots;
    j["atlas"] = {{"res", or_auto(b.atlas.res)},          {"texel_density", or_auto(b.atlas.texel_density)},
                  {"subsamples", b.atlas.subsamples},     {"max_res", or_auto(b.atlas.max_res)},
                  {"max_pages", b.atlas.max_pages},       {"mesh_scale", json::object()},
                  {"glass_texels", b.atlas.glass_texels}, {"light_density", b.atlas.light_density}};
    for (const auto& [mesh, scale] : b.atlas.mesh_scale) j["atlas"]["mesh_scale"][std::to_string(mesh)] = scale;
    if (b.env.sky) j["env"] = *b.env.sky;
    else if (!b.env.map_file.empty()) j["env"] = b.env.map_file;
    for (const auto& [name, settings] : b.outputs) j["outputs"][name] = settings.values;
    return j;
}

namespace {

// The whole of `text` read by `parse` (std::stoll, std::stod), or nothing.
template <class T, class Parse>
std::optional<T> parse_whole(const std::string& text, Parse parse) {
    size_t used = 0;
    try {
        const T v = parse(text, &used);
        if (!text.empty() && used == text.size()) return v;
    } catch (const std::exception&) {
    }
    return std::nullopt;
}

// A command-line value as the JSON the catalog checks.
namespace {

// "a,b,c" -> {"a", "b", "c"}; `wrong` for an empty text or item.
std::vector<std::string> comma_separated(const std::string& text, const SpecError& wrong) {
    std::vector<std::string> items;
    size_t at = 0;
    while (at < text.size()) {
        const size_t comma = std::min(text.find(',', at), text.size());
        items.push_back(text.substr(at, comma - at));
        if (items.back().empty()) throw wrong;
        at = comma + 1;
    }
    if (text.empty() || text.back() == ',') throw wrong;
    return items;
}

}  // namespace

json value_from_text(const Setting& s, const std::string& text) {
    const std::string flag = s.flag();
    if (s.accepts_auto && text == "auto") return "auto";
    auto bad = [&](const std::string& what) { return SpecError(flag, "'" + text + "' is not " + what); };
    switch (s.type) {
    case SettingType::Integer:
        if (const auto v =
                parse_whole<long long>(text, [](const std::string& t, size_t* used) { return std::stoll(t, used); }))
            return *v;
        throw bad(s.accepts_auto ? "an integer or auto" : "an integer");
    case SettingType::Number:
        if (const auto v =
                parse_whole<double>(text, [](const std::string& t, size_t* used) { return std::stod(t, used); }))
            return *v;
        throw bad(s.accepts_auto ? "a number or auto" : "a number");
    case SettingType::Choice: return text;
    case SettingType::Flag: return s.default_value != true;
    case SettingType::MeshList: {
        json meshes = json::array();
        for (const std::string& item : comma_separated(text, bad("a list of glTF mesh indices like 0,3,4"))) {
            if (item.find_first_not_of("0123456789") != std::string::npos || item.size() > 9)
                throw bad("a list of glTF mesh indices like 0,3,4");
            meshes.push_back(std::stoi(item));
        }
        return meshes;
    }
    case SettingType::MeshScales: {
        const SpecError wrong = bad("a list of glTF mesh indices and scales like 3=2,5=0.25");
        json scales = json::object();
        for (const std::string& item : comma_separated(text, wrong)) {
            const size_t equals = item.find('=');
            if (equals == 0 || equals == std::string::npos) throw wrong;
            const auto scale = parse_whole<double>(
                item.substr(equals + 1), [](const std::string& t, size_t* used) { return std::stod(t, used); });
            if (!scale) throw wrong;
            scales[item.substr(0, equals)] = *scale;  // the key is checked with the spec's
        }
        return scales;
    }
    case SettingType::Positions: {
        // The JSON itself, or a file holding it.
        std::string content = text;
        if (text.empty() || text[0] != '[') {
            std::ifstream in(text);
            if (!in) throw SpecError(flag, "cannot read " + text);
            content.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
        }
        json points = json::parse(content, nullptr, false);
        if (points.is_discarded()) throw bad("JSON (a file of [{\"position\": [x, y, z]}, …])");
        return points;
    }
    case SettingType::Environment: {
        float r, g, b;
        char tail;
        if (std::sscanf(text.c_str(), "%f,%f,%f%c", &r, &g, &b, &tail) == 3) return json::array({r, g, b});
        if (text.find(',') != std::string::npos) throw bad("a sky radiance R,G,B or an environment map file");
        return text;
    }
    }
    return text;
}

// A SpecError on a field re-raised under the command-line flag that set it
// (a field that came from the spec file keeps its field name).
[[noreturn]] void rethrow_as_flag(const SpecError& e, const std::map<std::string, std::string>& flags) {
    for (const Setting& s : setting_catalog()) {
        if (e.field() != s.field() || !flags.count(s.flag())) continue;
        const std::string what = e.what();
        throw SpecError(s.flag(), what.substr(s.field().size() + 2));
    }
    throw e;
}

}  // namespace

json bake_json_from_flags(const std::map<std::string, std::string>& flags, const json& base) {
    // A malformed base (a bad --spec file) is reported, never replaced.
    if (!base.is_object()) throw SpecError("", "a spec must be a JSON object");
    for (const char* group : {"outputs", "atlas"})
        if (base.contains(group)) require_object(base[group], group);
    if (base.contains("outputs"))
        for (auto it = base["outputs"].begin(); it != base["outputs"].end(); ++it)
            require_object(it.value(), "outputs." + it.key());
    json j = base;
    if (!j.contains("outputs")) j["outputs"] = json::object();
    auto select = [&](const std::string& output) {
        if (!j["outputs"].contains(output)) j["outputs"][output] = json::object();
    };
    // A flag of the res / texel_density pair wins over the other one in the base.
    if (flags.count("--res") && j.contains("atlas")) j["atlas"].erase("texel_density");
    if (flags.count("--texel-density") && j.contains("atlas")) j["atlas"].erase("res");
    for (const auto& [flag, text] : flags) {
        bool is_output = false;
        for (const std::string& o : output_names())
            if (flag == "--" + o) {
                select(o);
                is_output = true;
            }
        if (is_output) continue;
        const Setting* s = find_setting_by_flag(flag);
        const Setting* positive = s ? nullptr : find_on_by_default_flag(flag);
        if (!s && !positive) throw SpecError(flag, "unknown bake option");
        if (positive) s = positive;
        const json value = positive ? json(true) : value_from_text(*s, text);
        if (s->group.empty()) {
            j[s->name] = value;
        } else if (s->group == "atlas") {
            j["atlas"][s->name] = value;
        } else {
            select(s->group);
            j["outputs"][s->group][s->name] = value;
        }
    }
    if (j["outputs"].empty()) j["outputs"]["lightmap"] = json::object();
    // Checked here too (without any server's caps), so that a bad value is
    // reported under its flag.
    try {
        SpecLimits no_caps;
        no_caps.caps.clear();
        parse_bake_settings(j, no_caps);
    } catch (const SpecError& e) {
        rethrow_as_flag(e, flags);
    }
    return j;
}

uint64_t estimated_bake_bytes(uint64_t atlas_texels, int subsamples) {
    constexpr uint64_t kBytesPerTexel = 260, kBytesPerSample = 72;
    constexpr uint64_t kBase = 130ull << 20;
    const uint64_t samples = uint64_t(std::max(1, subsamples)) * uint64_t(std::max(1, subsamples));
    return kBase + (kBytesPerTexel + kBytesPerSample * samples) * atlas_texels;
}

std::vector<std::pair<std::string, bool>> bake_flags() {
    std::vector<std::pair<std::string, bool>> flags;
    for (const std::string& o : output_names()) flags.emplace_back("--" + o, false);
    for (const Setting& s : setting_catalog()) {
        flags.emplace_back(s.flag(), s.type != SettingType::Flag);
        if (const auto positive = positive_form(s)) flags.emplace_back(*positive, false);
    }
    return flags;
}

}  // namespace lf::protocol
