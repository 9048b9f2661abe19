// libFuzzer target: the JSON that lightfarmd and the worker parse from
// outside, as text.
//
//   * parse_job_spec: a POST /jobs body, under the server's limits and again
//     under the CLI's (no caps, local files allowed). An accepted spec must
//     survive what the service does with it: to_json, dump, parse again
//     (supervisor, worker) with the same bake_identity.
//   * bake_json_from_flags: the CLI's `bake` flags over a `--spec` base. The
//     flags are the top-level members whose key starts with "--" (a string is
//     the flag's text, anything else its JSON text, true/false/null ""); the
//     base is the rest. What it returns must validate (it says it does).
//   * parse_worker_event: one line of a worker's stdout.
//   * scene_summary_from_json: what `lightfarm inspect --json` printed.
//
// Each parser's documented refusal is caught (SpecError; std::invalid_argument
// for the worker protocol); any other exception escapes and libFuzzer reports
// it as a crash, as it does an ASan or UBSan report or a broken invariant.
#include "bake_settings.h"
#include "job_spec.h"
#include "worker_protocol.h"

#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <stdexcept>
#include <string>

namespace {

using nlohmann::json;
namespace protocol = lf::protocol;

[[noreturn]] void broken(const char* invariant, const std::string& detail) {
    std::fprintf(stderr, "fuzz_job_spec: invariant broken: %s\n%s\n", invariant, detail.c_str());
    std::abort();
}

protocol::SpecLimits server_limits() {
    protocol::SpecLimits limits;  // the default caps
    limits.allow_local_files = false;
    return limits;
}

protocol::SpecLimits cli_limits() {
    protocol::SpecLimits limits;
    limits.caps.clear();
    return limits;
}

void fuzz_job_spec(const json& j, const protocol::SpecLimits& limits) {
    protocol::JobSpec spec;
    try {
        spec = protocol::parse_job_spec(j, limits);
    } catch (const protocol::SpecError&) {
        return;
    }
    // lightfarmd stores to_json(spec); the supervisor parses it again and
    // writes its dump() for the worker's --spec, which parses that text.
    const std::string stored = protocol::to_json(spec).dump();
    const json again = json::parse(stored, nullptr, false);
    if (again.is_discarded()) broken("the canonical JSON of an accepted spec is not JSON", stored);
    protocol::JobSpec reparsed;
    try {
        reparsed = protocol::parse_job_spec(again, limits);
    } catch (const protocol::SpecError& e) {
        broken("the canonical JSON of an accepted spec is refused", j.dump() + "\n-> " + stored + "\n-> " + e.what());
    }
    if (protocol::bake_identity(reparsed) != protocol::bake_identity(spec))
        broken("bake_identity changes when the canonical JSON is parsed again",
               protocol::bake_identity(spec) + "\n-> " + protocol::bake_identity(reparsed));
}

void fuzz_flags(const json& j) {
    if (!j.is_object()) return;
    std::map<std::string, std::string> flags;
    json base = json::object();
    for (auto it = j.begin(); it != j.end(); ++it) {
        if (it.key().rfind("--", 0) != 0) {
            base[it.key()] = it.value();
            continue;
        }
        const json& v = it.value();
        if (v.is_string()) flags[it.key()] = v.get<std::string>();
        else if (v.is_boolean() || v.is_null()) flags[it.key()] = "";
        else flags[it.key()] = v.dump();
    }
    if (flags.empty()) return;
    json bake;
    try {
        bake = protocol::bake_json_from_flags(flags, base);
    } catch (const protocol::SpecError&) {
        return;
    }
    try {
        protocol::parse_bake_settings(bake, cli_limits());
    } catch (const protocol::SpecError& e) {
        broken("bake_json_from_flags returned settings that do not validate", bake.dump() + "\n-> " + e.what());
    }
}

void fuzz_worker_event(const json& j) {
    try {
        const protocol::WorkerEvent event = protocol::parse_worker_event(j);
        (void)protocol::to_json(event).dump();
    } catch (const std::invalid_argument&) {
    }
}

void fuzz_scene_summary(const json& j) {
    try {
        const protocol::SceneSummary summary = protocol::scene_summary_from_json(j);
        (void)protocol::to_json(summary).dump();
    } catch (const std::invalid_argument&) {
    }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const json j =
        json::parse(reinterpret_cast<const char*>(data), reinterpret_cast<const char*>(data) + size, nullptr, false);
    if (j.is_discarded()) return 0;
    fuzz_job_spec(j, server_limits());
    fuzz_job_spec(j, cli_limits());
    fuzz_flags(j);
    fuzz_worker_event(j);
    fuzz_scene_summary(j);
    return 0;
}
