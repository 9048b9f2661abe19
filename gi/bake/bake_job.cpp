#include "bake/bake_job.h"

#include "atlas/atlas.h"
#include "bake/double_sided.h"
#include "bake/event_heartbeat.h"
#include "bake/method_state.h"
#include "bake/light_density.h"
#include "bake/unlit_charts.h"
#include "atlas/lightmapped_gltf.h"
#include "bake/output_methods.h"
#include "bake/prepared_scene.h"
#include "bake/preparation_estimate.h"
#include "bake/snapshot_writer.h"
#include "gpu/shader.h"
#include "io/image_files.h"
#include "io/write_error.h"
#include "display_tone.h"
#include "lightmap_preview.h"
#include "scene/gltf_loader.h"
#include "util/hash.h"
#include "util/stopwatch.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <future>
#include <map>
#include <set>
#include <memory>
#include <optional>

namespace lf {

namespace fs = std::filesystem;

uint64_t available_memory(const fs::path& meminfo_file, const fs::path& cgroup_dir) {
    uint64_t available = 0;
    std::ifstream meminfo(meminfo_file);
    for (std::string line; std::getline(meminfo, line);)
        if (line.rfind("MemAvailable:", 0) == 0) available = std::strtoull(line.c_str() + 13, nullptr, 10) * 1024;
    // A container's limit (cgroup v2): what is left of memory.max.
    std::ifstream max_file(cgroup_dir / "memory.max"), current_file(cgroup_dir / "memory.current");
    std::string max_text;
    uint64_t current = 0;
    if (max_file >> max_text && max_text != "max" && current_file >> current) {
        const uint64_t limit = std::strtoull(max_text.c_str(), nullptr, 10);
        const uint64_t left = limit > current ? limit - current : 0;
        available = available == 0 ? left : std::min(available, left);
    }
    return available;
}

namespace {

std::string gigabytes(uint64_t bytes) {
    char text[32];
    std::snprintf(text, sizeof text, "%.1f GB", double(bytes) / 1e9);
    return text;
}

std::string texels_per_metre(double density) {
    char text[48];
    std::snprintf(text, sizeof text, "%.4g texels/m", density);
    return text;
}

// Refuses, before anything large is allocated, an atlas whose bake would not
// fit in memory, naming the largest resolution that would.
void check_bake_memory(const std::string& name, int width, int height, int subsamples) {
    const uint64_t available = available_memory();
    const uint64_t needed = protocol::estimated_bake_bytes(uint64_t(width) * uint64_t(height), subsamples);
    if (available == 0 || needed <= available) return;
    int fits = 0;
    while (protocol::estimated_bake_bytes(uint64_t(fits + 64) * uint64_t(fits + 64), subsamples) <= available)
        fits += 64;
    throw BakeInputError(name + ": a " + std::to_string(width) + "x" + std::to_string(height) + " atlas needs about " +
                         gigabytes(needed) + " to bake and this machine has " + gigabytes(available) +
                         " available; bake at --res " + std::to_string(fits) + " or less (or a lower --texel-density" +
                         (subsamples > 1 ? ", or fewer --subsamples" : "") + ")");
}

// With neither a resolution nor a texel density, the atlas takes its density
// from the scene (AtlasOptions::max_border_fraction): the radiosity map's
// bias against the path tracer grows with the share of the surface within
// half a texel of a chart border, measured at 0.6-1.8% per unit of that
// share where it is above 0.25 (monkey at 64² and 128², the staircase at
// 384², the Cornell box at 256²; docs/BENCHMARKS.md, "Resolution from the
// scene"). The atlas keeps the bias below the lightmap's target error, or
// 1% without one, counting 2% per unit.
constexpr double kBiasPerBorderFraction = 0.02;
constexpr double kDefaultResolutionBias = 0.01;

AtlasOptions atlas_options(const protocol::BakeSettings& s) {
    AtlasOptions options;
    options.resolution = s.atlas.res.value_or(0);
    options.texel_density = float(s.atlas.texel_density.value_or(0.0));
    options.max_resolution = options.auto_max_resolution = s.atlas.max_res.value_or(protocol::kAutoMaxAtlasRes);
    options.max_pages = s.atlas.max_pages;
    // The tightest target error of the per-texel outputs.
    double target = kDefaultResolutionBias;
    bool targeted = false;
    for (const auto& [name, o] : s.outputs) {
        if (protocol::find_output(name)->domain != protocol::OutputDomain::Texel || o.stop().target_error <= 0.0)
            continue;
        target = targeted ? std::min(target, o.stop().target_error) : o.stop().target_error;
        targeted = true;
    }
    options.max_border_fraction = float(target / kBiasPerBorderFraction);
    return options;
}

// The lightmap atlas on a copy of the scene (a generated atlas splits
// vertices; per-vertex outputs keep the input's). Charts no light reaches
// get few texels (gi/bake/unlit_charts.h), found with `geometry()`, a
// tracer of the scene's triangles (asked for once the charts are made).
void prepare_atlas(PreparedScene& p, const protocol::BakeSettings& settings,
                   const std::function<const Tracer&()>& geometry) {
    const std::string name = p.file.filename().string();
    if (std::none_of(p.scene.instances.begin(), p.scene.instances.end(),
                     [](const PrimitiveInstance& i) { return i.has_lightmap(); }))
        throw BakeInputError(name +
                             ": every mesh has lightmap scale 0 (lightfarm_lightmap_scale, atlas.mesh_scale): "
                             "nothing is left to lightmap; leave a mesh in, or bake --sh or --probes alone");
    AtlasOptions options = atlas_options(settings);
    // Charts no light reaches get few texels, but an atlas output that needs
    // no light (per-texel SH transfer, lit later by any environment; ambient
    // occlusion) gives every lit and unlit chart its texels; glass charts
    // get few unless asked (find_glass_charts).
    options.find_unlit_charts = [&](const std::vector<uint32_t>& chart, size_t count) {
        std::vector<uint8_t> few(count, 0);
        if (settings.atlas_needs_light()) {
            const UnlitCharts unlit = find_unlit_charts(p.scene, geometry(), chart, count, p.environment.has_value());
            p.unlit_chart_rays = unlit.rays;
            few = unlit.unlit;
        }
        if (!settings.atlas.glass_texels) {
            const std::vector<uint8_t> glass = find_glass_charts(p.scene, chart, count);
            for (size_t c = 0; c < count; ++c) {
                p.glass_charts += glass[c];
                few[c] |= glass[c];
            }
        }
        return few;
    };
    // Texels where the light changes, when asked (gi/bake/light_density.h).
    if (settings.atlas.light_density)
        options.light_scales = [&](const std::vector<uint32_t>& chart, size_t count, const std::vector<uint8_t>& few,
                                   double texel) {
            const LightScales scales = light_driven_chart_scales(p.scene, geometry(), chart, count, few, texel,
                                                                 p.environment ? &*p.environment : nullptr);
            p.light_density_rays = scales.rays;
            return scales.scale;
        };
    p.atlas_scene = p.scene;
    try {
        p.atlas = p.timed("atlas", [&] { return prepare_lightmap_atlas(*p.atlas_scene, options); });
    } catch (const AtlasDoesNotFit& e) {  // say what would fit, beyond max_res too
        AtlasOptions uncapped = options;
        uncapped.max_resolution = AtlasOptions{}.max_resolution;
        const int smallest = smallest_atlas_resolution(p.scene, uncapped);
        const std::string flag = settings.atlas.res ? "--res" : "--max-res";
        throw BakeInputError(name + ": " + e.what() +
                             (smallest > 0 ? " (the smallest resolution that fits is " + std::to_string(smallest) +
                                                 ": " + flag + " " + std::to_string(smallest) + ")"
                                           : ""));
    }
    check_bake_memory(name, p.atlas.width, p.atlas.height, settings.atlas.subsamples);
    // A mesh's lightmap scale shapes a generated atlas only: the file's own
    // TEXCOORD_1 is kept as it is (a scale of 0, no lightmap, holds for both).
    const auto scaled =
        std::find_if(p.scene.instances.begin(), p.scene.instances.end(),
                     [](const PrimitiveInstance& i) { return i.lightmap_scale != 1.0f && i.has_lightmap(); });
    if (!p.atlas.generated && scaled != p.scene.instances.end())
        p.warnings.push_back("node " + std::to_string(scaled->node) +
                             "'s lightmap scale (lightfarm_lightmap_scale, atlas.mesh_scale) is not applied: the scene "
                             "has its own lightmap UVs "
                             "(TEXCOORD_1), which are baked as they are");
    if (!p.atlas.generated && settings.atlas.light_density)
        p.warnings.push_back(
            "light_density is not applied: the scene has its own lightmap UVs (TEXCOORD_1), "
            "which are baked as they are");
    // A density asked for that the largest atlas cannot hold is baked lower: said, not silent.
    if (options.texel_density > 0.0f && p.atlas.texel_density < 0.99f * options.texel_density)
        p.warnings.push_back(
            "texel density " + texels_per_metre(options.texel_density) + " does not fit in " +
            (options.max_pages > 1 ? std::to_string(options.max_pages) + " pages of " : std::string("a ")) +
            std::to_string(options.max_resolution) + "² (max_pages, max_res): baked at " +
            texels_per_metre(p.atlas.texel_density) +
            (p.atlas.pages.count < options.max_pages
                 ? ", where its largest chart spans a whole page; raise --max-res (at most 16384) for more"
                 : "; raise --max-res (at most 16384) or --max-pages for more"));
}

// The atlas's texels: double-sided charts turned to face the scene first
// (gi/bake/double_sided.h, traced with `geometry`: the atlas moves no
// triangle), then the texels' sample points.
void prepare_texels(PreparedScene& p, const protocol::AtlasSettings& settings, const Tracer& geometry) {
    Scene& scene = *p.atlas_scene;
    const bool any_double_sided =
        std::any_of(scene.materials.begin(), scene.materials.end(), [](const Material& m) { return m.double_sided; });
    if (any_double_sided)
        p.turned = p.timed("double_sided", [&] { return face_double_sided_charts_to_the_scene(scene, geometry); });
    p.texels = p.timed("texel_samples", [&] {
        return rasterize_texel_samples(scene, p.atlas.width, p.atlas.height, settings.subsamples);
    });
}

// Everything the outputs share, made once: scene, atlas, GL context, tracer;
// `on_stage` is told as each stage begins.
// The job's atlas.mesh_scale over the file's extras: each listed mesh's
// instances take its scale. A mesh the scene does not draw is the job's
// input error.
void apply_mesh_scales(PreparedScene& p, const std::map<int, double>& mesh_scale) {
    std::set<int> drawn;
    for (const PrimitiveInstance& i : p.scene.instances) drawn.insert(i.mesh);
    for (const auto& [mesh, scale] : mesh_scale)
        if (!drawn.count(mesh))
            throw BakeInputError("atlas.mesh_scale: mesh " + std::to_string(mesh) + " is not drawn by " +
                                 p.file.filename().string() + " (it has " + std::to_string(drawn.size()) + " meshes)");
    for (PrimitiveInstance& i : p.scene.instances)
        if (const auto it = mesh_scale.find(i.mesh); it != mesh_scale.end()) i.lightmap_scale = float(it->second);
}

// How far preparation goes: everything the methods need, or the atlas only
// (plan_bake_atlas: what a bake would make, without its texels).
enum class PrepareUntil { Methods, Atlas };

std::unique_ptr<PreparedScene> prepare(const BakeJob& job, decltype(PreparedScene::on_stage) on_stage,
                                       PrepareUntil until = PrepareUntil::Methods) {
    auto p = std::make_unique<PreparedScene>();
    p->on_stage = std::move(on_stage);
    p->file = job.scene;
    p->scene = p->timed("load", [&] { return load_scene(job.scene); });
    const protocol::BakeSettings& s = job.settings;
    p->environment = read_environment(s.env);
    apply_mesh_scales(*p, s.atlas.mesh_scale);
    if (s.needs_light() && p->scene.emissive_triangle_count() == 0 && p->scene.lights.empty() && !p->environment)
        throw BakeInputError(job.scene.filename().string() +
                             ": nothing to bake: the scene has no emissive surface and no punctual light, and no "
                             "environment was given (give a uniform sky with --env R,G,B)");
    p->gpu = p->timed("gpu", [&] { return std::make_unique<GpuContext>(job.device); });
    // One BVH of the scene's triangles, for the per-chart decisions and then
    // the passes; where double-sided charts were turned, their triangles'
    // winding (which side is the front) is re-read into the same tree. It
    // builds on a thread of its own while the atlas makes its charts; the
    // first to trace waits for it ("bvh": that wait and the upload).
    std::future<Bvh> bvh = std::async(std::launch::async, [&scene = p->scene] { return build_bvh(scene); });
    const auto tracer = [&]() -> const Tracer& {
        if (!p->tracer) p->tracer = p->timed("bvh", [&] { return std::make_unique<Tracer>(bvh.get(), p->scene); });
        return *p->tracer;
    };
    if (s.uses_atlas()) {
        prepare_atlas(*p, s, tracer);
        if (until == PrepareUntil::Atlas) return p;  // (the BVH's future waits for its thread)
        prepare_texels(*p, s.atlas, tracer());
        if (p->turned.charts > 0) p->timed("bvh_turned", [&] { p->tracer->rewind(*p->atlas_scene); });
    }
    tracer();
    return p;
}

}  // namespace

nlohmann::json plan_bake_atlas(const BakeJob& job) {
    const Stopwatch clock;
    if (!job.settings.uses_atlas()) throw BakeInputError("nothing to plan: no requested output uses the atlas");
    const std::unique_ptr<PreparedScene> p = prepare(job, nullptr, PrepareUntil::Atlas);
    nlohmann::json plan = {{"scene", job.scene.filename().string()}, {"atlas", atlas_json(p->atlas)}};
    plan["warnings"] = p->warnings;
    plan["seconds"] = clock.seconds();
    return plan;
}

namespace {

// Every requested output's method, in the registry's order.
std::vector<std::unique_ptr<ProgressiveMethod>> make_methods(const PreparedScene& p, const protocol::BakeSettings& s) {
    std::vector<std::unique_ptr<ProgressiveMethod>> methods;
    for (const protocol::OutputKind& output : protocol::output_registry())
        if (s.output(output.name)) methods.push_back(method_factory(output.name)(p, s));
    return methods;
}

// make_methods, a buffer too large for the device refused as the job's
// input: the atlas (or the sample points per texel) is what makes one so
// large, and a smaller one is what the user can change.
std::vector<std::unique_ptr<ProgressiveMethod>> methods_that_fit(const PreparedScene& p, const BakeJob& job) {
    try {
        return make_methods(p, job.settings);
    } catch (const GpuBufferTooLarge& e) {
        std::string what = job.scene.filename().string() + ": this bake needs " + e.what();
        if (p.atlas.width > 0)
            what += " (a " + std::to_string(p.atlas.width) + "x" + std::to_string(p.atlas.height) +
                    " atlas); bake at a lower --res or --texel-density, or with --subsamples 1";
        throw BakeInputError(what);
    }
}

nlohmann::json describe_files(const std::vector<std::string>& files, const nlohmann::json& manifest) {
    nlohmann::json out = nlohmann::json::object();
    for (const std::string& f : files) {
        out[f] = "";
        for (const std::string& output : protocol::output_names()) {
            if (!manifest.contains(output)) continue;
            const nlohmann::json& known = manifest[output]["files"];
            if (known.contains(f)) out[f] = known[f];
            else if (known.contains(protocol::snapshot_pattern(f))) out[f] = known[protocol::snapshot_pattern(f)];
            else if (known.contains(protocol::page_pattern(f))) out[f] = known[protocol::page_pattern(f)];
        }
    }
    return out;
}

// A fresh bake into a folder that holds an older bake: the older one's
// snapshots and atlas pages go (the files that fit an output's snapshot or
// page pattern, nothing else), so that its higher pass numbers are not
// taken for this bake's, nor its pages for pages this bake has not.
void remove_old_numbered_files(const fs::path& out) {
    std::error_code ec;
    for (const fs::directory_entry& e : fs::directory_iterator(out, ec)) {
        const std::string name = e.path().filename().string();
        const std::string snapshot = protocol::snapshot_pattern(name), page = protocol::page_pattern(name);
        if ((snapshot == name && page == name) || !e.is_regular_file()) continue;
        for (const protocol::OutputKind& o : protocol::output_registry())
            for (const protocol::OutputFile& f : o.files)
                if (f.name == snapshot || f.name == page) fs::remove(e.path(), ec);
    }
}

// Where a method's saved state and its finished result live (bake/method_state.h).
fs::path resume_dir(const fs::path& out) { return out / protocol::kResumeDir; }
fs::path state_path(const fs::path& out, const std::string& output) { return resume_dir(out) / (output + ".state"); }
fs::path finished_path(const fs::path& out, const std::string& output) {
    return resume_dir(out) / (output + ".done.json");
}

// What a saved state of `output` must match to be restored: the output's
// canonical settings, the atlas's (when the job has one), the seed, the
// environment (a map's texels, not only its name) and the scene's content
// (Scene::content_hash: the file and every buffer and image it names). Each of them changes the sums a pass
// adds to. Not the method's description: counts the GPU makes there (texels
// moved out of geometry) may differ by a few from one device to another;
// which texel, vertex or probe each entry is, is the state's layout hash,
// which restore() checks.
std::string state_key(const BakeJob& job, const PreparedScene& prepared, const std::string& output) {
    const Scene& scene = prepared.scene;
    const nlohmann::json settings = protocol::to_json(job.settings);
    char content[17];
    std::snprintf(content, sizeof content, "%016llx", static_cast<unsigned long long>(scene.content_hash));
    nlohmann::json key = {{"output", output},
                          {"settings", settings["outputs"][output]},
                          {"seed", settings["seed"]},
                          {"env", settings.value("env", nlohmann::json())},
                          {"scene", content}};
    if (job.settings.uses_atlas()) key["atlas"] = settings["atlas"];
    if (prepared.environment && !prepared.environment->is_constant()) {
        std::snprintf(content, sizeof content, "%016llx",
                      static_cast<unsigned long long>(hash_vector(prepared.environment->texels)));
        key["env_content"] = content;
    }
    return key.dump();
}

// Where one output of the job starts: from pass 0, from a saved state, or
// already finished by an earlier run.
struct ResumePoint {
    PassStats stats;
    std::vector<std::string> snapshots;    // written by earlier runs
    std::optional<MethodResult> finished;  // the output was done: its files are there
};

// An output an earlier run finished: its result, if it is this bake's and its files are all there.
ResumePoint finished_output(const fs::path& out, const fs::path& path, const std::string& key) {
    std::ifstream in(path);
    const nlohmann::json done = nlohmann::json::parse(in, nullptr, false);
    if (done.is_discarded() || !done.is_object() || done.value("key", "") != key)
        throw MethodStateMismatch(path.filename().string() + ": another bake's, or damaged");
    ResumePoint point;
    point.stats = protocol::progress_from_json(done["stats"]);
    point.snapshots = done.value("snapshots", std::vector<std::string>{});
    MethodResult result{done.value("files", std::vector<std::string>{}), done.value("manifest", nlohmann::json{}),
                        nullptr};
    for (const std::string& f : result.files)
        if (!fs::exists(out / f)) throw MethodStateMismatch(f + ", which it finished, is missing");
    if (result.files.empty()) throw MethodStateMismatch(path.filename().string() + ": names no file");
    point.finished = std::move(result);
    return point;
}

// Where `method` resumes from, restored into it if its saved state's key
// is `key`; recorded in the start event.
ResumePoint resume_point(const fs::path& out, ProgressiveMethod& method, const std::string& key,
                         protocol::StartEvent& started) {
    const std::string output = method.output();
    try {
        ResumePoint point;
        if (fs::exists(finished_path(out, output))) {
            point = finished_output(out, finished_path(out, output), key);
        } else if (fs::exists(state_path(out, output))) {
            MethodState state = read_method_state(state_path(out, output));
            if (state.key != key)
                throw MethodStateMismatch(state_path(out, output).filename().string() +
                                          " is another bake's (its settings, seed, environment or scene differ)");
            method.restore(state);
            point.stats = state.stats;
            point.snapshots = std::move(state.files);
        } else {
            throw MethodStateMismatch("no state was saved (the earlier run stopped before its first snapshot)");
        }
        started.resumed[output] = point.stats;
        return point;
    } catch (const MethodStateMismatch& e) {
        started.not_resumed[output] = e.what();
        return {};
    }
}

// The snapshot's write, then the method's state beside it (naming every
// snapshot so far), on the writer thread: a run resumed from it starts after
// that snapshot's pass.
// The snapshot files in `names` of passes older than the newest `keep`
// passes there (`--keep-snapshots`; keep 0: none), in their order.
std::vector<std::string> snapshots_past(const std::vector<std::string>& names, int keep) {
    const auto pass_of = [](const std::string& name) {
        const size_t at = name.find(".pass-");
        return at == std::string::npos ? -1 : std::atoi(name.c_str() + at + 6);
    };
    std::set<int> passes;
    for (const std::string& name : names) passes.insert(pass_of(name));
    if (keep <= 0 || int(passes.size()) <= keep) return {};
    const int oldest_kept = *std::next(passes.rbegin(), keep - 1);
    std::vector<std::string> past;
    for (const std::string& name : names)
        if (pass_of(name) < oldest_kept) past.push_back(name);
    return past;
}

// `names` without the entries of `gone`.
void remove_names(std::vector<std::string>& names, const std::vector<std::string>& gone) {
    names.erase(
        std::remove_if(names.begin(), names.end(),
                       [&](const std::string& n) { return std::find(gone.begin(), gone.end(), n) != gone.end(); }),
        names.end());
}

// The snapshot's write, then what resuming needs saved with it: the method
// state, naming the snapshots kept (older ones beyond `keep` removed first).
SnapshotWrite with_state(SnapshotWrite write, std::shared_ptr<MethodState> state,
                         std::shared_ptr<std::vector<std::string>> snapshots, fs::path path, fs::path dir, int keep) {
    return [write = std::move(write), state = std::move(state), snapshots = std::move(snapshots),
            path = std::move(path), dir = std::move(dir), keep] {
        std::vector<std::string> names = write();
        snapshots->insert(snapshots->end(), names.begin(), names.end());
        const std::vector<std::string> past = snapshots_past(*snapshots, keep);
        for (const std::string& name : past) {
            std::error_code ignored;
            fs::remove(dir / name, ignored);
        }
        remove_names(*snapshots, past);
        state->files = *snapshots;
        write_method_state(path, *state);
        return names;
    };
}

// Runs one method through the progressive loop from `from`: progress after
// every pass; snapshots when the schedule says, read back here (with the
// method's state) after a batch of passes and built and written on the
// writer thread while the passes go on, announced once written (their names
// appended to `files`).
PassStats run_method(ProgressiveMethod& method, const std::string& key, const fs::path& out, const BakeEventSink& emit,
                     std::vector<std::string>& files, const ResumePoint& from, int keep_snapshots) {
    const std::string output = method.output();
    const Stopwatch clock;
    SnapshotSchedule schedule;
    SnapshotWriter writer;
    auto snapshots = std::make_shared<std::vector<std::string>>(from.snapshots);  // the writer thread's
    double read_seconds = 0.0;                                                    // of the snapshot being written
    const auto announce = [&](const std::vector<SnapshotWriter::Written>& written) {
        for (const SnapshotWriter::Written& w : written) {
            schedule.record_cost(read_seconds + w.seconds);
            for (const std::string& file : w.files) {
                files.push_back(file);
                emit(protocol::SnapshotEvent{output, file, w.pass});
            }
        }
        remove_names(files, snapshots_past(files, keep_snapshots));  // as the writer removed them
    };
    int taken = 0;  // the pass of the newest snapshot handed to the writer
    // The device holds the state after a batch's last pass: only there can a snapshot be read.
    const auto on_batch = [&](const std::vector<PassStats>& passes) {
        for (const PassStats& stats : passes) emit(protocol::ProgressEvent{output, stats});
        announce(writer.take_written());
        const PassStats& stats = passes.back();
        // Asked to stop (a cancelled job): one last snapshot of this pass,
        // whatever the schedule says, written and announced before the stop.
        const bool stop = stop_requested();
        if (stop ? taken != stats.pass : schedule.due(stats.pass, clock.seconds(), writer.idle())) {
            const Stopwatch read_clock;
            SnapshotWrite write = method.snapshot(out, stats);
            auto state = std::make_shared<MethodState>(method.state());
            state->key = key;
            read_seconds = read_clock.seconds();
            writer.submit(output, stats.pass,
                          with_state(std::move(write), state, snapshots, state_path(out, output), out, keep_snapshots));
            taken = stats.pass;
        }
        if (!stop) return;
        const std::vector<SnapshotWriter::Written> written = writer.drain();
        announce(written);
        std::vector<std::string> last;
        for (const SnapshotWriter::Written& w : written)
            if (w.pass == stats.pass) last = w.files;
        throw BakeStopped(output, stats.pass, last);
    };
    if (from.stats.pass > 0) emit(protocol::ProgressEvent{output, from.stats});
    const PassStats last = run_progressive(method, on_batch, from.stats, [&] { return schedule.next_pass(); });
    announce(writer.drain());
    return last;
}

// An output's result, kept until the job is done so that a resumed run
// reuses it rather than baking the output again.
void save_finished(const fs::path& out, const ProgressiveMethod& method, const std::string& key, const PassStats& stats,
                   const std::vector<std::string>& snapshots, const MethodResult& result) {
    const nlohmann::json done = {{"key", key},
                                 {"stats", protocol::to_json(stats)},
                                 {"snapshots", snapshots},
                                 {"files", result.files},
                                 {"manifest", result.manifest}};
    make_directories(resume_dir(out));
    write_file_atomic(finished_path(out, method.output()), done.dump() + "\n");
}

// One output from where it resumes: its passes (unless an earlier run
// finished it) and its final files, added to `done`; returns its manifest section.
nlohmann::json bake_output(ProgressiveMethod& m, const std::string& key, const ResumePoint& from, const fs::path& out,
                           int keep_snapshots, const BakeEventSink& emit, protocol::DoneEvent& done,
                           std::shared_ptr<const FloatImage>& final_image) {
    std::vector<std::string> snapshots = from.snapshots;
    PassStats last = from.stats;
    std::optional<MethodResult> result = from.finished;
    if (result) {
        emit(protocol::ProgressEvent{m.output(), last});
    } else {
        last = run_method(m, key, out, emit, snapshots, from, keep_snapshots);
        result = m.finish(out, last);
        save_finished(out, m, key, last, snapshots, *result);
    }
    done.files.insert(done.files.end(), snapshots.begin(), snapshots.end());
    done.final_files[m.output()] = result->files.front();
    done.files.insert(done.files.end(), result->files.begin(), result->files.end());
    done.progress = last;
    final_image = std::move(result->image);
    return std::move(result->manifest);
}

// The final image of `output`: the one its method still held, else (an
// output an earlier run finished) read from its file.
FloatImage final_image(const fs::path& file, std::shared_ptr<const FloatImage> held) {
    return held ? *held : read_exr(file);
}

// scene.lit.glb from the final images of the outputs that have a place in
// it (protocol::OutputKind::lit_scene_slot): the lightmap's RGB
// (irradiance/pi) RGBM-encoded, the occlusion's R as 8 bits. Returns
// whether it was written (some output had a slot), and what it holds.
std::optional<std::string> write_lit_scene(const BakeJob& job, const PreparedScene& prepared, protocol::DoneEvent& done,
                                           const std::map<std::string, std::shared_ptr<const FloatImage>>& held) {
    const Scene& atlas_scene = *prepared.atlas_scene;
    std::optional<protocol::RgbmImage> lightmap;
    std::optional<GreyImage> occlusion;
    std::string holds;
    for (const protocol::OutputKind& o : protocol::output_registry()) {
        const auto file = done.final_files.find(o.name);
        if (o.lit_scene_slot.empty() || file == done.final_files.end()) continue;
        const FloatImage image = final_image(job.out / file->second, held.at(o.name));
        const std::vector<float>& r = image.at("R");
        if (o.lit_scene_slot == "lightmap") {
            const auto &g = image.at("G"), &b = image.at("B");
            std::vector<float> rgb(r.size() * 3);
            for (size_t i = 0; i < r.size(); ++i) {
                rgb[3 * i] = r[i];
                rgb[3 * i + 1] = g[i];
                rgb[3 * i + 2] = b[i];
            }
            lightmap = protocol::encode_rgbm(rgb, image.width, image.height);
            holds += ", the final lightmap (MOZ_lightmap, RGBM PNG; see README)";
            write_unlit_glb(job.scene, atlas_scene, unlit_look(prepared.texels, rgb), job.out / "scene.unlit.glb");
            done.files.push_back("scene.unlit.glb");
            // The atlas to look at, as the service's preview.png shows it.
            write_file_atomic(
                job.out / "preview.png",
                protocol::lightmap_preview_png(rgb, image.width, image.height, protocol::automatic_exposure(rgb)));
            done.files.push_back("preview.png");
        } else if (o.lit_scene_slot == "occlusion") {
            occlusion = GreyImage{image.width, image.height, std::vector<uint8_t>(r.size())};
            for (size_t i = 0; i < r.size(); ++i)
                occlusion->values[i] = uint8_t(std::lround(255.0f * std::clamp(r[i], 0.0f, 1.0f)));
            holds += ", the ambient occlusion (occlusionTexture on TEXCOORD_1)";
        }
    }
    if (holds.empty()) return std::nullopt;
    write_lit_glb(job.scene, atlas_scene, {lightmap ? &*lightmap : nullptr, occlusion ? &*occlusion : nullptr},
                  job.out / "scene.lit.glb");
    return "scene.lightmapped.glb with" + holds.substr(1);
}

}  // namespace

std::optional<Environment> read_environment(const protocol::EnvironmentSetting& env) {
    try {
        if (!env.map_file.empty()) return load_environment(env.map_file);
    } catch (const std::runtime_error& e) {
        throw BakeInputError(e.what());
    }
    if (!env.sky) return std::nullopt;
    char text[96];  // a sky's source reads as it was given: "R,G,B"
    std::snprintf(text, sizeof text, "%.9g,%.9g,%.9g", (*env.sky)[0], (*env.sky)[1], (*env.sky)[2]);
    return load_environment(text);
}

// What preparation will be made of, as far as it is known before loading.
PreparationSize preparation_size(const BakeJob& job) {
    PreparationSize size;
    std::error_code ec;
    size.scene_bytes = fs::file_size(job.scene, ec);
    if (job.scene.extension() == ".gltf")  // and its buffers beside it
        for (const auto& entry : fs::directory_iterator(job.scene.parent_path(), ec))
            if (entry.path().extension() == ".bin") size.scene_bytes += entry.file_size(ec);
    size.atlas = job.settings.uses_atlas();
    size.outputs = int(job.settings.outputs.size());
    return size;
}

// Sample points per texel over subsamples²: the texels along chart edges
// take more (the shared scenes: 1.0 for the Cornell box's and the monkey's
// large charts, 2.1-2.2 for the staircase's and the spheres' small ones).
constexpr double kSamplePointsPerSubsample = 1.6;

// A "prepare" event as each stage begins, with preparation's time left from
// the sizes known by then.
std::function<void(const PreparedScene&, const std::string&)> prepare_events(const BakeJob& job,
                                                                             const BakeEventSink& emit,
                                                                             Stopwatch clock) {
    auto estimate = std::make_shared<PreparationEstimate>(preparation_size(job));
    return [=, &job](const PreparedScene& p, const std::string& stage) {
        if (p.scene.triangle_count() > 0 && !estimate->knows_triangles()) {  // once, after loading
            uint64_t double_sided = 0;
            for (uint32_t material : p.scene.triangle_material)
                double_sided += material < p.scene.materials.size() && p.scene.materials[material].double_sided;
            const bool see_through = std::any_of(p.scene.materials.begin(), p.scene.materials.end(),
                                                 [](const Material& m) { return m.is_see_through(); });
            estimate->set_triangles(p.scene.triangle_count(), double_sided, see_through);
        }
        if (!p.texels.samples.empty()) estimate->set_sample_points(p.texels.samples.size());
        else if (p.atlas.width > 0) {  // made, not yet sampled: its covered share, subsamples² a texel and more
            const int sub = job.settings.atlas.subsamples;
            estimate->set_sample_points(uint64_t(double(p.atlas.width) * p.atlas.height * p.atlas.utilisation *
                                                 kSamplePointsPerSubsample * sub * sub));
        }
        const double elapsed = clock.seconds();
        emit(protocol::PrepareEvent{stage, elapsed, estimate->seconds_left(stage, elapsed)});
    };
}

// The start event: the device, what each method bakes (and the rays of one
// of its passes, for the job's ETA), preparation's time and warnings.
protocol::StartEvent start_event(const PreparedScene& prepared,
                                 const std::vector<std::unique_ptr<ProgressiveMethod>>& methods) {
    protocol::StartEvent started;
    started.vendor = prepared.gpu->info().vendor;
    started.renderer = prepared.gpu->info().renderer;
    started.triangles = prepared.scene.triangle_count();
    started.prepare_seconds = prepared.prepare_seconds;
    started.warnings = prepared.warnings;
    for (const auto& m : methods) {
        started.outputs[m->output()] = m->description();
        started.outputs[m->output()]["rays_per_pass"] = m->rays_per_pass();
    }
    return started;
}

// manifest.json's first part: the scene, the device, the settings and what
// preparation did (its "outputs" are filled in as they bake).
nlohmann::json manifest_of_preparation(const BakeJob& job, const PreparedScene& prepared) {
    nlohmann::json manifest = {
        {"scene", job.scene.filename().string()},
        {"device", {{"vendor", prepared.gpu->info().vendor}, {"renderer", prepared.gpu->info().renderer}}},
        {"settings", protocol::to_json(job.settings)},
        // One load, one atlas, one context, one BVH for every output.
        {"prepared",
         {{"seconds", prepared.prepare_seconds},
          {"outputs", nlohmann::json::array()},
          {"triangles", prepared.scene.triangle_count()},
          {"atlas_generated", prepared.atlas.generated},
          {"double_sided_charts_turned", prepared.turned.charts},
          {"double_sided_triangles_turned", prepared.turned.triangles},
          {"double_sided_rays", prepared.turned.rays},
          {"unlit_charts", prepared.atlas.unlit_charts},
          {"glass_charts", prepared.glass_charts},
          {"unlit_chart_rays", prepared.unlit_chart_rays},
          {"light_density_rays", prepared.light_density_rays}}},
    };
    for (const auto& [stage, seconds] : prepared.stage_seconds) manifest["prepared"]["stages"][stage] = seconds;
    if (!prepared.warnings.empty()) manifest["warnings"] = prepared.warnings;
    return manifest;
}

protocol::DoneEvent run_bake_job(const BakeJob& job, const BakeEventSink& to_caller) {
    EventHeartbeat heartbeat(to_caller);
    const BakeEventSink emit = heartbeat.sink();
    const Stopwatch clock;
    make_directories(job.out);
    const std::unique_ptr<PreparedScene> prepared = prepare(job, prepare_events(job, emit, clock));
    std::vector<std::unique_ptr<ProgressiveMethod>> methods =
        prepared->timed("methods", [&] { return methods_that_fit(*prepared, job); });
    prepared->prepare_seconds = clock.seconds();

