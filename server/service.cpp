#include "service.h"
#include "service_rooms.h"

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

// The route being served on this thread and when it started, for /metrics.
// cpp-httplib serves a request start to finish on one thread.
thread_local std::string current_route;
thread_local std::chrono::steady_clock::time_point request_started;

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

// No inline script or style runs on a page of ours: the status page's
// scripts and styles are files (/ui/{file}), and its one inline script, the
// import map that tells the 3D view where three.js is (an import map cannot
// be a file), is allowed by its hash alone. Its data block is JSON, which
// no browser runs.
std::string content_security_policy() {
    const std::string page(embedded_web_files().at("status.html"));
    const std::string open = "<script type=\"importmap\">";
    const size_t from = page.find(open), to = page.find("</script>", from);
    if (from == std::string::npos || to == std::string::npos)
        throw std::logic_error("web/ui/status.html: no import map, or one without its </script>");
    const std::string import_map = page.substr(from + open.size(), to - from - open.size());
    return "default-src 'self'; script-src 'self' 'sha256-" + sha256_base64(import_map) +
           "'; style-src 'self'; img-src 'self' data: blob:; connect-src 'self' blob: data:; object-src 'none'; "
           "base-uri 'none'; frame-ancestors 'none'";
}

}  // namespace

// What the rooms share (service_rooms.h).

void send_json(httplib::Response& res, int status, const json& body) {
    res.status = status;
    // A message may quote what a client sent: never let its bytes make the answer fail.
    res.set_content(body.dump(2, ' ', false, json::error_handler_t::replace) + "\n", "application/json");
}

bool is_artifact_name(const std::string& name) {
    return !name.empty() && name[0] != '.' && name.find(".tmp") == std::string::npos &&
           name.find('/') == std::string::npos;
}

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
    // The name its owner gave it, else the name it was stored under.
    if (!scene.name.empty()) summary.source = scene.name;
    else if (!scene.main_file.empty()) summary.source = scene.main_file;
    return summary;
}

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
        {"GET", "/ui/{file}", Auth::Token, &Service::web_file},
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
    // Nor can one address, with as many tokens as it likes: half of them
    // unless set (behind a proxy every client has its address: raise it).
    int& per_address = config_.limits.event_streams_per_address;
    per_address = per_address <= 0 ? std::max(1, config_.limits.event_streams / 2)
                                   : std::min(per_address, config_.limits.event_streams);
    // A body being read holds a request thread as long as its client takes
    // to send it: one token gets an eighth of the threads, one address a
    // quarter (with the default 64: 8 and 16), unless set.
    if (config_.limits.body_reads_per_token <= 0)
        config_.limits.body_reads_per_token = std::max(1, config_.http_threads / 8);
    if (config_.limits.body_reads_per_address <= 0)
        config_.limits.body_reads_per_address = std::max(1, config_.http_threads / 4);
    // And all tenants together half of them (the other half serves the API),
    // never every one.
    int& body_reads = config_.limits.body_reads;
    body_reads = body_reads <= 0 ? std::max(1, config_.http_threads / 2)
                                 : std::max(1, std::min(body_reads, config_.http_threads - 1));
    for (const std::string& t : tokens) owners_.insert(owner_of(t));
    DataDir(config_.data_dir).create();
    store_ = open_job_store(config_);
    for (const std::string& id : jobs_without_records(config_.data_dir, *store_)) lost_jobs_.insert(id);
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
    // guessed from the bytes, and the status page's scripts, styles and
    // fetches from this server only (blob: and data: for the 3D view's
    // embedded images; content_security_policy).
    http_->set_default_headers({
        {"X-Content-Type-Options", "nosniff"},
        {"X-Frame-Options", "DENY"},
        {"Referrer-Policy", "no-referrer"},
        {"Content-Security-Policy", content_security_policy()},
    });

    for (const Route& route : routes()) {
        auto handler = [this, &route](const httplib::Request& req, httplib::Response& res) { serve(route, req, res); };
        if (std::string(route.method) == "GET") http_->Get(route_regex(route.path), handler);
        else http_->Post(route_regex(route.path), handler);
    }

    install_http_hooks();
}

