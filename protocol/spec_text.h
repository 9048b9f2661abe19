#pragma once
// How the spec parsers (bake_settings.cpp, job_spec.cpp) name a value in a
// SpecError: one wording for every field. Internal to lightfarm_protocol.
#include <nlohmann/json.hpp>

#include <string>

namespace lf::protocol {

// "an integer", "a number", "a string", "an array", "an object", …
std::string json_type_name(const nlohmann::json& j);

// The shortest text for a number: 8192, not 8192.000000.
std::string number_text(double v);

}  // namespace lf::protocol
