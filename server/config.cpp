#include "config.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>

namespace lf::server {

namespace fs = std::filesystem;

const char* const kServerUsage = R"(usage: lightfarmd [options]

  --listen HOST:PORT     address to serve on (default 127.0.0.1:8750; port 0 = any free port)
  --data DIR             jobs, scenes and artifacts (default $XDG_DATA_HOME/lightfarm,
                         else ~/.local/share/lightfarm); one lightfarmd per DIR,
                         except with --store (then every node may share it)
  --tokens FILE          bearer tokens, one per line (default DATA/tokens, created
                         with a new random token when missing)
  --engine PATH          the lightfarm CLI that bakes (default: beside lightfarmd, else PATH)
  --web-dir DIR          where npm installed the status page's three.js (DIR/node_modules/three;
                         default: the source tree's web/)
  --workers N            concurrent bakes (default: two per GPU, one without a GPU)
  --attempts N           worker runs per job before it fails (default 3)
  --stall-timeout S      kill a worker silent for S seconds (default 300)
  --job-timeout S        kill an attempt running longer than S seconds (default 14400)
  --http-threads N       request threads; each event stream holds one (default 64)
  --store URI            the job store shared by many nodes: postgresql://USER@HOST:PORT/DB
                         (a libpq URI; default: DATA/jobs.sqlite, one lightfarmd per DIR);
                         then --data DIR may be a filesystem every node mounts
  --node-name NAME       this node's name, unique among the store's nodes (default: host name)
  --lease-seconds S      a job claimed by a node is its for S seconds after each renewal
                         (renewed every S/3); a killed node's job goes to another after
                         at most S (default 30)
  --limit KEY=VALUE      upload_bytes, spec_bytes, triangles, texture_size, queued_jobs, free_disk_bytes,
                         res, passes, time_limit, max_seconds, max_attempts;
                         HTTP: header_seconds, request_seconds, keep_alive_seconds, drain_seconds,
                         header_bytes, connections, connections_per_address,
                         event_streams, event_streams_per_token, event_streams_per_address,
                         body_reads, body_reads_per_token, body_reads_per_address
)";

namespace {
double parse_number(const std::string& option, const std::string& text) {
    size_t used = 0;
    double v = 0;
    try {
        v = std::stod(text, &used);
    } catch (const std::exception&) {
        used = 0;
    }
    if (text.empty() || used != text.size()) throw std::invalid_argument(option + ": '" + text + "' is not a number");
    return v;
}

void set_limit(ServerLimits& limits, const std::string& assignment) {
    const size_t eq = assignment.find('=');
    if (eq == std::string::npos) throw std::invalid_argument("--limit takes KEY=VALUE, not '" + assignment + "'");
    const std::string key = assignment.substr(0, eq), text = assignment.substr(eq + 1);
    const double v = parse_number("--limit " + key, text);
    // Seconds and a job's caps may be fractions; bytes and counts are whole
    // (a negative one would wrap round to a huge unsigned limit).
    const bool fraction = key.size() > 8 && key.compare(key.size() - 8, 8, "_seconds") == 0;
    const bool cap = limits.spec.caps.count(key) > 0;
    if (!std::isfinite(v)) throw std::invalid_argument("--limit " + key + ": '" + text + "' is not a finite number");
    if (cap && !(v > 0)) throw std::invalid_argument("--limit " + key + ": a cap must be above 0, not '" + text + "'");
    if (!fraction && !cap && (v < 0 || v != std::floor(v) || v >= 9.2e18))
        throw std::invalid_argument("--limit " + key + ": a whole number, 0 or more, not '" + text + "'");
    if (key == "upload_bytes") limits.upload_bytes = uint64_t(v);
    else if (key == "spec_bytes") limits.spec_bytes = uint64_t(v);
    else if (key == "triangles") limits.triangles = int64_t(v);
    else if (key == "texture_size") limits.texture_size = int64_t(v);
    else if (key == "queued_jobs") limits.queued_jobs = int(v);
    else if (key == "free_disk_bytes") limits.free_disk_bytes = uint64_t(v);
    else if (key == "header_seconds") limits.header_seconds = v;
    else if (key == "request_seconds") limits.request_seconds = v;
    else if (key == "keep_alive_seconds") limits.keep_alive_seconds = v;
    else if (key == "drain_seconds") limits.drain_seconds = v;
    else if (key == "header_bytes") limits.header_bytes = int64_t(v);
    else if (key == "connections") limits.connections = int(v);
    else if (key == "connections_per_address") limits.connections_per_address = int(v);
    else if (key == "event_streams") limits.event_streams = int(v);
    else if (key == "event_streams_per_token") limits.event_streams_per_token = int(v);
    else if (key == "event_streams_per_address") limits.event_streams_per_address = int(v);
    else if (key == "body_reads") limits.body_reads = int(v);
    else if (key == "body_reads_per_token") limits.body_reads_per_token = int(v);
    else if (key == "body_reads_per_address") limits.body_reads_per_address = int(v);
    else if (cap) limits.spec.caps[key] = v;
    else throw std::invalid_argument("--limit: unknown key '" + key + "'");
}
}  // namespace

