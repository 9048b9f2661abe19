#include "scene/gltf_errors.h"

#include <algorithm>

namespace lf::gltf {

std::string printable(std::string_view text, size_t max_chars) {
    std::string out;
    const size_t n = std::min(text.size(), max_chars);
    out.reserve(n + 3);
    for (size_t i = 0; i < n; ++i) {
        const unsigned char c = static_cast<unsigned char>(text[i]);
        // Bytes >= 0x80 pass (UTF-8 names); only C0 controls and DEL can break a line or a terminal.
        out += (c < 0x20 || c == 0x7f) ? '?' : char(c);
    }
    if (text.size() > max_chars) out += "...";
    return out;
}

std::string in_quotes(std::string_view text, size_t max_chars) { return "\"" + printable(text, max_chars) + "\""; }

void Errors::fail(const std::string& what) const {
    throw SceneError(printable(file_, 200) + ": " + printable(what, 400));
}

void Errors::fail(std::string_view object, int64_t index, const std::string& what) const {
    fail(std::string(object) + " " + std::to_string(index) + ": " + what);
}

void Errors::fail(std::string_view object, const std::string& what) const { fail(std::string(object) + ": " + what); }

std::string Errors::label(std::string_view object, int64_t index, std::string_view name) {
    std::string out = std::string(object) + " " + std::to_string(index);
    if (!name.empty()) out += " " + in_quotes(name, 40);
    return out;
}

}  // namespace lf::gltf
