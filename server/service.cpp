#include "service.h"

#include "data_dir.h"
#include "disk_space.h"
#include "hash.h"
#include "http_error.h"
#include "http_gate.h"
#include "log.h"
#include "postgres_job_store.h"
#include "preview.h"
#include "sqlite_job_store.h"
#include "web_files.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <httplib.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <regex>
#include <thread>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// The store keys ownership by a hash of the token, never the token itself.
std::string owner_of(const std::string& token) { return sha256_hex("lightfarm-token:" + token).substr(0, 32); }

void send_json(httplib::Response& res, int status, const json& body) {
    res.status = status;
    // A message may quote what a client sent: never let its bytes make the answer fail.
    res.set_content(body.dump(2, ' ', false, json::error_handler_t::replace) + "\n", "application/json");
}

// The route being served on this thread and when it started, for /metrics.
// cpp-httplib serves a request start to finish on one thread.
thread_local std::string current_route;
thread_local std::chrono::steady_clock::time_point request_started;

// Workers write a file as a temporary and rename it; those temporaries, and
// the supervisor's own dot files, are not artifacts.
bool is_artifact_name(const std::string& name) {
    return !name.empty() && name[0] != '.' && name.find(".tmp") == std::string::npos &&
           name.find('/') == std::string::npos;
}

struct Artifact {
    std::string name;
    uintmax_t size;
};

std::vector<Artifact> artifacts_in(const fs::path& dir) {
    std::vector<Artifact> found;
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
        const std::string name = e.path().filename().string();
        std::error_code size_ec;
        if (!e.is_regular_file(size_ec) || !is_artifact_name(name)) continue;
        const uintmax_t size = e.file_size(size_ec);
        if (!size_ec) found.push_back({name, size});
    }
    std::sort(found.begin(), found.end(), [](const Artifact& a, const Artifact& b) { return a.name < b.name; });
    return found;
}

// A stored scene's summary as the checks at submit read it, named as the
// user uploaded it. A summary from an older engine that does not say whether
// the scene has a light is taken as lit: what is not known is not refused.
protocol::SceneSummary summary_of(const SceneRecord& scene) {
    protocol::SceneSummary summary;
    try {
        summary = protocol::scene_summary_from_json(scene.summary);
    } catch (const std::invalid_argument&) {
        summary.has_lightmap_uvs = true;
    }
    if (!scene.summary.is_object() || !scene.summary.contains("emissive_triangles") ||
        !scene.summary.contains("punctual_light_count"))
        summary.emissive_triangles = std::max<uint64_t>(summary.emissive_triangles, 1);
    summary.source = scene.main_file.empty() ? summary.source : scene.main_file;
    return summary;
}

// "/v1/jobs/{id}/artifacts/{name}" -> regex with one group per parameter.
std::string route_regex(const std::string& path) {
    static const std::regex param(R"(\{[a-z_]+\})");
    // {path} spans folders (a file under a directory); any other parameter is one segment.
    return std::regex_replace(std::regex_replace(path, std::regex(R"(\{path\})"), "(.+)"), param, "([^/]+)");
}

}  // namespace

namespace {

// A name (a path, an id, an artifact name, a parameter) is used exactly as
// sent or refused: no NUL, no control character, valid UTF-8 (no overlong
// forms, surrogates or code points past U+10FFFF), no C1 controls.
bool is_clean_text(const std::string& s) {
    const auto* p = reinterpret_cast<const unsigned char*>(s.data());
    const size_t n = s.size();
    for (size_t i = 0; i < n;) {
        const unsigned char c = p[i];
        if (c < 0x80) {
            if (c < 0x20 || c == 0x7f) return false;
            ++i;
            continue;
        }
        size_t len;
        uint32_t cp;
        if (c >= 0xc2 && c <= 0xdf) len = 2, cp = c & 0x1f;
        else if (c >= 0xe0 && c <= 0xef) len = 3, cp = c & 0x0f;
        else if (c >= 0xf0 && c <= 0xf4) len = 4, cp = c & 0x07;
        else return false;
        if (i + len > n) return false;
        for (size_t k = 1; k < len; ++k) {
            if ((p[i + k] & 0xc0) != 0x80) return false;
            cp = (cp << 6) | (p[i + k] & 0x3f);
        }
        if ((len == 3 && cp < 0x800) || (len == 4 && cp < 0x10000) || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff) ||
            (cp >= 0x80 && cp <= 0x9f))
            return false;
        i += len;
    }
    return true;
}

