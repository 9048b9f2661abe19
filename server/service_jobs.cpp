// The job routes: submit, list, status, events, artifacts, cancel, and the
// nodes that run them.
#include "service.h"
#include "service_rooms.h"

#include "data_dir.h"
#include "hash.h"
#include "http_error.h"
#include "log.h"
#include "queue_estimate.h"

#include <httplib.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr int kTypicalJobs = 20;  // the jobs that finished last, whose median prices a queued one

json Service::status_json(const JobRecord& job, StatusLookups* lookups) const {
    StatusLookups own;
    if (!lookups) lookups = &own;
    protocol::JobStatus status = job.status;
    if (status.state == JobState::Queued) {
        if (!lookups->queue) lookups->queue = queue_outlook();
        const QueueOutlook& q = *lookups->queue;
        const int ahead = store_->queued_ahead(status.id);
        status.queue = protocol::QueuePlace{ahead, q.running,
                                            queued_start_estimate(ahead, q.slots, q.running_left, q.typical_seconds)};
    }
    json j = protocol::to_json(status);
    // What a person recognises the scene by: its file's name and size (a
    // listing looks each scene up once, however many jobs bake it).
    auto [it, fresh] = lookups->briefs.try_emplace(job.status.scene);
    if (fresh) it->second = scene_brief(job.status.scene, job.owner);
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

// The jobs running on the farm and their time left, the workers of its
// alive nodes, and a typical job's time: what a queued job waits for.
Service::QueueOutlook Service::queue_outlook() const {
    QueueOutlook q;
    for (const JobRecord& job : store_->running_jobs()) q.running_left.push_back(job.status.progress.eta_seconds);
    q.running = int(q.running_left.size());
    for (const NodeRecord& node : store_->nodes())
        if (node.alive() && node.info.is_object()) q.slots += node.info.value("workers", 0);
    q.slots = std::max(q.slots, q.running);
    q.typical_seconds = typical_job_seconds(store_->recent_job_seconds(kTypicalJobs));
    return q;
}

// POST /v1/jobs: a spec checked against this server's caps and the scene's
// summary, answered from an earlier identical bake's artifacts or queued.
void Service::post_job(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    refuse_when_disk_full(res);
    const protocol::JobSpec spec = accepted_spec(req, caller);
    JobRecord job;
    job.owner = caller.owner;
    job.cache_key = sha256_hex(protocol::bake_identity(spec));
    job.max_seconds = spec.limits.max_seconds.value_or(config_.default_max_seconds);
    job.status.id = random_hex(12);
    job.status.scene = spec.scene;
    job.status.spec = protocol::to_json(spec);
    job.status.max_attempts = spec.limits.max_attempts.value_or(config_.default_attempts);
    job.status.created_at = now_seconds();

    if (answer_from_cache(job, caller, res)) return;
    store_->insert_job(job);
    changes_.notify();
    send_json(res, 201, {{"id", job.status.id}, {"state", "queued"}});
}

// The request's job spec, if this server takes it now (HttpError if not):
// valid under the server's caps, its scene the caller's and able to hold
// it, the caller's queue not full.
protocol::JobSpec Service::accepted_spec(const httplib::Request& req, const Caller& caller) {
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
    const std::optional<SceneRecord> scene = store_->scene_for(spec.scene, caller.owner);
    if (!scene)
        throw HttpError(404, "scene: no scene " + spec.scene + " (upload it with POST /v1/scenes first)",
                        {{"field", "scene"}});
    // What the scene makes impossible is known now, from its upload's
    // summary: a 400 naming the field and the fix, not three failed workers.
    try {
        protocol::check_spec_against_scene(spec.bake, summary_of(*scene));
    } catch (const protocol::SpecError& e) {
        throw HttpError(400, e.what(), {{"field", e.field()}});
    }
    const int queued = store_->queued_count(caller.owner);
    if (queued >= config_.limits.queued_jobs)
        throw HttpError(429,
                        "queued_jobs: " + std::to_string(queued) + " jobs already queued, the limit is " +
                            std::to_string(config_.limits.queued_jobs),
                        {{"field", "queued_jobs"}, {"limit", config_.limits.queued_jobs}});
    return spec;
}

// The same scene bytes, outputs and seed were baked before by the same
// owner: `job` succeeds at once with those artifacts (hard links, so each
// job directory stands alone) and is answered; false (nothing changed) when
// there is none, or the copy failed. Another owner's bake is never used: its
// answer's speed would tell that someone had baked those bytes so (issue
// #55), so each tenant bakes its own (and its files name the scene as it
// uploaded it).
bool Service::answer_from_cache(JobRecord& job, const Caller& caller, httplib::Response& res) {
    const std::optional<JobRecord> earlier = store_->succeeded_with_key(job.cache_key, caller.owner);
    if (!earlier) return false;
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
    if (ec) {
        fs::remove_all(tmp, ec);
        log_line("job " + job.status.id + ": cache copy from " + earlier->status.id + " failed, baking instead");
        return false;
    }
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
    done.cached_from = earlier->status.id;  // the caller's own job
    store_->insert_job(job, {protocol::job_event(done)});
    changes_.notify();
    send_json(res, 201, {{"id", job.status.id}, {"state", "succeeded"}, {"cached", true}});
    return true;
}

// Each job's status without its spec (its own GET has it): a spec may be
// as large as spec_bytes, and one token's 300 cached jobs of a 0.6 MB spec
// made one listing 881 MB (issue #55); a listing now grows by a job's
// status alone.
json Service::jobs_json(const std::string& owner) const {
    json jobs = json::array();
    StatusLookups lookups;
    for (const JobRecord& job : store_->jobs_of(owner)) {
        json status = status_json(job, &lookups);
        status.erase("spec");
        jobs.push_back(std::move(status));
    }
    return {{"jobs", jobs}};
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
        const json& r = running.count(n.name) ? running.at(n.name) : json{{"count", 0}, {"jobs", json::array()}};
        nodes.push_back({{"name", n.name},
                         {"alive", n.alive()},
                         {"self", n.name == store_->node().name},
                         {"started_at", n.started_at},
                         {"last_heartbeat", n.heartbeat_at},
                         {"seconds_since_heartbeat", std::max(0.0, n.heartbeat_age)},
                         {"gpus", n.info.is_object() ? n.info.value("gpus", 0) : 0},
                         {"workers", n.info.is_object() ? n.info.value("workers", 0) : 0},
                         {"lease_seconds", n.lease_seconds()},
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

namespace {

// The Last-Event-ID a reconnecting client sends: the id of the last event
// it has (0 when it has none).
int64_t last_event_id(const httplib::Request& req) {
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
    return after;
}

}  // namespace

void Service::job_events(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const JobRecord job = owned_job(req, caller);
    auto cursor = std::make_shared<EventCursor>(EventCursor{last_event_id(req), std::chrono::steady_clock::now()});
    const std::string id = job.status.id;
    reserve_event_stream(res, caller, req.remote_addr, id);
    auto release = [this, owner = caller.owner, address = req.remote_addr](bool) {
        std::lock_guard lock(streams_mutex_);
        --streams_open_;
        if (--streams_by_owner_[owner] <= 0) streams_by_owner_.erase(owner);
        if (--streams_by_address_[address] <= 0) streams_by_address_.erase(address);
        --metrics_.event_streams;
    };
    res.set_header("Cache-Control", "no-cache");
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, id, cursor](size_t, httplib::DataSink& sink) { return send_new_events(id, *cursor, sink); }, release);
}

// Event streams have their own budget of request threads: in total, per
// token and per client address, well below --http-threads, so that they
// never take the threads the rest of the API needs, and neither one token
// nor one address with many tokens can take them all.
void Service::reserve_event_stream(httplib::Response& res, const Caller& caller, const std::string& address,
                                   const std::string& id) {
    std::lock_guard lock(streams_mutex_);
    const ServerLimits& l = config_.limits;
    auto count = [](const std::map<std::string, int>& m, const std::string& key) {
        const auto it = m.find(key);
        return it == m.end() ? 0 : it->second;
    };
    const char* field = nullptr;
    int limit = 0, open = 0;
    std::string whose;
    // With the request bodies being read, streams hold no more than
    // threads_for_bodies_and_streams: a quarter of the threads serves the rest.
    const int bodies = int(metrics_.http_body_reads.load());
    const int shared = threads_for_bodies_and_streams(config_.http_threads);
    if (streams_open_ >= l.event_streams) {
        field = "event_streams", limit = open = l.event_streams;
    } else if (streams_open_ + bodies >= shared) {
        field = "event_streams", limit = std::max(0, shared - bodies), open = streams_open_;
        whose = " and " + std::to_string(bodies) + " request bodies are being read, together " +
                std::to_string(shared) + " of the " + std::to_string(config_.http_threads) +
                " request threads: the most they may hold";
    } else if (count(streams_by_owner_, caller.owner) >= l.event_streams_per_token) {
        field = "event_streams_per_token", limit = open = l.event_streams_per_token, whose = " for this token";
    } else if (count(streams_by_address_, address) >= l.event_streams_per_address) {
        field = "event_streams_per_address", limit = open = l.event_streams_per_address;
        whose = " from this address";
    }
    if (field) {
        metrics_.count_refusal(field);
        res.set_header("Retry-After", "5");
        throw HttpError(503,
                        std::string(field) + ": " + std::to_string(open) + " event streams are open" + whose +
                            (open == limit ? ", the limit" : "") + "; retry later or poll GET /v1/jobs/" + id,
                        {{"field", field}, {"limit", limit}});
    }
    ++streams_open_;
    ++streams_by_owner_[caller.owner];
    ++streams_by_address_[address];
    ++metrics_.event_streams;
}

// One wake-up of a job's event stream: the events after the cursor, a
// keep-alive, or the end. False when the client is gone.
bool Service::send_new_events(const std::string& id, EventCursor& cursor, httplib::DataSink& sink) {
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
        events = store_->events_after(id, cursor.last_id);
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
        cursor.last_id = e.id;
        cursor.last_write = std::chrono::steady_clock::now();
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
    const auto since = duration_cast<milliseconds>(steady_clock::now() - cursor.last_write);
    changes_.wait(seen, std::clamp(milliseconds(15000) - since, milliseconds(1), milliseconds(2000)));
    if (!sink.is_writable()) return false;
    if (changes_.generation() == seen && !changes_.stopping() &&
        steady_clock::now() - cursor.last_write >= seconds(15)) {
        static const std::string keep_alive = ": keep-alive\n\n";
        cursor.last_write = steady_clock::now();
        return sink.write(keep_alive.data(), keep_alive.size());
    }
    return true;
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

namespace {

// A download answers at most the file's bytes once: a Range header of many
// ranges, or of ranges that overlap, made one request of a few bytes send a
// thousand copies of an artifact (issue #55). Such a request is answered 416.
// cpp-httplib (0.11) applies a request's ranges to whatever answer it gets,
// an error's too (the 416's own JSON came back in a thousand parts): the
// ranges are cleared before the refusal. The request is httplib's own,
// non-const object, handed to handlers as const.
constexpr size_t kMaxRanges = 16;

void check_ranges(const httplib::Request& req, size_t size, const std::string& id, const std::string& name) {
    const httplib::Ranges& ranges = req.ranges;
    if (ranges.empty()) return;
    const auto refuse = [&](const std::string& why) {
        const_cast<httplib::Request&>(req).ranges.clear();
        throw HttpError(416, "job " + id + " artifact " + name + ": " + why, {{"id", id}, {"name", name}});
    };
    if (ranges.size() > kMaxRanges) refuse(std::to_string(ranges.size()) + " ranges, at most 16");
    std::vector<std::pair<size_t, size_t>> spans;  // [first, last], inclusive
    for (const auto& [first, last] : ranges) {
        if (size == 0) refuse("the file is empty");
        const size_t from = first < 0 ? size - std::min(size, size_t(last)) : size_t(first);
        const size_t to = first < 0 || last < 0 ? size - 1 : std::min(size_t(last), size - 1);
        if (from > to || from >= size) refuse("a range past the file's " + std::to_string(size) + " bytes");
        spans.emplace_back(from, to);
    }
    std::sort(spans.begin(), spans.end());
    for (size_t i = 1; i < spans.size(); ++i)
        if (spans[i].first <= spans[i - 1].second) refuse("ranges overlap");
}

}  // namespace

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
    check_ranges(req, size, job.status.id, name);
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
