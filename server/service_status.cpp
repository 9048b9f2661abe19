// The status page and what it reads beside the API: the page, its styles and
// scripts, health, metrics, previews of a job's lightmap, and the 3D view's
// three.js.
#include "service.h"
#include "service_rooms.h"

#include "http_error.h"
#include "outputs.h"
#include "preview.h"
#include "web_files.h"

#include <httplib.h>

#include <filesystem>
#include <fstream>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;

void Service::healthz(const httplib::Request&, httplib::Response& res, const Caller&) {
    json body = {{"status", "ok"}};
    // Serving, but with job records lost before it started (jobs_without_records).
    if (!lost_jobs_.empty()) body["jobs_without_records"] = lost_jobs_.size();
    send_json(res, 200, body);
}

void Service::metrics(const httplib::Request&, httplib::Response& res, const Caller&) {
    std::vector<Metrics::NodeGauge> nodes;
    std::map<std::string, int> running;
    for (const JobRecord& job : store_->running_jobs()) ++running[job.node];
    for (const NodeRecord& n : store_->nodes())
        nodes.push_back({n.name, n.alive(), running[n.name], std::max(0.0, n.heartbeat_age)});
    const std::string lost =
        "# HELP lightfarm_jobs_without_records job directories whose records the store lost "
        "(counted at start)\n# TYPE lightfarm_jobs_without_records gauge\n"
        "lightfarm_jobs_without_records " +
        std::to_string(lost_jobs_.size()) + "\n";
    res.set_content(
        metrics_.render(store_->count_by_state()) + Metrics::render_nodes(store_->node().name, nodes) + lost,
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
    // They go in place of the `null` in the page's data block, which status.js reads.
    const std::string block = R"(<script type="application/json" id="initial-jobs">)", none = "null";
    const size_t at = page.find(block + none + "</script>");
    if (at == std::string::npos)
        throw std::logic_error("web/ui/status.html has no " + block + none + "</script> for the caller's jobs");
    page.replace(at + block.size(), none.size(), jobs);
    res.set_content(page, "text/html; charset=utf-8");
}

namespace {

// The Content-Type of a file of web/ui that GET /ui/{file} serves: its
// styles and scripts; empty for any other name (the pages have routes of
// their own: / fills in the caller's jobs, and a caller without a token gets
// login.html there).
std::string served_web_file_type(const std::string& name) {
    const auto ends_with = [&](const std::string& suffix) {
        return name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
    };
    if (ends_with(".css")) return "text/css; charset=utf-8";
    if (ends_with(".js")) return "text/javascript; charset=utf-8";
    return "";
}

// What GET /ui/{file} serves, for a 404's message: "status-view3d.js, status.css, ...".
std::string served_web_file_names() {
    std::string names;
    for (const auto& file : embedded_web_files())
        if (!served_web_file_type(file.first).empty()) names += (names.empty() ? "" : ", ") + file.first;
    return names;
}

}  // namespace

// GET /ui/{file}: the status page's styles and scripts (status.css,
// status.js, ...), from the copy of web/ui embedded in the binary. The name
// is looked up among the embedded files, never joined to a path, so no name
// reaches anything else.
void Service::web_file(const httplib::Request& req, httplib::Response& res, const Caller&) {
    const std::string name = req.matches[1];
    const std::string type = served_web_file_type(name);
    const auto& files = embedded_web_files();
    const auto found = files.find(name);
    if (type.empty() || found == files.end())
        throw HttpError(404,
                        "no such file of the status page: /ui/" + name + " (it has " + served_web_file_names() + ")");
    // Asked for again each time (a few KiB): the page itself is sent afresh
    // each time, and a page from an upgraded lightfarmd must not run the
    // scripts a browser kept from the one before.
    res.set_header("Cache-Control", "no-cache");
    res.set_content(std::string(found->second), type);
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

namespace {

// The output a preview shows: `?output=NAME`, or the first output of the
// registry whose image the lit scene carries (lightmap, then ao) that the
// job has a file of. An AO-only job's preview is its occlusion (issue #56:
// the previews knew only the lightmap).
std::string previewed_output(const httplib::Request& req, const protocol::JobStatus& job) {
    const std::string asked = req.has_param("output") ? req.get_param_value("output") : "";
    if (!asked.empty()) {
        const protocol::OutputKind* o = protocol::find_output(asked);
        if (!o || o->lit_scene_slot.empty())
            throw HttpError(400, "output=" + asked + ": previews show an image output's (lightmap, ao)",
                            {{"field", "output"}});
        return asked;
    }
    for (const protocol::OutputKind& o : protocol::output_registry())
        if (!o.lit_scene_slot.empty() && job.latest.count(o.name)) return o.name;
    return "lightmap";
}

}  // namespace

void Service::send_preview(const httplib::Request& req, httplib::Response& res, const Caller& caller,
                           PreviewKind kind) {
    const JobRecord job = owned_job(req, caller);
    const std::string output = previewed_output(req, job.status);
    // Its newest file, as the worker's events named it (its final file
    // once done, else its latest snapshot): never guessed from file names.
    const auto latest = job.status.latest.find(output);
    if (latest == job.status.latest.end() || !is_artifact_name(latest->second.file))
        throw HttpError(404, "job " + job.status.id + " has no " + output + " snapshot yet", {{"id", job.status.id}});
    const std::string chosen = latest->second.file;

    const fs::path path = supervisor_->job_dir(job.status.id) / chosen;
    std::error_code ec;
    if (!fs::is_regular_file(path, ec))
        throw HttpError(404, "job " + job.status.id + " has no artifact " + chosen, {{"id", job.status.id}});
    const std::string source = path.string() + ":" + std::to_string(fs::file_size(path, ec)) + ":" +
                               std::to_string(fs::last_write_time(path, ec).time_since_epoch().count());
    std::map<PreviewKind, Preview> previews;
    if (auto kept = previews_.find(job.status.id, source)) {
        previews = std::move(*kept);
    } else {
        try {
            previews = render_previews(path.string());
        } catch (const std::exception& e) {
            throw HttpError(500, e.what(), {{"id", job.status.id}});
        }
        previews_.keep(job.status.id, source, previews);
    }
    const auto found = previews.find(kind);
    if (found == previews.end())
        throw HttpError(404, "job " + job.status.id + ": " + chosen + " has no \"error\" channel",
                        {{"id", job.status.id}});
    const Preview& preview = found->second;
    res.set_header("X-Lightfarm-Source", chosen);
    res.set_header("X-Lightfarm-Output", output);
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

}  // namespace lf::server
