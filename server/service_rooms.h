// What the service's rooms share: the routes of jobs (service_jobs.cpp),
// scenes (service_scenes.cpp) and the status page (service_status.cpp), and
// the gate, routing and authentication in front of them (service.cpp).
// Internal to server/.
#pragma once

#include "job_store.h"

#include <nlohmann/json.hpp>
#include "worker_protocol.h"

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace httplib {
struct Response;
}

namespace lf::server {

// Answers `status` with `body` as indented JSON.
void send_json(httplib::Response& res, int status, const nlohmann::json& body);

// Workers write a file as a temporary and rename it; those temporaries, and
// the supervisor's own dot files, are not artifacts.
bool is_artifact_name(const std::string& name);

struct Artifact {
    std::string name;
    uintmax_t size;
};
// A job directory's artifacts, by name.
std::vector<Artifact> artifacts_in(const std::filesystem::path& dir);

// A stored scene's summary as the checks at submit read it, named as the
// user uploaded it. A summary from an older engine that does not say whether
// the scene has a light is taken as lit: what is not known is not refused.
protocol::SceneSummary summary_of(const SceneRecord& scene);
// The summary as the upload and GET /v1/scenes/{id} answer it: its `source`
// the scene's name as read for its owner (SceneRecord::name), and its id.
nlohmann::json scene_json(const SceneRecord& scene);

}  // namespace lf::server
