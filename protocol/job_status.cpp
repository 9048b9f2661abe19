#include "job_status.h"

#include "outputs.h"

#include <algorithm>
#include <cmath>

namespace lf::protocol {

using nlohmann::json;

std::string to_string(JobState s) {
    switch (s) {
    case JobState::Queued: return "queued";
    case JobState::Running: return "running";
    case JobState::Succeeded: return "succeeded";
    case JobState::Failed: return "failed";
    case JobState::Cancelled: return "cancelled";
    }
    return "unknown";
}

std::optional<JobState> parse_job_state(const std::string& s) {
    for (JobState st :
         {JobState::Queued, JobState::Running, JobState::Succeeded, JobState::Failed, JobState::Cancelled})
        if (to_string(st) == s) return st;
    return std::nullopt;
}

bool is_final(JobState s) { return s == JobState::Succeeded || s == JobState::Failed || s == JobState::Cancelled; }

std::optional<double> estimate_eta(const StopSettings& stop, const Progress& p) {
    if (p.pass <= 0 || p.seconds <= 0.0) return std::nullopt;
    const double per_pass = p.seconds / p.pass;
    std::optional<double> eta;
    auto consider = [&](double left) {
        left = std::max(0.0, left);
        eta = eta ? std::min(*eta, left) : left;
    };
    consider(per_pass * (stop.passes - p.pass));
    if (stop.time_limit > 0.0) consider(stop.time_limit - p.seconds);
    if (stop.target_error > 0.0 && p.error_estimate && *p.error_estimate > 0.0) {
        // Monte Carlo error falls as 1/sqrt(passes): passes needed = pass * (E / target)^2.
        const double ratio = *p.error_estimate / stop.target_error;
        consider(per_pass * p.pass * (ratio * ratio - 1.0));
    }
    return eta;
}

void JobProgress::start(const StartEvent& start) {
    prepare_seconds_ = start.prepare_seconds;
    for (auto it = start.outputs.begin(); it != start.outputs.end(); ++it) {
        const json rays = it.value().is_object() ? it.value().value("rays_per_pass", json()) : json();
        const bool positive =
            rays.is_number_unsigned() ? rays.get<uint64_t>() > 0 : rays.is_number_integer() && rays.get<int64_t>() > 0;
        if (positive) rays_per_pass_[it.key()] = rays.get<uint64_t>();
    }
    latest_ = start.resumed;
}

Progress JobProgress::update(const std::string& output, Progress p) {
    latest_[output] = p;
    p.prepare_seconds = prepare_seconds_;
    p.earlier_outputs_seconds = 0.0;
    bool earlier = true;
    for (const OutputKind& kind : output_registry()) {
        if (kind.name == output) earlier = false;
        if (earlier && latest_.count(kind.name)) p.earlier_outputs_seconds += latest_.at(kind.name).seconds;
    }
    p.eta_seconds.reset();
    const OutputSettings* settings = bake_.output(output);
    if (!settings) return p;
    const std::optional<double> own = estimate_eta(settings->stop(), p);
    const std::optional<double> rest =
        p.seconds > 0.0 ? seconds_to_come(output, double(p.rays) / p.seconds) : std::nullopt;
    if (own && rest) p.eta_seconds = *own + *rest;
    p.shown_fraction = shown_fraction_;
    shown_fraction_ = done_fraction(p).value_or(shown_fraction_);
    p.shown_fraction = shown_fraction_;
    return p;
}

// The outputs after `after`: each from where it resumes to its pass count,
// at `rays_per_second`, or to its time limit if that comes first. (Its
// target error cannot be priced before it runs: an upper bound until then.)
std::optional<double> JobProgress::seconds_to_come(const std::string& after, double rays_per_second) const {
    double seconds = 0.0;
    bool later = false;
    for (const OutputKind& kind : output_registry()) {
        const OutputSettings* settings = bake_.output(kind.name);
        if (later && settings) {
            const StopSettings stop = settings->stop();
            const Progress from = latest_.count(kind.name) ? latest_.at(kind.name) : Progress{};
            const auto rays = rays_per_pass_.find(kind.name);
            if (rays == rays_per_pass_.end() || rays_per_second <= 0.0) return std::nullopt;
            double left = std::max(0, stop.passes - from.pass) * double(rays->second) / rays_per_second;
            if (stop.time_limit > 0.0) left = std::min(left, std::max(0.0, stop.time_limit - from.seconds));
            seconds += left;
        }
        if (kind.name == after) later = true;
    }
    return seconds;
}

json to_json(const JobDone& d) {
    json j = to_json(d.progress);
    j["files"] = d.files;
    j["final"] = d.final_files;
    j["cached"] = d.cached;
    if (d.cached_from) j["cached_from"] = *d.cached_from;
    return j;
}

JobEvent job_event(const JobDone& e) { return {0, "done", to_json(e)}; }

JobEvent job_event(const JobRetrying& e) {
    json data = {{"attempt", e.attempt}, {"cause", e.cause}};
    if (e.server_fault) data["server_fault"] = true;
    return {0, "retrying", data};
}

JobEvent job_event(const JobFailed& e) {
    return {0, "failed", {{"error", e.error}, {"cause", e.cause}, {"attempts", e.attempts}}};
}

JobEvent job_event(const JobCancelled& e) { return {0, "cancelled", {{"previous_state", e.previous_state}}}; }

json to_json(const LatestFile& f) { return {{"file", f.file}, {"pass", f.pass}, {"final", f.final_file}}; }

json to_json(const std::map<std::string, LatestFile>& latest) {
    json j = json::object();
    for (const auto& [output, f] : latest) j[output] = to_json(f);
    return j;
}

std::map<std::string, LatestFile> latest_from_json(const json& j) {
    std::map<std::string, LatestFile> latest;
    if (!j.is_object()) return latest;
    for (auto it = j.begin(); it != j.end(); ++it) {
        const json& f = it.value();
        if (!f.is_object() || !f.contains("file") || !f["file"].is_string()) continue;
        LatestFile l;
        l.file = f["file"].get<std::string>();
        if (f.contains("pass") && f["pass"].is_number_integer()) l.pass = f["pass"].get<int>();
        l.final_file = f.value("final", false);
        latest[it.key()] = l;
    }
    return latest;
}

json to_json(const JobStatus& s) {
    // A job that ended without finishing (failed, cancelled) has no time left:
    // the ETA of its last progress is not shown as if it still ran.
    Progress progress = s.progress;
    if (s.state == JobState::Failed || s.state == JobState::Cancelled) progress.eta_seconds.reset();
    json j = {{"id", s.id},
              {"scene", s.scene},
              {"state", to_string(s.state)},
              {"spec", s.spec},
              {"progress", to_json(progress)},
              {"attempts", s.attempts},
              {"max_attempts", s.max_attempts},
              {"cached", s.cached},
              {"latest", to_json(s.latest)},
              {"created_at", s.created_at}};
    j["started_at"] = s.started_at > 0 ? json(s.started_at) : json(nullptr);
    j["finished_at"] = s.finished_at > 0 ? json(s.finished_at) : json(nullptr);
    if (!s.error.empty()) j["error"] = s.error;
    if (!s.cause.empty()) j["cause"] = s.cause;
    if (s.queue)
        j["queue"] = {{"ahead", s.queue->ahead},
                      {"running", s.queue->running},
                      {"starts_in_seconds", s.queue->starts_in_seconds ? json(*s.queue->starts_in_seconds) : json()}};
    return j;
}

JobStatus status_from_json(const json& j) {
    JobStatus s;
    s.id = j.value("id", "");
    s.scene = j.value("scene", "");
    s.state = parse_job_state(j.value("state", "")).value_or(JobState::Queued);
    s.spec = j.value("spec", json::object());
    s.progress = progress_from_json(j.value("progress", json::object()));
    s.attempts = j.value("attempts", 0);
    s.max_attempts = j.value("max_attempts", 0);
    s.cached = j.value("cached", false);
    s.latest = latest_from_json(j.value("latest", json::object()));
    s.error = j.value("error", "");
    s.cause = j.value("cause", "");
    auto time = [&](const char* key) { return j.contains(key) && j[key].is_number() ? j[key].get<double>() : 0.0; };
    s.created_at = time("created_at");
    s.started_at = time("started_at");
    s.finished_at = time("finished_at");
    if (j.contains("queue") && j["queue"].is_object()) {
        const auto count = [&](const char* key) {
            const json& v = j["queue"].value(key, json());
            return v.is_number_integer() ? int(std::clamp<int64_t>(v.get<int64_t>(), 0, 1 << 30)) : 0;
        };
        s.queue = QueuePlace{count("ahead"), count("running"), std::nullopt};
        const json& starts = j["queue"].value("starts_in_seconds", json());
        if (starts.is_number() && starts.get<double>() >= 0.0) s.queue->starts_in_seconds = starts.get<double>();
    }
    return s;
}

bool is_final_event(const std::string& type) { return type == "done" || type == "failed" || type == "cancelled"; }

std::string format_sse(const JobEvent& e) {
    // dump() never emits a raw newline, so the data fits on one line.
    return "id: " + std::to_string(e.id) + "\nevent: " + e.type + "\ndata: " + e.data.dump() + "\n\n";
}

std::vector<JobEvent> SseParser::feed(const std::string& chunk) {
    std::vector<JobEvent> events;
    buffer_ += chunk;
    size_t start = 0;
    for (size_t nl; (nl = buffer_.find('\n', start)) != std::string::npos; start = nl + 1) {
        std::string line = buffer_.substr(start, nl - start);
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty()) {  // a blank line ends an event
            if (!current_.type.empty() || !data_.empty()) {
                current_.data = json::parse(data_, nullptr, false);
                if (current_.data.is_discarded()) current_.data = data_;
                if (current_.type.empty()) current_.type = "message";
                events.push_back(current_);
            }
            current_ = JobEvent{};
            data_.clear();
            continue;
        }
        if (line[0] == ':') continue;
        const size_t colon = line.find(':');
        const std::string field = line.substr(0, colon);
        std::string value = colon == std::string::npos ? "" : line.substr(colon + 1);
        if (!value.empty() && value[0] == ' ') value.erase(0, 1);
        if (field == "id") current_.id = std::atoll(value.c_str());
        else if (field == "event") current_.type = value;
        else if (field == "data") data_ += (data_.empty() ? "" : "\n") + value;
    }
    buffer_.erase(0, start);
    return events;
}

}  // namespace lf::protocol
