#include "remote.h"

#include "bake_help.h"

#include "args.h"
#include "job_spec.h"
#include "job_status.h"
#include "percent_decoding.h"

#include <httplib.h>
#include <nlohmann/json.hpp>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <set>
#include <thread>

namespace lf::cli {

namespace fs = std::filesystem;
using nlohmann::json;

const char* const kRemoteUsage = R"(usage of the remote commands (a lightfarmd server):
  submit SCENE [bake options] [--wait [--out DIR] [--json] [--snapshots]]
                                     upload SCENE (a .glb, or a .gltf with its files),
                                     create a job, print its id; --wait follows it and
                                     downloads the final files into --out (default
                                     ./JOB; --snapshots: the intermediate ones too).
                                     The bake options are those of `lightfarm bake`:
                                     every output (--OUTPUT) and setting
  watch JOB [--json]                 follow a job's progress until it ends
  fetch JOB [--out DIR] [--latest | --snapshots]
                                     download a job's final files (--snapshots: and
                                     its intermediate ones; --latest: the newest file
                                     of each output: its final file once done, else
                                     its newest snapshot)
  cancel JOB                         cancel a queued or running job
  jobs [--json]                      list your jobs
  every remote command: --server URL (default http://127.0.0.1:8750)
                        --token TOKEN (default $LIGHTFARM_TOKEN)
)";

namespace {

// Any failure that ends the command: one line for the user.
struct RemoteError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

class Remote {
public:
    explicit Remote(const Args& args) : server_(args.get("--server", "http://127.0.0.1:8750")), client_(server_) {
        std::string token = args.get("--token");
        if (token.empty()) {
            const char* env = std::getenv("LIGHTFARM_TOKEN");
            token = env ? env : "";
        }
        if (token.empty()) throw UsageError("no token: pass --token TOKEN or set LIGHTFARM_TOKEN");
        if (!client_.is_valid()) throw UsageError("--server: '" + server_ + "' is not a URL like http://host:port");
        client_.set_bearer_token_auth(token);
        client_.set_connection_timeout(5);
        client_.set_read_timeout(60);
    }

