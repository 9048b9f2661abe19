// lightfarmd's HTTP API (protocol/openapi.json): routes, authentication,
// limits. Owns the job store, the scene store and the worker supervisor.
#pragma once

#include "config.h"
#include "events.h"
#include "job_store.h"
#include "metrics.h"
#include "preview.h"
#include "preview_cache.h"
#include "scene_store.h"
#include "supervisor.h"

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <regex>
#include <set>
#include <string>
#include <vector>

namespace httplib {
class DataSink;
class Server;
struct Request;
struct Response;
}  // namespace httplib

namespace lf::server {

class GatedServer;  // cpp-httplib's server behind lightfarmd's connection gate (http_gate.h)

// Short job ids: kMinJobIdPrefix or more lower-case hex digits.
constexpr size_t kMinJobIdPrefix = 6;
bool is_job_id_prefix(const std::string& id);

// The job store `config` names: PostgreSQL for --store, else DATA/jobs.sqlite;
// speaking for the node --node-name, with leases of --lease-seconds.
std::unique_ptr<JobStore> open_job_store(const ServerConfig& config);
// The one of `jobs` whose id starts with `prefix` (nullopt: none, or not a
// prefix); throws HttpError 409 when several do.
std::optional<JobRecord> job_by_id_prefix(const std::string& prefix, std::vector<JobRecord> jobs);
// The job directories under DATA/jobs whose jobs `store` has no record of:
// records lost with the store's newest writes (a SQLite WAL lost after a
// checkpoint, a database restored from an older backup).
std::vector<std::string> jobs_without_records(const std::string& data_dir, JobStore& store);

// JSON to inline in an HTML <script>: the same value, with no character that
// HTML's script parsing or JavaScript's line breaks react to (<, >, &,
// U+2028, U+2029 as \u escapes).
std::string json_for_script(const nlohmann::json& value);

class Service {
public:
    // `tokens`: the bearer tokens that may use the API.
    Service(ServerConfig config, const std::vector<std::string>& tokens);
    ~Service();

    // Binds config.host:config.port (port 0: any free one) and returns the
    // port. Throws std::runtime_error when it cannot.
    int bind();
    // Starts the workers and serves until stop(). Blocks.
    void run();
    // From any thread (a signal handler thread): ends run().
    void stop();

    // Every route, as the API document names it. The server registers
    // exactly these, so a test can hold them against protocol/openapi.json.
    struct RouteInfo {
        std::string method;  // "GET", "POST"
        std::string path;    // "/v1/jobs/{id}"
        bool needs_token;
    };
    static std::vector<RouteInfo> route_table();

private:
    struct Caller {
        std::string owner;  // a hash of the token: the store never holds tokens
    };
    using Handler = void (Service::*)(const httplib::Request&, httplib::Response&, const Caller&);
    enum class Auth { None, Token, Page };
    struct Route {
        const char* method;
        const char* path;
        Auth auth;
        Handler handler;
    };
    static const std::vector<Route>& routes();

    std::optional<Caller> authenticate(const httplib::Request& req, bool allow_cookie) const;
    // What can be decided from the request line and headers, before any body
    // is read: names, the route, the token, the body's framing and size.
    // Answers (fills `res`, returns true) when the request must go no further.
    bool check_before_body(const httplib::Request& req, httplib::Response& res);
    struct Refusal {
        int status;
        nlohmann::json body;
    };
    std::optional<Refusal> check_post_framing(httplib::Request& req, const Route& route) const;
    const Route* match_route(const std::string& method, const std::string& path) const;
    void serve(const Route& route, const httplib::Request& req, httplib::Response& res);
    void install_http_hooks();
    // The caller's job the path's {id} names: its whole id, or an unambiguous
    // prefix (job_by_id_prefix; 404 when no job of the caller's has it).
    JobRecord owned_job(const httplib::Request& req, const Caller& caller);
    // What a listing of jobs looks up once, however many jobs it lists.
    // What a queued job's place and start depend on, read once (a listing).
    struct QueueOutlook {
        int running = 0;                                  // the jobs running now
        int slots = 0;                                    // the farm's workers (alive nodes')
        std::vector<std::optional<double>> running_left;  // each running job's ETA, where it has one
        std::optional<double> typical_seconds;            // queue_estimate.h
    };
    struct StatusLookups {
        std::map<std::string, nlohmann::json> briefs;  // scene id -> its name and size
        std::optional<QueueOutlook> queue;
    };
    QueueOutlook queue_outlook() const;
    // A job's status for the API; `lookups` spares a listing the store
    // queries its jobs share.
    nlohmann::json status_json(const JobRecord& job, StatusLookups* lookups = nullptr) const;
    nlohmann::json scene_brief(const std::string& scene_id, const std::string& owner) const;
    nlohmann::json jobs_json(const std::string& owner) const;  // GET /v1/jobs's body