// What failed, for a 500's message: without the server's paths (the log has
// the whole message).
std::string describe_failure(const std::exception& e, const std::string& data_dir) {
    if (const auto* fe = dynamic_cast<const fs::filesystem_error*>(&e))
        return std::string("a file operation failed: ") + fe->code().message();
    std::string m = e.what();
    if (!data_dir.empty())
        for (size_t at = m.find(data_dir); at != std::string::npos; at = m.find(data_dir, at + 6))
            m.replace(at, data_dir.size(), "<data>");
    static const std::regex absolute_path(R"((^|[\s'"(=:\[])/[^\s'"()\],;]*)");
    return std::regex_replace(m, absolute_path, "$1<path>");
}

}  // namespace

const std::vector<Service::Route>& Service::routes() {
    static const std::vector<Route> table = {
        {"GET", "/healthz", Auth::None, &Service::healthz},
        {"GET", "/metrics", Auth::Token, &Service::metrics},
        {"GET", "/", Auth::Page, &Service::status_page},
        {"POST", "/v1/scenes", Auth::Token, &Service::post_scene},
        {"GET", "/v1/scenes/{id}", Auth::Token, &Service::get_scene},
        {"POST", "/v1/jobs", Auth::Token, &Service::post_job},
        {"GET", "/v1/jobs", Auth::Token, &Service::list_jobs},
        {"GET", "/v1/nodes", Auth::Token, &Service::list_nodes},
        {"GET", "/v1/jobs/{id}", Auth::Token, &Service::get_job},
        {"GET", "/v1/jobs/{id}/events", Auth::Token, &Service::job_events},
        {"GET", "/v1/jobs/{id}/artifacts", Auth::Token, &Service::list_artifacts},
        {"GET", "/v1/jobs/{id}/artifacts/{name}", Auth::Token, &Service::get_artifact},
        {"GET", "/v1/jobs/{id}/preview.png", Auth::Token, &Service::preview},
        {"GET", "/v1/jobs/{id}/lightmap.rgbm.png", Auth::Token, &Service::lightmap_rgbm},
        {"GET", "/v1/jobs/{id}/error.png", Auth::Token, &Service::error_map},
        {"GET", "/ui/three/{path}", Auth::Token, &Service::web_library},
        {"POST", "/v1/jobs/{id}/cancel", Auth::Token, &Service::cancel_job},
    };
    return table;
}

std::vector<Service::RouteInfo> Service::route_table() {
    std::vector<RouteInfo> info;
    for (const Route& r : routes()) info.push_back({r.method, r.path, r.auth != Auth::None});
    return info;
}

Service::Service(ServerConfig config, const std::vector<std::string>& tokens) : config_(std::move(config)) {
    if (config_.limits.event_streams <= 0) config_.limits.event_streams = std::max(1, config_.http_threads / 2);
    // No two tokens may hold every stream between them: one token gets at
    // most a quarter of them (with the default 64 threads: 8 of 32).
    config_.limits.event_streams_per_token =
        std::max(1, std::min(config_.limits.event_streams_per_token, config_.limits.event_streams / 4));
    for (const std::string& t : tokens) owners_.insert(owner_of(t));
    DataDir(config_.data_dir).create();
    store_ = open_job_store(config_);
    scenes_ = std::make_unique<SceneStore>(config_, *store_);
    supervisor_ = std::make_unique<Supervisor>(*store_, config_, changes_, metrics_);
    http_ = std::make_unique<GatedServer>(config_.limits, config_.http_threads, metrics_);
    for (const Route& r : routes()) route_regexes_.emplace_back(route_regex(r.path));

    // Keep the listening socket, to raise its backlog in bind(). SO_REUSEADDR
    // only (a restart binds at once past TIME_WAIT): cpp-httplib's default
    // adds SO_REUSEPORT, with which a second lightfarmd (another data
    // directory) bound the same port and the kernel split the traffic
    // between the two, one job 200 on one and 404 on the other.
    http_->set_socket_options([this](socket_t sock) {
        const int yes = 1;
        ::setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
        listen_socket_ = int(sock);
    });
    http_->set_payload_max_length(size_t(config_.limits.upload_bytes));
    // Every answer: no page of ours in another site's frame, no content type
    // guessed from the bytes, and the status page's scripts and fetches from
    // this server only (blob: and data: for the 3D view's embedded images).
    http_->set_default_headers({
        {"X-Content-Type-Options", "nosniff"},
        {"X-Frame-Options", "DENY"},
        {"Referrer-Policy", "no-referrer"},
        {"Content-Security-Policy",
         "default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
         "img-src 'self' data: blob:; connect-src 'self' blob: data:; object-src 'none'; base-uri 'none'; "
         "frame-ancestors 'none'"},
    });

    for (const Route& route : routes()) {
        auto handler = [this, &route](const httplib::Request& req, httplib::Response& res) {
            current_route = route.path;
            try {
                Caller caller;
                if (route.auth == Auth::Page && req.has_param("token")) {
                    // A person opening /?token=T: keep T in a cookie (the
                    // page's fetches and <img> send it), drop it from the URL.
                    const std::string token = req.get_param_value("token");
                    if (owners_.count(owner_of(token))) {
                        res.set_header("Set-Cookie",
                                       "lightfarm_token=" + token + "; Path=/; HttpOnly; SameSite=Strict");
                        res.set_redirect("/", 303);
                        return;
                    }
                } else if (route.auth != Auth::None) {
                    const std::optional<Caller> who = authenticate(req, std::string(route.method) == "GET");
                    if (!who && route.auth == Auth::Token) {
                        res.set_header("WWW-Authenticate", "Bearer");
                        throw HttpError(401, "missing or unknown bearer token (send 'Authorization: Bearer TOKEN')");
                    }
                    if (who) caller = *who;
                }
                if (route.auth == Auth::Page && caller.owner.empty()) {
                    res.status = 401;
                    res.set_content(std::string(embedded_web_files().at("login.html")), "text/html; charset=utf-8");
                    return;
                }
                (this->*route.handler)(req, res, caller);
            } catch (const HttpError& e) {
                if (e.status() == 503 && e.body().contains("retry_after") && !res.has_header("Retry-After"))
                    res.set_header("Retry-After", std::to_string(e.body()["retry_after"].get<int>()));
                send_json(res, e.status(), e.body());
            } catch (const StoreError& e) {
                // Nothing of the request was stored: say so, never 201.
                log_line(std::string(route.method) + " " + route.path + ": " + e.what());
                res.set_header("Retry-After", "5");
                send_json(res, 503,
                          {{"error", std::string("the job store cannot take this now (") + e.what() +
                                         "); nothing was stored, retry later"},
                           {"retry_after", 5}});
            } catch (const std::exception& e) {
                // The log has the whole message; the client learns what
                // failed, without the server's paths.
                log_line(std::string(route.method) + " " + route.path + ": " + e.what());
                send_json(res, 500,
                          {{"error", std::string(route.method) + " " + route.path +
                                         " failed: " + describe_failure(e, config_.data_dir)}});
            }
        };
        if (std::string(route.method) == "GET") http_->Get(route_regex(route.path), handler);
        else http_->Post(route_regex(route.path), handler);
    }

    // Statuses cpp-httplib answers itself (a body that did not arrive, ...)
    // get a JSON body too; answers that already have one pass through.
    http_->set_error_handler([this](const httplib::Request&, httplib::Response& res) {
        if (!res.body.empty()) return;
        if (tl_request && tl_request->timed_out)
            send_json(res, 408,
                      {{"error", "the request did not arrive whole within " +
                                     json(config_.limits.request_seconds).dump() + " s"},
                       {"field", "request_seconds"}});
        else if (res.status == 413 || (tl_request && tl_request->over_budget))
            send_json(res, 413,
                      {{"error",
                        "request body exceeds the limit of " + std::to_string(config_.limits.upload_bytes) + " bytes"},
                       {"field", "upload_bytes"},
                       {"limit", config_.limits.upload_bytes}});
        else if (res.status == 404) send_json(res, 404, {{"error", "no such route"}});
        else send_json(res, res.status, {{"error", "HTTP " + std::to_string(res.status)}});
    });
    // Anything thrown outside a route's own handler: a JSON 500, never the
    // exception's text in a header.
    http_->set_exception_handler([](const httplib::Request& req, httplib::Response& res, std::exception_ptr ep) {
        std::string what = "unknown exception";
        try {
            if (ep) std::rethrow_exception(ep);
        } catch (const std::exception& e) {
            what = e.what();
        } catch (...) {
        }
        log_line(req.method + " " + current_route + ": " + what);
        send_json(res, 500, {{"error", "internal error serving " + current_route}});
    });
    // Before the body: a client that sends `Expect: 100-continue` is answered
    // before it sends the body; every other one before it is read.
    http_->set_expect_100_continue_handler([this](const httplib::Request& req, httplib::Response& res) {
        request_started = std::chrono::steady_clock::now();
        return check_before_body(req, res) ? res.status : 100;
    });
    http_->set_pre_routing_handler([this](const httplib::Request& req, httplib::Response& res) {
        if (req.get_header_value("Expect") != "100-continue") request_started = std::chrono::steady_clock::now();
        return check_before_body(req, res) ? httplib::Server::HandlerResponse::Handled
                                           : httplib::Server::HandlerResponse::Unhandled;
    });
    http_->set_logger([this](const httplib::Request&, const httplib::Response& res) {
        // An event stream lasts as long as its job; it is not a latency.
        if (current_route.find("/events") != std::string::npos) return;
        const double seconds =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - request_started).count();
        metrics_.observe_request(current_route, res.status, seconds);
    });
}

