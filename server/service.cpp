#include "service.h"

#include "hash.h"
#include "http_error.h"
#include "log.h"
#include "preview.h"
#include "sqlite_job_store.h"
#include "status_page.h"

#include <httplib.h>
#include <sys/socket.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <regex>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

double now_seconds() {
    return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

// The store keys ownership by a hash of the token, never the token itself.
std::string owner_of(const std::string& token) { return sha256_hex("lightfarm-token:" + token).substr(0, 32); }

void send_json(httplib::Response& res, int status, const json& body) {
    res.status = status;
    res.set_content(body.dump(2) + "\n", "application/json");
}

// The route being served on this thread and when it started, for /metrics.
// cpp-httplib serves a request start to finish on one thread.
thread_local std::string current_route;
thread_local std::chrono::steady_clock::time_point request_started;

std::string content_type_of(const std::string& name) {
    const std::string ext = fs::path(name).extension().string();
    if (ext == ".exr") return "image/x-exr";
    if (ext == ".png") return "image/png";
    if (ext == ".json") return "application/json";
    if (ext == ".glb") return "model/gltf-binary";
    if (ext == ".gltf") return "model/gltf+json";
    if (ext == ".txt" || ext == ".log") return "text/plain";
    return "application/octet-stream";
}

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
    return std::regex_replace(path, param, "([^/]+)");
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
        {"GET", "/v1/jobs/{id}", Auth::Token, &Service::get_job},
        {"GET", "/v1/jobs/{id}/events", Auth::Token, &Service::job_events},
        {"GET", "/v1/jobs/{id}/artifacts", Auth::Token, &Service::list_artifacts},
        {"GET", "/v1/jobs/{id}/artifacts/{name}", Auth::Token, &Service::get_artifact},
        {"GET", "/v1/jobs/{id}/preview.png", Auth::Token, &Service::preview},
        {"POST", "/v1/jobs/{id}/cancel", Auth::Token, &Service::cancel_job},
    };
    return table;
}

std::vector<Service::RouteInfo> Service::route_table() {
    std::vector<RouteInfo> info;
    for (const Route& r : routes()) info.push_back({r.method, r.path, r.auth != Auth::None});
    return info;
}

Service::Service(ServerConfig config, const std::vector<std::string>& tokens)
    : config_(std::move(config)), http_(std::make_unique<httplib::Server>()) {
    for (const std::string& t : tokens) owners_.insert(owner_of(t));
    fs::create_directories(fs::path(config_.data_dir) / "jobs");
    fs::create_directories(fs::path(config_.data_dir) / "scenes");
    fs::create_directories(fs::path(config_.data_dir) / "tmp");
    store_ = std::make_unique<SqliteJobStore>((fs::path(config_.data_dir) / "jobs.sqlite").string());
    scenes_ = std::make_unique<SceneStore>(config_, *store_);
    supervisor_ = std::make_unique<Supervisor>(*store_, config_, changes_, metrics_);

    const int threads = config_.http_threads;
    http_->new_task_queue = [threads] { return new httplib::ThreadPool(size_t(threads)); };
    // Keep the listening socket, to raise its backlog in bind().
    http_->set_socket_options([this](socket_t sock) {
        httplib::default_socket_options(sock);
        listen_socket_ = int(sock);
    });
    http_->set_payload_max_length(size_t(config_.limits.upload_bytes));

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
                    res.set_content(kLoginPage, "text/html; charset=utf-8");
                    return;
                }
                (this->*route.handler)(req, res, caller);
            } catch (const HttpError& e) {
                send_json(res, e.status(), e.body());
            } catch (const std::exception& e) {
                log_line(std::string(route.method) + " " + req.path + ": " + e.what());
                send_json(res, 500, {{"error", std::string("internal error: ") + e.what()}});
            }
        };
        if (std::string(route.method) == "GET") http_->Get(route_regex(route.path), handler);
        else http_->Post(route_regex(route.path), handler);
    }

    // Statuses cpp-httplib answers itself (no route, body too large) get a
    // JSON body too; answers that already have one pass through.
    http_->set_error_handler([this](const httplib::Request&, httplib::Response& res) {
        if (!res.body.empty()) return;
        if (res.status == 404) send_json(res, 404, {{"error", "no such route"}});
        else if (res.status == 413)
            send_json(res, 413, {{"error", "request body exceeds the limit of " + std::to_string(config_.limits.upload_bytes) + " bytes"},
                                 {"field", "upload_bytes"}, {"limit", config_.limits.upload_bytes}});
        else send_json(res, res.status, {{"error", "HTTP " + std::to_string(res.status)}});
    });
    http_->set_pre_routing_handler([](const httplib::Request&, httplib::Response&) {
        current_route = "unmatched";
        request_started = std::chrono::steady_clock::now();
        return httplib::Server::HandlerResponse::Unhandled;
    });
    http_->set_logger([this](const httplib::Request&, const httplib::Response& res) {
        // An event stream lasts as long as its job; it is not a latency.
        if (current_route.find("/events") != std::string::npos) return;
        const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - request_started).count();
        metrics_.observe_request(current_route, res.status, seconds);
    });
}

