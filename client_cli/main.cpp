// lightfarm: the command-line tool. A thin layer over the gi library: each
// command parses its options, calls the library, prints the result.
#include "args.h"
#include "bake_help.h"
#include "bake_reporter.h"
#include "remote.h"

#include "atlas/atlas.h"
#include "bake/bake_job.h"
#include "bake/probe_bench.h"
#include "job_spec.h"
#include "job_status.h"
#include "sh/sh_glb.h"
#include "gpu/context.h"
#include "probes/probe_eval.h"
#include "io/output_comparison.h"
#include "io/write_error.h"
#include "scene/gltf_loader.h"
#include "scene/scene_summary.h"
#include "trace/raybench.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <set>

#include <signal.h>
#include <unistd.h>

namespace {

using lf::cli::Args;
using lf::cli::UsageError;

constexpr const char* kUsage = R"(usage: lightfarm COMMAND [options]

commands:
  inspect SCENE [--json]             what was loaded from a .gltf/.glb
  raybench SCENE [--device auto|gpu|cpu] [--seconds S]
                                     ray throughput of the tracer (JSON)
  bake SCENE --out DIR [--spec SPEC.json] [--OUTPUT …] [--device auto|gpu|gpu:N|cpu] [--json]
       [--resume] [bake settings: `lightfarm bake --help`, or the README's table]
                                     bake the outputs asked for (`lightfarm bake --help`
                                     lists them; without one, the lightmap)
  bake SCENE --plan [--json] [bake settings]
                                     the atlas that bake would make, without baking
  sh-shade TRANSFER ENV --out shaded.glb [--scene SCENE] [--sh-window W]
                                     vertex colours = SH transfer x environment
  devices [--json]                   the EGL devices (GPUs, llvmpipe) a bake can use
  compare BAKE.exr REFERENCE.exr [--mask MASK.pfm|.exr] [--layer direct|indirect|raw] [--block N]
  compare TRANSFER.bin REFERENCE.bin error against a reference (JSON)
  compare BAKE_DIR REFERENCE_DIR [--layer L]
                                     two bakes of one scene, any atlases, at points of its surface
  probe-eval PROBES.json POINTS.json irradiance/pi at points from baked probes, four estimators (JSON)
  probebench SCENE [--at X,Y,Z] [--toward X,Y,Z] [--res-list 32,64,128,256] [--m-list 1,2,4,8]
       [--passes N] [--points N] [--seconds S] [--device auto|gpu|cpu]
                                     probes: capture time, evaluation throughput, error (JSON)
)";

std::string one_scene(const Args& args, const char* command) {
    if (args.positional().size() != 1) throw UsageError(std::string(command) + " takes exactly one SCENE argument");
    return args.positional()[0];
}

int inspect(int argc, char** argv) {
    Args args(argc, argv, 2, {}, {"--json"});
    // Sizes are checked from image headers; pixels are not decoded (an upload
    // check must not cost what a hostile image would make it cost).
    lf::LoadLimits limits;
    limits.decode_images = false;
    const lf::Scene scene = lf::load_scene(one_scene(args, "inspect"), limits);
    if (args.flag("--json")) {
        lf::protocol::SceneSummary summary = lf::summarize(scene);
        // What the service checks a job against before it runs: the smallest
        // atlas a generated one fits in.
        if (!summary.has_lightmap_uvs) summary.min_atlas_res = lf::smallest_atlas_resolution(scene);
        std::cout << lf::protocol::to_json(summary).dump(2) << "\n";
    } else std::cout << lf::format_summary(scene);
    return 0;
}

int raybench(int argc, char** argv) {
    Args args(argc, argv, 2, {"--device", "--seconds"}, {});
    const lf::Scene scene = lf::load_scene(one_scene(args, "raybench"));
    lf::GpuContext gpu(lf::parse_device_choice(args.get("--device", "auto")));
    lf::RaybenchOptions options;
    options.min_seconds = args.number("--seconds", options.min_seconds);
    std::cout << lf::run_raybench(gpu, scene, options).dump(2) << "\n";
    return 0;
}

glm::vec3 vector3(const Args& args, const std::string& key) {
    const std::vector<double> v = args.numbers(key, {});
    if (v.size() != 3) throw UsageError(key + " takes X,Y,Z");
    return glm::vec3(float(v[0]), float(v[1]), float(v[2]));
}

std::vector<int> integers(const Args& args, const std::string& key, const std::vector<int>& fallback) {
    std::vector<int> out;
    for (double v : args.numbers(key, std::vector<double>(fallback.begin(), fallback.end()))) {
        if (v != std::floor(v) || v < 1 || v > 4096)
            throw UsageError(key + ": " + std::to_string(v) + " is not a count");
        out.push_back(int(v));
    }
    return out;
}

int probebench(int argc, char** argv) {
    Args args(argc, argv, 2,
              {"--device", "--at", "--toward", "--res-list", "--m-list", "--passes", "--points", "--seconds"}, {});
    lf::GpuContext gpu(lf::parse_device_choice(args.get("--device", "auto")));
    const std::filesystem::path file = one_scene(args, "probebench");
    const lf::Scene scene = lf::load_scene(file);
    lf::ProbeBenchOptions options;
    if (args.has("--at")) options.at = vector3(args, "--at");
    if (args.has("--toward")) options.toward = vector3(args, "--toward");
    options.capture_resolutions = integers(args, "--res-list", options.capture_resolutions);
    options.ms = integers(args, "--m-list", options.ms);
    options.passes = integers(args, "--passes", {options.passes})[0];
    options.random_points = integers(args, "--points", {options.random_points})[0];
    options.min_seconds = args.number("--seconds", options.min_seconds);
    nlohmann::json out = lf::run_probe_bench(scene, options);
    out["scene"] = file.filename().string();
    out["device"] = {{"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer}};
    std::cout << out.dump(2) << "\n";
    return 0;
}

// What the service asks to size its worker pool: one worker per GPU.
int devices(int argc, char** argv) {
    Args args(argc, argv, 2, {}, {"--json"});
    const std::vector<lf::EglDeviceInfo> list = lf::list_egl_devices();
    int gpus = 0;
    nlohmann::json out = {{"devices", nlohmann::json::array()}};
    for (const lf::EglDeviceInfo& d : list) {
        out["devices"].push_back({{"software", d.software}, {"gpu_index", d.gpu_index}});
        gpus += d.software ? 0 : 1;
    }
    out["gpus"] = gpus;
    if (args.flag("--json")) {
        std::cout << out.dump() << "\n";
    } else {
        std::cout << gpus << " GPU(s)";
        for (const lf::EglDeviceInfo& d : list)
            std::cout << (d.software ? ", software (llvmpipe)" : ", gpu:" + std::to_string(d.gpu_index));
        std::cout << "\n";
    }
    return 0;
}

// The error of a bake against a reference, as JSON (gi/io/output_comparison.h).
int compare(int argc, char** argv) {
    Args args(argc, argv, 2, {"--mask", "--layer", "--block"}, {});
    if (args.positional().size() != 2)
        throw UsageError("compare takes BAKE and REFERENCE (.exr lightmaps, .bin SH transfer or bake folders)");
    lf::OutputComparisonOptions options;
    if (args.has("--mask")) options.mask = args.get("--mask");
    if (args.has("--layer")) options.layer = args.get("--layer");
    const double block = args.number("--block", 1.0);
    if (!(block >= 1.0 && block <= 4096.0 && block == std::floor(block)))
        throw UsageError("--block takes a whole number of texels from 1 to 4096, not " + args.get("--block"));
    options.block = int(block);
    std::cout << lf::compare_outputs(args.positional()[0], args.positional()[1], options).dump() << "\n";
    return 0;
}

// A --spec file that cannot be read whole (protocol::kExitSpecUnreadable):
// its writer's trouble, not its settings'.
struct SpecUnreadable : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// `--spec FILE`: a job spec (as the service stores it, or a manifest's "settings").
nlohmann::json read_spec_file(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) throw UsageError("--spec: cannot read " + path + " (no such file)");
    std::ifstream in(path);
    if (!in) throw SpecUnreadable("--spec: cannot read " + path);
    nlohmann::json spec = nlohmann::json::parse(in, nullptr, false);
    if (spec.is_discarded()) throw SpecUnreadable("--spec: " + path + " is not whole JSON (empty, or cut short)");
    if (!spec.is_object()) throw UsageError("--spec: " + path + " is not a JSON object");
    return spec;
}

// The job's settings: the spec file's, overridden by the flags, through the
// one catalog and the one validity rule (lf::protocol::parse_job_spec).
lf::protocol::BakeSettings bake_settings(const Args& args, const std::string& scene) {
    std::map<std::string, std::string> given;
    for (const auto& [flag, takes_value] : lf::protocol::bake_flags()) {
        if (takes_value && args.has(flag)) given[flag] = args.get(flag);
        if (!takes_value && args.flag(flag)) given[flag] = "";
    }
    try {
        nlohmann::json spec = lf::protocol::bake_json_from_flags(
            given, args.has("--spec") ? read_spec_file(args.get("--spec")) : nlohmann::json::object());
        spec["scene"] = scene;  // the file given here, whatever the spec names
        lf::protocol::SpecLimits no_caps;
        no_caps.caps.clear();
        return lf::protocol::parse_job_spec(spec, no_caps).bake;
    } catch (const lf::protocol::SpecError& e) {
        throw UsageError(std::string(args.has("--spec") ? "--spec " + args.get("--spec") + ": " : "") + e.what());
    }
}

// SIGTERM (lightfarmd cancelling the job, or anyone's kill) and SIGINT
// (Ctrl-C): once the passes run, one last snapshot of where the bake stands
// and its state saved, then exit kExitStopped; before, nothing to save: exit
// at once. A second signal ends it at once (SA_RESETHAND).
void on_stop_signal(int) {
    if (!lf::request_stop()) _exit(lf::protocol::kExitStopped);
}

void stop_on_signals() {
    struct sigaction action {};
    action.sa_handler = on_stop_signal;
    action.sa_flags = SA_RESETHAND | SA_RESTART;
    sigemptyset(&action.sa_mask);
    sigaction(SIGTERM, &action, nullptr);
    sigaction(SIGINT, &action, nullptr);
}

// The command that goes on from where a stopped bake stands: this one, with --resume.
std::string resume_command(int argc, char** argv) {
    std::string command = "lightfarm";
    bool resume = false;
    for (int i = 1; i < argc; ++i) {
        command += std::string(" ") + argv[i];
        resume = resume || std::string(argv[i]) == "--resume";
    }
    return resume ? command : command + " --resume";
}

// `bake --plan`: the atlas the bake would make, and its warnings, without baking.
int plan(const lf::BakeJob& job, bool json) {
    const nlohmann::json plan = lf::plan_bake_atlas(job);
    if (json) {
        std::cout << plan.dump(2) << "\n";
        return 0;
    }
    const nlohmann::json& a = plan["atlas"];
    const size_t few = a["unlit_charts"].get<size_t>();
    const int pages = a["pages"].get<int>();
    const std::string size = std::to_string(a["width"].get<int>()) + "x" + std::to_string(a["page_height"].get<int>());
    std::printf(
        "%s: %s, %.2f texels/m%s, %zu charts%s, border fraction %.3f, %.0f%% of its texels "
        "used; planned in %.1f s\n",
        plan["scene"].get<std::string>().c_str(),
        (pages == 1 ? "a " + size + " atlas" : std::to_string(pages) + " atlas pages of " + size).c_str(),
        a["texel_density"].get<double>(), a["density_from_scene"].get<bool>() ? " (from the scene)" : "",
        a["charts"].get<size_t>(),
        few ? (" (" + std::to_string(few) + " unlit or glass, at 1/8 of the density)").c_str() : "",
        a["border_fraction"].get<double>(), 100.0 * a["utilisation"].get<double>(), plan["seconds"].get<double>());
    for (const auto& w : plan["warnings"]) std::printf("warning: %s\n", w.get<std::string>().c_str());
    return 0;
}

int bake(int argc, char** argv) {
    std::set<std::string> valued = {"--out", "--device", "--spec"}, flags = {"--json", "--resume", "--plan"};
    for (const auto& [flag, takes_value] : lf::protocol::bake_flags()) (takes_value ? valued : flags).insert(flag);
    Args args(argc, argv, 2, valued, flags);
    lf::BakeJob job;
    job.scene = one_scene(args, "bake");
    job.device = lf::parse_device_choice(args.get("--device", "auto"));
    job.settings = bake_settings(args, job.scene.string());
    if (args.flag("--plan")) return plan(job, args.flag("--json"));
    if (!args.has("--out")) throw UsageError("bake needs --out DIR");
    job.out = args.get("--out");
    job.resume = args.flag("--resume");

    lf::cli::BakeReporter report(args.flag("--json"), job.settings);
    stop_on_signals();
    lf::protocol::DoneEvent done;
    try {
        done = lf::run_bake_job(job, std::ref(report));
    } catch (const lf::BakeStopped& e) {
        std::cerr << "\nlightfarm bake: " << e.what() << "\nlightfarm bake: its state is saved in " << job.out.string()
                  << "; to go on from " << e.output << "'s pass " << e.pass << ":\n  " << resume_command(argc, argv)
                  << "\n";
        return lf::protocol::kExitStopped;
    }
    if (!args.flag("--json")) {
        std::cout << "files in " << job.out.string() << ":";
        for (const std::string& f : done.files) std::cout << " " << f;
        std::cout << "\n";
    }
    return 0;
}

int sh_shade(int argc, char** argv) {
    Args args(argc, argv, 2, {"--out", "--scene", "--sh-window"}, {});
    if (args.positional().size() != 2) throw UsageError("sh-shade takes TRANSFER and ENV");
    if (!args.has("--out")) throw UsageError("sh-shade needs --out shaded.glb");
    lf::ShShadeOptions options;
    options.scene = args.get("--scene", "");
    options.window = lf::parse_sh_window(args.get("--sh-window", "none"));
    std::cout << lf::shade_sh_glb(args.positional()[0], args.positional()[1], args.get("--out"), options).dump(2)
              << "\n";
    return 0;
}

// Irradiance / pi at points (POINTS: [{"position": [x,y,z], "normal": [x,y,z]}, ...])
// from a baked probe set, by the four estimators of gi/probes/probe_eval.h.
int probe_eval(int argc, char** argv) {
    Args args(argc, argv, 2, {}, {});
    if (args.positional().size() != 2) throw UsageError("probe-eval takes PROBES.json and POINTS.json");
    nlohmann::json out;
    try {
        const lf::ProbeSet set = lf::read_probe_set(args.positional()[0]);
        const std::vector<lf::ShadingPoint> points = lf::read_shading_points(args.positional()[1]);
        out = lf::evaluate_at_points(set, points);
    } catch (const std::exception& e) {  // an unreadable or malformed input file
        std::cerr << "lightfarm probe-eval: error: " << e.what() << "\n";
        return lf::protocol::kExitInputError;
    }
    std::cout << out.dump(2) << "\n";
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "help") {
        std::cout << kUsage << lf::cli::kRemoteUsage;
        return argc < 2 ? 2 : 0;
    }
    const std::string command = argv[1];
    for (int i = 2; i < argc; ++i)
        if (std::string(argv[i]) == "--help") {  // every command answers --help
            // The command's own entry (every command has one); the whole usage for an unknown one.
            const std::string own =
                lf::cli::command_usage(lf::cli::is_remote_command(command) ? lf::cli::kRemoteUsage : kUsage, command);
            if (command == "bake") std::cout << lf::cli::bake_help();
            else std::cout << (own.empty() ? std::string(kUsage) : own);
            if (command == "submit") std::cout << "\n" << lf::cli::bake_settings_help();
            return 0;
        }
    try {
        if (lf::cli::is_remote_command(command)) return lf::cli::run_remote_command(command, argc, argv);
        if (command == "inspect") return inspect(argc, argv);
        if (command == "raybench") return raybench(argc, argv);
        if (command == "bake") return bake(argc, argv);
        if (command == "compare") return compare(argc, argv);
        if (command == "devices") return devices(argc, argv);
        if (command == "sh-shade") return sh_shade(argc, argv);
        if (command == "probe-eval") return probe_eval(argc, argv);
        if (command == "probebench") return probebench(argc, argv);
        throw UsageError("unknown command '" + command + "'");
    } catch (const std::invalid_argument& e) {  // a bad option value
        std::cerr << "lightfarm: " << e.what() << "\n";
        return lf::protocol::kExitUsage;
    } catch (const UsageError& e) {
        std::cerr << "lightfarm: " << e.what() << "\n(lightfarm --help lists the commands and options)\n";
        return lf::protocol::kExitUsage;
    } catch (const SpecUnreadable& e) {
        std::cerr << "lightfarm: " << e.what() << "\n";
        return lf::protocol::kExitSpecUnreadable;
    } catch (const lf::SceneError& e) {  // the file cannot be loaded: an input error, not a crash
        std::cerr << "lightfarm " << command << ": error: " << e.what() << "\n";
        return lf::protocol::kExitInputError;
    } catch (const lf::BakeInputError& e) {
        std::cerr << "lightfarm " << command << ": error: " << e.what() << "\n";
        return lf::protocol::kExitInputError;
    } catch (const lf::WriteError& e) {  // the disk's trouble, not the scene's
        std::cerr << "lightfarm " << command << ": error: " << e.what() << "\n";
        return lf::protocol::kExitMachineFault;
    } catch (const std::exception& e) {
        // One line, with the context the thrower put in (file, object, shader).
        std::cerr << "lightfarm " << command << ": error: " << e.what() << "\n";
        return 1;
    }
}
