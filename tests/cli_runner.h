// Runs the lightfarm binary (LIGHTFARM_BIN) as a user would, for the CLI tests.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace lf::test {

struct CliRun {
    int exit_code;
    std::string out;  // stdout
    std::string err;  // stderr
};

// `lightfarm ARGS` through the shell; stdout and stderr apart.
inline CliRun run_lightfarm(const std::string& args) {
    const std::filesystem::path err_file =
        std::filesystem::temp_directory_path() / ("lightfarm-cli-stderr-" + std::to_string(getpid()));
    const std::string command = std::string(LIGHTFARM_BIN) + " " + args + " 2>" + err_file.string();
    FILE* pipe = popen(command.c_str(), "r");
    std::string out;
    char buffer[4096];
    size_t n;
    while ((n = fread(buffer, 1, sizeof buffer, pipe)) > 0) out.append(buffer, n);
    const int status = pclose(pipe);
    std::ifstream e(err_file);
    std::stringstream err;
    err << e.rdbuf();
    std::filesystem::remove(err_file);
    return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out, err.str()};
}

}  // namespace lf::test