const Service::Route* Service::match_route(const std::string& method, const std::string& path) const {
    const std::string m = method == "HEAD" ? "GET" : method;
    for (size_t i = 0; i < routes().size(); ++i)
        if (m == routes()[i].method && std::regex_match(path, route_regexes_[i])) return &routes()[i];
    return nullptr;
}

bool Service::check_before_body(const httplib::Request& req, httplib::Response& res) {
    // The request object is httplib's own (process_request's local): the
    // framing fixes below change its headers before its body is read.
    auto& mutable_req = const_cast<httplib::Request&>(req);
    const bool has_length = req.has_header("Content-Length");
    const bool has_encoding = req.has_header("Transfer-Encoding");
    const bool is_post = req.method == "POST";
    // An answer now leaves any body unread: the connection closes after it.
    auto answer = [&](int status, json body) {
        if (has_encoding || (has_length && req.get_header_value("Content-Length") != "0")) {
            if (tl_request) tl_request->close_after = true;
            mutable_req.set_header("Connection", "close");
        }
        send_json(res, status, body);
        return true;
    };

    const Route* route = nullptr;
    current_route = "unmatched";
    if (!is_clean_text(req.path))
        return answer(
            400, {{"error", "the path holds a NUL byte, a control character or invalid UTF-8"}, {"field", "path"}});
    for (const auto& [key, value] : req.params)
        if (!is_clean_text(key) || !is_clean_text(value))
            return answer(400, {{"error", "a query parameter holds a NUL byte, a control character or invalid UTF-8"},
                                {"field", "query"}});
    route = match_route(req.method, req.path);
    if (!route) return answer(404, {{"error", "no such route"}});
    current_route = route->path;

    if (route->auth == Auth::Token && !authenticate(req, std::string(route->method) == "GET")) {
        res.set_header("WWW-Authenticate", "Bearer");
        return answer(401, {{"error", "missing or unknown bearer token (send 'Authorization: Bearer TOKEN')"}});
    }

    if (!is_post) {
        // httplib reads no body of a GET: one that came would be read as the next request.
        if (has_encoding || (has_length && req.get_header_value("Content-Length") != "0")) {
            if (tl_request) tl_request->close_after = true;
            mutable_req.set_header("Connection", "close");
        }
        return false;
    }
    if (has_encoding)
        return answer(411,
                      {{"error", "send the body with a Content-Length: Transfer-Encoding (chunked) is not accepted"},
                       {"field", "Content-Length"}});
    if (!has_length) {
        // A POST without a body and without Content-Length (curl -X POST)
        // has an empty body (RFC 9112 6.3), not one that lasts until the
        // connection closes.
        mutable_req.set_header("Content-Length", "0");
    } else {
        const std::string text = req.get_header_value("Content-Length");
        uint64_t length = 0;
        const bool digits =
            !text.empty() && text.size() <= 19 && text.find_first_not_of("0123456789") == std::string::npos;
        if (!digits || req.get_header_value_count("Content-Length") != 1)
            return answer(400,
                          {{"error", "Content-Length: '" + text + "' is not a length"}, {"field", "Content-Length"}});
        length = std::stoull(text);
        // Only an upload carries a scene; every other body is a small JSON
        // object (a job spec), under a limit of its own.
        const bool upload = std::string(route->path) == "/v1/scenes";
        const uint64_t limit = upload ? config_.limits.upload_bytes : config_.limits.spec_bytes;
        if (length > limit)
            return answer(413, {{"error", "request body of " + text + " bytes exceeds the limit of " +
                                              std::to_string(limit) + " bytes"},
                                {"field", upload ? "upload_bytes" : "spec_bytes"},
                                {"limit", limit}});
    }
    const std::string type = req.get_header_value("Content-Type");
    if (type.rfind("application/x-www-form-urlencoded", 0) == 0) {
        // What curl sends when told nothing: not a scene, and httplib would
        // parse it as a form (and refuse one over 8 KiB as a 413).
        if (std::string(route->path) == "/v1/scenes")
            return answer(415,
                          {{"error",
                            "Content-Type: send a .glb as model/gltf-binary, a .gltf as model/gltf+json, "
                            "or a .gltf with its files as multipart/form-data (curl sends "
                            "application/x-www-form-urlencoded unless told: add -H 'Content-Type: model/gltf-binary')"},
                           {"field", "Content-Type"}});
        mutable_req.headers.erase("Content-Type");
        mutable_req.set_header("Content-Type", "application/json");
    }
    return false;
}

