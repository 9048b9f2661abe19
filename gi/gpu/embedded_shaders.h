// GLSL sources under gi/shaders, embedded at build time (cmake/embed_files.cmake).
#pragma once

#include <map>
#include <string>
#include <string_view>

namespace lf {

// File name (e.g. "trace.glsl") -> source text.
const std::map<std::string, std::string_view>& embedded_shaders();

}  // namespace lf
