// lightfarmd's settings: command-line options over embedded defaults, so that
// `lightfarmd` with no arguments is a working local service.
#pragma once

#include "job_spec.h"

#include <cstdint>
#include <string>
#include <vector>

namespace lf::server {

struct ServerLimits {
    uint64_t upload_bytes = 256ull << 20;  // one request body
    int64_t triangles = 5'000'000;         // per scene, from `lightfarm inspect`
    int64_t texture_size = 8192;           // width or height of any texture
    int queued_jobs = 100;                 // queued jobs per token
    protocol::SpecLimits spec;             // res, passes, time_limit, max_seconds, max_attempts
};

struct ServerConfig {
    std::string host = "127.0.0.1";
    int port = 8750;                  // 0: any free port (the chosen one is logged and written to DATA/lightfarmd.url)
    std::string data_dir = "lightfarm-data";
    std::string tokens_file;          // empty: DATA/tokens, created with a random token if missing
    std::string engine;               // empty: found beside lightfarmd, else in PATH
    int workers = 0;  // 0: one per GPU (the engine's `devices`), one without a GPU
    int http_threads = 64;            // SSE readers hold a thread each
    int default_attempts = 3;
    double default_max_seconds = 4 * 3600;  // one attempt's wall-clock deadline
    double stall_seconds = 300;       // no worker output for this long = hung
    double inspect_seconds = 60;      // deadline of `lightfarm inspect` on an upload
    ServerLimits limits;
};

// Parses argv (after the program name). Throws std::invalid_argument with a
// readable message; `--help` sets `help`.
ServerConfig parse_server_args(const std::vector<std::string>& args, bool& help);
extern const char* const kServerUsage;

// The engine CLI: `configured` if set, else `lightfarm` beside this executable
// in the build tree (../client_cli/lightfarm) or the install (./lightfarm),
// else "lightfarm" (searched in PATH).
std::string find_engine(const std::string& configured);

// Reads a tokens file: one token per line; blank lines and '#' lines ignored.
std::vector<std::string> read_tokens(const std::string& path);

}  // namespace lf::server
