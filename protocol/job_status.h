// A job's status and its events, as the server reports them and clients read
// them: GET /v1/jobs/{id} and the Server-Sent Events of /v1/jobs/{id}/events.
#pragma once

#include "bake_settings.h"
#include "worker_protocol.h"

#include <algorithm>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace lf::protocol {

enum class JobState { Queued, Running, Succeeded, Failed, Cancelled };

std::string to_string(JobState s);
std::optional<JobState> parse_job_state(const std::string& s);
// Succeeded, failed and cancelled jobs never change again.
bool is_final(JobState s);

// Seconds left, from an output's stopping rules (passes, time limit, target
// error) and its progress so far; empty when no rule gives an answer yet.
// With several rules the bake stops at the first one met.
std::optional<double> estimate_eta(const StopSettings& stop, const Progress& p);

// A job's progress across its outputs, which the worker bakes one after
// another in the registry's order: what the status page, `watch` and the
// local bar show. One ETA for the whole job (issue #36: a lightmap + SH job
// showed 0 s left when its lightmap ended): the output in progress by
// estimate_eta, plus each output still to come at its own stop rule, its
// passes priced at the rays per second the job traces now and the rays one
// of its passes traces (the start event's "rays_per_pass"). Unknown while
// any part is. The done fraction counts preparation and the outputs baked
// before this one, and never goes back (Progress::shown_fraction): a lightmap
// + SH job's bar went from 85% to 11% when SH started and its passes proved
// slower than priced.
class JobProgress {
public:
    JobProgress() = default;
    explicit JobProgress(const BakeSettings& bake) : bake_(bake) {}

    // The start event: preparation's seconds, each output's rays per pass,
    // and where a resumed output continues from.
    void start(const StartEvent& start);
    // An output's totals after a pass, with the job's ETA, preparation and
    // earlier outputs' seconds filled in; remembers them.
    Progress update(const std::string& output, Progress p);
    // The bar stays at least there (a retried job's, where its last attempt left it).
    void hold_at_least(double fraction) { shown_fraction_ = std::max(shown_fraction_, std::clamp(fraction, 0.0, 1.0)); }
    double prepare_seconds() const { return prepare_seconds_; }

private:
    std::optional<double> seconds_to_come(const std::string& after, double rays_per_second) const;

    BakeSettings bake_;
    double prepare_seconds_ = 0.0;
    std::map<std::string, uint64_t> rays_per_pass_;  // output -> the start event's estimate (absent: unknown)
    std::map<std::string, Progress> latest_;         // output -> its totals so far (resumed, then reported)
    double shown_fraction_ = 0.0;                    // the most of the job shown so far
};

// The newest file of one output, as the worker's events named it: a snapshot
// event's file and pass, replaced by the output's final file when the done
// event names it. Never found by sorting file names (pass-16384 sorts before
// pass-2048).
struct LatestFile {
    std::string file;         // a plain file name among the job's artifacts
    int pass = 0;             // the pass it holds (0: unknown)
    bool final_file = false;  // the output's final file (the done event's "final")
};
nlohmann::json to_json(const LatestFile& f);
// Output name -> its newest file, as JSON {"lightmap": {"file", "pass", "final"}}.
nlohmann::json to_json(const std::map<std::string, LatestFile>& latest);
std::map<std::string, LatestFile> latest_from_json(const nlohmann::json& j);

// Where a queued job stands: the jobs queued before it (the queue is first
// come, first served) and the jobs running now. The status of a queued job
// says it, so `watch`, `submit --wait` and the status page tell a person
// that the job waits, and behind what (issue #54: silent for 131 s).
struct QueuePlace {
    int ahead = 0;
    int running = 0;
    // The server's estimate of when it starts, in seconds from now
    // (server/queue_estimate.h); empty when nothing prices the jobs before
    // it yet (no job has finished on this farm).
    std::optional<double> starts_in_seconds;
};

struct JobStatus {
    std::string id;
    std::string scene;
    JobState state = JobState::Queued;
    nlohmann::json spec;  // the validated job spec (to_json(JobSpec))
    Progress progress;
    std::optional<QueuePlace> queue;  // while queued: where it stands (the server fills it in)
    int attempts = 0;                 // worker runs started so far
    int max_attempts = 0;
    std::string error;    // when failed: what went wrong, for a person
    std::string cause;    // when failed: the last attempt's cause (exit status, stderr line, timeout)
    bool cached = false;  // artifacts reused from an identical earlier bake
    std::map<std::string, LatestFile> latest;                // output name -> its newest file so far
    double created_at = 0, started_at = 0, finished_at = 0;  // Unix seconds, 0 = not yet
};
nlohmann::json to_json(const JobStatus& s);

// The data of a job's "done" event: its final progress, every file (final
// and intermediate), each output's final file, and whether the result was
// copied from an earlier job of the same bake. One type, whether a worker
// finished the job or the cache did.
struct JobDone {
    Progress progress;
    std::vector<std::string> files;
    std::map<std::string, std::string> final_files;  // output -> its main file
    bool cached = false;
    std::optional<std::string> cached_from;  // the earlier job, told to its own owner only
};
nlohmann::json to_json(const JobDone& d);
JobStatus status_from_json(const nlohmann::json& j);

// One event of a job's stream. Ids count 1, 2, 3 ... per job.
// Types: "started" (an attempt began), "progress", "snapshot" (a new
// intermediate artifact), "retrying" (an attempt failed, another follows),
// and exactly one final "done", "failed" or "cancelled".
struct JobEvent {
    int64_t id = 0;
    std::string type;
    nlohmann::json data;
};
bool is_final_event(const std::string& type);

// The server's job events, one type each, so that no payload is written by
// hand in two places: "done" (JobDone, above), "retrying", "failed",
// "cancelled". job_event() makes the event to store (its id is the store's).
// "retrying": the attempt that ended and why; server_fault when the machine
// failed, not the job (that attempt is not counted).
struct JobRetrying {
    int attempt = 0;
    std::string cause;
    bool server_fault = false;
};
// "failed": what failed (the job's error), why, after how many attempts.
struct JobFailed {
    std::string error, cause;
    int attempts = 0;
};
// "cancelled": the state the job was in.
struct JobCancelled {
    std::string previous_state;
};
JobEvent job_event(const JobDone& e);
JobEvent job_event(const JobRetrying& e);
JobEvent job_event(const JobFailed& e);
JobEvent job_event(const JobCancelled& e);

// "id: 3\nevent: progress\ndata: {...}\n\n"
std::string format_sse(const JobEvent& e);

// Reads a Server-Sent Events stream fed in arbitrary chunks.
class SseParser {
public:
    // Returns the events completed by this chunk. Comments (": keep-alive")
    // are skipped; data that is not JSON is kept as a JSON string.
    std::vector<JobEvent> feed(const std::string& chunk);

private:
    std::string buffer_;
    JobEvent current_;
    std::string data_;
};

}  // namespace lf::protocol
