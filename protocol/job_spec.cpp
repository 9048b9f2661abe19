#include "job_spec.h"

#include <sstream>

namespace lf::protocol {

using nlohmann::json;

namespace {

std::string type_name(const json& j) {
    if (j.is_number_integer() || j.is_number_unsigned()) return "an integer";
    const std::string name = j.type_name();
    return (name == "array" || name == "object" ? "an " : "a ") + name;
}

// Shortest text for a number: 10, not 10.0.
std::string number_text(double v) {
    std::ostringstream s;
    s.precision(15);
    s << v;
    return s.str();
}

// A job limit: a number in (0, cap] (max_seconds) or an integer in [1, cap] (max_attempts).
double check_limit(const json& v, bool integer, const SpecLimits& limits, const std::string& key) {
    const std::string field = "limits." + key;
    if (!v.is_number() || (integer && !(v.is_number_integer() || v.is_number_unsigned())))
        throw SpecError(field,
                        std::string("must be ") + (integer ? "an integer" : "a number") + ", not " + type_name(v));
    const double x = v.get<double>();
    if (!(integer ? x >= 1.0 : x > 0.0))
        throw SpecError(field, std::string("must be ") + (integer ? "at least 1" : "positive"));
    if (x > limits.cap(key))
        throw SpecError(field, number_text(x) + " exceeds this server's limit " + number_text(limits.cap(key)));
    if (integer && x > 1e6) throw SpecError(field, number_text(x) + " exceeds the maximum 1000000");
    return x;
}

}  // namespace

JobSpec parse_job_spec(const json& j, const SpecLimits& limits) {
    if (!j.is_object()) throw SpecError("", "a job spec must be a JSON object, not " + type_name(j));
    for (auto it = j.begin(); it != j.end(); ++it) {
        static const char* const known[] = {"scene", "outputs", "atlas", "seed", "env", "limits"};
        bool found = false;
        for (const char* k : known) found = found || it.key() == k;
        if (!found) throw SpecError(it.key(), "unknown field (known: scene, outputs, atlas, seed, env, limits)");
    }
    JobSpec spec;
    if (!j.contains("scene")) throw SpecError("scene", "is required");
    if (!j["scene"].is_string()) throw SpecError("scene", "must be a string, not " + type_name(j["scene"]));
    spec.scene = j["scene"].get<std::string>();
    if (spec.scene.empty()) throw SpecError("scene", "must not be empty");

    spec.bake = parse_bake_settings(j, limits);

    if (j.contains("limits")) {
        const json& l = j["limits"];
        if (!l.is_object()) throw SpecError("limits", "must be an object, not " + type_name(l));
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
}

std::string bake_identity(const JobSpec& spec) {
    // nlohmann::json objects keep keys sorted, so dump() is canonical.
    json j = to_json(spec);
    j.erase("limits");
    return j.dump();
}

}  // namespace lf::protocol
