// One line per event on stderr, with a UTC timestamp: what an operator reads.
#pragma once

#include <string>

namespace lf::server {
void log_line(const std::string& message);
}
