// lightfarmd's settings: command-line options over embedded defaults, so that
// `lightfarmd` with no arguments is a working local service.
#pragma once

#include "job_spec.h"

#include <cstdint>
#include <string>
#include <vector>

namespace lf::server {

struct ServerLimits {
    uint64_t upload_bytes = 256ull << 20;  // one upload's body
    uint64_t spec_bytes = 1ull << 20;      // any other request's body (a job spec)
    int64_t triangles = 5'000'000;         // per scene, from `lightfarm inspect`
    int64_t texture_size = 8192;           // width or height of any texture
    int queued_jobs = 100;                 // queued jobs per token
    // Below this much free space on the data directory's disk the server
    // takes no new work (503) and starts no worker: queued jobs wait.
    uint64_t free_disk_bytes = 64ull << 20;
    protocol::SpecLimits spec;  // res, passes, time_limit, max_seconds, max_attempts

    // The HTTP layer (docs/service.md, "Slow and idle clients"). A request's
    // line and headers are gathered off the request threads, and must arrive
    // whole within header_seconds (from the connection, or from the first
    // byte of a later request on a kept-alive one) and within header_bytes;
    // the whole request, body included, within request_seconds.
    double header_seconds = 10;
    double request_seconds = 300;
    double keep_alive_seconds = 5;    // an idle kept-alive connection is closed after this
    double drain_seconds = 5;         // on SIGTERM, requests in flight have this long to finish
    int64_t header_bytes = 64 << 10;  // request line + headers (the request line alone: 8192)
    // At a connection cap, a new connection first closes an idle one (one
    // that has sent nothing): the oldest of its own address, or at the total
    // cap, of the address holding the most. Only if none is idle is it 503.
    int connections = 512;             // open connections, in total
    int connections_per_address = 64;  // open connections from one client address (an eighth of the total)
    int event_streams = 0;             // open event streams, in total; 0: half of --http-threads (the most allowed)
    int event_streams_per_token = 16;  // open event streams of one token
    // Open event streams from one client address, whatever its tokens (0:
    // half of event_streams): many tokens of one address cannot take them all.
    int event_streams_per_address = 0;
    // A request's body is read on a request thread, as long as the client
    // takes to send it: bodies being read at once, per bearer token and per
    // client address (0: an eighth and a quarter of --http-threads).
    int body_reads_per_token = 0;
    int body_reads_per_address = 0;
    // Bodies being read at once in total (0: half of --http-threads), so
    // that many tenants together cannot hold every request thread either.
    int body_reads = 0;
};

// Request threads that request bodies being read and event streams may
// hold together: all but a quarter of --http-threads, which always serve the
// rest of the API (each has its own cap too: body_reads, event_streams).
inline int threads_for_bodies_and_streams(int http_threads) { return http_threads - http_threads / 4; }

struct ServerConfig {
    std::string host = "127.0.0.1";
    int port = 8750;          // 0: any free port (the chosen one is logged and written to DATA/lightfarmd.url)
    std::string data_dir;     // empty: $XDG_DATA_HOME/lightfarm, else $HOME/.local/share/lightfarm
    std::string tokens_file;  // empty: DATA/tokens, created with a random token if missing
    std::string engine;       // empty: found beside lightfarmd, else in PATH
    std::string web_dir = LIGHTFARM_WEB_DIR;  // web/ with node_modules/three (scripts/common.sh installs it)
    int workers = 0;                          // 0: worker_count(): two per GPU, one without a GPU
    int http_threads = 64;                    // SSE readers hold a thread each
    int default_attempts = 3;
    double default_max_seconds = 4 * 3600;  // one attempt's wall-clock deadline
    double stall_seconds = 300;             // no worker output for this long = hung
    double inspect_seconds = 60;            // deadline of `lightfarm inspect` on an upload
    ServerLimits limits;
    bool accept_empty_store =
        false;             // --accept-empty-store: start on an empty store, moving orphaned job/scene dirs aside
    int max_inspects = 2;  // --max-inspects N: concurrent upload checks; more wait, then 503
    uint64_t inspect_memory_bytes =
        2ull << 30;  // --inspect-memory-mb M: address-space limit (RLIMIT_AS) of an upload check
    double event_retention_days =
        7;  // --event-retention-days D: a finished job's progress events compacted after D days
    // Scale-out (docs/scale-out.md): --store postgresql://USER@HOST:PORT/DB
    // shares one database among many nodes; empty: DATA/jobs.sqlite, one node.
    std::string store;
    std::string node_name;      // --node-name NAME: unique among the store's nodes; empty: the host name
    double lease_seconds = 30;  // --lease-seconds S: a dead node's job goes to another after at most S
};

// Parses argv (after the program name). Throws std::invalid_argument with a
// readable message; `--help` sets `help`.
ServerConfig parse_server_args(const std::vector<std::string>& args, bool& help);

// How many bakes run at once on a machine with `gpus` GPUs: --workers, or
// two per GPU, so that one job's preparation (load, atlas, BVH on the CPU)
// and file writing overlap another's passes and a queue keeps each GPU busy;
// one without a GPU, where preparation and passes share the same cores.
int worker_count(const ServerConfig& config, int gpus);
extern const char* const kServerUsage;

// The engine CLI: `configured` if set, else `lightfarm` beside this executable
// in the build tree (../client_cli/lightfarm) or the install (./lightfarm),
// else "lightfarm" (searched in PATH).
std::string find_engine(const std::string& configured);

// Reads a tokens file: one token per line; blank lines and '#' lines ignored.
std::vector<std::string> read_tokens(const std::string& path);

}  // namespace lf::server