    protocol::StartEvent started = start_event(*prepared, methods);
    // Each output from where an interrupted run of this job left it; a
    // fresh run first drops any state an older run left behind.
    std::vector<std::string> keys;
    for (const auto& m : methods) keys.push_back(state_key(job, *prepared, m->output()));
    std::vector<ResumePoint> resumed(methods.size());
    if (job.resume) {
        for (size_t i = 0; i < methods.size(); ++i) resumed[i] = resume_point(job.out, *methods[i], keys[i], started);
    } else {
        fs::remove_all(resume_dir(job.out));
        remove_old_numbered_files(job.out);
    }
    emit(started);
    // The geometry a viewer needs to show the lightmap's snapshots on the
    // scene (the status page's 3D view), there before the first snapshot.
    // Its lights leave it when the job bakes the lightmap, which holds their
    // direct light (a light counts once; its viewer would add them again).
    if (prepared->atlas_scene) {
        const bool lights_baked = std::any_of(protocol::output_registry().begin(), protocol::output_registry().end(),
                                              [&](const protocol::OutputKind& o) {
                                                  return o.lit_scene_slot == "lightmap" && job.settings.output(o.name);
                                              });
        write_lightmapped_glb(job.scene, *prepared->atlas_scene, job.out / "scene.lightmapped.glb", lights_baked);
    }

