// The CLI's commands against a lightfarmd server: submit, watch, fetch,
// cancel, jobs. The bake options of `submit` are those of `lightfarm bake`,
// read through protocol/'s one catalog.
#pragma once

#include <string>

namespace lf::cli {

// True for the commands run_remote_command handles.
bool is_remote_command(const std::string& command);

// Runs `lightfarm COMMAND ...` (argv[1] is the command). Prints a server or
// connection error as one line on stderr; returns the exit status (0 ok, 1
// failed, 2 usage).
int run_remote_command(const std::string& command, int argc, char** argv);

extern const char* const kRemoteUsage;

}  // namespace lf::cli