    void healthz(const httplib::Request&, httplib::Response&, const Caller&);
    void metrics(const httplib::Request&, httplib::Response&, const Caller&);
    void status_page(const httplib::Request&, httplib::Response&, const Caller&);
    // 503 (with Retry-After) while the data directory's disk is below --limit free_disk_bytes.
    void refuse_when_disk_full(httplib::Response&);
    void post_scene(const httplib::Request&, httplib::Response&, const Caller&);
    void get_scene(const httplib::Request&, httplib::Response&, const Caller&);
    void post_job(const httplib::Request&, httplib::Response&, const Caller&);
    protocol::JobSpec accepted_spec(const httplib::Request& req, const Caller& caller);
    bool answer_from_cache(JobRecord& job, const Caller& caller, httplib::Response& res);
    void list_jobs(const httplib::Request&, httplib::Response&, const Caller&);
    void list_nodes(const httplib::Request&, httplib::Response&, const Caller&);
    // GET /v1/nodes's body: every node of the store, and the caller's jobs on each.
    nlohmann::json nodes_json(const std::string& owner) const;
    void get_job(const httplib::Request&, httplib::Response&, const Caller&);
    void job_events(const httplib::Request&, httplib::Response&, const Caller&);
    // Where a job's event stream is: the last event sent, and when it last wrote.
    struct EventCursor {
        int64_t last_id;
        std::chrono::steady_clock::time_point last_write;
    };
    // Takes one of the event streams' own budget of request threads, in total
    // and per token, or answers 503.
    void reserve_event_stream(httplib::Response& res, const Caller& caller, const std::string& address,
                              const std::string& job_id);
    bool send_new_events(const std::string& job_id, EventCursor& cursor, httplib::DataSink& sink);
    void list_artifacts(const httplib::Request&, httplib::Response&, const Caller&);
    void get_artifact(const httplib::Request&, httplib::Response&, const Caller&);
    void preview(const httplib::Request&, httplib::Response&, const Caller&);
    void lightmap_rgbm(const httplib::Request&, httplib::Response&, const Caller&);
    void error_map(const httplib::Request&, httplib::Response&, const Caller&);
    void send_preview(const httplib::Request&, httplib::Response&, const Caller&, PreviewKind);
    void web_file(const httplib::Request&, httplib::Response&, const Caller&);
    void web_library(const httplib::Request&, httplib::Response&, const Caller&);
    void cancel_job(const httplib::Request&, httplib::Response&, const Caller&);

    ServerConfig config_;
    std::set<std::string> owners_;  // hashes of the valid tokens
    std::unique_ptr<JobStore> store_;
    ChangeSignal changes_;
    Metrics metrics_;
    std::unique_ptr<SceneStore> scenes_;
    std::unique_ptr<Supervisor> supervisor_;
    std::unique_ptr<GatedServer> http_;
    std::vector<std::regex> route_regexes_;  // routes()[i]'s path as a regex
    std::set<std::string> lost_jobs_;        // jobs_without_records at start: 410, not a silent 404

    // Open event streams, in total, by owner and by client address (their own budget of request threads).
    std::mutex streams_mutex_;
    int streams_open_ = 0;
    std::map<std::string, int> streams_by_owner_;
    std::map<std::string, int> streams_by_address_;
    int listen_socket_ = -1;
    static constexpr int kListenBacklog = 1024;
    // What the previews may hold in memory (the status page's three images
    // of a 2048² lightmap are about 6 MB).
    static constexpr uint64_t kPreviewCacheBytes = uint64_t(64) << 20;

    // Every kind of preview of a job's newest lightmap, made from one read.
    PreviewCache previews_{kPreviewCacheBytes};
};

}  // namespace lf::server
