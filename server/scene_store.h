// Scene uploads: checked, stored once per content under DATA/scenes/<id>/,
// and validated by running `lightfarm inspect --json` on them in a separate
// process, so that a file that crashes the loader costs a 400, not the server.
#pragma once

#include "config.h"
#include "job_store.h"

#include <nlohmann/json.hpp>

#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <string>
#include <vector>

namespace lf::server {

struct UploadFile {
    std::string name;  // relative path inside the upload ("scene.gltf", "textures/a.png")
    std::string bytes;
};

class SceneStore {
public:
    SceneStore(const ServerConfig& config, JobStore& store);

    struct Result {
        SceneRecord scene;
        bool created;  // false: this token had uploaded these bytes before
    };
    // One .glb or .gltf (with data: URIs), or a .gltf with the files it
    // references. Throws HttpError (400 bad input, 413 over a limit, 503 when
    // too many uploads are being checked: body {"retry_after": seconds}) and
    // StoreError (the store could not record it; nothing is kept).
    //
    // At most config.max_inspects checks (`lightfarm inspect`) run at once,
    // each under an address-space limit of config.inspect_memory_bytes; up to
    // 4 x max_inspects more uploads wait (at most inspect_seconds) for a turn.
    Result upload(const std::vector<UploadFile>& files, const std::string& owner);

private:
    // A turn to run the checker: waits for one, or throws HttpError 503.
    class InspectTurn;
    // `lightfarm inspect --json` on the upload's main file, in a process of
    // its own (a turn, a time and a memory limit), and the scene's size
    // checked against the limits: its summary. Throws HttpError.
    nlohmann::json inspect(const std::filesystem::path& main_file);
    const ServerConfig& config_;
    JobStore& store_;
    std::string engine_;
    std::mutex inspect_mutex_;
    std::condition_variable inspect_cv_;
    int inspecting_ = 0;  // checks running
    int waiting_ = 0;     // uploads waiting for a turn
};

// Checks a relative path from an upload or a glTF URI: no absolute paths, no
// "..", no backslashes, control or shell characters. Returns the reason it is
// refused, or "" when it is fine.
std::string unsafe_path_reason(const std::string& path);

// A name a tenant sent, as a message shows it: control characters and bytes
// that are not UTF-8 as \xNN, so that a message neither stops at a NUL
// (issue #55: a NUL name's message was cut there) nor holds bytes its JSON
// cannot carry; any other text as it is.
std::string shown_name(const std::string& name);

}  // namespace lf::server
