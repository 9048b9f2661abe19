// The scene routes: uploads (POST /v1/scenes) and their summaries.
#include "service.h"
#include "service_rooms.h"

#include "disk_space.h"
#include "http_error.h"

#include <httplib.h>

#include <filesystem>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;

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
                            "name: '" + shown_name(name) + "' must end in " + kind + " for this body (a " +
                                (json_body ? "JSON glTF" : "binary glTF") + ")",
                            {{"field", "name"}});
        files.push_back({name, req.body});
    }
    const SceneStore::Result r = scenes_->upload(files, caller.owner);
    send_json(res, r.created ? 201 : 200, scene_json(r.scene));
}

void Service::get_scene(const httplib::Request& req, httplib::Response& res, const Caller& caller) {
    const std::string id = req.matches[1].str();
    const std::optional<SceneRecord> scene = store_->scene_for(id, caller.owner);
    if (!scene) throw HttpError(404, "no scene " + id, {{"id", id}});
    send_json(res, 200, scene_json(*scene));
}

// A scene's summary as its owner sees it: named as that owner uploaded it
// (the stored summary's `source` is the first uploader's), with its id.
json scene_json(const SceneRecord& scene) {
    json body = scene.summary.is_object() ? scene.summary : json::object();
    body["source"] = summary_of(scene).source;
    body["id"] = scene.id;
    return body;
}

json Service::scene_brief(const std::string& scene_id, const std::string& owner) const {
    json brief = json::object();
    if (const std::optional<SceneRecord> scene = store_->scene_for(scene_id, owner)) {
        const protocol::SceneSummary summary = summary_of(*scene);
        brief = {{"scene_name", summary.source}, {"scene_triangles", summary.triangles}};
    }
    return brief;
}

}  // namespace lf::server
