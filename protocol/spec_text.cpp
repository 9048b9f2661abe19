#include "spec_text.h"

#include <sstream>

namespace lf::protocol {

std::string json_type_name(const nlohmann::json& j) {
    if (j.is_number_integer() || j.is_number_unsigned()) return "an integer";
    if (j.is_number()) return "a number";
    const std::string name = j.type_name();
    return (name == "array" || name == "object" ? "an " : "a ") + name;
}

std::string number_text(double v) {
    std::ostringstream s;
    s.precision(15);
    s << v;
    return s.str();
}

}  // namespace lf::protocol
