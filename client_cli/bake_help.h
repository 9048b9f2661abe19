// The bake options as `lightfarm bake --help` and `submit` list them: the
// catalog's settings (protocol/bake_settings.h), as the README's table has them.
#pragma once

#include <string>

namespace lf::cli {

// "settings:\n" and one line per setting: flag, value syntax, help, [default].
std::string bake_settings_help();
// The bake command's usage line, then bake_settings_help().
std::string bake_help();
// One command's entry of a usage text ("  COMMAND …" and its indented
// continuation lines) as "usage: lightfarm COMMAND …"; "" when the text has
// no such command.
std::string command_usage(const std::string& usage, const std::string& command);

}  // namespace lf::cli