ServerConfig parse_server_args(const std::vector<std::string>& args, bool& help) {
    ServerConfig c;
    help = false;
    for (size_t i = 0; i < args.size(); ++i) {
        const std::string& a = args[i];
        if (a == "--help" || a == "-h") {
            help = true;
            continue;
        }
        if (a == "--accept-empty-store") {
            c.accept_empty_store = true;
            continue;
        }
        if (i + 1 >= args.size())
            throw std::invalid_argument(a.rfind("--", 0) == 0 ? a + " needs a value"
                                                              : "unexpected argument '" + a + "'");
        const std::string& v = args[++i];
        if (a == "--listen") {
            const size_t colon = v.rfind(':');
            if (colon == std::string::npos) throw std::invalid_argument("--listen takes HOST:PORT, not '" + v + "'");
            c.host = v.substr(0, colon);
            c.port = int(parse_number("--listen port", v.substr(colon + 1)));
        } else if (a == "--data") c.data_dir = v;
        else if (a == "--tokens") c.tokens_file = v;
        else if (a == "--engine") c.engine = v;
        else if (a == "--web-dir") c.web_dir = v;
        else if (a == "--workers") c.workers = int(parse_number(a, v));
        else if (a == "--attempts") c.default_attempts = int(parse_number(a, v));
        else if (a == "--stall-timeout") c.stall_seconds = parse_number(a, v);
        else if (a == "--job-timeout") c.default_max_seconds = parse_number(a, v);
        else if (a == "--http-threads") c.http_threads = int(parse_number(a, v));
        else if (a == "--limit") set_limit(c.limits, v);
        else if (a == "--max-inspects") c.max_inspects = int(parse_number(a, v));
        else if (a == "--inspect-memory-mb") c.inspect_memory_bytes = uint64_t(parse_number(a, v) * 1048576.0);
        else if (a == "--event-retention-days") c.event_retention_days = parse_number(a, v);
        else if (a == "--store") c.store = v;
        else if (a == "--node-name") c.node_name = v;
        else if (a == "--lease-seconds") c.lease_seconds = parse_number(a, v);
        else throw std::invalid_argument("unknown option " + a);
    }
    if (c.workers < 0 || (c.workers == 0 && std::find(args.begin(), args.end(), "--workers") != args.end()))
        throw std::invalid_argument("--workers must be at least 1");
    if (c.default_attempts < 1) throw std::invalid_argument("--attempts must be at least 1");
    if (c.http_threads < 4) throw std::invalid_argument("--http-threads must be at least 4");
    if (c.max_inspects < 1) throw std::invalid_argument("--max-inspects must be at least 1");
    if (c.inspect_memory_bytes < (64ull << 20)) throw std::invalid_argument("--inspect-memory-mb must be at least 64");
    if (c.event_retention_days < 0) throw std::invalid_argument("--event-retention-days must be at least 0");
    if (!c.store.empty() && c.store.rfind("postgresql://", 0) != 0 && c.store.rfind("postgres://", 0) != 0)
        throw std::invalid_argument("--store: '" + c.store +
                                    "' is not a PostgreSQL URI; write postgresql://USER@HOST:PORT/DB "
                                    "(without --store, the job store is DATA/jobs.sqlite)");
    if (!(c.lease_seconds >= 1)) throw std::invalid_argument("--lease-seconds must be at least 1");
    if (c.node_name.find_first_of(" \t\n\"\\") != std::string::npos || c.node_name.size() > 128)
        throw std::invalid_argument("--node-name: at most 128 characters, without spaces, quotes or backslashes");
    const ServerLimits& l = c.limits;
    if (!(l.drain_seconds >= 0) || !std::isfinite(l.drain_seconds))
        throw std::invalid_argument("--limit: drain_seconds must be a number of seconds, 0 or more");
    if (!(l.header_seconds > 0) || !(l.request_seconds >= l.header_seconds) || !(l.keep_alive_seconds > 0))
        throw std::invalid_argument(
            "--limit: header_seconds and keep_alive_seconds must be positive, request_seconds at least header_seconds");
    if (l.header_bytes < 8192 || l.header_bytes > (16 << 20))
        throw std::invalid_argument("--limit header_bytes: between 8192 and 16777216");
    // cpp-httplib (built without poll) answers 500 on a socket numbered
    // FD_SETSIZE (1024) or above: the connections must stay below it.
    if (l.connections < 1 || l.connections > 900) throw std::invalid_argument("--limit connections: between 1 and 900");
    if (l.connections_per_address < 1 || l.event_streams < 0 || l.event_streams_per_token < 1)
        throw std::invalid_argument("--limit: connections_per_address and event_streams_per_token must be at least 1");
    // Event streams hold a request thread each: they may never take more than half.
    c.limits.event_streams = l.event_streams == 0 ? c.http_threads / 2 : std::min(l.event_streams, c.http_threads / 2);
    return c;
}

std::string find_engine(const std::string& configured) {
    if (!configured.empty()) return configured;
    std::error_code ec;
    const fs::path self = fs::read_symlink("/proc/self/exe", ec);
    if (!ec) {
        for (const fs::path& candidate :
             {self.parent_path() / ".." / "client_cli" / "lightfarm", self.parent_path() / "lightfarm"}) {
            if (access(candidate.c_str(), X_OK) == 0) return fs::weakly_canonical(candidate).string();
        }
    }
    return "lightfarm";
}

std::vector<std::string> read_tokens(const std::string& path) {
    std::ifstream in(path);
    if (!in) throw std::runtime_error("cannot read tokens file " + path);
    std::vector<std::string> tokens;
    for (std::string line; std::getline(in, line);) {
        const size_t b = line.find_first_not_of(" \t\r");
        if (b == std::string::npos || line[b] == '#') continue;
        const size_t e = line.find_last_not_of(" \t\r");
        tokens.push_back(line.substr(b, e - b + 1));
    }
    return tokens;
}

int worker_count(const ServerConfig& config, int gpus) {
    if (config.workers > 0) return config.workers;
    return gpus > 0 ? 2 * gpus : 1;
}

}  // namespace lf::server
