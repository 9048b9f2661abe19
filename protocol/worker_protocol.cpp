#include "worker_protocol.h"

#include <algorithm>
#include <cstdio>
#include <limits>
#include <stdexcept>

namespace lf::protocol {

using nlohmann::json;

json to_json(const Progress& p) {
    json j = {{"pass", p.pass}, {"rays", p.rays}, {"seconds", p.seconds}};
    j["error_estimate"] = p.error_estimate ? json(*p.error_estimate) : json(nullptr);
    j["eta_seconds"] = p.eta_seconds ? json(*p.eta_seconds) : json(nullptr);
    j["prepare_seconds"] = p.prepare_seconds;
    j["earlier_outputs_seconds"] = p.earlier_outputs_seconds;
    if (p.shown_fraction > 0.0) j["shown_fraction"] = p.shown_fraction;
    if (!p.preparing.empty()) {
        j["preparing"] = p.preparing;
        j["prepare_eta_seconds"] = p.prepare_eta_seconds ? json(*p.prepare_eta_seconds) : json(nullptr);
    }
    const std::optional<double> fraction = done_fraction(p);
    j["fraction"] = fraction ? json(*fraction) : json(nullptr);
    return j;
}

std::optional<double> done_fraction(const Progress& p) {
    const double shown = std::clamp(p.shown_fraction, 0.0, 1.0);
    if (!p.eta_seconds) return shown > 0.0 ? std::optional<double>(shown) : std::nullopt;
    const double done =
        std::max(0.0, p.prepare_seconds) + std::max(0.0, p.earlier_outputs_seconds) + std::max(0.0, p.seconds);
    const double left = std::max(0.0, *p.eta_seconds);
    return std::max(shown, done + left > 0.0 ? done / (done + left) : 1.0);
}

Progress progress_from_json(const json& j) {
    Progress p;
    if (!j.is_object()) return p;
    // Counts are read only when they are non-negative integers in range: a
    // float or negative "rays" was undefined behaviour (found by fuzzing).
    if (j.contains("pass") && j["pass"].is_number_integer() && j["pass"].get<int64_t>() >= 0 &&
        j["pass"].get<int64_t>() <= std::numeric_limits<int>::max())
        p.pass = int(j["pass"].get<int64_t>());
    if (j.contains("rays") && j["rays"].is_number_unsigned()) p.rays = j["rays"].get<uint64_t>();
    else if (j.contains("rays") && j["rays"].is_number_integer() && j["rays"].get<int64_t>() >= 0)
        p.rays = uint64_t(j["rays"].get<int64_t>());
    if (j.contains("seconds") && j["seconds"].is_number()) p.seconds = j["seconds"].get<double>();
    if (j.contains("error_estimate") && j["error_estimate"].is_number())
        p.error_estimate = j["error_estimate"].get<double>();
    if (j.contains("eta_seconds") && j["eta_seconds"].is_number()) p.eta_seconds = j["eta_seconds"].get<double>();
    if (j.contains("prepare_seconds") && j["prepare_seconds"].is_number())
        p.prepare_seconds = j["prepare_seconds"].get<double>();
    if (j.contains("earlier_outputs_seconds") && j["earlier_outputs_seconds"].is_number())
        p.earlier_outputs_seconds = j["earlier_outputs_seconds"].get<double>();
    if (j.contains("shown_fraction") && j["shown_fraction"].is_number())
        p.shown_fraction = std::clamp(j["shown_fraction"].get<double>(), 0.0, 1.0);
    if (j.contains("preparing") && j["preparing"].is_string()) p.preparing = j["preparing"].get<std::string>();
    if (j.contains("prepare_eta_seconds") && j["prepare_eta_seconds"].is_number())
        p.prepare_eta_seconds = j["prepare_eta_seconds"].get<double>();
    return p;
}

std::string snapshot_file_name(const std::string& stem, int pass, const std::string& extension) {
    char number[16];
    std::snprintf(number, sizeof number, "%04d", pass);
    return stem + ".pass-" + number + "." + extension;
}

std::string snapshot_pattern(const std::string& name) {
    if (!is_snapshot_file(name)) return name;
    const size_t at = name.find(".pass-") + 6;
    return name.substr(0, at) + "NNNN" + name.substr(name.find('.', at));
}

std::string page_file_name(const std::string& stem, int page, const std::string& extension) {
    return stem + ".page-" + std::to_string(page) + "." + extension;
}

std::string page_pattern(const std::string& name) {
    const size_t at = name.find(".page-");
    if (at == std::string::npos) return name;
    size_t digits = at + 6;
    while (digits < name.size() && name[digits] >= '0' && name[digits] <= '9') ++digits;
    if (digits == at + 6 || digits == name.size() || name[digits] != '.') return name;
    return name.substr(0, at + 6) + "N" + name.substr(digits);
}

bool is_snapshot_file(const std::string& name) {
    const size_t at = name.find(".pass-");
    if (at == std::string::npos) return false;
    size_t digits = at + 6;
    while (digits < name.size() && name[digits] >= '0' && name[digits] <= '9') ++digits;
    return digits > at + 6 && digits < name.size() && name[digits] == '.';
}

namespace {

json progress_fields(const Progress& p) {
    json j = to_json(p);
    for (const char* servers : {"eta_seconds", "prepare_seconds", "earlier_outputs_seconds", "fraction",
                                "shown_fraction", "preparing", "prepare_eta_seconds"})
        j.erase(servers);  // not the worker's
    return j;
}

bool said_again(const json& j) { return j.contains("again") && j["again"].is_boolean() && j["again"].get<bool>(); }

std::string string_field(const json& j, const char* key) {
    if (!j.contains(key) || !j[key].is_string())
        throw std::invalid_argument(std::string("worker event without a string \"") + key + "\"");
    return j[key].get<std::string>();
}

// An optional string: absent is "", any other type is an error.
std::string optional_string(const json& j, const char* key) {
    if (!j.contains(key)) return "";
    if (!j[key].is_string()) throw std::invalid_argument(std::string("\"") + key + "\" must be a string");
    return j[key].get<std::string>();
}

// A count: a non-negative integer (signed or not, as JSON built in code or parsed from text has it).
uint64_t count_field(const json& j, const char* key) {
    if (!j.contains(key)) return 0;
    const json& v = j[key];
    if (v.is_number_unsigned()) return v.get<uint64_t>();
    if (v.is_number_integer() && v.get<int64_t>() >= 0) return uint64_t(v.get<int64_t>());
    throw std::invalid_argument(std::string("\"") + key + "\" must be a non-negative integer");
}

}  // namespace

json to_json(const WorkerEvent& e) {
    if (const auto* p = std::get_if<PrepareEvent>(&e)) {
        json j = {{"event", "prepare"}, {"stage", p->stage}, {"seconds", p->seconds}};
        j["eta_seconds"] = p->eta_seconds ? json(*p->eta_seconds) : json(nullptr);
        if (p->again) j["again"] = true;
        return j;
    }
    if (const auto* s = std::get_if<StartEvent>(&e)) {
        json j = {{"event", "start"},
                  {"vendor", s->vendor},
                  {"renderer", s->renderer},
                  {"triangles", s->triangles},
                  {"prepare_seconds", s->prepare_seconds},
                  {"outputs", s->outputs}};
        for (const auto& [output, at] : s->resumed) j["resumed"][output] = progress_fields(at);
        for (const auto& [output, why] : s->not_resumed) j["not_resumed"][output] = why;
        if (!s->warnings.empty()) j["warnings"] = s->warnings;
        return j;
    }
    if (const auto* p = std::get_if<ProgressEvent>(&e)) {
        json j = progress_fields(p->progress);
        j["event"] = "progress";
        j["output"] = p->output;
        if (p->again) j["again"] = true;
        return j;
    }
    if (const auto* s = std::get_if<SnapshotEvent>(&e))
        return {{"event", "snapshot"}, {"output", s->output}, {"file", s->file}, {"pass", s->pass}};
    const auto& d = std::get<DoneEvent>(e);
    json j = progress_fields(d.progress);
    j["event"] = "done";
    j["files"] = d.files;
    j["final"] = d.final_files;
    return j;
}

WorkerEvent parse_worker_event(const json& j) {
    if (!j.is_object()) throw std::invalid_argument("a worker event is a JSON object");
    const std::string kind = string_field(j, "event");
    if (kind == "prepare") {
        PrepareEvent p;
        p.stage = string_field(j, "stage");
        if (j.contains("seconds") && j["seconds"].is_number()) p.seconds = j["seconds"].get<double>();
        if (j.contains("eta_seconds") && j["eta_seconds"].is_number()) p.eta_seconds = j["eta_seconds"].get<double>();
        p.again = said_again(j);
        return p;
    }
    if (kind == "start") {
        StartEvent s;
        s.vendor = optional_string(j, "vendor");
        s.renderer = optional_string(j, "renderer");
        s.triangles = count_field(j, "triangles");
        if (j.contains("prepare_seconds") && j["prepare_seconds"].is_number()) s.prepare_seconds = j["prepare_seconds"];
        if (j.contains("outputs") && j["outputs"].is_object()) s.outputs = j["outputs"];
        if (j.contains("resumed") && j["resumed"].is_object())
            for (auto it = j["resumed"].begin(); it != j["resumed"].end(); ++it)
                s.resumed[it.key()] = progress_from_json(it.value());
        if (j.contains("not_resumed") && j["not_resumed"].is_object())
            for (auto it = j["not_resumed"].begin(); it != j["not_resumed"].end(); ++it)
                if (it.value().is_string()) s.not_resumed[it.key()] = it.value().get<std::string>();
        if (j.contains("warnings") && j["warnings"].is_array())
            for (const json& w : j["warnings"])
                if (w.is_string()) s.warnings.push_back(w.get<std::string>());
        return s;
    }
    if (kind == "progress") return ProgressEvent{optional_string(j, "output"), progress_from_json(j), said_again(j)};
    if (kind == "snapshot") {
        const Progress at = progress_from_json(j);
        if (!j.contains("pass") || at.pass != j["pass"])
            throw std::invalid_argument("snapshot event without a valid pass");
        return SnapshotEvent{optional_string(j, "output"), string_field(j, "file"), at.pass};
    }
    if (kind == "done") {
        DoneEvent d;
        d.progress = progress_from_json(j);
        if (j.contains("files") && j["files"].is_array())
            for (const json& f : j["files"])
                if (f.is_string()) d.files.push_back(f.get<std::string>());
        if (j.contains("final") && j["final"].is_object())
            for (auto it = j["final"].begin(); it != j["final"].end(); ++it)
                if (it.value().is_string()) d.final_files[it.key()] = it.value().get<std::string>();
        return d;
    }
    throw std::invalid_argument("unknown worker event \"" + kind + "\"");
}

json to_json(const SceneSummary& s) {
    json j = s.details.is_object() ? s.details : json::object();
    j["source"] = s.source;
    j["triangles"] = s.triangles;
    j["emissive_triangles"] = s.emissive_triangles;
    j["punctual_light_count"] = s.punctual_lights;
    j["max_texture_size"] = s.max_texture_size;
    j["has_lightmap_uvs"] = s.has_lightmap_uvs;
    j["min_atlas_res"] = s.min_atlas_res;
    return j;
}

SceneSummary scene_summary_from_json(const json& j) {
    if (!j.is_object()) throw std::invalid_argument("a scene summary is a JSON object");
    SceneSummary s;
    s.details = j;
    s.source = optional_string(j, "source");
    s.triangles = count_field(j, "triangles");
    s.emissive_triangles = count_field(j, "emissive_triangles");
    s.punctual_lights = count_field(j, "punctual_light_count");
    s.max_texture_size = int(std::min<uint64_t>(count_field(j, "max_texture_size"), 1u << 30));
    if (j.contains("has_lightmap_uvs") && !j["has_lightmap_uvs"].is_boolean())
        throw std::invalid_argument("\"has_lightmap_uvs\" must be true or false");
    s.has_lightmap_uvs = j.value("has_lightmap_uvs", false);
    s.min_atlas_res = int(std::min<uint64_t>(count_field(j, "min_atlas_res"), 1u << 30));
    return s;
}

std::string temporary_file_name(const std::string& name, long pid) {
    return "." + name + ".tmp-" + std::to_string(pid);
}

bool is_temporary_file_of(const std::string& file_name, long pid) {
    const std::string tail = ".tmp-" + std::to_string(pid);
    return file_name.size() > tail.size() + 1 && file_name[0] == '.' &&
           file_name.compare(file_name.size() - tail.size(), tail.size(), tail) == 0;
}

}  // namespace lf::protocol
