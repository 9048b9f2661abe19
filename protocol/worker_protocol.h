// The engine-server contract: what a worker (`lightfarm bake --json`) prints,
// one JSON object per stdout line, what `lightfarm inspect --json` prints, and
// what a worker's exit status means. The engine encodes these types and the
// server decodes them; neither side writes or reads the JSON by hand.
//
//   {"event":"prepare", "stage":"atlas", "seconds", "eta_seconds"}   (before "start", as each stage begins;
//    said again each second while it runs, with "again": true)
//   {"event":"start", "vendor", "renderer", "triangles", "prepare_seconds", "outputs": {NAME: {...}},
//    "resumed": {NAME: {"pass", "rays", "seconds", "error_estimate"}}, "not_resumed": {NAME: "why"}}
//   {"event":"progress", "output":"lightmap", "pass", "rays", "seconds", "error_estimate"}   (per pass; the
//    last said again each second while a pass or the final writes run long, with "again": true)
//   {"event":"snapshot", "output":"lightmap", "file":"lightmap.pass-0004.exr", "pass":4}
//   {"event":"done", "pass", "rays", "seconds", "error_estimate", "files":[...], "final":{NAME: FILE}}
#pragma once

#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <variant>
#include <vector>

namespace lf::protocol {

// A worker's exit status. Input errors (a bad setting, a scene that cannot be
// baked) fail the job at once: running it again cannot help. Anything else
// (a crash, a lost GPU, a signal) costs one attempt and is retried.
enum WorkerExit : int {
    kExitOk = 0,
    kExitFailure = 1,     // the engine's own trouble: retry
    kExitUsage = 2,       // bad command line or settings
    kExitInputError = 3,  // the scene or the settings cannot be baked (no light, atlas cannot fit, bad file)
    // The --spec file could not be read, or is not whole JSON (empty, cut
    // short): the trouble of whoever wrote it (the server, on a full disk),
    // never the job's settings. The server requeues the job without
    // counting the attempt.
    kExitSpecUnreadable = 4,
    // A file of the bake could not be written (disk full, I/O error): the
    // machine's trouble, requeued like kExitSpecUnreadable without counting
    // the attempt.
    kExitMachineFault = 5,
    // Stopped on request (SIGTERM: the job was cancelled) after writing one
    // last snapshot of where the bake stood, announced before the exit.
    kExitStopped = 6,
};
inline bool is_input_error_exit(int code) { return code == kExitUsage || code == kExitInputError; }

// In a job's output directory: what a worker saves with its snapshots so that
// a later run with --resume continues from there (the engine's
// bake/method_state.h), removed once the job is done.
inline constexpr const char* kResumeDir = ".resume";

// A worker writes each file whole or not at all: first as ".NAME.tmp-PID"
// beside it, then renamed. One it was killed writing stays behind: the
// supervisor removes a worker's once it has ended (is_temporary_file_of).
std::string temporary_file_name(const std::string& name, long pid);
bool is_temporary_file_of(const std::string& file_name, long pid);

// "<stem>.pass-NNNN.<extension>": an intermediate snapshot's file name (a
// final file never has ".pass-" in it). Clients tell snapshots from final
// files by it (`lightfarm fetch` without --snapshots).
std::string snapshot_file_name(const std::string& stem, int pass, const std::string& extension);
bool is_snapshot_file(const std::string& name);
// A snapshot's name with its pass as "NNNN" ("lightmap.pass-0004.exr" ->
// "lightmap.pass-NNNN.exr"): how outputs name their snapshot files; any
// other name as it is.
std::string snapshot_pattern(const std::string& name);

// "<stem>.page-N.<extension>": page N (from 0) of an atlas image whose
// charts took several pages (a final file), and its pattern
// ("lightmap.page-2.exr" -> "lightmap.page-N.exr"; any other name as it is).
std::string page_file_name(const std::string& stem, int page, const std::string& extension);
std::string page_pattern(const std::string& name);

// Where a progressive bake stands: totals after the latest pass. The engine's
// pass statistics and the server's progress are this one type.
struct Progress {
    int pass = 0;                          // passes done so far
    uint64_t rays = 0;                     // rays traced so far
    double seconds = 0.0;                  // time in passes so far
    std::optional<double> error_estimate;  // relative standard error, once known
    std::optional<double> eta_seconds;     // the server's estimate of what is left
    double prepare_seconds = 0.0;          // the server's: the job's preparation before its first pass
    double earlier_outputs_seconds = 0.0;  // the server's: passes of the job's outputs baked before this one
    // The server's, while the job prepares (before its first pass): the
    // stage running ("load", "atlas", ...; "" once passes run), with
    // prepare_seconds so far and preparation's time left, from the scene's
    // size (gi/bake/preparation_estimate.h).
    std::string preparing;
    std::optional<double> prepare_eta_seconds;
    // The server's: the most of the job the bar has shown so far
    // (JobProgress): it never goes back, though the ETA may grow (the
    // outputs still to come priced anew once they run).
    double shown_fraction = 0.0;
};
// How much of the job is done, preparation and earlier outputs included:
// (preparation + earlier outputs + passes' seconds) over that plus the ETA, 1
// once the ETA is 0, and never less than shown_fraction; empty while the ETA
// is unknown and nothing was shown. The bars of the status page and of `lightfarm watch`.
std::optional<double> done_fraction(const Progress& p);
nlohmann::json to_json(const Progress& p);
Progress progress_from_json(const nlohmann::json& j);

// A stage of the job's preparation begins (load, atlas, texel samples,
// methods ...): preparation is most of a short bake's time and minutes of a
// large atlas's, and nothing else is said until the start event.
struct PrepareEvent {
    std::string stage;
    double seconds = 0.0;               // preparation so far
    std::optional<double> eta_seconds;  // preparation's time left, from the scene's size; empty: unknown yet
    // The stage said again while it runs long ("again": true; the worker
    // lets no line get older than a second: gi/bake/event_heartbeat.h).
    bool again = false;
};
struct StartEvent {
    std::string vendor, renderer;
    uint64_t triangles = 0;
    double prepare_seconds = 0.0;                       // load, atlas, BVH, methods: once for the whole job
    nlohmann::json outputs = nlohmann::json::object();  // output name -> what it bakes (texels, vertices, settings)
    // A resumed bake (`lightfarm bake --resume`, a retried job): where each
    // output's passes continue from (its totals so far; absent: pass 0),
    // and why an output could not resume (no state saved, another bake's).
    std::map<std::string, Progress> resumed;
    std::map<std::string, std::string> not_resumed;
    // What the bake did otherwise than asked, for a person to read (a
    // texel density that does not fit the largest atlas, baked lower).
    std::vector<std::string> warnings;
};
struct ProgressEvent {
    std::string output;
    Progress progress;
    bool again = false;  // the last pass said again while a pass or the final writes run long
};
struct SnapshotEvent {
    std::string output;
    std::string file;  // a plain file name in the job's directory
    int pass = 0;
};
struct DoneEvent {
    Progress progress;                               // of the output baked last
    std::vector<std::string> files;                  // every file written, final and intermediate
    std::map<std::string, std::string> final_files;  // output name -> its main file
};
using WorkerEvent = std::variant<PrepareEvent, StartEvent, ProgressEvent, SnapshotEvent, DoneEvent>;

nlohmann::json to_json(const WorkerEvent& e);
// Throws std::invalid_argument for a line that is not a worker event.
WorkerEvent parse_worker_event(const nlohmann::json& j);

// What `lightfarm inspect --json` says of a scene, as the server stores it and
// checks jobs against it before they run. The engine's summary has more
// fields (`details`), kept as they are.
struct SceneSummary {
    std::string source;  // the file's name as uploaded, never a server path
    uint64_t triangles = 0;
    uint64_t emissive_triangles = 0;
    uint64_t punctual_lights = 0;
    int max_texture_size = 0;
    bool has_lightmap_uvs = false;  // every primitive has TEXCOORD_1 (kept as the atlas)
    // The smallest atlas side a generated atlas fits in (0: unknown or has_lightmap_uvs).
    int min_atlas_res = 0;
    nlohmann::json details = nlohmann::json::object();
    bool has_light() const { return emissive_triangles > 0 || punctual_lights > 0; }
};
nlohmann::json to_json(const SceneSummary& s);
SceneSummary scene_summary_from_json(const nlohmann::json& j);

}  // namespace lf::protocol
