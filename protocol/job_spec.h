// The job spec: what a client asks lightfarmd to bake, and how it is checked.
//
//   {"scene": "<scene id>",
//    "outputs": {"lightmap": {"res": 256, "passes": 64}},
//    "seed": 1,
//    "limits": {"max_seconds": 600, "max_attempts": 3}}
//
// Each output's settings are exactly the options of `lightfarm bake` (same
// names, '_' in JSON for '-' on the command line). The catalog below is the
// only place that knows them: the server validates a spec against it and turns
// it back into bake arguments, and the CLI parses its bake options through it,
// so a new output (sh, probes) is a new catalog entry and no server change.
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf::protocol {

// A spec that does not validate. what() is "field: reason", e.g.
// "lightmap.res: 100000 exceeds the limit 8192"; field() is "lightmap.res".
class SpecError : public std::runtime_error {
public:
    SpecError(const std::string& field, const std::string& reason)
        : std::runtime_error(field.empty() ? reason : field + ": " + reason), field_(field) {}
    const std::string& field() const { return field_; }

private:
    std::string field_;
};

// One setting of one output.
struct SettingInfo {
    enum class Type { Integer, Number };
    std::string name;      // JSON key, e.g. "texel_density"
    std::string cli_flag;  // bake option, e.g. "--texel-density"
    Type type = Type::Number;
    double min = 0.0;      // smallest allowed value
    bool min_exclusive = false;  // true: must be > min
    // Which server limit caps the value ("res", "passes", "time_limit"), or
    // empty for none. Limits are named by these keys in SpecLimits.
    std::string limit;
    std::string help;
};

// One kind of output a job can ask for.
struct OutputInfo {
    std::string name;                      // "lightmap"
    std::vector<std::string> select_args;  // bake arguments that turn this output on ({} for lightmap)
    std::vector<SettingInfo> settings;
    // Pairs of settings that may not be given together (res vs texel_density).
    std::vector<std::pair<std::string, std::string>> exclusive;
};

// Every output the protocol knows, in a fixed order.
const std::vector<OutputInfo>& output_catalog();
const OutputInfo* find_output(const std::string& name);

// The server's caps on what a spec may ask for, by limit key. Keys used by the
// catalog ("res", "passes", "time_limit") plus the job's own: "max_seconds"
// (wall time of one attempt) and "max_attempts".
struct SpecLimits {
    std::map<std::string, double> caps = {
        {"res", 8192},
        {"passes", 100000},
        {"time_limit", 4 * 3600},
        {"max_seconds", 4 * 3600},
        {"max_attempts", 10},
    };
    double cap(const std::string& key) const;  // +infinity when absent
};

// What the job may use; absent = the server's default.
struct JobLimits {
    std::optional<double> max_seconds;  // wall-clock deadline of one attempt
    std::optional<int> max_attempts;    // worker runs before the job fails
};

struct JobSpec {
    std::string scene;
    // Output name -> its settings, already validated (numbers of the right
    // type and range, known keys only).
    std::map<std::string, nlohmann::json> outputs;
    uint64_t seed = 1;
    JobLimits limits;
};

// Parses and validates; throws SpecError naming the first bad field. Unknown
// fields are errors.
JobSpec parse_job_spec(const nlohmann::json& j, const SpecLimits& limits = {});
nlohmann::json to_json(const JobSpec& spec);

// The part of a spec that determines the bake's result (scene, outputs,
// seed; not limits), as canonical JSON text: equal text = equal bake.
std::string bake_identity(const JobSpec& spec);

// The `lightfarm bake` options for a spec's outputs and seed, in catalog
// order, e.g. {"--res", "256", "--passes", "64", "--seed", "1"}.
std::vector<std::string> bake_arguments(const JobSpec& spec);

// The inverse for the CLI: every bake option the catalog knows (those that
// take a value) ...
std::vector<std::string> bake_option_flags();
// ... and the outputs they ask for: flag -> text value (as typed) to output
// name -> settings. With no output flag at all, asks for a default lightmap.
// Throws SpecError naming the flag for a value that is not a number.
std::map<std::string, nlohmann::json> outputs_from_bake_options(const std::map<std::string, std::string>& values);

}  // namespace lf::protocol