    protocol::DoneEvent done;
    nlohmann::json manifest = manifest_of_preparation(job, *prepared);
    std::map<std::string, std::shared_ptr<const FloatImage>> final_images;  // by output
    // From here a stop request (SIGTERM) ends the bake after a last snapshot
    // (before, there is nothing to save: the worker exits at once).
    const StopPoint stop_point;
    for (size_t i = 0; i < methods.size(); ++i) {
        manifest["prepared"]["outputs"].push_back(methods[i]->output());
        manifest[methods[i]->output()] =
            bake_output(*methods[i], keys[i], resumed[i], job.out, job.settings.keep_snapshots, emit, done,
                        final_images[methods[i]->output()]);
    }
    std::optional<std::string> lit_scene;
    if (prepared->atlas_scene) {
        done.files.push_back("scene.lightmapped.glb");
        lit_scene = write_lit_scene(job, *prepared, done, final_images);
        if (lit_scene) done.files.push_back("scene.lit.glb");
    }
    done.files.push_back("manifest.json");
    manifest["files"] = describe_files(done.files, manifest);
    manifest["files"]["manifest.json"] = "this file; its \"settings\" are a spec for `lightfarm bake --spec`";
    if (prepared->atlas_scene)
        manifest["files"]["scene.lightmapped.glb"] = "the input scene with TEXCOORD_1 = the lightmap's UVs";
    if (lit_scene) manifest["files"]["scene.lit.glb"] = *lit_scene;
    if (manifest["files"].contains("preview.png"))
        manifest["files"]["preview.png"] =
            "the final lightmap to look at as an atlas: tone-mapped 8-bit sRGB at the "
            "automatic exposure, as the service's GET /v1/jobs/{id}/preview.png shows it";
    if (manifest["files"].contains("scene.unlit.glb"))
        manifest["files"]["scene.unlit.glb"] =
            "the lit scene for any glTF viewer: each material unlit (KHR_materials_unlit), its base colour the light "
            "leaving each texel as lightfarm's 3D view shows it (sRGB, TEXCOORD_1; see README)";
    write_file_atomic(job.out / "manifest.json", manifest.dump(2) + "\n");
    fs::remove_all(resume_dir(job.out));  // the job is done: nothing to resume
    heartbeat.stop();
    to_caller(done);
    return done;
}

}  // namespace lf