// cpp-httplib's hooks around the routes: JSON bodies for the answers it
// makes itself, the checks before a body is read, and request metrics.
void Service::install_http_hooks() {
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

namespace {

// Whether a browser says the request came from another site's page: its
// Sec-Fetch-Site (cross-site or same-site; "none" is the address bar), else
// an Origin or Referer naming another host than the one asked.
bool from_another_site(const httplib::Request& req) {
    const std::string site = req.get_header_value("Sec-Fetch-Site");
    if (!site.empty()) return site != "none" && site != "same-origin";
    const std::string host = req.get_header_value("Host");
    for (const char* header : {"Origin", "Referer"}) {
        const std::string from = req.get_header_value(header);
        if (from.empty()) continue;
        const size_t start = from.find("://");
        if (start == std::string::npos) return true;
        const std::string authority = from.substr(start + 3, from.find('/', start + 3) - start - 3);
        if (authority != host) return true;
    }
    return false;
}

}  // namespace

// One request on `route`: the caller authenticated as the route asks, the
// handler run, and every failure answered as JSON that names what failed.
void Service::serve(const Route& route, const httplib::Request& req, httplib::Response& res) {
    current_route = route.path;
    // Only an artifact's bytes are served by range (get_artifact bounds
    // them); cpp-httplib would cut any other answer, a listing or an error,
    // into as many copies as the Range header asks. The request is httplib's
    // own non-const object, handed to handlers as const.
    if (route.handler != &Service::get_artifact) const_cast<httplib::Request&>(req).ranges.clear();
    try {
        Caller caller;
        if (route.auth == Auth::Page && req.has_param("token")) {
            // A person opening /?token=T: keep T in a cookie (the
            // page's fetches and <img> send it), drop it from the URL.
            // Only from the address bar or this server's own pages: a link
            // on another site would log the victim in as its author (login
            // CSRF, issue #55), and their jobs would be the attacker's.
            if (from_another_site(req))
                throw HttpError(403,
                                "a link from another site cannot sign you in: open this server's address "
                                "(with ?token=) yourself",
                                {{"field", "token"}});
            const std::string token = req.get_param_value("token");
            if (owners_.count(owner_of(token))) {
                res.set_header("Set-Cookie", "lightfarm_token=" + token + "; Path=/; HttpOnly; SameSite=Strict");
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
        // The tenant learns why in the store's terms, not its internals
        // (a database's paths, address and hints stay in the log).
        send_json(res, 503,
                  {{"error", "the job store cannot take this now (" + e.cause() + "); nothing was stored, retry later"},
                   {"retry_after", 5}});
    } catch (const std::exception& e) {
        // The log has the whole message; the client learns what
        // failed, without the server's paths.
        log_line(std::string(route.method) + " " + route.path + ": " + e.what());
        send_json(res, 500,
                  {{"error", std::string(route.method) + " " + route.path +
                                 " failed: " + describe_failure(e, config_.data_dir)}});
    }
}

const Service::Route* Service::match_route(const std::string& method, const std::string& path) const {
    const std::string m = method == "HEAD" ? "GET" : method;
    for (size_t i = 0; i < routes().size(); ++i)
        if (m == routes()[i].method && std::regex_match(path, route_regexes_[i])) return &routes()[i];
    return nullptr;
}

// A POST's framing, before its body is read: a Content-Length (not
// chunked) within the route's limit, and a form's Content-Type read as JSON
// (or refused for an upload). Fixes the headers httplib will read the body
// by; returns the refusal when the request must go no further.
std::optional<Service::Refusal> Service::check_post_framing(httplib::Request& req, const Route& route) const {
    if (req.has_header("Transfer-Encoding"))
        return Refusal{411,
                       {{"error", "send the body with a Content-Length: Transfer-Encoding (chunked) is not accepted"},
                        {"field", "Content-Length"}}};
    if (!req.has_header("Content-Length")) {
        // A POST without a body and without Content-Length (curl -X POST)
        // has an empty body (RFC 9112 6.3), not one that lasts until the
        // connection closes.
        req.set_header("Content-Length", "0");
    } else {
        const std::string text = req.get_header_value("Content-Length");
        uint64_t length = 0;
        const bool digits =
            !text.empty() && text.size() <= 19 && text.find_first_not_of("0123456789") == std::string::npos;
        if (!digits || req.get_header_value_count("Content-Length") != 1)
            return Refusal{400,
                           {{"error", "Content-Length: '" + text + "' is not a length"}, {"field", "Content-Length"}}};
        length = std::stoull(text);
        // Only an upload carries a scene; every other body is a small JSON
        // object (a job spec), under a limit of its own.
        const bool upload = std::string(route.path) == "/v1/scenes";
        const uint64_t limit = upload ? config_.limits.upload_bytes : config_.limits.spec_bytes;
        if (length > limit)
            return Refusal{413,
                           {{"error", "request body of " + text + " bytes exceeds the limit of " +
                                          std::to_string(limit) + " bytes"},
                            {"field", upload ? "upload_bytes" : "spec_bytes"},
                            {"limit", limit}}};
    }
    const std::string type = req.get_header_value("Content-Type");
    if (type.rfind("application/x-www-form-urlencoded", 0) == 0) {
        // What curl sends when told nothing: not a scene, and httplib would
        // parse it as a form (and refuse one over 8 KiB as a 413).
        if (std::string(route.path) == "/v1/scenes")
            return Refusal{
                415,
                {{"error",
                  "Content-Type: send a .glb as model/gltf-binary, a .gltf as model/gltf+json, "
                  "or a .gltf with its files as multipart/form-data (curl sends "
                  "application/x-www-form-urlencoded unless told: add -H 'Content-Type: model/gltf-binary')"},
                 {"field", "Content-Type"}}};
        req.headers.erase("Content-Type");
        req.set_header("Content-Type", "application/json");
    }
    return std::nullopt;
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
    if (const std::optional<Refusal> refusal = check_post_framing(mutable_req, *route))
        return answer(refusal->status, refusal->body);
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
    http_->drain_within(config_.limits.drain_seconds);
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

std::vector<std::string> jobs_without_records(const std::string& data_dir, JobStore& store) {
    std::vector<std::string> lost;
    std::error_code ec;
    for (fs::directory_iterator it(DataDir(data_dir).jobs(), ec), end; !ec && it != end; it.increment(ec))
        if (it->is_directory(ec) && !store.has_job(it->path().filename().string()))
            lost.push_back(it->path().filename().string());
    std::sort(lost.begin(), lost.end());
    return lost;
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
    // Its directory is here but its record is not (nobody can say whose it
    // was, so anyone who knows the unguessable id is told).
    if (lost_jobs_.count(id))
        throw HttpError(410,
                        "job " + id +
                            ": the job store lost its record (its files are still in the server's data directory); "
                            "the server's operator can restore the store from a backup",
                        {{"id", id}, {"record_lost", true}});
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

std::unique_ptr<JobStore> open_job_store(const ServerConfig& config) {
    const NodeIdentity node{config.node_name, config.lease_seconds};
    if (!config.store.empty()) return std::make_unique<PostgresJobStore>(config.store, node);
    return std::make_unique<SqliteJobStore>((fs::path(config.data_dir) / "jobs.sqlite").string(), node);
}

}  // namespace lf::server