Service::~Service() {
    stop();
    http_->stop_gate();  // (run() did already, when it ran)
}

int Service::bind() {
    const int port = config_.port == 0 ? http_->bind_to_any_port(config_.host)
                                       : (http_->bind_to_port(config_.host, config_.port) ? config_.port : -1);
    if (port < 0)
        throw std::runtime_error("cannot listen on " + config_.host + ":" + std::to_string(config_.port) +
                                 " (in use by another process? --listen HOST:PORT picks another)");
    // cpp-httplib (Debian's is a shared library, so its macro cannot be
    // changed) listens with a backlog of 5. Many clients connecting at once
    // (200 readers in the load test) then overflow it: the kernel drops their
    // SYNs and they wait for a retransmission (1 s, 3 s ...) or time out.
    // listen() again on a listening socket only sets the new backlog.
    if (listen_socket_ >= 0 && ::listen(listen_socket_, kListenBacklog) != 0)
        log_line(std::string("cannot raise the listen backlog: ") + strerror(errno));
    return port;
}

void Service::run() {
    supervisor_->start();
    http_->start_gate();
    http_->listen_after_bind();
    http_->stop_gate();
}

void Service::stop() {
    // Workers first (their jobs go back to the queue), then the event
    // streams, then the listener, which waits for the request threads.
    supervisor_->stop();
    changes_.shutdown();
    http_->stop();
}

std::optional<Service::Caller> Service::authenticate(const httplib::Request& req, bool allow_cookie) const {
    std::string token;
    const std::string auth = req.get_header_value("Authorization");
    if (auth.rfind("Bearer ", 0) == 0) {
        token = auth.substr(7);
    } else if (allow_cookie) {
        // Only for GET: the read-only status page and its images. A cookie
        // never authorises a change, so a forged cross-site POST gets nothing.
        const std::string cookies = req.get_header_value("Cookie");
        static const std::regex cookie(R"((?:^|;\s*)lightfarm_token=([^;]*))");
        std::smatch m;
        if (std::regex_search(cookies, m, cookie)) token = m[1].str();
    }
    if (token.empty()) return std::nullopt;
    const std::string owner = owner_of(token);
    if (!owners_.count(owner)) return std::nullopt;
    return Caller{owner};
}

JobRecord Service::owned_job(const httplib::Request& req, const Caller& caller) {
    const std::string id = req.matches[1].str();
    std::optional<JobRecord> job = store_->job(id);
    // Another token's job answers exactly like a job that does not exist.
    if (job && job->owner == caller.owner) return *job;
    // The short ids a person reads on screen (the status page shows 12
    // characters): an unambiguous prefix of one of the caller's jobs.
    if (is_job_id_prefix(id))
        if (std::optional<JobRecord> named = job_by_id_prefix(id, store_->jobs_of(caller.owner))) return *named;
    throw HttpError(404, "no job " + id, {{"id", id}});
}

bool is_job_id_prefix(const std::string& id) {
    return id.size() >= kMinJobIdPrefix && id.size() <= 24 &&
           id.find_first_not_of("0123456789abcdef") == std::string::npos;
}

std::optional<JobRecord> job_by_id_prefix(const std::string& prefix, std::vector<JobRecord> jobs) {
    if (!is_job_id_prefix(prefix)) return std::nullopt;
    std::vector<JobRecord> matches;
    for (JobRecord& j : jobs)
        if (j.status.id.compare(0, prefix.size(), prefix) == 0) matches.push_back(std::move(j));
    if (matches.size() > 1)
        throw HttpError(409, "job id prefix " + prefix + " is ambiguous: " + std::to_string(matches.size()) + " jobs",
                        {{"id", prefix}});
    if (matches.empty()) return std::nullopt;
    return matches.front();
}

json Service::scene_brief(const std::string& scene_id) const {
    json brief = json::object();
    if (const std::optional<SceneRecord> scene = store_->scene(scene_id)) {
        const protocol::SceneSummary summary = summary_of(*scene);
        brief = {{"scene_name", summary.source}, {"scene_triangles", summary.triangles}};
    }
    return brief;
}