Service::~Service() {
    stop();
}

int Service::bind() {
    const int port = config_.port == 0 ? http_->bind_to_any_port(config_.host)
                                       : (http_->bind_to_port(config_.host, config_.port) ? config_.port : -1);
    if (port < 0) throw std::runtime_error("cannot listen on " + config_.host + ":" + std::to_string(config_.port));
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
    http_->listen_after_bind();
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
    if (!job || job->owner != caller.owner) throw HttpError(404, "no job " + id, {{"id", id}});
    return *job;
}

json Service::status_json(const JobRecord& job) const {
    json j = protocol::to_json(job.status);
    const std::string base = "/v1/jobs/" + job.status.id;
    j["links"] = {{"self", base}, {"events", base + "/events"}, {"artifacts", base + "/artifacts"}, {"preview", base + "/preview.png"}};
    return j;
}

void Service::healthz(const httplib::Request&, httplib::Response& res, const Caller&) {
    send_json(res, 200, {{"status", "ok"}});
}

void Service::metrics(const httplib::Request&, httplib::Response& res, const Caller&) {
    res.set_content(metrics_.render(store_->count_by_state()), "text/plain; version=0.0.4");
}

void Service::status_page(const httplib::Request&, httplib::Response& res, const Caller&) {
    res.set_content(kStatusPage, "text/html; charset=utf-8");
}

