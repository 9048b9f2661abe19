// The status page's files (web/ui: status.html, its status.css and scripts,
// login.html), embedded in the binary at build time (cmake/embed_files.cmake),
// by file name. GET / serves status.html with the caller's jobs inlined
// (service_status.cpp); a page request without a token gets login.html.
// GET /ui/{file} serves the .css and .js files by name, and the page loads
// three.js from /ui/three.
#pragma once

#include <map>
#include <string>
#include <string_view>

namespace lf::server {

const std::map<std::string, std::string_view>& embedded_web_files();

}  // namespace lf::server