json Service::status_json(const JobRecord& job, std::map<std::string, json>* briefs) const {
    json j = protocol::to_json(job.status);
    // What a person recognises the scene by: its file's name and size (a
    // listing looks each scene up once, however many jobs bake it).
    std::map<std::string, json> own;
    if (!briefs) briefs = &own;
    auto [it, fresh] = briefs->try_emplace(job.status.scene);
    if (fresh) it->second = scene_brief(job.status.scene);
    j.update(it->second);
    const std::string base = "/v1/jobs/" + job.status.id;
    j["links"] = {{"self", base},
                  {"events", base + "/events"},
                  {"artifacts", base + "/artifacts"},
                  {"preview", base + "/preview.png"},
                  {"lightmap_rgbm", base + "/lightmap.rgbm.png"},
                  {"error_map", base + "/error.png"}};
    return j;
}

void Service::healthz(const httplib::Request&, httplib::Response& res, const Caller&) {
    send_json(res, 200, {{"status", "ok"}});
}

void Service::metrics(const httplib::Request&, httplib::Response& res, const Caller&) {
    std::vector<Metrics::NodeGauge> nodes;
    std::map<std::string, int> running;
    for (const JobRecord& job : store_->running_jobs()) ++running[job.node];
    for (const NodeRecord& n : store_->nodes()) {
        const double lease = n.info.is_object() ? n.info.value("lease_seconds", 30.0) : 30.0;
        nodes.push_back({n.name, n.heartbeat_age < lease, running[n.name], std::max(0.0, n.heartbeat_age)});
    }
    res.set_content(metrics_.render(store_->count_by_state()) + Metrics::render_nodes(store_->node().name, nodes),
                    "text/plain; version=0.0.4");
}

// JSON to inline in an HTML <script>: every character that HTML's script
// parsing reacts to (<, >, &: "</script>", "<!--" which would swallow the
// rest of the page) and JavaScript's line separators (U+2028, U+2029) as
// \u escapes, which mean the same inside JSON strings, the only place they
// can occur in dump()'s output.
std::string json_for_script(const json& value) {
    const std::string text = value.dump();
    std::string out;
    out.reserve(text.size());
    for (size_t i = 0; i < text.size(); ++i) {
        const char c = text[i];
        if (c == '<') out += "\\u003c";
        else if (c == '>') out += "\\u003e";
        else if (c == '&') out += "\\u0026";
        else if (c == '\xe2' && i + 2 < text.size() && text[i + 1] == '\x80' &&
                 (text[i + 2] == '\xa8' || text[i + 2] == '\xa9')) {
            out += text[i + 2] == '\xa8' ? "\\u2028" : "\\u2029";
            i += 2;
        } else out += c;
    }
    return out;
}

void Service::status_page(const httplib::Request&, httplib::Response& res, const Caller& caller) {
    // The caller's jobs come with the page, so it shows them at once instead
    // of after its first fetch, escaped so that no value can end the script
    // or open a comment (a file named "<!--<script>.gltf" blanked the page).
    const std::string jobs = json_for_script(jobs_json(caller.owner));
    std::string page(embedded_web_files().at("status.html"));
    const std::string slot = "/*JOBS*/null";
    page.replace(page.find(slot), slot.size(), jobs);
    res.set_content(page, "text/html; charset=utf-8");
}

// New work waits while the data directory's disk is full: a 503 stores
// nothing, so nothing accepted is ever lost to the full disk.
void Service::refuse_when_disk_full(httplib::Response& res) {
    const uint64_t free = free_disk_bytes(config_.data_dir);
    if (free >= config_.limits.free_disk_bytes) return;
    metrics_.count_refusal("free_disk_bytes");
    res.set_header("Retry-After", "30");
    throw HttpError(
        503,
        "free_disk_bytes: the server's disk is full (" + megabytes(free) + " free); nothing was stored, retry later",
        {{"field", "free_disk_bytes"}});
}

void Service::post_scene(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    refuse_when_disk_full(res);
    std::vector<UploadFile> files;
    if (req.is_multipart_form_data()) {
        for (const auto& [field, part] : req.files)
            files.push_back({part.filename.empty() ? field : part.filename, part.content});
    } else {
        // A bare body is one file: a .glb, or a .gltf whose buffers are data:
        // URIs, named by ?name= (the file's own name, shown in the summary and
        // the job list; it was always "scene.glb") or by its kind.
        const size_t first = req.body.find_first_not_of(" \t\r\n");
        const bool json_body = first != std::string::npos && req.body[first] == '{';
        const std::string kind = json_body ? ".gltf" : ".glb";
        std::string name = req.has_param("name") ? req.get_param_value("name") : "scene" + kind;
        if (name.size() < kind.size() || name.compare(name.size() - kind.size(), kind.size(), kind) != 0)
            throw HttpError(400,
                            "name: '" + name + "' must end in " + kind + " for this body (a " +
                                (json_body ? "JSON glTF" : "binary glTF") + ")",
                            {{"field", "name"}});
        files.push_back({name, req.body});
    }
    const SceneStore::Result r = scenes_->upload(files, caller.owner);
    json body = r.scene.summary;
    body["id"] = r.scene.id;
    send_json(res, r.created ? 201 : 200, body);
}

void Service::get_scene(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const std::string id = req.matches[1].str();
    std::optional<SceneRecord> scene = store_->scene(id);
    if (!scene || !store_->scene_owned_by(id, caller.owner)) throw HttpError(404, "no scene " + id, {{"id", id}});
    json body = scene->summary;
    body["id"] = scene->id;
    send_json(res, 200, body);
}