    // Sends and returns the answer's JSON; a non-2xx answer becomes a
    // RemoteError carrying the server's own message.
    json call(httplib::Result r, const std::string& what) {
        check(r, what);
        const json body = json::parse(r->body, nullptr, false);
        return body.is_discarded() ? json::object() : body;
    }
    void check(const httplib::Result& r, const std::string& what) {
        if (!r) throw RemoteError("cannot reach " + server_ + " (" + httplib::to_string(r.error()) + ") to " + what);
        if (r->status >= 200 && r->status < 300) return;
        const json body = json::parse(r->body, nullptr, false);
        const std::string message =
            body.is_object() && body.contains("error") ? body["error"].get<std::string>() : r->body;
        throw RemoteError(message + " (HTTP " + std::to_string(r->status) + ")");
    }
    httplib::Client& http() { return client_; }
    const std::string& server() const { return server_; }

private:
    std::string server_;
    httplib::Client client_;
};

std::string read_file(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw RemoteError("cannot read " + path.string());
    return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// Uploads a .glb as the body, or a .gltf with every file its buffers and
// images name as multipart parts. Returns the scene id.
std::string upload_scene(Remote& remote, const fs::path& scene) {
    const std::string bytes = read_file(scene);
    std::string ext = scene.extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    if (ext == ".glb") {
        // Named by the file's own name (?name=), percent-encoded.
        std::string name;
        for (const unsigned char c : scene.filename().string()) {
            char hex[4];
            std::snprintf(hex, sizeof hex, "%%%02X", c);
            name += std::isalnum(c) || c == '.' || c == '-' || c == '_' ? std::string(1, char(c)) : std::string(hex);
        }
        return remote.call(remote.http().Post("/v1/scenes?name=" + name, bytes, "model/gltf-binary"),
                           "upload " + scene.string())["id"];
    }
    if (ext == ".gltf") {
        const json doc = json::parse(bytes, nullptr, false);
        if (!doc.is_object()) throw RemoteError(scene.string() + " is not JSON");
        httplib::MultipartFormDataItems items = {{"scene", bytes, scene.filename().string(), "model/gltf+json"}};
        std::set<std::string> sent;
        for (const char* array : {"buffers", "images"}) {
            if (!doc.contains(array) || !doc[array].is_array()) continue;
            for (const json& item : doc[array]) {
                if (!item.is_object() || !item.contains("uri") || !item["uri"].is_string()) continue;
                const std::string uri = item["uri"];
                if (uri.rfind("data:", 0) == 0) continue;
                const std::optional<std::string> decoded = protocol::percent_decode(uri);
                if (!decoded) throw RemoteError(scene.string() + ": the URI '" + uri + "' has a malformed %-escape");
                const std::string& name = *decoded;
                if (!sent.insert(name).second) continue;
                items.push_back({"file", read_file(scene.parent_path() / name), name, "application/octet-stream"});
            }
        }
        return remote.call(remote.http().Post("/v1/scenes", items), "upload " + scene.string())["id"];
    }
    throw UsageError("SCENE must be a .glb or .gltf file, not " + scene.string());
}

std::string format_seconds(double s) {
    char buf[32];
    if (s >= 3600) std::snprintf(buf, sizeof buf, "%dh%02dm", int(s / 3600), int(s / 60) % 60);
    else if (s >= 60) std::snprintf(buf, sizeof buf, "%dm%02ds", int(s / 60), int(s) % 60);
    else std::snprintf(buf, sizeof buf, "%.0fs", s);
    return buf;
}

}  // namespace

std::string progress_line(const std::string& job, const std::string& output, const protocol::Progress& p) {
    // Done so far against what is left: passes or time, whichever stop comes
    // first, as the server's ETA already takes every stop into account.
    // Preparation counts: its seconds are part of the job's done fraction.
    const double fraction = std::clamp(protocol::done_fraction(p).value_or(0.0), 0.0, 1.0);
    const int width = 24, filled = int(std::lround(fraction * width));
    char percent[16];
    std::snprintf(percent, sizeof percent, "%3d%%", int(std::lround(100.0 * fraction)));
    std::string who = job.substr(0, 12);
    if (!output.empty()) who += (who.empty() ? "" : " ") + output;
    std::string line = who + "  [" + std::string(size_t(filled), '#') + std::string(size_t(width - filled), '-') +
                       "] " + percent + "  pass " + std::to_string(p.pass);
    if (p.error_estimate) {
        char error[32];
        std::snprintf(error, sizeof error, "  error %.4f", *p.error_estimate);
        line += error;
    }
    if (p.eta_seconds) line += "  ETA " + format_seconds(*p.eta_seconds);
    return line;
}

std::string preparing_line(const std::string& job, const protocol::PrepareEvent& e) {
    std::string line =
        job.substr(0, 12) + (job.empty() ? "" : "  ") + "preparing: " + e.stage + "  " + format_seconds(e.seconds);
    if (e.eta_seconds) line += "  ETA " + format_seconds(*e.eta_seconds);
    return line;
}

std::string queued_line(const std::string& job, const protocol::QueuePlace& q) {
    return job.substr(0, 12) + (job.empty() ? "" : "  ") + "queued: " + std::to_string(q.ahead) +
           (q.ahead == 1 ? " job" : " jobs") + " ahead of it, " + std::to_string(q.running) + " running, " +
           (q.starts_in_seconds ? "starts in about " + format_seconds(*q.starts_in_seconds)
                                : "no estimate of its start yet (no job has finished here)");
}

namespace {

// While the job is queued its events say nothing: its status says where it
// stands, read once a second and told when it changes (a line on stderr, or
// with --json a {"event": "queued", "ahead", "running", "starts_in_seconds"}
// line), until it starts.
void tell_while_queued(Remote& remote, const std::string& job, bool json_lines) {
    std::optional<std::pair<int, int>> told;
    for (;;) {
        auto r = remote.http().Get("/v1/jobs/" + job);
        if (!r || r->status != 200) return;  // the events say why, or the job's end
        const json body = json::parse(r->body, nullptr, false);
        if (!body.is_object()) return;
        const protocol::JobStatus status = protocol::status_from_json(body);
        if (status.state != protocol::JobState::Queued || !status.queue) return;
        const std::pair<int, int> place{status.queue->ahead, status.queue->running};
        if (place != told) {
            if (json_lines)
                std::cout << json{{"event", "queued"},
                                  {"ahead", place.first},
                                  {"running", place.second},
                                  {"starts_in_seconds",
                                   status.queue->starts_in_seconds ? json(*status.queue->starts_in_seconds) : json()}}
                                 .dump()
                          << std::endl;
            else std::cerr << queued_line(job, *status.queue) << "\n" << std::flush;
            told = place;
        }
        std::this_thread::sleep_for(std::chrono::seconds(1));
    }
}

// While it lives, Ctrl-C (SIGINT) on a command that follows a job says that
// the job goes on at the server and how to follow or stop it, then exits
// 130 (issue #54: the command just died, and a user could not tell that
// the job went on). The message is made before the handler is set: a
// signal handler may only write() and _exit().
class SayTheJobGoesOnAtCtrlC {
public:
    SayTheJobGoesOnAtCtrlC(const std::string& job, const std::string& server) {
        const std::string text = "\nlightfarm: job " + job + " goes on at " + server + ": `lightfarm watch " + job +
                                 " --server " + server + "` follows it again, `lightfarm cancel " + job + " --server " +
                                 server + "` stops it\n";
        size_ = std::min(text.size(), sizeof message_);
        std::memcpy(message_, text.data(), size_);
        struct sigaction action {};
        action.sa_handler = [](int) {
            (void)!::write(2, message_, size_);
            _exit(130);
        };
        sigemptyset(&action.sa_mask);
        sigaction(SIGINT, &action, &previous_);
    }
    ~SayTheJobGoesOnAtCtrlC() { sigaction(SIGINT, &previous_, nullptr); }
    SayTheJobGoesOnAtCtrlC(const SayTheJobGoesOnAtCtrlC&) = delete;
    SayTheJobGoesOnAtCtrlC& operator=(const SayTheJobGoesOnAtCtrlC&) = delete;

private:
    static inline char message_[1024];
    static inline size_t size_ = 0;
    struct sigaction previous_ {};
};

// Follows a job's events until its final one, reconnecting with
// Last-Event-ID when the connection drops. Returns the final event.
protocol::JobEvent follow(Remote& remote, const std::string& job, bool json_lines) {
    const SayTheJobGoesOnAtCtrlC ctrl_c(job, remote.server());
    tell_while_queued(remote, job, json_lines);
    const bool tty = isatty(2);
    int64_t last = 0;
    protocol::JobEvent final_event;
    for (int tries = 0; tries < 10 && final_event.type.empty(); ++tries) {
        httplib::Headers headers;
        if (last > 0) headers.emplace("Last-Event-ID", std::to_string(last));
        protocol::SseParser parser;
        std::string error_body;
        int status = 0;
        auto r = remote.http().Get(
            "/v1/jobs/" + job + "/events", headers,
            [&](const httplib::Response& res) {
                status = res.status;
                return true;
            },
            [&](const char* data, size_t n) {
                if (status != 200) {
                    error_body.append(data, n);
                    return true;
                }
                for (const protocol::JobEvent& e : parser.feed(std::string(data, n))) {
                    last = e.id;
                    if (json_lines) {
                        std::cout << json{{"id", e.id}, {"event", e.type}, {"data", e.data}}.dump() << std::endl;
                    } else if (e.type == "progress" && tty) {
                        const protocol::Progress p = protocol::progress_from_json(e.data);
                        std::cerr << "\r" << progress_line(job, e.data.value("output", ""), p) << "    " << std::flush;
                    } else if (e.type == "preparing") {
                        json event = e.data;
                        event["event"] = "prepare";
                        const protocol::WorkerEvent prepare = protocol::parse_worker_event(event);
                        const std::string line = preparing_line(job, std::get<protocol::PrepareEvent>(prepare));
                        std::cerr << (tty ? "\r" + line + "    " : line + "\n") << std::flush;
                    } else if (e.type == "snapshot" && !tty) {
                        std::cerr << "snapshot " << e.data.value("file", "") << "\n";
                    } else if (e.type == "retrying") {
                        std::cerr << (tty ? "\n" : "") << "attempt " << e.data.value("attempt", 0)
                                  << " failed: " << e.data.value("cause", "") << "; retrying\n";
                    }
                    if (protocol::is_final_event(e.type)) {
                        final_event = e;
                        return false;
                    }
                }
                return true;
            });
        if (status != 0 && status != 200) {
            const json body = json::parse(error_body, nullptr, false);
            throw RemoteError(
                (body.is_object() && body.contains("error") ? body["error"].get<std::string>() : error_body) +
                " (HTTP " + std::to_string(status) + ")");
        }
        if (final_event.type.empty()) std::this_thread::sleep_for(std::chrono::seconds(1));
    }
    if (tty && !json_lines) std::cerr << "\n";
    if (final_event.type.empty()) throw RemoteError("lost the event stream of job " + job + " at " + remote.server());
    return final_event;
}

// Which of a job's files to download.
enum class Files { Final, FinalAndSnapshots, Latest };

// GET `route` into `path`: into a temporary file, closed (its last bytes
// reach the disk there, and a full disk shows), then renamed into place. A
// failure leaves neither a temporary file nor a file cut short, and names
// the file and why.
void download(Remote& remote, const std::string& route, const fs::path& path) {
    const fs::path tmp = path.parent_path() / ("." + path.filename().string() + ".tmp");
    auto cannot_write = [&](const fs::path& file, int error) {
        std::error_code ignored;
        fs::remove(tmp, ignored);
        return RemoteError(file.string() + ": cannot write (" + std::strerror(error) + ")");
    };
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw cannot_write(tmp, errno);
    int write_error = 0;
    auto r = remote.http().Get(route, [&](const char* data, size_t n) {
        if (!out.write(data, std::streamsize(n))) write_error = errno;
        return bool(out);
    });
    if (write_error) throw cannot_write(tmp, write_error);
    try {
        remote.check(r, "download " + path.filename().string());
    } catch (...) {
        std::error_code ignored;
        fs::remove(tmp, ignored);
        throw;
    }
    out.close();
    if (!out) throw cannot_write(tmp, errno);
    std::error_code ec;
    fs::rename(tmp, path, ec);
    if (ec) throw cannot_write(path, ec.value());
}

// Downloads artifacts into `dir`.
void fetch(Remote& remote, const std::string& job, const fs::path& dir, Files which) {
    std::vector<std::string> names;
    if (which == Files::Latest) {
        // The newest file of each output, as the server learnt it from the
        // worker's events (file names do not sort by pass: pass-16384 < pass-2048).
        const json status = remote.call(remote.http().Get("/v1/jobs/" + job), "read job " + job);
        for (const auto& [output, latest] : protocol::latest_from_json(status.value("latest", json::object())))
            names.push_back(latest.file);
    } else {
        const json listing =
            remote.call(remote.http().Get("/v1/jobs/" + job + "/artifacts"), "list the files of job " + job);
        for (const json& a : listing["artifacts"])
            if (which == Files::FinalAndSnapshots || !protocol::is_snapshot_file(a["name"])) names.push_back(a["name"]);
    }
    if (names.empty())
        throw RemoteError("job " + job + " has no " + (which == Files::Final ? "final " : "") + "files yet" +
                          (which == Files::Final ? " (--latest: its newest snapshots)" : ""));
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) throw RemoteError(dir.string() + ": cannot write (" + ec.message() + ")");
    for (const std::string& name : names) {
        download(remote, "/v1/jobs/" + job + "/artifacts/" + name, dir / name);
        std::cerr << "fetched " << (dir / name).string() << "\n";
    }
}

// Ends with the job's final state, said on stderr (stdout stays the job id
// or the JSON lines): done, failed with its cause, or cancelled.
int finish_with(const protocol::JobEvent& e, const std::string& job) {
    if (e.type == "done") {
        std::cerr << "lightfarm: job " << job << " succeeded"
                  << (e.data.value("cached", false) ? " (from the cache)" : "") << ": " << e.data.value("pass", 0)
                  << " passes, " << e.data.value("seconds", 0.0) << " s, "
                  << e.data.value("files", json::array()).size() << " files\n";
        return 0;
    }
    if (e.type == "failed")
        std::cerr << "lightfarm: job " << job << " failed: " << e.data.value("error", "") << ": "
                  << e.data.value("cause", "") << "\n";
    else std::cerr << "lightfarm: job " << job << " was cancelled\n";
    return 1;
}

const std::set<std::string> kCommon = {"--server", "--token"};

std::set<std::string> with_common(std::set<std::string> s) {
    s.insert(kCommon.begin(), kCommon.end());
    return s;
}

std::string one_job(const Args& args, const std::string& command) {
    if (args.positional().size() != 1) throw UsageError(command + " takes exactly one JOB argument");
    return args.positional()[0];
}

int submit(int argc, char** argv) {
    // Every output and setting of `lightfarm bake`, from the one catalog.
    std::set<std::string> valued = with_common({"--out"});
    std::set<std::string> flags = {"--wait", "--json", "--snapshots"};
    for (const auto& [flag, takes_value] : protocol::bake_flags()) (takes_value ? valued : flags).insert(flag);
    const Args args(argc, argv, 2, valued, flags);
    if (args.positional().size() != 1) throw UsageError("submit takes exactly one SCENE argument");
    std::map<std::string, std::string> bake;
    for (const auto& [flag, takes_value] : protocol::bake_flags()) {
        if (takes_value && args.has(flag)) bake[flag] = args.get(flag);
        if (!takes_value && args.flag(flag)) bake[flag] = "";
    }
    json spec;
    try {
        spec = protocol::bake_json_from_flags(bake);
    } catch (const protocol::SpecError& e) {
        throw UsageError(e.what());
    }

    Remote remote(args);
    spec["scene"] = upload_scene(remote, args.positional()[0]);
    const json job = remote.call(remote.http().Post("/v1/jobs", spec.dump(), "application/json"), "create the job");
    const std::string id = job["id"];
    std::cout << id << std::endl;
    if (!args.flag("--wait")) return 0;
    const protocol::JobEvent end = follow(remote, id, args.flag("--json"));
    if (end.type == "done")
        fetch(remote, id, args.get("--out", id), args.flag("--snapshots") ? Files::FinalAndSnapshots : Files::Final);
    return finish_with(end, id);
}

int watch(int argc, char** argv) {
    const Args args(argc, argv, 2, kCommon, {"--json"});
    const std::string id = one_job(args, "watch");
    Remote remote(args);
    return finish_with(follow(remote, id, args.flag("--json")), id);
}

int fetch_command(int argc, char** argv) {
    const Args args(argc, argv, 2, with_common({"--out"}), {"--latest", "--snapshots"});
    const std::string id = one_job(args, "fetch");
    if (args.flag("--latest") && args.flag("--snapshots")) throw UsageError("fetch: --latest or --snapshots, not both");
    Remote remote(args);
    // A job that did not succeed has no final files, whatever else its
    // folder holds (a cancelled lightmap job's scene.lightmapped.glb was
    // fetched alone, quietly): say so, and what can be fetched instead.
    if (!args.flag("--latest") && !args.flag("--snapshots")) {
        const std::string state = remote.call(remote.http().Get("/v1/jobs/" + id), "read job " + id).value("state", "");
        if (state != "succeeded")
            throw RemoteError("job " + id + " " + (state == "failed" || state == "cancelled" ? "was " : "is ") + state +
                              ": it has no final files (--latest: the newest file of each output; --snapshots: "
                              "every file it wrote)");
    }
    fetch(remote, id, args.get("--out", id),
          args.flag("--latest")      ? Files::Latest
          : args.flag("--snapshots") ? Files::FinalAndSnapshots
                                     : Files::Final);
    return 0;
}

int cancel(int argc, char** argv) {
    const Args args(argc, argv, 2, kCommon, {});
    const std::string id = one_job(args, "cancel");
    Remote remote(args);
    const json status = remote.call(remote.http().Post("/v1/jobs/" + id + "/cancel"), "cancel job " + id);
    std::cout << id << " " << status.value("state", "") << "\n";
    return 0;
}

int jobs(int argc, char** argv) {
    const Args args(argc, argv, 2, kCommon, {"--json"});
    if (!args.positional().empty()) throw UsageError("jobs takes no arguments");
    Remote remote(args);
    const json list = remote.call(remote.http().Get("/v1/jobs"), "list jobs");
    if (args.flag("--json")) {
        std::cout << list.dump(2) << "\n";
        return 0;
    }
    for (const json& j : list["jobs"]) {
        const protocol::JobStatus s = protocol::status_from_json(j);
        std::cout << s.id << "  " << protocol::to_string(s.state) << "  pass " << s.progress.pass;
        if (s.progress.error_estimate) std::cout << "  error " << *s.progress.error_estimate;
        if (!s.error.empty()) std::cout << "  " << s.error << ": " << s.cause;
        std::cout << "\n";
    }
    return 0;
}

}  // namespace

bool is_remote_command(const std::string& command) {
    return command == "submit" || command == "watch" || command == "fetch" || command == "cancel" || command == "jobs";
}

int run_remote_command(const std::string& command, int argc, char** argv) {
    try {
        if (command == "submit") return submit(argc, argv);
        if (command == "watch") return watch(argc, argv);
        if (command == "fetch") return fetch_command(argc, argv);
        if (command == "cancel") return cancel(argc, argv);
        if (command == "jobs") return jobs(argc, argv);
        throw UsageError("unknown command '" + command + "'");
    } catch (const UsageError& e) {
        // The mistake and the command's own usage, not every option there is.
        std::cerr << "lightfarm " << command << ": " << e.what() << "\n"
                  << command_usage(kRemoteUsage, command) << "(lightfarm " << command << " --help lists its options"
                  << (command == "submit" ? ", every bake setting among them" : "") << ")\n";
        return 2;
    } catch (const std::exception& e) {
        std::cerr << "lightfarm " << command << ": error: " << e.what() << "\n";
        return 1;
    }
}

}  // namespace lf::cli
