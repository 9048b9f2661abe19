#include "job_spec.h"

#include <cmath>
#include <limits>
#include <sstream>

namespace lf::protocol {

using nlohmann::json;

const std::vector<OutputInfo>& output_catalog() {
    using T = SettingInfo::Type;
    static const std::vector<OutputInfo> catalog = {
        {"lightmap",
         {"--lightmap"},
         {
             {"res", "--res", T::Integer, 1, false, "res", "atlas width and height in texels"},
             {"texel_density", "--texel-density", T::Number, 0, true, "", "texels per metre (atlas size follows the scene)"},
             {"passes", "--passes", T::Integer, 1, false, "passes", "stop after this many passes"},
             {"target_error", "--target-error", T::Number, 0, true, "", "stop when the error estimate falls below this"},
             {"time_limit", "--time-limit", T::Number, 0, true, "time_limit", "stop after this many seconds of baking"},
         },
         {{"res", "texel_density"}}},
        {"sh",
         {"--sh"},
         {
             {"sh_bands", "--sh-bands", T::Integer, 0, false, "", "SH bands 1..4; 0 = auto (fewest within 2% of 4 bands)"},
             {"sh_bounces", "--sh-bounces", T::Integer, 0, false, "", "interreflection bounces (0 = shadowed transfer, at most 4)"},
             {"sh_passes", "--sh-passes", T::Integer, 1, false, "passes", "stop after this many passes of 64 rays per vertex"},
             {"sh_target_error", "--sh-target-error", T::Number, 0, true, "", "stop when the transfer's relative standard error falls below this"},
             {"sh_time_limit", "--sh-time-limit", T::Number, 0, true, "time_limit", "stop after this many seconds of baking"},
         },
         {}},
    };
    return catalog;
}

const OutputInfo* find_output(const std::string& name) {
    for (const OutputInfo& o : output_catalog())
        if (o.name == name) return &o;
    return nullptr;
}

double SpecLimits::cap(const std::string& key) const {
    auto it = caps.find(key);
    return it == caps.end() ? std::numeric_limits<double>::infinity() : it->second;
}

namespace {

// Shortest text for a number: 8192, not 8192.000000.
std::string number_text(double v) {
    std::ostringstream s;
    s.precision(15);
    s << v;
    return s.str();
}

std::string type_name(const json& j) {
    if (j.is_number_integer() || j.is_number_unsigned()) return "an integer";
    if (j.is_number()) return "a number";
    const std::string name = j.type_name();
    return (name == "array" || name == "object" ? "an " : "a ") + name;
}

void require_object(const json& j, const std::string& field) {
    if (!j.is_object()) throw SpecError(field, "must be an object, not " + type_name(j));
}

// Every key of `j` must be one of `known`.
void reject_unknown(const json& j, const std::vector<std::string>& known, const std::string& prefix) {
    for (auto it = j.begin(); it != j.end(); ++it) {
        bool found = false;
        for (const std::string& k : known) found = found || k == it.key();
        if (!found) {
            std::string list;
            for (const std::string& k : known) list += (list.empty() ? "" : ", ") + k;
            throw SpecError(prefix + it.key(), "unknown field (known: " + list + ")");
        }
    }
}

// Checks a number against its type, minimum and server cap; returns it as JSON
// of the right type (integers stay integers).
json check_number(const json& v, SettingInfo::Type type, double min, bool min_exclusive,
                  double cap, const std::string& field) {
    if (!v.is_number()) throw SpecError(field, "must be a number, not " + type_name(v));
    const double x = v.get<double>();
    if (!std::isfinite(x)) throw SpecError(field, "must be finite");
    if (type == SettingInfo::Type::Integer && !(v.is_number_integer() || v.is_number_unsigned()))
        throw SpecError(field, "must be an integer, not " + number_text(x));
    if (min_exclusive ? !(x > min) : !(x >= min))
        throw SpecError(field, number_text(x) + " is below the minimum " + (min_exclusive ? "(exclusive) " : "") + number_text(min));
    if (x > cap) throw SpecError(field, number_text(x) + " exceeds the limit " + number_text(cap));
    if (type == SettingInfo::Type::Integer) return json(v.get<int64_t>());
    return json(x);
}

json parse_output(const OutputInfo& info, const json& j, const SpecLimits& limits) {
    const std::string prefix = info.name + ".";
    require_object(j, info.name);
    std::vector<std::string> known;
    for (const SettingInfo& s : info.settings) known.push_back(s.name);
    reject_unknown(j, known, prefix);

    json out = json::object();
    for (const SettingInfo& s : info.settings) {
        if (!j.contains(s.name)) continue;
        const double cap = s.limit.empty() ? std::numeric_limits<double>::infinity() : limits.cap(s.limit);
        out[s.name] = check_number(j[s.name], s.type, s.min, s.min_exclusive, cap, prefix + s.name);
    }
    for (const auto& [a, b] : info.exclusive)
        if (out.contains(a) && out.contains(b))
            throw SpecError(prefix + b, "cannot be given together with " + a);
    return out;
}

}  // namespace

JobSpec parse_job_spec(const json& j, const SpecLimits& limits) {
    require_object(j, "");
    reject_unknown(j, {"scene", "outputs", "seed", "limits"}, "");
    JobSpec spec;

    if (!j.contains("scene")) throw SpecError("scene", "is required");
    if (!j["scene"].is_string()) throw SpecError("scene", "must be a string, not " + type_name(j["scene"]));
    spec.scene = j["scene"].get<std::string>();
    if (spec.scene.empty()) throw SpecError("scene", "must not be empty");

    if (!j.contains("outputs")) throw SpecError("outputs", "is required");
    const json& outputs = j["outputs"];
    require_object(outputs, "outputs");
    if (outputs.empty()) throw SpecError("outputs", "must ask for at least one output");
    for (auto it = outputs.begin(); it != outputs.end(); ++it) {
        const OutputInfo* info = find_output(it.key());
        if (!info) {
            std::string list;
            for (const OutputInfo& o : output_catalog()) list += (list.empty() ? "" : ", ") + o.name;
            throw SpecError("outputs." + it.key(), "unknown output (known: " + list + ")");
        }
        spec.outputs[info->name] = parse_output(*info, it.value(), limits);
    }

    if (j.contains("seed")) {
        const json& s = j["seed"];
        if (!s.is_number_integer() && !s.is_number_unsigned())
            throw SpecError("seed", "must be a non-negative integer, not " + type_name(s));
        if (s.is_number_integer() && s.get<int64_t>() < 0) throw SpecError("seed", "must not be negative");
        spec.seed = s.get<uint64_t>();
    }

    if (j.contains("limits")) {
        const json& l = j["limits"];
        require_object(l, "limits");
        reject_unknown(l, {"max_seconds", "max_attempts"}, "limits.");
        if (l.contains("max_seconds"))
            spec.limits.max_seconds = check_number(l["max_seconds"], SettingInfo::Type::Number, 0, true,
                                                   limits.cap("max_seconds"), "limits.max_seconds").get<double>();
        if (l.contains("max_attempts"))
            spec.limits.max_attempts = int(check_number(l["max_attempts"], SettingInfo::Type::Integer, 1, false,
                                                        limits.cap("max_attempts"), "limits.max_attempts").get<int64_t>());
    }
    return spec;
}

json to_json(const JobSpec& spec) {
    json j = {{"scene", spec.scene}, {"outputs", json::object()}, {"seed", spec.seed}};
    for (const auto& [name, settings] : spec.outputs) j["outputs"][name] = settings;
    json limits = json::object();
    if (spec.limits.max_seconds) limits["max_seconds"] = *spec.limits.max_seconds;
    if (spec.limits.max_attempts) limits["max_attempts"] = *spec.limits.max_attempts;
    if (!limits.empty()) j["limits"] = limits;
    return j;
}

std::string bake_identity(const JobSpec& spec) {
    // nlohmann::json objects keep keys sorted, so dump() is canonical.
    json j = to_json(spec);
    j.erase("limits");
    return j.dump();
}

std::vector<std::string> bake_arguments(const JobSpec& spec) {
    std::vector<std::string> args;
    for (const OutputInfo& info : output_catalog()) {
        auto it = spec.outputs.find(info.name);
        if (it == spec.outputs.end()) continue;
        args.insert(args.end(), info.select_args.begin(), info.select_args.end());
        for (const SettingInfo& s : info.settings) {
            if (!it->second.contains(s.name)) continue;
            const json& v = it->second[s.name];
            args.push_back(s.cli_flag);
            args.push_back(v.is_number_float() ? number_text(v.get<double>()) : v.dump());
        }
    }
    args.push_back("--seed");
    args.push_back(std::to_string(spec.seed));
    return args;
}

std::vector<std::string> bake_option_flags() {
    std::vector<std::string> flags;
    for (const OutputInfo& info : output_catalog())
        for (const SettingInfo& s : info.settings) flags.push_back(s.cli_flag);
    return flags;
}

std::map<std::string, json> outputs_from_bake_options(const std::map<std::string, std::string>& values) {
    std::map<std::string, json> outputs;
    for (const OutputInfo& info : output_catalog()) {
        for (const SettingInfo& s : info.settings) {
            auto it = values.find(s.cli_flag);
            if (it == values.end()) continue;
            const std::string& text = it->second;
            size_t used = 0;
            json value;
            try {
                if (s.type == SettingInfo::Type::Integer) value = int64_t(std::stoll(text, &used));
                else value = std::stod(text, &used);
            } catch (const std::exception&) {
                used = 0;
            }
            if (text.empty() || used != text.size())
                throw SpecError(s.cli_flag, "'" + text + "' is not " +
                                (s.type == SettingInfo::Type::Integer ? "an integer" : "a number"));
            if (!outputs.count(info.name)) outputs[info.name] = json::object();
            outputs[info.name][s.name] = value;
        }
    }
    if (outputs.empty()) outputs["lightmap"] = json::object();
    return outputs;
}

}  // namespace lf::protocol