void Service::post_job(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    refuse_when_disk_full(res);
    const json body = json::parse(req.body, nullptr, false);
    if (body.is_discarded()) throw HttpError(400, "the request body is not JSON");
    // The one validity rule (protocol/bake_settings.h) under this server's
    // caps; a server never reads files a job names. A spec is validated here,
    // once: the supervisor trusts what was stored.
    protocol::SpecLimits limits = config_.limits.spec;
    limits.allow_local_files = false;
    protocol::JobSpec spec;
    try {
        spec = protocol::parse_job_spec(body, limits);
    } catch (const protocol::SpecError& e) {
        throw HttpError(400, e.what(), {{"field", e.field()}});
    }
    if (!store_->scene_owned_by(spec.scene, caller.owner))
        throw HttpError(404, "scene: no scene " + spec.scene + " (upload it with POST /v1/scenes first)",
                        {{"field", "scene"}});
    // What the scene makes impossible is known now, from its upload's
    // summary: a 400 naming the field and the fix, not three failed workers.
    if (const std::optional<SceneRecord> scene = store_->scene(spec.scene)) {
        try {
            protocol::check_spec_against_scene(spec.bake, summary_of(*scene));
        } catch (const protocol::SpecError& e) {
            throw HttpError(400, e.what(), {{"field", e.field()}});
        }
    }
    const int queued = store_->queued_count(caller.owner);
    if (queued >= config_.limits.queued_jobs)
        throw HttpError(429,
                        "queued_jobs: " + std::to_string(queued) + " jobs already queued, the limit is " +
                            std::to_string(config_.limits.queued_jobs),
                        {{"field", "queued_jobs"}, {"limit", config_.limits.queued_jobs}});

    JobRecord job;
    job.owner = caller.owner;
    job.cache_key = sha256_hex(protocol::bake_identity(spec));
    job.max_seconds = spec.limits.max_seconds.value_or(config_.default_max_seconds);
    job.status.id = random_hex(12);
    job.status.scene = spec.scene;
    job.status.spec = protocol::to_json(spec);
    job.status.max_attempts = spec.limits.max_attempts.value_or(config_.default_attempts);
    job.status.created_at = now_seconds();

    // The same scene bytes, outputs and seed were baked before: hand out
    // those artifacts (hard links, so each job directory stands alone).
    if (std::optional<JobRecord> earlier = store_->succeeded_with_key(job.cache_key)) {
        const fs::path from = supervisor_->job_dir(earlier->status.id);
        const fs::path to = supervisor_->job_dir(job.status.id);
        const fs::path tmp = DataDir(config_.data_dir).tmp("cache-" + job.status.id);
        std::error_code ec;
        fs::create_directories(tmp, ec);
        std::vector<std::string> files;
        for (const Artifact& a : artifacts_in(from)) {
            fs::create_hard_link(from / a.name, tmp / a.name, ec);
            if (ec) fs::copy_file(from / a.name, tmp / a.name, fs::copy_options::overwrite_existing, ec);
            if (ec) break;
            files.push_back(a.name);
        }
        if (!ec) fs::rename(tmp, to, ec);
        if (!ec) {
            job.status.state = JobState::Succeeded;
            job.status.cached = true;
            job.status.progress = earlier->status.progress;
            job.status.latest = earlier->status.latest;
            job.status.started_at = job.status.finished_at = job.status.created_at;
            protocol::JobDone done;
            done.progress = job.status.progress;
            done.files = files;
            for (const auto& [output, latest] : job.status.latest)
                if (latest.final_file) done.final_files[output] = latest.file;
            done.cached = true;
            // Another token's job is not this caller's to know of.
            if (earlier->owner == caller.owner) done.cached_from = earlier->status.id;
            store_->insert_job(job, {protocol::job_event(done)});
            changes_.notify();
            send_json(res, 201, {{"id", job.status.id}, {"state", "succeeded"}, {"cached", true}});
            return;
        }
        fs::remove_all(tmp, ec);
        log_line("job " + job.status.id + ": cache copy from " + earlier->status.id + " failed, baking instead");
    }

    store_->insert_job(job);
    changes_.notify();
    send_json(res, 201, {{"id", job.status.id}, {"state", "queued"}});
}

json Service::jobs_json(const std::string& owner) const {
    json jobs = json::array();
    std::map<std::string, json> briefs;
    for (const JobRecord& job : store_->jobs_of(owner)) jobs.push_back(status_json(job, &briefs));
    return {{"jobs", jobs}};
}

std::unique_ptr<JobStore> open_job_store(const ServerConfig& config) {
    const NodeIdentity node{config.node_name, config.lease_seconds};
    if (!config.store.empty()) return std::make_unique<PostgresJobStore>(config.store, node);
    return std::make_unique<SqliteJobStore>((fs::path(config.data_dir) / "jobs.sqlite").string(), node);
}

json Service::nodes_json(const std::string& owner) const {
    // How many jobs each node runs, and which of them are the caller's (the
    // others' ids are not the caller's business).
    std::map<std::string, json> running;
    for (const JobRecord& job : store_->running_jobs()) {
        json& r = running[job.node];
        if (r.is_null()) r = {{"count", 0}, {"jobs", json::array()}};
        r["count"] = r["count"].get<int>() + 1;
        if (job.owner == owner) r["jobs"].push_back(job.status.id);
    }
    json nodes = json::array();
    for (const NodeRecord& n : store_->nodes()) {
        const double lease = n.info.is_object() ? n.info.value("lease_seconds", 30.0) : 30.0;
        const json& r = running.count(n.name) ? running.at(n.name) : json{{"count", 0}, {"jobs", json::array()}};
        nodes.push_back({{"name", n.name},
                         {"alive", n.heartbeat_age < lease},
                         {"self", n.name == store_->node().name},
                         {"started_at", n.started_at},
                         {"last_heartbeat", n.heartbeat_at},
                         {"seconds_since_heartbeat", std::max(0.0, n.heartbeat_age)},
                         {"gpus", n.info.is_object() ? n.info.value("gpus", 0) : 0},
                         {"workers", n.info.is_object() ? n.info.value("workers", 0) : 0},
                         {"lease_seconds", lease},
                         {"running", r["count"]},
                         {"jobs", r["jobs"]}});
    }
    return {{"nodes", nodes}};
}