void Service::post_scene(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    std::vector<UploadFile> files;
    if (req.is_multipart_form_data()) {
        for (const auto& [field, part] : req.files)
            files.push_back({part.filename.empty() ? field : part.filename, part.content});
    } else {
        // A bare body is one file: a .glb, or a .gltf whose buffers are data: URIs.
        const size_t first = req.body.find_first_not_of(" \t\r\n");
        const bool json_body = first != std::string::npos && req.body[first] == '{';
        files.push_back({json_body ? "scene.gltf" : "scene.glb", req.body});
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
        throw HttpError(404, "scene: no scene " + spec.scene + " (upload it with POST /v1/scenes first)", {{"field", "scene"}});
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
        throw HttpError(429, "queued_jobs: " + std::to_string(queued) + " jobs already queued, the limit is " +
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
        const fs::path tmp = fs::path(config_.data_dir) / "tmp" / ("cache-" + job.status.id);
        std::error_code ec;
        fs::create_directories(tmp, ec);
        json files = json::array();
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
            json done = protocol::to_json(job.status.progress);
            done["files"] = files;
            json finals = json::object();
            for (const auto& [output, latest] : job.status.latest)
                if (latest.final_file) finals[output] = latest.file;
            done["final"] = finals;
            done["cached"] = true;
            done["cached_from"] = earlier->status.id;
            store_->insert_job(job, {{0, "done", done}});
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

void Service::list_jobs(const httplib::Request&, httplib::Response& res, const Caller& caller) {
    json jobs = json::array();
    for (const JobRecord& job : store_->jobs_of(caller.owner)) jobs.push_back(status_json(job));
    send_json(res, 200, {{"jobs", jobs}});
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
    auto last = std::make_shared<int64_t>(after);
    res.set_header("Cache-Control", "no-cache");
    res.set_chunked_content_provider("text/event-stream", [this, id, last](size_t, httplib::DataSink& sink) {
        const uint64_t seen = changes_.generation();
        // The state first, then the events: finish() stores a final state and
        // the final event in one transaction, so when the state read here is
        // final, the events read next hold the final event. (Read the other
        // way round, a job finishing between the two reads ended the stream
        // without its final event.)
        const std::optional<JobRecord> now = store_->job(id);
        const bool ended = !now || protocol::is_final(now->status.state);
        const std::vector<protocol::JobEvent> events = store_->events_after(id, *last);
        for (const protocol::JobEvent& e : events) {
            const std::string text = protocol::format_sse(e);
            if (!sink.write(text.data(), text.size())) return false;
            *last = e.id;
            if (protocol::is_final_event(e.type)) {
                sink.done();
                return true;
            }
        }
        if (!events.empty()) return true;
        // Nothing new. A finished job's stream ends here (the client had
        // everything); otherwise wait for a change, with a comment now and
        // then so that proxies and clients see the connection is alive.
        if (ended || changes_.stopping()) {
            sink.done();
            return true;
        }
        changes_.wait(seen, std::chrono::seconds(15));
        if (changes_.generation() == seen && !changes_.stopping()) {
            static const std::string keep_alive = ": keep-alive\n\n";
            return sink.write(keep_alive.data(), keep_alive.size());
        }
        return true;
    });
}

void Service::list_artifacts(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    json list = json::array();
    for (const Artifact& a : artifacts_in(supervisor_->job_dir(job.status.id)))
        list.push_back({{"name", a.name},
                        {"size", a.size},
                        {"content_type", content_type_of(a.name)},
                        {"url", "/v1/jobs/" + job.status.id + "/artifacts/" + a.name}});
    send_json(res, 200, {{"id", job.status.id}, {"state", protocol::to_string(job.status.state)}, {"artifacts", list}});
}

void Service::get_artifact(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    const std::string name = req.matches[2].str();
    if (!is_artifact_name(name) || name == "..")
        throw HttpError(404, "job " + job.status.id + " has no artifact " + name, {{"id", job.status.id}, {"name", name}});
    // Open once: a worker may replace the file (rename) meanwhile, and this
    // download then keeps the version it started with, whole.
    auto file = std::make_shared<std::ifstream>(supervisor_->job_dir(job.status.id) / name, std::ios::binary);
    if (!*file)
        throw HttpError(404, "job " + job.status.id + " has no artifact " + name, {{"id", job.status.id}, {"name", name}});
    file->seekg(0, std::ios::end);
    const size_t size = size_t(file->tellg());
    file->seekg(0);
    res.set_content_provider(size, content_type_of(name), [file](size_t offset, size_t length, httplib::DataSink& sink) {
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
    std::string png;
    {
        std::lock_guard lock(preview_mutex_);
        auto it = previews_.find(job.status.id);
        if (it != previews_.end() && it->second.source == source) png = it->second.png;
    }
    if (png.empty()) {
        try {
            png = exr_to_png(path.string());
        } catch (const std::exception& e) {
            throw HttpError(500, e.what(), {{"id", job.status.id}});
        }
        std::lock_guard lock(preview_mutex_);
        previews_[job.status.id] = {source, png};
    }
    res.set_header("X-Lightfarm-Source", chosen);
    res.set_header("Cache-Control", "no-cache");
    res.set_content(png, "image/png");
}

void Service::cancel_job(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    const std::string& id = job.status.id;
    const std::string was = protocol::to_string(job.status.state);
    if (!store_->finish(id, JobState::Cancelled, "cancelled by request", "", {0, "cancelled", {{"previous_state", was}}})) {
        const std::string state = protocol::to_string(store_->job(id)->status.state);
        throw HttpError(409, "job " + id + " already " + state, {{"id", id}, {"state", state}});
    }
    supervisor_->cancel(id);  // kills its worker if one runs
    changes_.notify();
    log_line("job " + id + ": cancelled (was " + was + ")");
    send_json(res, 200, status_json(*store_->job(id)));
}

}  // namespace lf::server