void Service::list_nodes(const httplib::Request&, httplib::Response& res, const Caller& caller) {
    send_json(res, 200, nodes_json(caller.owner));
}

void Service::list_jobs(const httplib::Request&, httplib::Response& res, const Caller& caller) {
    send_json(res, 200, jobs_json(caller.owner));
}

void Service::get_job(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    send_json(res, 200, status_json(owned_job(req, caller)));
}

void Service::job_events(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    int64_t after = 0;
    if (req.has_header("Last-Event-ID")) {
        const std::string text = req.get_header_value("Last-Event-ID");
        size_t used = 0;
        try {
            after = std::stoll(text, &used);
        } catch (const std::exception&) {
            used = 0;
        }
        if (text.empty() || used != text.size() || after < 0)
            throw HttpError(400, "Last-Event-ID: '" + text + "' is not an event id", {{"field", "Last-Event-ID"}});
    }
    const std::string id = job.status.id;

    // Event streams have their own budget of request threads: in total and
    // per token, well below --http-threads, so that they never take the
    // threads the rest of the API needs.
    {
        std::lock_guard lock(streams_mutex_);
        const int total = config_.limits.event_streams, per_token = config_.limits.event_streams_per_token;
        const char* field = streams_open_ >= total                         ? "event_streams"
                            : streams_by_owner_[caller.owner] >= per_token ? "event_streams_per_token"
                                                                           : nullptr;
        if (field) {
            if (streams_by_owner_[caller.owner] == 0) streams_by_owner_.erase(caller.owner);
            const int limit = std::string(field) == "event_streams" ? total : per_token;
            metrics_.count_refusal(field);
            res.set_header("Retry-After", "5");
            throw HttpError(503,
                            std::string(field) + ": " + std::to_string(limit) + " event streams are open" +
                                (std::string(field) == "event_streams" ? "" : " for this token") +
                                ", the limit; retry later or poll GET /v1/jobs/" + id,
                            {{"field", field}, {"limit", limit}});
        }
        ++streams_open_;
        ++streams_by_owner_[caller.owner];
        ++metrics_.event_streams;
    }
    auto release = [this, owner = caller.owner](bool) {
        std::lock_guard lock(streams_mutex_);
        --streams_open_;
        if (--streams_by_owner_[owner] <= 0) streams_by_owner_.erase(owner);
        --metrics_.event_streams;
    };

    auto last = std::make_shared<int64_t>(after);
    auto last_write = std::make_shared<std::chrono::steady_clock::time_point>(std::chrono::steady_clock::now());
    res.set_header("Cache-Control", "no-cache");
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, id, last, last_write](size_t, httplib::DataSink& sink) {
            // On every wake-up: is the client still there? (Progress of any job
            // wakes every stream; a stream whose client left ends here, whether
            // or not its own job has news.)
            if (!sink.is_writable()) return false;
            const uint64_t seen = changes_.generation();
            // The state first, then the events: finish() stores a final state and
            // the final event in one transaction, so when the state read here is
            // final, the events read next hold the final event. (Read the other
            // way round, a job finishing between the two reads ended the stream
            // without its final event.)
            std::optional<JobRecord> now;
            std::vector<protocol::JobEvent> events;
            try {
                now = store_->job(id);
                events = store_->events_after(id, *last);
            } catch (const StoreError& e) {
                // The store cannot be read now: end the stream; the client
                // resumes from Last-Event-ID, losing nothing.
                log_line("job " + id + ": event stream ended: " + e.what());
                return false;
            }
            const bool ended = !now || protocol::is_final(now->status.state);
            for (const protocol::JobEvent& e : events) {
                const std::string text = protocol::format_sse(e);
                if (!sink.write(text.data(), text.size())) return false;
                *last = e.id;
                *last_write = std::chrono::steady_clock::now();
                if (protocol::is_final_event(e.type)) {
                    sink.done();
                    return true;
                }
            }
            if (!events.empty()) return true;
            // Nothing new. A finished job's stream ends here (the client had
            // everything); otherwise wait for a change, with a comment when
            // nothing was written for 15 s so that proxies and clients see the
            // connection is alive, and a look at the client every 2 s at most.
            if (ended || changes_.stopping()) {
                sink.done();
                return true;
            }
            using namespace std::chrono;
            const auto since = duration_cast<milliseconds>(steady_clock::now() - *last_write);
            changes_.wait(seen, std::clamp(milliseconds(15000) - since, milliseconds(1), milliseconds(2000)));
            if (!sink.is_writable()) return false;
            if (changes_.generation() == seen && !changes_.stopping() &&
                steady_clock::now() - *last_write >= seconds(15)) {
                static const std::string keep_alive = ": keep-alive\n\n";
                *last_write = steady_clock::now();
                return sink.write(keep_alive.data(), keep_alive.size());
            }
            return true;
        },
        release);
}

void Service::list_artifacts(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    json list = json::array();
    for (const Artifact& a : artifacts_in(supervisor_->job_dir(job.status.id)))
        list.push_back({{"name", a.name},
                        {"size", a.size},
                        {"content_type", protocol::content_type_of(a.name)},
                        {"url", "/v1/jobs/" + job.status.id + "/artifacts/" + a.name}});
    send_json(res, 200, {{"id", job.status.id}, {"state", protocol::to_string(job.status.state)}, {"artifacts", list}});
}

void Service::get_artifact(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    const std::string name = req.matches[2].str();
    if (!is_artifact_name(name) || name == "..")
        throw HttpError(404, "job " + job.status.id + " has no artifact " + name,
                        {{"id", job.status.id}, {"name", name}});
    // Open once: a worker may replace the file (rename) meanwhile, and this
    // download then keeps the version it started with, whole.
    const fs::path path = supervisor_->job_dir(job.status.id) / name;
    std::error_code ec;
    auto file = std::make_shared<std::ifstream>(path, std::ios::binary);
    if (!fs::is_regular_file(path, ec) || !*file)
        throw HttpError(404, "job " + job.status.id + " has no artifact " + name,
                        {{"id", job.status.id}, {"name", name}});
    file->seekg(0, std::ios::end);
    const std::streamoff end = file->tellg();
    if (end < 0)
        throw HttpError(404, "job " + job.status.id + " has no artifact " + name,
                        {{"id", job.status.id}, {"name", name}});
    const size_t size = size_t(end);
    file->seekg(0);
    res.set_content_provider(size, protocol::content_type_of(name),
                             [file](size_t offset, size_t length, httplib::DataSink& sink) {
                                 char buf[64 * 1024];
                                 file->seekg(std::streamoff(offset));
                                 const size_t n = std::min(length, sizeof buf);
                                 file->read(buf, std::streamsize(n));
                                 const std::streamsize got = file->gcount();
                                 if (got <= 0) return false;
                                 return sink.write(buf, size_t(got));
                             });
}

void Service::preview(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    send_preview(req, res, caller, PreviewKind::Tonemapped);
}
void Service::lightmap_rgbm(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    send_preview(req, res, caller, PreviewKind::Rgbm);
}
void Service::error_map(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    send_preview(req, res, caller, PreviewKind::Error);
}

void Service::send_preview(const httplib::Request& req, httplib::Response& res, const Caller& caller,
                           PreviewKind kind) {
    const JobRecord job = owned_job(req, caller);
    // The newest lightmap, as the worker's events named it (its final file
    // once done, else its latest snapshot): never guessed from file names.
    const auto latest = job.status.latest.find("lightmap");
    if (latest == job.status.latest.end() || !is_artifact_name(latest->second.file))
        throw HttpError(404, "job " + job.status.id + " has no lightmap snapshot yet", {{"id", job.status.id}});
    const std::string chosen = latest->second.file;

    const fs::path path = supervisor_->job_dir(job.status.id) / chosen;
    std::error_code ec;
    if (!fs::is_regular_file(path, ec))
        throw HttpError(404, "job " + job.status.id + " has no artifact " + chosen, {{"id", job.status.id}});
    const std::string source = path.string() + ":" + std::to_string(fs::file_size(path, ec)) + ":" +
                               std::to_string(fs::last_write_time(path, ec).time_since_epoch().count());
    std::map<PreviewKind, Preview> previews;
    {
        std::lock_guard lock(preview_mutex_);
        auto it = previews_.find(job.status.id);
        if (it != previews_.end() && it->second.source == source) previews = it->second.previews;
    }
    if (previews.empty()) {
        try {
            previews = render_previews(path.string());
        } catch (const std::exception& e) {
            throw HttpError(500, e.what(), {{"id", job.status.id}});
        }
        std::lock_guard lock(preview_mutex_);
        previews_[job.status.id] = {source, previews};
    }
    const auto found = previews.find(kind);
    if (found == previews.end())
        throw HttpError(404, "job " + job.status.id + ": " + chosen + " has no \"error\" channel",
                        {{"id", job.status.id}});
    const Preview& preview = found->second;
    res.set_header("X-Lightfarm-Source", chosen);
    res.set_header("X-Lightfarm-Pass", std::to_string(latest->second.pass));
    for (const auto& [name, value] : preview.headers) res.set_header(name.c_str(), value);
    res.set_header("Cache-Control", "no-cache");
    res.set_content(preview.png, "image/png");
}

// GET /ui/three/{path}: three.js from the npm registry (web/node_modules,
// installed by the scripts), for the status page's 3D view. Only files
// under that folder, only the kinds a page loads.
void Service::web_library(const httplib::Request& req, httplib::Response& res, const Caller&) {
    const std::string relative = req.matches[1];
    if (relative.find("..") != std::string::npos || relative.empty() || relative.front() == '/')
        throw HttpError(404, "no such file: " + relative);
    const fs::path root = fs::path(config_.web_dir) / "node_modules" / "three";
    const fs::path path = root / relative;
    std::error_code ec;
    const std::string extension = path.extension().string();
    if (extension != ".js" || !fs::is_regular_file(path, ec)) {
        if (!fs::is_directory(root, ec))  // where it was looked for is the server's business, not the caller's
            throw HttpError(404,
                            "three.js is not installed on this server: run scripts/run (or `npm ci` in web/) there");
        throw HttpError(404, "no such file: three/" + relative);
    }
    std::ifstream in(path, std::ios::binary);
    std::string body((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    res.set_header("Cache-Control", "max-age=3600");
    res.set_content(body, "text/javascript; charset=utf-8");
}

void Service::cancel_job(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    const std::string& id = job.status.id;
    const std::string was = protocol::to_string(job.status.state);
    if (!store_->finish(id, JobState::Cancelled, "cancelled by request", "",
                        protocol::job_event(protocol::JobCancelled{was}))) {
        const std::string state = protocol::to_string(store_->job(id)->status.state);
        throw HttpError(409, "job " + id + " already " + state, {{"id", id}, {"state", state}});
    }
    supervisor_->cancel(id);  // kills its worker if one runs
    changes_.notify();
    log_line("job " + id + ": cancelled (was " + was + ")");
    send_json(res, 200, status_json(*store_->job(id)));
}

}  // namespace lf::server
